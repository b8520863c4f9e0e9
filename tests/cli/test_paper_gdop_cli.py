"""``gdop_paper`` on ``stls --lag 3`` rows: the paper's STLS GDOP of the window that supplied the
epoch, checked against a computation from the printed WLS fixes with explicit inverses."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from gnss_cli.behavior.windows import windows
from gnss_cli.cli import simulate, solve
from gnss_cli.cli.exits import run_app

WINDOW = 15  # fixed sliding windows of 15 epochs, given on the command line


def _run(app: object, prog: str, args: list[object]) -> None:
    with pytest.raises(SystemExit) as exc:
        run_app(app, prog, [str(a) for a in args])  # type: ignore[arg-type]
    assert int(exc.value.code or 0) == 0


def _direct(wls_ecef_m: np.ndarray) -> float:
    """The formula on one window, with explicit matrices: shared kernel with its root at z = 1, lag 3,
    so r~ of degree 2 on the differences; H = [H_3(v_x) H_3(v_y) H_3(v_z)]. The shared structure's
    H H^T holds dot products of difference vectors, so the ECEF frame gives the ENU value."""
    v = np.diff(wls_ecef_m, axis=0)
    n = v.shape[0] - 2
    h = np.hstack([np.array([v[i : i + n, c] for i in range(3)]) for c in range(3)])  # (3, 3 n)
    s = np.linalg.svd(h, compute_uv=False)[-1]
    m = h[:2] @ h[:2].T
    k = np.linalg.inv(m - s**2 * np.eye(2))
    return float(np.sqrt(np.trace(k @ m @ k)))


def test_stls_lag3_rows_have_the_papers_stls_gdop(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    sim = tmp_path / "sim"
    _run(simulate.app, "gnss-simulate", ["--trajectory", "flight", "--duration", "40", "--interval", "1", "--systems", "G",
                                         "--seed", "3", "--errors", "noise", "--noise-sigma", "1", "--out-dir", sim,
                                         "--quiet"])
    out = tmp_path / "out"
    # behavior_pfa 0: no behavior test, so the windows are the fixed sliding ones computed below
    # (the spans the test chooses are checked in tests/pipeline/test_spans.py); integrity off: no
    # residual gate, so each window's kernel is that of its WLS fixes
    untested = tmp_path / "untested.toml"
    untested.write_text("[stls]\nbehavior_pfa = 0\n")
    _run(solve.app, "gnss-solve", [sim / "obs.rnx", sim / "nav.rnx", "--method", "wls,stls", "--lag", "3",
                                   "--window", str(WINDOW), "--iono", "none", "--tropo", "none", "--integrity", "off",
                                   "--config", untested, "--out-dir", out, "-q"])
    capsys.readouterr()
    pos = pd.read_csv(out / "positions.csv")
    assert "gdop_paper" in pd.read_csv(out / "dop.csv").columns
    wls = pos[pos["method"] == "wls"].reset_index(drop=True)
    stls = pos[pos["method"] == "stls"].reset_index(drop=True)
    assert (wls["status"] == "ok").all() and (stls["status"] == "ok").all() and len(stls) == 41
    assert wls["gdop_paper"].isna().all()  # empty on rows of other methods
    got = stls["gdop_paper"].to_numpy()
    assert np.all(np.isfinite(got)) and np.all(got > 0)
    x = wls[["x_m", "y_m", "z_m"]].to_numpy()
    bounds, owner = windows(len(wls), WINDOW)
    want = np.array([_direct(x[bounds[o][0] : bounds[o][1]]) for o in owner])
    # the CSV keeps 3 decimals of gdop_paper and 0.1 mm of the fixes
    np.testing.assert_allclose(got, want, rtol=1e-3, atol=6e-4)
    # one value per window: epochs supplied by the same window share it, and windows differ
    assert len(np.unique(got)) > 1
    # not the geometry DOP: a different quantity in another unit (1/m)
    assert not np.allclose(got, stls["gdop"].to_numpy(), rtol=0.05)
    summary = pd.read_csv(out / "summary.csv").set_index("method")
    assert summary.loc["stls", "mean_gdop_paper"] == pytest.approx(float(np.mean(got)), rel=1e-3, abs=1e-3)


def test_a_window_without_the_formula_says_so_in_its_record(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Lag 1 with the shared kernel (the fixed root z = 1 leaves nothing identified): the formula
    does not exist, so the cells are empty and every window's record in --model-out says why."""
    import json

    sim = tmp_path / "sim"
    _run(simulate.app, "gnss-simulate", ["--duration", "40", "--interval", "1", "--systems", "G", "--seed", "3",
                                         "--errors", "noise", "--out-dir", sim, "--quiet"])
    out, model = tmp_path / "p.csv", tmp_path / "m.json"
    _run(solve.app, "gnss-solve", [sim / "obs.rnx", sim / "nav.rnx", "--method", "wls,stls", "--lag", "1",
                                   "-o", out, "--model-out", model, "-q"])
    capsys.readouterr()
    pos = pd.read_csv(out)
    assert pos.loc[pos["method"] == "stls", "gdop_paper"].isna().all()
    records = [w for w in json.loads(model.read_text())["windows"] if w["method"] == "stls"]
    assert records and all("no paper STLS GDOP" in w["message"] for w in records)
