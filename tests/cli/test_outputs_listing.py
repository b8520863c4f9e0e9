"""Outputs that say what they wrote: the closing ``wrote`` lines of gnss-solve and gnss-batch,
the command line and settings at the start of summary.csv and of the report, progress lines
that end at 100 %."""

from __future__ import annotations

import io
import re
import shlex
from pathlib import Path

import pandas as pd
import pytest

from gnss_cli.cli.exits import run_app
from gnss_cli.cli.progress import Progress
from gnss_cli.plots import RUN_FIGURES

SAMPLE = Path(__file__).resolve().parents[2] / "sample_rinex" / "static"
FILES = [SAMPLE / "obs.rnx", SAMPLE / "nav.rnx"]


def invoke(args, capsys, prog="gnss-solve"):  # type: ignore[no-untyped-def]
    if prog == "gnss-solve":
        from gnss_cli.cli.solve import app
    else:
        from gnss_cli.cli.batch import app
    with pytest.raises(SystemExit) as exc:
        run_app(app, prog, [str(a) for a in args])
    out, err = capsys.readouterr()
    return exc.value.code, out, err


def _wrote(err: str, prog: str = "gnss-solve") -> dict[str, str]:
    return dict(re.findall(rf"^{prog}: wrote (.+?) \((.+)\)$", err, flags=re.M))


def test_out_dir_run_lists_every_file_with_its_rows(tmp_path, capsys) -> None:  # type: ignore[no-untyped-def]
    out = tmp_path / "o"
    code, stdout, err = invoke([*FILES, "--method", "ls,wls", "--reference-csv", SAMPLE / "truth.csv", "--out-dir", out], capsys)
    assert code == 0, err
    wrote = _wrote(err)
    assert set(wrote) == {str(p) for p in out.iterdir()}
    for name in ("positions", "errors", "dop", "satellites"):
        rows = len(pd.read_csv(out / f"{name}.csv"))
        assert wrote[str(out / f"{name}.csv")].startswith(f"{rows} rows"), name
    assert wrote[str(out / "positions.csv")] == "242 rows: ls, wls"
    assert wrote[str(out / "summary.csv")] == "2 rows, one per method"
    lines = err.strip().splitlines()
    assert all(line.startswith("gnss-solve: wrote ") for line in lines[-5:])  # the run ends with the listing


def test_pos_with_several_methods_says_one_file_per_method(tmp_path, capsys) -> None:  # type: ignore[no-untyped-def]
    base = tmp_path / "b.pos"
    code, _, err = invoke([*FILES, "--method", "ls,wls", "-o", base], capsys)
    assert code == 0, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["b.ls.pos", "b.wls.pos"]
    wrote = _wrote(err)
    assert wrote == {str(tmp_path / "b.ls.pos"): "121 epochs of ls", str(tmp_path / "b.wls.pos"): "121 epochs of wls"}
    assert f"gnss-solve: pos holds one method: 2 files, one per method (b.ls.pos, b.wls.pos); {base} itself is not written" in err


def test_quiet_and_stdout_list_nothing(tmp_path, capsys) -> None:  # type: ignore[no-untyped-def]
    code, _, err = invoke([*FILES, "--method", "wls", "--out-dir", tmp_path / "q", "-q"], capsys)
    assert code == 0 and err == ""
    code, out, err = invoke([*FILES, "--method", "wls"], capsys)
    assert code == 0 and out and "wrote" not in err


def test_summary_starts_with_the_command_and_the_settings(tmp_path, capsys) -> None:  # type: ignore[no-untyped-def]
    out = tmp_path / "with space"
    args = [*FILES, "--method", "ls,wls", "--elevation-mask", "12.5", "--reference", "geodetic:55.5,8.5,50", "--out-dir", out]
    code, _, err = invoke(args, capsys)
    assert code == 0, err
    summary = pd.read_csv(out / "summary.csv")  # no options needed
    assert list(summary.columns[:3]) == ["command", "settings", "method"]
    assert summary["command"].nunique() == 1 and summary["settings"].nunique() == 1
    assert shlex.split(summary["command"].iloc[0]) == ["gnss-solve", *map(str, args)]
    settings = dict(kv.split("=", 1) for kv in summary["settings"].iloc[0].split("; "))
    assert settings["methods"] == "ls,wls" and settings["elevation_mask_deg"] == "12.5"
    assert settings["reference"] == "geodetic:55.5,8.5,50" and settings["systems"] == "G,E"
    assert settings["levels"] == ("risk 0.001, prior satellite 0.001, prior constellation 0.0001, faults at once 1, "
                                  "nominal bias 4 C/N0 sigmas, alert limits inf/inf m")
    assert settings["nlos"] == "off"
    assert list(summary["method"]) == ["ls", "wls"]


def test_report_records_the_command_before_the_summary(tmp_path, capsys) -> None:  # type: ignore[no-untyped-def]
    pytest.importorskip("matplotlib")
    page_path = tmp_path / "r.html"
    code, _, err = invoke([*FILES, "--method", "ls,wls", "--report", page_path, "-o", tmp_path / "p.csv"], capsys)
    assert code == 0, err
    page = page_path.read_text()
    command = "gnss-solve " + " ".join(shlex.quote(str(a)) for a in [*FILES, "--method", "ls,wls", "--report", page_path,
                                                                       "-o", tmp_path / "p.csv"])
    assert page.index(command) < page.index("<h2>Summary</h2>")
    assert _wrote(err)[str(page_path)] == f"HTML report, {len(RUN_FIGURES)} figures"
    # the figures stage ends its progress at 100 % (stderr is not a terminal here)
    stages = re.findall(r"^gnss-solve: \[ *[\d.]+ s\] figures +([\d.]+) %$", err, flags=re.M)
    assert stages and stages[-1] == "100.0"


def test_progress_line_of_an_unfinished_stage_gets_its_closing_line() -> None:
    stream = io.StringIO()
    progress = Progress("p", stream=stream, start_delay_s=0.0, min_gap_s=0.0, interval_s=100.0)
    progress("figures", 0.0)
    progress("figures", 0.5)
    progress("figures", 1.0)
    progress.done()
    progress.done()
    lines = stream.getvalue().splitlines()
    assert [line.split("]")[1].strip() for line in lines] == ["figures   0.0 %", "figures 100.0 %"]


def test_batch_lists_its_outputs_and_its_summary_starts_with_the_command(tmp_path, capsys) -> None:  # type: ignore[no-untyped-def]
    out = tmp_path / "res"
    args = [FILES[0], "--nav", FILES[1], "--method", "ls,wls", "--jobs", "1", "--out", out]
    code, _, err = invoke(args, capsys, "gnss-batch")
    assert code == 0, err
    wrote = _wrote(err, "gnss-batch")
    assert wrote == {str(out / "positions"): "Parquet dataset: 242 rows in 1 file, 1 station",
                     str(out / "files.csv"): "1 row, one per observation file",
                     str(out / "summary.csv"): "2 rows, one per file and method"}
    summary = pd.read_csv(out / "summary.csv")
    assert list(summary.columns[:4]) == ["command", "settings", "obs_path", "station"]
    assert shlex.split(summary["command"].iloc[0]) == ["gnss-batch", *map(str, args)]
