"""Reference options on the command line (gnss-solve and gnss-batch): the UrbanNav ground truth
used as it is, a geodetic --reference, and the warnings of a reference that matches few epochs."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import pandas as pd
import pymap3d
import pytest

from gnss_cli.cli.batch import app as batch_app
from gnss_cli.cli.exits import run_app
from gnss_cli.cli.solve import app

SAMPLE = Path(__file__).resolve().parents[2] / "sample_rinex" / "static"
FILES = [SAMPLE / "obs.rnx", SAMPLE / "nav.rnx"]


def invoke(args, capsys, application=app, prog="gnss-solve"):  # type: ignore[no-untyped-def]
    with pytest.raises(SystemExit) as exc:
        run_app(application, prog, [str(a) for a in args])
    out, err = capsys.readouterr()
    return exc.value.code, out, err


def test_tst2_ground_truth_as_is_equals_the_truth_converted_independently(rinex_dir, tmp_path, capsys) -> None:  # type: ignore[no-untyped-def]
    d = rinex_dir / "tst2-2020155-urban-static"
    truth = d / "groundTruth_TST.csv"
    files = [d / "2020_06_03_TST_03.obs.gz", d / "hksc155d.20n", "--method", "ls,wls", "--environment", "open"]
    code, _, err = invoke([*files, "--reference-csv", truth, "--out-dir", tmp_path / "as_is"], capsys)
    assert code == 0, err
    raw = np.loadtxt(truth, delimiter=",")
    # the independent route: GPS week of 2020-06-03 from the calendar, ECEF by pymap3d
    week = (np.datetime64("2020-06-03") - np.datetime64("1980-01-06")).astype(int) // 7
    x, y, z = pymap3d.geodetic2ecef(raw[:, 2], raw[:, 3], raw[:, 4])
    converted = tmp_path / "truth_ecef.csv"
    pd.DataFrame({"gps_week": week, "tow_s": raw[:, 1], "x_m": x, "y_m": y, "z_m": z}).to_csv(converted, index=False)
    code, _, err2 = invoke([*files, "--reference-csv", converted, "--out-dir", tmp_path / "converted"], capsys)
    assert code == 0, err2
    a, b = (pd.read_csv(tmp_path / k / "summary.csv") for k in ("as_is", "converted"))
    assert (a["epochs_with_reference"] > 0).all()
    pd.testing.assert_series_equal(a["epochs_with_reference"], b["epochs_with_reference"])
    np.testing.assert_allclose(a["rms_3d_m"], b["rms_3d_m"], rtol=0, atol=1e-4)
    # the truth covers 157 of 986 epochs: fewer than half of the solved ones
    n = int(a.loc[a["method"] == "wls", "epochs_with_reference"].iloc[0])
    solved = int(a["epochs_solved"].max())
    assert f"gnss-solve: warning: reference {truth} matches " in err and f" of the {solved} solved epochs" in err
    assert n < solved / 2


def test_geodetic_reference_equals_the_ecef_one(capsys) -> None:  # type: ignore[no-untyped-def]
    lat, lon, h = 55.5, 8.5, 50.0  # the simulated receiver
    ecef = ",".join(f"{v:.4f}" for v in pymap3d.geodetic2ecef(lat, lon, h))
    code, geo, err = invoke([*FILES, "-q", "--method", "wls", "--reference", f"geodetic:{lat},{lon},{h}"], capsys)
    assert code == 0, err
    code, xyz, err = invoke([*FILES, "-q", "--method", "wls", f"--reference={ecef}"], capsys)
    assert code == 0, err
    a, b = pd.read_csv(io.StringIO(geo)), pd.read_csv(io.StringIO(xyz))
    assert a["err_3d_m"].notna().all()
    np.testing.assert_allclose(a[["e_err_m", "n_err_m", "u_err_m"]], b[["e_err_m", "n_err_m", "u_err_m"]], rtol=0, atol=3e-4)  # 4-decimal cells


def test_lat_lon_height_without_prefix_exits_3_with_a_hint(capsys) -> None:  # type: ignore[no-untyped-def]
    code, _, err = invoke([*FILES, "--reference", "55.5,8.5,50"], capsys)
    assert code == 3
    assert err.strip().splitlines()[-1].startswith("gnss-solve: error: --reference: ") and "geodetic:LAT,LON,H" in err


def _shifted_truth(tmp_path: Path, keep: slice, days: int = 0) -> Path:
    df = pd.read_csv(SAMPLE / "truth.csv")
    df["time"] = (pd.to_datetime(df["time"]) + pd.Timedelta(days=days)).dt.strftime("%Y-%m-%dT%H:%M:%S.%f")
    out = tmp_path / "truth.csv"
    df.iloc[keep][["time", "x_m", "y_m", "z_m"]].to_csv(out, index=False)
    return out


def test_reference_matching_no_epoch_warns_and_keeps_the_dop_statistics(tmp_path, capsys) -> None:  # type: ignore[no-untyped-def]
    ref = _shifted_truth(tmp_path, slice(None), days=1)
    code, _, err = invoke([*FILES, "--method", "ls,wls", "--reference-csv", ref, "--out-dir", tmp_path / "o"], capsys)
    assert code == 0, err
    assert f"gnss-solve: warning: reference {ref} matches none of the 121 solved epochs" in err
    summary = pd.read_csv(tmp_path / "o" / "summary.csv")
    assert (summary["epochs_with_reference"] == 0).all() and summary["rms_3d_m"].isna().all()
    for d in ("gdop", "pdop", "hdop", "vdop", "tdop"):
        assert summary[f"mean_{d}"].notna().all() and (summary[f"mean_{d}"] > 0.0).all()
    # the same DOP statistics as without any reference
    code, _, err = invoke([*FILES, "--method", "ls,wls", "--out-dir", tmp_path / "none"], capsys)
    assert code == 0 and "warning: reference" not in err
    plain = pd.read_csv(tmp_path / "none" / "summary.csv")
    np.testing.assert_allclose(summary["mean_gdop"], plain["mean_gdop"], rtol=0, atol=1e-9)


def test_reference_matching_a_third_warns_with_counts(tmp_path, capsys) -> None:  # type: ignore[no-untyped-def]
    ref = _shifted_truth(tmp_path, slice(0, 40))
    code, _, err = invoke([*FILES, "--method", "wls", "--reference-csv", ref, "-o", tmp_path / "p.csv"], capsys)
    assert code == 0, err
    assert f"gnss-solve: warning: reference {ref} matches 40 of the 121 solved epochs" in err
    half = _shifted_truth(tmp_path, slice(0, 61))
    code, _, err = invoke([*FILES, "--method", "wls", "--reference-csv", half, "-o", tmp_path / "q.csv"], capsys)
    assert code == 0 and "warning: reference" not in err


def test_batch_takes_the_geodetic_reference_and_warns_in_files_csv(tmp_path, capsys) -> None:  # type: ignore[no-untyped-def]
    lat, lon, h = 55.5, 8.5, 50.0
    ecef = ",".join(f"{v:.4f}" for v in pymap3d.geodetic2ecef(lat, lon, h))
    rms = []
    for k, ref in enumerate((f"--reference=geodetic:{lat},{lon},{h}", f"--reference={ecef}")):
        code, _, err = invoke([FILES[0], "--nav", FILES[1], "--method", "wls", "--jobs", "1", ref, "--out", tmp_path / str(k), "-q"],
                              capsys, batch_app, "gnss-batch")
        assert code == 0, err
        rms.append(pd.read_csv(tmp_path / str(k) / "files.csv")["rms_3d_m"].iloc[0])
    assert np.isfinite(rms[0]) and abs(rms[0] - rms[1]) < 1e-4
    ref = _shifted_truth(tmp_path, slice(None), days=1)
    code, _, err = invoke([FILES[0], "--nav", FILES[1], "--method", "wls", "--jobs", "1", "--reference-csv", ref,
                           "--out", tmp_path / "none"], capsys, batch_app, "gnss-batch")
    assert code == 0, err
    files = pd.read_csv(tmp_path / "none" / "files.csv")
    assert "matches none of the 121 solved epochs" in files["warnings"].iloc[0]
    assert f"gnss-batch: warning: obs.rnx: reference {ref} matches none of the 121 solved epochs" in err
