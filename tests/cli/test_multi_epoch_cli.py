"""The multi-epoch methods on the command line, as the method vocabulary promises them: what ran
is written down, ``--measurements`` reaches every method, and the smoother keeps the numbers of the
model it was before it had its own name."""

from __future__ import annotations

import io
import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from gnss_cli.cli.exits import run_app
from gnss_cli.cli.solve import app

SAMPLE = Path(__file__).resolve().parents[2] / "sample_rinex" / "static"


def _run(args: list[object], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    with pytest.raises(SystemExit) as exc:
        run_app(app, "gnss-solve", [str(a) for a in args])
    out, err = capsys.readouterr()
    return int(exc.value.code or 0), out, err


def _yamatogawa(rinex_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str], *flags: str) -> tuple[pd.DataFrame, str]:
    d = rinex_dir / "yamatogawa-2010006-kinematic"
    out = tmp_path / "out"
    code, _, err = _run([d / "yamatogawa_rover.obs", d / "brdc0060.10n", "--reference-pos", d / "rtk_ref_rover.pos",
                         "--out-dir", out, *flags], capsys)
    assert code == 0, err
    return pd.read_csv(out / "errors.csv"), (out / "summary.csv").read_text()


def test_kf_with_phase_uses_the_phase_rows(rinex_dir: Path, tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    """Yamatogawa has L1 phase: with it the kf's track changes and improves horizontally (the phase
    ties the shape of the walk), and summary.csv says which measurements each run used."""
    errs, sums = {}, {}
    for kinds in ("pseudorange,doppler", "pseudorange,doppler,phase"):
        errors, summary = _yamatogawa(rinex_dir, tmp_path / kinds, capsys, "--method", "kf", "--measurements", kinds)
        row = pd.read_csv(io.StringIO(summary)).set_index("method").loc["kf"]
        assert row["measurements"] == kinds.replace(",", "+")
        errs[kinds] = errors[errors["method"] == "kf"]
        sums[kinds] = row
    h = {k: float(np.sqrt(np.mean(e["e_err_m"] ** 2 + e["n_err_m"] ** 2))) for k, e in errs.items()}
    assert h["pseudorange,doppler,phase"] < 0.6 * h["pseudorange,doppler"], h


def test_stls_chooses_its_spans_with_integrity_off(rinex_dir: Path, tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    """``--integrity off`` drops the residual gates, not stls's behavior test, which chooses its
    spans: on the Yamatogawa walk stls --lag 3 stays near its ``fde`` result (measured 0.91 against
    0.94 m horizontal RMS), where with the test off each whole segment was one lag-3 kernel (4.60 m)."""
    h = {}
    for integrity in ("fde", "off"):
        errors, _ = _yamatogawa(rinex_dir, tmp_path / integrity, capsys, "--method", "stls", "--lag", "3",
                                "--measurements", "pseudorange", "--integrity", integrity)
        e = errors[errors["method"] == "stls"]
        h[integrity] = float(np.sqrt(np.mean(e["e_err_m"] ** 2 + e["n_err_m"] ** 2)))
    assert h["off"] <= 1.25 * h["fde"], h


def test_smoother_keeps_the_former_default_numbers(rinex_dir: Path, tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    """``--method smoother`` (quadrature, lag 3, every measurement) is the former default
    ``stls --lag 3`` on a file with Doppler: Yamatogawa 2.487 m 3D RMS with phase (measured on the
    code before, with rnx2rtkp's weights: no C/N0 term), horizontal 0.368 m; since the smoother
    bridges missed epochs (the file's first step is two seconds: its first epoch had kept the WLS
    fix) 2.489 and 0.354 m. (With the NLOS detector on, its 76 exclusions from the WLS fixes:
    2.41 m and 0.45 m.)"""
    weights = tmp_path / "weights.toml"
    weights.write_text('[weights]\ncn0_model = "off"\n')
    errors, summary = _yamatogawa(rinex_dir, tmp_path, capsys, "--method", "smoother", "--config", str(weights))
    row = pd.read_csv(io.StringIO(summary)).set_index("method").loc["smoother"]
    assert row["measurements"] == "pseudorange+doppler+phase" and row["model"] == "motion quadrature"
    e = errors[errors["method"] == "smoother"]
    rms3 = float(np.sqrt(np.mean(e["err_3d_m"] ** 2)))
    rmsh = float(np.sqrt(np.mean(e["e_err_m"] ** 2 + e["n_err_m"] ** 2)))
    assert rms3 == pytest.approx(2.489, abs=0.005) and rmsh == pytest.approx(0.354, abs=0.005), (rms3, rmsh)


def test_what_ran_is_written_down(tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    """summary.csv, --model-out and the closing stderr lines name each method's estimator, model,
    lag, window, measurements and integrity; stls --lag 3 holds identified kernels."""
    out = tmp_path / "out"
    code, _, err = _run([SAMPLE / "obs.rnx", SAMPLE / "nav.rnx", "--method", "wls,stls,smoother,kf", "--lag", "3",
                         "--measurements", "pseudorange", "--out-dir", out, "--model-out", tmp_path / "m.json"], capsys)
    assert code == 0, err
    summary = pd.read_csv(out / "summary.csv").set_index("method")
    assert list(summary.columns[:8]) == ["command", "settings", "estimator", "model", "lag", "window", "measurements",
                                         "integrity"]
    assert summary.loc["stls", "estimator"] == "identified Hankel STLS (measurement domain, alternation)"
    assert summary.loc["stls", "window"] == "whole segments" and summary.loc["stls", "measurements"] == "pseudorange"
    assert summary.loc["smoother", "estimator"] == "fixed-model batch smoother"
    assert summary.loc["kf", "measurements"] == "pseudorange" and summary.loc["smoother", "measurements"] == "pseudorange"
    assert summary.loc["wls", "estimator"].startswith("weighted least squares")
    doc = json.loads((tmp_path / "m.json").read_text())
    assert set(doc["methods"]) == {"wls", "stls", "smoother", "kf"}
    stls = [w for w in doc["windows"] if w["method"] == "stls"]
    assert stls and all(w["model"] == "identified" and len(w["shared_coefficients"]) == 4 for w in stls)
    assert not all(np.allclose(w["shared_coefficients"], [-1, 3, -3, 1]) for w in stls)  # identified, not fixed
    assert [w["method"] for w in doc["windows"]].count("smoother") == 1
    for m in ("stls", "smoother", "kf"):
        assert any(line.startswith(f"gnss-solve: {m}: ") and summary.loc[m, "estimator"] in line
                   for line in err.splitlines()), err


def test_the_report_settings_name_what_each_method_ran() -> None:
    """The HTML report's settings table (``cli.figures.solve_settings``) has a line per method with
    its resolved estimator, model, measurements and integrity, as summary.csv."""
    from gnss_cli.cli.figures import solve_settings
    from gnss_cli.config import load_config
    from gnss_cli.pipeline import process

    cfg = load_config(None, {"methods": "wls,smoother", "measurements": "pseudorange"})
    result = process(SAMPLE / "obs.rnx", [SAMPLE / "nav.rnx"], cfg)
    settings = solve_settings([SAMPLE / "obs.rnx", SAMPLE / "nav.rnx"], cfg, result, "none")
    line = str(settings["method smoother"])
    assert line.startswith("fixed-model batch smoother") and "motion quadrature" in line and "pseudorange;" in line
    assert str(settings["method wls"]).startswith("weighted least squares")


def test_untested_whole_segments_are_warned_about(tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    """With ``[stls] behavior_pfa = 0`` nothing splits a whole segment where one lag-3 kernel does
    not hold (the default ``--window 0``): the run says so on stderr, as a warning, and still
    solves. ``--integrity off`` keeps the behavior test (it chooses the spans): no warning."""
    untested = tmp_path / "untested.toml"
    untested.write_text("[stls]\nbehavior_pfa = 0\n")
    code, _, err = _run([SAMPLE / "obs.rnx", SAMPLE / "nav.rnx", "--method", "stls", "--lag", "3", "--config", untested,
                         "-o", tmp_path / "p.csv"], capsys)
    assert code == 0, err
    warned = [line for line in err.splitlines() if line.startswith("gnss-solve: warning: stls --lag 3 --window 0")]
    assert len(warned) == 1 and "behavior_pfa = 0" in warned[0] and "--window N" in warned[0]
    assert (tmp_path / "p.csv").stat().st_size > 0
    assert "lag 3, whole segments, untested," in err  # the run's line says what ran
    code, _, err = _run([SAMPLE / "obs.rnx", SAMPLE / "nav.rnx", "--method", "stls", "--lag", "3", "--integrity", "off",
                         "-o", tmp_path / "q.csv"], capsys)
    assert code == 0, err
    assert "warning: stls" not in err


def test_measurements_the_file_lacks_are_warned_about(tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    """``--measurements`` naming the phase on a file without it (the sample: C1C D1C S1C): the run
    warns once, on stderr, which kinds the methods use instead, and summary.csv records them; asking
    only for what the file has gives no such warning."""
    out = tmp_path / "out"
    code, _, err = _run([SAMPLE / "obs.rnx", SAMPLE / "nav.rnx", "--method", "smoother,kf",
                         "--measurements", "pseudorange,doppler,phase", "--out-dir", out], capsys)
    assert code == 0, err
    warned = [line for line in err.splitlines() if line.startswith("gnss-solve: warning: --measurements")]
    assert warned == ["gnss-solve: warning: --measurements pseudorange,doppler,phase: the observation file has no "
                      "carrier phase; smoother, kf use pseudorange+doppler"], err
    summary = pd.read_csv(out / "summary.csv").set_index("method")
    assert set(summary.loc[["smoother", "kf"], "measurements"]) == {"pseudorange+doppler"}
    code, _, err = _run([SAMPLE / "obs.rnx", SAMPLE / "nav.rnx", "--method", "kf", "--measurements", "pseudorange,doppler",
                         "-o", tmp_path / "p.csv"], capsys)
    assert code == 0 and "--measurements" not in err, err
