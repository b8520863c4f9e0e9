"""``--help`` of the four commands as a user reads it: the panels, plain notation, the examples
(each one run, in order, in an empty folder), and ``-q`` keeping stderr empty."""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest
import typer

from gnss_cli.cli import batch, identify, simulate, solve

REPO = Path(__file__).resolve().parents[2]
SAMPLE = REPO / "sample_rinex" / "static"
APPS = {"gnss-simulate": simulate.app, "gnss-solve": solve.app, "gnss-identify": identify.app, "gnss-batch": batch.app}
"""The commands, in the order their examples run (each may read what an earlier one wrote)."""
MODULES = {name: f"gnss_cli.cli.{name.removeprefix('gnss-')}" for name in APPS}
PANELS = {
    "gnss-solve": ["Inputs", "Processing", "Multi-epoch", "Integrity", "Reference", "Output", "Run"],
    "gnss-batch": ["Inputs", "Processing", "Multi-epoch", "Integrity", "Reference", "Output", "Run"],
    "gnss-simulate": ["Scenario", "Errors", "Output", "Run"],
    "gnss-identify": ["Inputs", "Model", "Output", "Run"],
}
"""Every panel each command shows, in the order shown."""
ODD_NOTATION = {
    "a type in angle brackets (<str>, <list[Path]>)": r"<[A-Za-z_][\w\[\], ]*>",
    "a default in parentheses ([default: (wls)])": r"default: \(",
    "braces ({OBS NAV})": r"[{}]",
    "a repeated bracketed group (...]...)": r"\]\.\.\.",
    "a bracketed metavar in the usage line ([OBS ...])": r"^Usage: .*\[(?!OPTIONS\])",
}
OUTPUT_FLAGS = ("-o", "--output", "--out-dir", "--out", "--model-out")


def _run(command: str, args: list[str], cwd: Path, columns: int = 80) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "COLUMNS": str(columns)}
    return subprocess.run([sys.executable, "-m", MODULES[command], *args], cwd=cwd, env=env, capture_output=True,
                          text=True, timeout=600)


def _sections(text: str) -> dict[str, list[str]]:
    """Section title -> its lines (a title is an unindented line ending with a colon)."""
    out: dict[str, list[str]] = {}
    current = None
    for line in text.splitlines():
        if re.fullmatch(r"[A-Z][\w -]*:", line):
            current = line[:-1]
            out[current] = []
        elif current is not None:
            out[current].append(line)
    return out


def examples(help_text: str, command: str) -> list[list[str]]:
    """The command lines of the ``Examples:`` section of ``help_text`` (``\\`` continues a line)."""
    lines = "\n".join(_sections(help_text).get("Examples", [])).replace("\\\n", " ").splitlines()
    return [shlex.split(line)[1:] for line in lines if line.strip().startswith(command + " ")]


@pytest.mark.parametrize("columns", [80, 200])
@pytest.mark.parametrize("command", list(APPS))
def test_help_shows_every_panel_in_plain_notation(command: str, columns: int, tmp_path: Path) -> None:
    proc = _run(command, ["--help"], tmp_path, columns)
    assert proc.returncode == 0 and proc.stderr == ""
    text = proc.stdout
    for what, pattern in ODD_NOTATION.items():
        assert not re.search(pattern, text, re.M), (what, re.search(pattern, text, re.M))
    sections = _sections(text)
    assert [s for s in sections if s not in ("Examples",)] == PANELS[command]
    assert max(len(line) for line in text.splitlines()) <= 80
    # every option and argument is in exactly one panel, with the metavar it declares
    listed = [line.strip().split("  ")[0] for s in PANELS[command] for line in sections[s]
              if line.startswith("  ") and not line.startswith("   ")]
    params = [p for p in typer.main.get_command(APPS[command]).params if not getattr(p, "hidden", False)]
    assert len(listed) == len(params) + 1  # + -h, --help
    for p in params:
        if p.param_type_name == "argument":
            names = [n for n in listed if n == p.metavar]
        else:  # its flags and, for a value, the metavar it declares
            assert p.is_flag or p.metavar, f"{p.opts}: no metavar"
            want = {*p.opts, *p.secondary_opts} | (set() if p.is_flag else {p.metavar})
            names = [n for n in listed if set(re.split(r", | / | ", n)) == want]
        assert len(names) == 1, (p.name, listed)


def test_help_panels_hold_the_options_a_user_looks_for_there(tmp_path: Path) -> None:
    sections = _sections(_run("gnss-solve", ["--help"], tmp_path).stdout)
    where = {"Inputs": ["OBS NAV...", "--config FILE"], "Processing": ["-m, --method", "--systems", "--elevation-mask"],
             "Multi-epoch": ["--lag L", "--motion", "--kf-model"], "Integrity": ["--integrity MODE", "--robust"],
             "Reference": ["--reference-sinex FILE", "--reference-csv FILE"],
             "Output": ["-o, --output FILE", "--out-dir DIR", "--format"], "Run": ["--processes N", "-q, --quiet"]}
    for panel, names in where.items():
        for name in names:
            assert any(line.startswith(f"  {name}") for line in sections[panel]), (panel, name)
    usage = _run("gnss-solve", ["--help"], tmp_path).stdout.splitlines()[0]
    assert usage == "Usage: gnss-solve [OPTIONS] OBS NAV..."
    assert re.search(r"--method METHOD\[,METHOD\.\.\.\]\n +ls, wls.*\[default: wls\]", "\n".join(sections["Processing"]), re.S)


def test_examples_are_extracted_as_printed() -> None:
    text = ("Options:\n  gnss-solve not-an-example\n\nExamples:\n  Two lines:\n    gnss-solve a.rnx b.rnx -m ls \\\n"
            "        -o 'x y.csv'\n  Not this one:\n    gnss-batch x --out y\n")
    assert examples(text, "gnss-solve") == [["a.rnx", "b.rnx", "-m", "ls", "-o", "x y.csv"]]


@pytest.mark.parametrize("command", list(APPS))
def test_every_example_parses(command: str) -> None:
    """Click accepts every flag and value of every example (a renamed or removed flag fails here)."""
    click_command = typer.main.get_command(APPS[command])
    with click_command.make_context(command, ["--help"], resilient_parsing=True) as ctx:
        found = examples(click_command.get_help(ctx), command)
    assert len(found) >= (3 if command == "gnss-solve" else 1)
    for args in found:
        with click_command.make_context(command, list(args)) as ctx:
            assert ctx.params  # parsed


def _sample_station(folder: Path) -> None:
    """What the gnss-solve examples take from a station: ``site.rnx`` (the sample observations under
    the 4-character marker name SITE), ``nav.rnx`` and ``site.snx`` (SINEX with SITE's true position)."""
    header, body = SAMPLE.joinpath("obs.rnx").read_text().split("END OF HEADER", 1)
    header = re.sub(r"^.*MARKER NAME", f"{'SITE':<60}MARKER NAME", header, count=1, flags=re.M)
    folder.joinpath("site.rnx").write_text(header + "END OF HEADER" + body)
    folder.joinpath("nav.rnx").write_bytes(SAMPLE.joinpath("nav.rnx").read_bytes())
    x, y, z = pd.read_csv(SAMPLE / "truth.csv").loc[0, ["x_m", "y_m", "z_m"]]
    rows = [f" {i:5d} {t:6s} SITE  A    1 24:061:00000 m    2 {v:21.14e} 1.0e-03" for i, (t, v) in
            enumerate([("STAX", x), ("STAY", y), ("STAZ", z)], 1)]
    folder.joinpath("site.snx").write_text("%=SNX 2.02\n+SOLUTION/ESTIMATE\n*INDEX TYPE__ CODE PT SOLN\n"
                                           + "\n".join(rows) + "\n-SOLUTION/ESTIMATE\n%ENDSNX\n")


def test_every_example_runs(tmp_path: Path) -> None:
    """The examples of the four epilogs, run in one folder (simulate, solve, identify, batch): each
    exits 0 and writes the outputs it names."""
    _sample_station(tmp_path)
    ran = []
    for command in APPS:
        for args in examples(_run(command, ["--help"], tmp_path).stdout, command):
            proc = _run(command, args, tmp_path)
            assert proc.returncode == 0, (command, args, proc.stderr)
            outputs = [args[i + 1] for i, a in enumerate(args[:-1]) if a in OUTPUT_FLAGS]
            assert all((tmp_path / o).exists() for o in outputs), (command, args, outputs)
            ran.append(command)
    assert ran.count("gnss-solve") >= 3 and {"gnss-simulate", "gnss-identify", "gnss-batch"} <= set(ran)
    # the SINEX example: every epoch has SITE's position as reference (the sample's WLS: 2.5 m 3D RMS)
    summary = pd.read_csv(tmp_path / "site" / "summary.csv").set_index("method")
    assert (summary["epochs_with_reference"] == summary["epochs"]).all() and summary.loc["wls", "rms_3d_m"] < 5


def test_identify_example_fits_a_drawn_flight_too(tmp_path: Path) -> None:
    """The chain of the examples on ``--trajectory flight`` (a path drawn from --seed), where a
    full lag-3 kernel is singular: the gnss-identify example (``--structure shared``) still runs,
    and without it the error is one plain sentence saying what to try."""
    sim = _run("gnss-simulate", ["--trajectory", "flight", "--duration", "300", "--interval", "1", "--out-dir", "flight",
                                 "-q"], tmp_path)
    assert sim.returncode == 0, sim.stderr
    solve_args = next(a for a in examples(_run("gnss-solve", ["--help"], tmp_path).stdout, "gnss-solve")
                      if "flight.csv" in a)
    assert _run("gnss-solve", [*solve_args, "-q"], tmp_path).returncode == 0
    (identify_args,) = examples(_run("gnss-identify", ["--help"], tmp_path).stdout, "gnss-identify")
    proc = _run("gnss-identify", identify_args, tmp_path)
    assert proc.returncode == 0 and (tmp_path / "predicted.csv").is_file(), proc.stderr
    k = identify_args.index("--structure")
    full = _run("gnss-identify", [*identify_args[:k], *identify_args[k + 2:]], tmp_path)
    assert full.returncode == 5 and full.stderr.count("\n") == 1, full.stderr
    assert full.stderr.startswith("gnss-identify: error: stls: no full lag-3 kernel can be fitted to these 200 samples")
    assert full.stderr.endswith("; try --structure shared, a smaller --lag or a longer --train\n"), full.stderr


def test_quiet_runs_write_nothing_on_stderr(tmp_path: Path) -> None:
    obs, nav = str(SAMPLE / "obs.rnx"), str(SAMPLE / "nav.rnx")
    runs = {
        "gnss-simulate": ["--duration", "60", "--interval", "10", "--out-dir", "sim"],
        "gnss-solve": [obs, nav, "-o", "positions.csv"],
        "gnss-identify": ["positions.csv", "--lag", "2", "-o", "identified.csv"],
        "gnss-batch": [obs, "--nav", nav, "--out", "batch", "-j", "1"],
    }
    for command, args in runs.items():
        proc = _run(command, [*args, "-q"], tmp_path)
        assert proc.returncode == 0 and proc.stderr == "", (command, proc.stderr)
    for command in ("gnss-simulate", "gnss-identify"):  # without -q they do write a summary
        args = [a.replace("sim", "sim2").replace("identified", "identified2") for a in runs[command]]
        proc = _run(command, args, tmp_path)
        assert proc.returncode == 0 and proc.stderr.startswith(f"{command}: "), (command, proc.stderr)


def test_quiet_runs_still_report_errors(tmp_path: Path) -> None:
    """``-q`` silences progress and summaries, never the error: each command given a missing
    input exits 4 with a line naming it on stderr (gnss-batch: the file's line and the count)."""
    nav = str(SAMPLE / "nav.rnx")
    runs = {
        "gnss-simulate": ["--trajectory", "csv:nosuch.csv", "--out-dir", "sim"],
        "gnss-solve": ["nosuch.rnx", nav],
        "gnss-identify": ["nosuch.csv"],
        "gnss-batch": ["nosuch.rnx", "--nav", nav, "--out", "batch", "-j", "1"],
    }
    for command, args in runs.items():
        proc = _run(command, [*args, "-q"], tmp_path)
        assert proc.returncode == 4 and "nosuch" in proc.stderr, (command, proc.returncode, proc.stderr)
    lines = proc.stderr.splitlines()
    assert len(lines) == 2 and "nosuch.rnx: failed (exit 4)" in lines[0], lines
    assert lines[1].startswith("gnss-batch: 0 of 1 files solved, 1 failed"), lines


@pytest.mark.parametrize(("command", "typo", "offered", "retired"), [
    ("gnss-solve", "--mehtod", "(Possible options: --method)", "--model"),
    ("gnss-solve", "--modle", "--kf-model", "--model"),
    ("gnss-batch", "--smoothr", "", "--smoother"),
])
def test_a_misspelt_flag_is_never_offered_a_retired_spelling(command: str, typo: str, offered: str, retired: str,
                                                             tmp_path: Path) -> None:
    """Click suggests the close matches among the options; a retired spelling (hidden, it exits 2
    itself) is not among them, and the mistake stays a usage error."""
    proc = _run(command, [str(SAMPLE / "obs.rnx"), str(SAMPLE / "nav.rnx"), typo, "x"], tmp_path)
    assert proc.returncode == 2 and f"No such option: {typo}" in proc.stderr, proc.stderr
    assert offered in proc.stderr and not re.search(rf"[ (]{retired}\b", proc.stderr), proc.stderr


def test_docs_quote_the_help_as_printed(tmp_path: Path) -> None:
    """docs/cli.md's copy of ``gnss-solve --help`` is what the command prints at 80 columns."""
    doc = (REPO / "docs" / "cli.md").read_text()
    quoted = re.search(r"```text\n(Usage: gnss-solve .*?)```", doc, re.S)
    if quoted is None:
        pytest.skip("docs/cli.md quotes no gnss-solve --help")
    assert quoted.group(1) == _run("gnss-solve", ["--help"], tmp_path, 80).stdout
