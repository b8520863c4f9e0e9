"""``--format``, ``--time-system`` and ``--reference-pos`` on the command line: file names,
format inference from ``-o``, one file per method, UTC stamps, RTKLIB references."""

from __future__ import annotations

import io
import json
import subprocess
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from gnss_cli.cli.exits import run_app
from gnss_cli.cli.solve import _SUFFIXES, FORMAT_NAMES, app
from gnss_cli.formats import FORMATS, format_from_path

PEER_CONF = Path(__file__).resolve().parents[2].parent / "shared" / "peer" / "rnx2rtkp-spp.conf"


def invoke(args, capsys):  # type: ignore[no-untyped-def]
    with pytest.raises(SystemExit) as exc:
        run_app(app, "gnss-solve", [str(a) for a in args])
    out, err = capsys.readouterr()
    return exc.value.code, out, err


@pytest.fixture()
def d0759(rinex_dir):  # type: ignore[no-untyped-def]
    return [rinex_dir / "rtklib-0759" / "07590920.05o", rinex_dir / "rtklib-0759" / "07590920.05n"]


def test_the_command_line_knows_the_writers_formats_and_extensions() -> None:
    assert FORMAT_NAMES == FORMATS
    assert all(format_from_path(f"a{ext}") == fmt for ext, fmt in _SUFFIXES.items())
    assert format_from_path("a.txt") is None and format_from_path("-") is None


def test_format_from_the_output_extension_and_one_pos_file_per_method(d0759, tmp_path, capsys) -> None:  # type: ignore[no-untyped-def]
    code, out, err = invoke([*d0759, "-m", "ls,wls", "-q", "-o", tmp_path / "run.pos"], capsys)
    assert code == 0 and out == "", err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run.ls.pos", "run.wls.pos"]
    text = (tmp_path / "run.wls.pos").read_bytes()
    assert text.startswith(b"% program   : gnss-solve") and b"\r\n" in text and b"% method    : wls" in text
    code, _, err = invoke([*d0759, "-q", "-o", tmp_path / "one.parquet"], capsys)
    assert code == 0, err
    assert (tmp_path / "one.parquet").read_bytes()[:4] == b"PAR1"
    assert len(pd.read_parquet(tmp_path / "one.parquet")) == 120


def test_out_dir_names_the_positions_by_format_and_keeps_csv_tables(d0759, tmp_path, capsys) -> None:  # type: ignore[no-untyped-def]
    code, _, err = invoke([*d0759, "-m", "ls,wls", "-q", "--format", "nmea", "--out-dir", tmp_path / "o"], capsys)
    assert code == 0, err
    assert sorted(p.name for p in (tmp_path / "o").iterdir()) == ["dop.csv", "positions.ls.nmea", "positions.wls.nmea", "satellites.csv", "summary.csv"]
    summary = pd.read_csv(tmp_path / "o" / "summary.csv")
    assert {"mean_x_m", "mean_lat_deg", "scatter_e_m", "scatter_u_m"} <= set(summary.columns)
    code, _, err = invoke([*d0759, "-q", "--format", "geojson", "--out-dir", tmp_path / "g"], capsys)
    assert code == 0, err
    assert "positions.geojson" in {p.name for p in (tmp_path / "g").iterdir()}


def test_text_formats_on_stdout_and_utc_time_stamps(d0759, tmp_path, capsys) -> None:  # type: ignore[no-untyped-def]
    code, out, err = invoke([*d0759, "-q", "--format", "geojson", "--time-system", "utc"], capsys)
    assert code == 0, err
    doc = json.loads(out)
    first = next(f for f in doc["features"] if f["geometry"] and f["geometry"]["type"] == "Point")
    assert first["properties"]["time"] == "2005-04-01T23:59:47.000" and first["properties"]["time_system"] == "utc"
    code, out, _ = invoke([*d0759, "-q", "--time-system", "utc"], capsys)
    df = pd.read_csv(io.StringIO(out))
    assert df["time"].iloc[0] == "2005-04-01T23:59:47.000" and df["tow_s"].iloc[0] == 518400.0
    config = tmp_path / "utc.toml"
    config.write_text('[processing]\ntime_system = "utc"\n')
    code, out2, _ = invoke([*d0759, "-q", "--config", config], capsys)
    assert code == 0 and out2 == out
    code, out, _ = invoke([*d0759, "-q", "--format", "nmea", "--time-system", "utc"], capsys)
    assert out.startswith("$GPGGA,235947.00,")


def test_reference_pos_equals_the_same_reference_as_csv(rinex_dir, tmp_path, capsys) -> None:  # type: ignore[no-untyped-def]
    folder = rinex_dir / "yamatogawa-2010006-kinematic"
    ref_pos = folder / "rtk_ref_rover.pos"
    files = [folder / "yamatogawa_rover.obs", folder / "brdc0060.10n"]
    rows = [line.split() for line in ref_pos.read_text().splitlines() if line.strip() and not line.startswith("%")]
    t = pd.Timestamp("1980-01-06") + pd.to_timedelta([int(r[0]) * 604800 + float(r[1]) for r in rows], unit="s")
    csv = tmp_path / "ref.csv"
    pd.DataFrame({"time": t.strftime("%Y-%m-%dT%H:%M:%S.%f"), "x_m": [float(r[2]) for r in rows],
                  "y_m": [float(r[3]) for r in rows], "z_m": [float(r[4]) for r in rows]}).to_csv(csv, index=False)
    code, out_pos, err = invoke([*files, "-q", "--reference-pos", ref_pos], capsys)
    assert code == 0, err
    code, out_csv, _ = invoke([*files, "-q", "--reference-csv", csv], capsys)
    a, b = pd.read_csv(io.StringIO(out_pos)), pd.read_csv(io.StringIO(out_csv))
    assert a["err_3d_m"].notna().sum() > 150
    pd.testing.assert_frame_equal(a, b)
    # the same trajectory stamped in UTC (GPST - 15 s in 2010) gives the same errors
    utc = tmp_path / "ref_utc.pos"
    lines = ["%  UTC                       x-ecef(m)      y-ecef(m)      z-ecef(m)   Q  ns"]
    lines += [f"{(ti - pd.Timedelta(seconds=15)).strftime('%Y/%m/%d %H:%M:%S.%f')[:-3]} {r[2]} {r[3]} {r[4]} {r[5]} {r[6]}"
              for ti, r in zip(t, rows)]
    utc.write_text("\n".join(lines) + "\n")
    code, out_utc, err = invoke([*files, "-q", "--reference-pos", utc], capsys)
    assert code == 0, err
    pd.testing.assert_frame_equal(pd.read_csv(io.StringIO(out_utc)), a)


def test_reference_pos_in_lat_lon_height_from_rnx2rtkp(rnx2rtkp, d0759, tmp_path, capsys) -> None:  # type: ignore[no-untyped-def]
    """rnx2rtkp's own llh output in UTC as the reference: the errors equal those against its
    ECEF output in GPST to 1 mm."""
    conf = tmp_path / "llh.conf"
    conf.write_text(PEER_CONF.read_text().replace("out-solformat      =xyz", "out-solformat      =llh"))
    obs, nav = d0759
    llh, xyz = tmp_path / "llh.pos", tmp_path / "xyz.pos"
    subprocess.run([rnx2rtkp, "-k", str(conf), "-p", "0", "-t", "-u", "-o", str(llh), str(obs), str(nav)], check=True, capture_output=True)
    subprocess.run([rnx2rtkp, "-k", str(PEER_CONF), "-p", "0", "-e", "-o", str(xyz), str(obs), str(nav)], check=True, capture_output=True)
    assert "latitude(deg)" in llh.read_text() and "UTC" in llh.read_text()
    errors = []
    for ref in (llh, xyz):
        code, out, err = invoke([*d0759, "-q", "--reference-pos", ref], capsys)
        assert code == 0, err
        errors.append(pd.read_csv(io.StringIO(out))[["e_err_m", "n_err_m", "u_err_m"]].to_numpy())
    # rnx2rtkp stamps a solution at the receiver-clock-corrected time; on this file its stamps
    # stay within the 10 ms matching tolerance of the epochs, so every epoch matches
    both = np.isfinite(errors[0]).all(axis=1)
    assert (both == np.isfinite(errors[1]).all(axis=1)).all() and both.sum() == 120
    assert np.abs(errors[0][both] - errors[1][both]).max() < 1e-3
