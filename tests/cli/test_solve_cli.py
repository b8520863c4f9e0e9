"""gnss-solve's command-line contract: exit codes, one-line errors, no partial output, CSV shape."""

from __future__ import annotations

import io
import os
import re
import sys

import pandas as pd
import pytest

from gnss_cli.cli.exits import run_app
from gnss_cli.cli.solve import app
from gnss_cli.report import INTEGRITY_COLUMNS, POSITION_COLUMNS, SD_COLUMNS, VELOCITY_COLUMNS

REF_0759 = "-3976219.1879,3382371.6041,3652511.1428"


def invoke(args, capsys):
    with pytest.raises(SystemExit) as exc:
        run_app(app, "gnss-solve", [str(a) for a in args])
    out, err = capsys.readouterr()
    return exc.value.code, out, err


@pytest.fixture()
def d0759(rinex_dir):
    return rinex_dir / "rtklib-0759"


def test_csv_on_stdout_has_documented_header_and_a_row_per_epoch(d0759, capsys):
    code, out, err = invoke([d0759 / "07590920.05o", d0759 / "07590920.05n", "--method", "ls,wls", "--reference", REF_0759], capsys)
    assert code == 0, err
    df = pd.read_csv(io.StringIO(out))
    assert list(df.columns) == POSITION_COLUMNS + ["e_err_m", "n_err_m", "u_err_m", "err_3d_m"] + SD_COLUMNS + INTEGRITY_COLUMNS + VELOCITY_COLUMNS
    assert len(df) == 240 and set(df["method"]) == {"ls", "wls"}
    assert df[VELOCITY_COLUMNS].isna().all().all()  # no Doppler in this file: empty cells
    assert (df["status"] == "ok").all()
    assert df["time"].iloc[0] == "2005-04-02T00:00:00.000"
    assert "ls: 120/120 epochs solved" in err


def test_out_dir_writes_four_tables(d0759, tmp_path, capsys):
    code, out, _ = invoke([d0759 / "07590920.05o", d0759 / "07590920.05n", "--reference", REF_0759, "--out-dir", tmp_path / "o", "-q"], capsys)
    assert code == 0 and out == ""
    names = sorted(p.name for p in (tmp_path / "o").iterdir())
    assert names == ["dop.csv", "errors.csv", "positions.csv", "satellites.csv", "summary.csv"]
    summary = pd.read_csv(tmp_path / "o" / "summary.csv")
    assert summary.loc[0, "epochs_solved"] == 120 and summary.loc[0, "rms_3d_m"] < 1.93


def _bad_cases(rinex_dir):
    mal = sorted((rinex_dir / "malformed").iterdir())
    nav = rinex_dir / "rtklib-0759" / "07590920.05n"
    obs = rinex_dir / "rtklib-0759" / "07590920.05o"
    other_nav = rinex_dir / "yamatogawa-2010006-kinematic" / "brdc0060.10n"
    cases = [(f"malformed/{p.name}", [p, nav], p.name) for p in mal]
    cases += [
        ("missing path", [rinex_dir / "nope.05o", nav], "nope.05o"),
        ("nav given as obs", [nav, nav], "07590920.05n"),
        ("obs given as nav", [obs, obs], "07590920.05o"),
        ("no matching ephemeris", [obs, other_nav], "brdc0060.10n"),
    ]
    return cases


PROGRESS = re.compile(r"gnss-solve: \[ *\d+\.\d s\] ")


def test_bad_inputs_exit_4_with_one_line_and_no_output(rinex_dir, tmp_path, capsys):
    for label, args, name in _bad_cases(rinex_dir):
        target = tmp_path / f"{label.replace('/', '_')}.csv"
        code, out, err = invoke([*args, "-o", target], capsys)
        assert code == 4, (label, code, err)
        lines = [ln for ln in err.strip().splitlines() if not PROGRESS.match(ln)]
        assert len(lines) == 1 and lines[0].startswith("gnss-solve: error: ") and name in lines[0], (label, err)
        assert "Traceback" not in err
        assert out == "" and not target.exists(), label
    assert not any(p.name.startswith(".") for p in tmp_path.iterdir())  # no temporary leftovers


def test_usage_and_config_errors(d0759, tmp_path, capsys):
    obs, nav = d0759 / "07590920.05o", d0759 / "07590920.05n"
    code, _, err = invoke([obs], capsys)
    assert code == 2 and "NAV" in err
    code, _, err = invoke([obs, nav, "--method", "magic"], capsys)
    assert code == 3 and "magic" in err
    bad = tmp_path / "bad.toml"
    bad.write_text("[processing]\nelevation_mask_deg = 95\n")
    code, _, err = invoke([obs, nav, "--config", bad], capsys)
    assert code == 3 and "elevation_mask_deg" in err
    code, _, err = invoke([obs, nav, "--reference", "1,2"], capsys)
    assert code == 3 and "--reference" in err
    for text, word in (('[wtls]\ncolumn_scaling = "median"\n', "column_scaling"),
                       ('[processing]\nmethods = ["wtls"]\n[stls]\norbit_sigma_m = 0.0\n', "orbit_sigma_m"),
                       ('[wtls]\nscale = 1.0\n', "[wtls]")):
        bad.write_text(text)
        code, _, err = invoke([obs, nav, "--config", bad], capsys)
        assert code == 3 and word in err, (text, err)


def test_flags_override_config_file(d0759, tmp_path, capsys):
    cfg = tmp_path / "c.toml"
    cfg.write_text('[processing]\nmethods = ["ls"]\nelevation_mask_deg = 15.0\n')
    code, out, _ = invoke([d0759 / "07590920.05o", d0759 / "07590920.05n", "--config", cfg, "-q"], capsys)
    df15 = pd.read_csv(io.StringIO(out))
    assert code == 0 and set(df15["method"]) == {"ls"}
    code, out, _ = invoke([d0759 / "07590920.05o", d0759 / "07590920.05n", "--config", cfg, "--elevation-mask", "0", "-q"], capsys)
    df0 = pd.read_csv(io.StringIO(out))
    assert (df0["n_sat"] >= df15["n_sat"]).all() and (df0["n_sat"] > df15["n_sat"]).any()


def test_console_script_runs_as_module(d0759, tmp_path):
    import subprocess

    r = subprocess.run(
        [sys.executable, "-m", "gnss_cli.cli.solve", str(d0759 / "07590920.05o"), str(d0759 / "07590920.05n"), "-q"],
        capture_output=True, text=True, timeout=120, env={**os.environ, "PYTHONPATH": os.getcwd()},
    )
    assert r.returncode == 0 and r.stdout.startswith("time,gps_week,tow_s,method,")
