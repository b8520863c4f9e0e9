"""The identified Hankel STLS (``stls --lag L``): multi-epoch DOP, a simulated flight, real static
and kinematic data."""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from gnss_cli.behavior import KernelRepresentation
from gnss_cli.behavior.multi_epoch import behavior_basis, epoch_information, multi_epoch_cov
from gnss_cli.behavior.windows import segments, windows
from gnss_cli.cli.exits import run_app
from gnss_cli.cli.solve import app
from gnss_cli.config import ProcessingConfig, StlsConfig, load_config
from gnss_cli.gnss.frames import ecef2enu_rotation, ecef2geodetic
from gnss_cli.io.reference import reference_from_csv
from gnss_cli.pipeline import load_epochs, smooth, solve_method

RTKLIB_0759_ECEF_M = np.array([-3976219.1879, 3382371.6041, 3652511.1428])


def _simulate(out: Path, trajectory: str) -> Path:
    cmd = [sys.executable, "-m", "gnss_cli.cli.simulate", "--trajectory", trajectory, "--duration", "600",
           "--interval", "1", "--systems", "G", "--seed", "3", "--errors", "noise", "--noise-sigma", "1",
           "--out-dir", str(out)]
    subprocess.run(cmd, check=True, capture_output=True)
    return out


@pytest.fixture(scope="module")
def static_set(tmp_path_factory: pytest.TempPathFactory):  # type: ignore[no-untyped-def]
    d = _simulate(tmp_path_factory.mktemp("static"), "static")
    cfg = load_config(None, {"iono": "none", "tropo": "none", "methods": "ls,wls"})
    data = load_epochs(d / "obs.rnx", [d / "nav.rnx"], cfg)
    ref = np.asarray(reference_from_csv(d / "truth.csv", data.time_gps_s))
    return cfg, data, solve_method(data, "ls", cfg), solve_method(data, "wls", cfg), ref


@pytest.fixture(scope="module")
def flight_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return _simulate(tmp_path_factory.mktemp("flight"), "standard-flight")


def _smoothing(cfg: ProcessingConfig, **options: object) -> ProcessingConfig:
    return dataclasses.replace(cfg, stls=dataclasses.replace(StlsConfig(), **options))


def _rms_3d(x: np.ndarray, ref: np.ndarray) -> float:
    e = x - ref
    ok = np.all(np.isfinite(e), axis=1)
    return float(np.sqrt(np.mean(np.sum(e[ok] ** 2, axis=1))))


def _cli_positions(args: list[str]) -> dict[str, np.ndarray]:
    import io

    import pandas as pd

    res = CliRunner().invoke(app, [*args, "-q"])
    assert res.exit_code == 0, res.output
    df = pd.read_csv(io.StringIO(res.stdout))
    return {m: g for m, g in df.groupby("method")}


# ------------------------------------------------------------------ building blocks
def test_multi_epoch_cov_equals_dense_stacked_inverse() -> None:
    """The clock-eliminated formula equals the blocks of (G_N^T W G_N)^-1 built densely."""
    rng = np.random.default_rng(1)
    n_t, n_sv = 7, 6
    u = rng.normal(size=(n_t, n_sv, 3))
    p_m = -u / np.linalg.norm(u, axis=2, keepdims=True)
    wgt = rng.uniform(0.5, 2.0, size=(n_t, n_sv))

    info, h, cv = epoch_information(p_m, wgt)
    for ker in (KernelRepresentation.static(3), KernelRepresentation.pva(3),
                KernelRepresentation.shared(np.poly([1.0, 0.9, 0.8])[::-1], 3)):
        basis = behavior_basis(ker, n_t)
        assert np.allclose(ker.residual(basis[:, :, 0]), 0.0, atol=1e-9)
        k = basis.shape[2]
        g = np.zeros((n_t * n_sv, k + n_t))
        for t in range(n_t):
            g[t * n_sv:(t + 1) * n_sv, :k] = p_m[t] @ basis[t]
            g[t * n_sv:(t + 1) * n_sv, k + t] = 1.0
        q_x = np.linalg.inv(g.T @ (wgt.reshape(-1, 1) * g))
        got = multi_epoch_cov(basis, info, h, cv)
        for t in range(n_t):
            jac = np.zeros((4, k + n_t))
            jac[:3, :k] = basis[t]
            jac[3, k + t] = 1.0
            assert np.allclose(got[t], jac @ q_x @ jac.T, rtol=1e-9, atol=1e-12)


def test_multi_epoch_cov_with_one_clock_per_system_equals_dense_stacked_inverse() -> None:
    """Two systems (two clocks per epoch, one absent at some epochs as a 0.01 m^2 constraint row)."""
    rng = np.random.default_rng(2)
    n_t, n_sv = 6, 8
    u = rng.normal(size=(n_t, n_sv, 3))
    p_m = np.concatenate([-u / np.linalg.norm(u, axis=2, keepdims=True), np.zeros((n_t, 2, 3))], axis=1)
    sysidx = np.array([0, 0, 0, 0, 1, 1, 1, 1])
    clock_cols = np.zeros((n_t, n_sv + 2, 2))
    clock_cols[:, np.arange(n_sv), sysidx] = 1.0
    wgt = np.zeros((n_t, n_sv + 2))
    wgt[:, :n_sv] = rng.uniform(0.5, 2.0, size=(n_t, n_sv))
    wgt[1, 4:n_sv] = 0.0  # system 1 absent at epoch 1: its clock is fixed by a constraint row
    clock_cols[1, n_sv + 1, 1] = 1.0
    wgt[1, n_sv + 1] = 100.0

    info, h, cv = epoch_information(p_m, wgt, clock_cols)
    for ker in (KernelRepresentation.static(3), KernelRepresentation.pva(3)):
        basis = behavior_basis(ker, n_t)
        k = basis.shape[2]
        n_r = n_sv + 2
        g = np.zeros((n_t * n_r, k + 2 * n_t))
        for t in range(n_t):
            g[t * n_r:(t + 1) * n_r, :k] = p_m[t] @ basis[t]
            g[t * n_r:(t + 1) * n_r, k + 2 * t:k + 2 * t + 2] = clock_cols[t]
        q_x = np.linalg.inv(g.T @ (wgt.reshape(-1, 1) * g))
        got = multi_epoch_cov(basis, info, h, cv)
        assert got.shape == (n_t, 5, 5)
        for t in range(n_t):
            jac = np.zeros((5, k + 2 * n_t))
            jac[:3, :k] = basis[t]
            jac[3:, k + 2 * t:k + 2 * t + 2] = np.eye(2)
            np.testing.assert_allclose(got[t], jac @ q_x @ jac.T, rtol=1e-9, atol=1e-12)


def test_segments_and_windows() -> None:
    t = np.array([0.0, 1, 2, 3, 5, 6, 7, 8, 9, 10])
    solved = np.ones(10, dtype=bool)
    solved[7] = False
    segs = segments(t, solved)
    assert [s.tolist() for s in segs] == [[0, 1, 2, 3], [4, 5, 6], [8, 9]]
    bounds, owner = windows(20, 8)
    assert bounds == [(0, 8), (4, 12), (8, 16), (12, 20)]
    assert owner[0] == 0 and owner[-1] == 3 and owner.size == 20
    assert windows(20, 0)[0] == [(0, 20)]


def test_window_owner_is_the_nearest_centre() -> None:
    """The owner from the midpoints between centres equals a brute-force nearest-centre search."""
    for n in range(1, 70):
        for window in (2, 5, 8, 15, 16):
            for step in (None, 1, 3):
                bounds, owner = windows(n, window, step)
                centres = np.array([(a + b - 1) / 2.0 for a, b in bounds])
                dist = np.abs(np.arange(n)[:, None] - centres[None, :])
                assert np.array_equal(owner, np.argmin(dist, axis=1)), (n, window, step)


def test_multi_epoch_cov_of_stacked_windows_equals_one_at_a_time() -> None:
    rng = np.random.default_rng(2)
    n_t, n_sv = 6, 7
    bases, infos, hs, cvs = [], [], [], []

    for ker in (KernelRepresentation.pva(3), KernelRepresentation.shared(np.poly([1.0, 0.95, 0.9])[::-1], 3)):
        u = rng.normal(size=(n_t, n_sv, 3))
        info, h, cv = epoch_information(-u / np.linalg.norm(u, axis=2, keepdims=True), rng.uniform(0.5, 2.0, (n_t, n_sv)))
        bases.append(behavior_basis(ker, n_t))
        infos.append(info)
        hs.append(h)
        cvs.append(cv)
    both = multi_epoch_cov(np.stack(bases), np.stack(infos), np.stack(hs), np.stack(cvs))
    for k in range(2):
        np.testing.assert_allclose(both[k], multi_epoch_cov(bases[k], infos[k], hs[k], cvs[k]), rtol=1e-12, atol=1e-14)


# ------------------------------------------------------------------ simulated flight
def test_flight_stls_lag3_identify_beats_ls(flight_dir: Path, tmp_path: Path) -> None:
    """The identified shared kernel over windows of the fixes."""
    d = flight_dir
    model_out = tmp_path / "models.json"
    rows = _cli_positions([str(d / "obs.rnx"), str(d / "nav.rnx"), "--method", "ls,stls", "--lag", "3",
                           "--reference-csv", str(d / "truth.csv"), "--iono", "none",
                           "--tropo", "none", "--model-out", str(model_out)])
    err = {m: g["err_3d_m"].to_numpy() for m, g in rows.items()}
    assert (rows["stls"]["status"] == "ok").all()
    rms = {m: float(np.sqrt(np.mean(e**2))) for m, e in err.items()}
    ratio = rms["stls"] / rms["ls"]
    print(f"flight: stls lag 3 3D RMS {rms['stls']:.3f} m, LS {rms['ls']:.3f} m, ratio {ratio:.3f}")
    assert ratio <= 0.6
    assert np.all(rows["stls"]["gdop"].to_numpy() <= rows["ls"]["gdop"].to_numpy() * (1 + 1e-6) + 1e-3)
    models = json.loads(model_out.read_text())
    assert models["methods"]["stls"]["lag"] == "3" and len(models["windows"]) > 10
    assert models["methods"]["stls"]["estimator"] == "identified Hankel STLS (measurement domain, alternation)"
    w0 = models["windows"][0]
    assert w0["method"] == "stls" and w0["model"] == "identified"
    assert {"kernel_R", "order", "poles", "misfit", "status"} <= set(w0)
    # the shared kernel keeps its root at z = 1
    assert np.isclose(sum(w0["shared_coefficients"]), 0.0, atol=1e-9)


def test_lag_without_stls_is_a_usage_error(flight_dir: Path, capsys: pytest.CaptureFixture[str]) -> None:
    d = flight_dir
    with pytest.raises(SystemExit) as exc:
        run_app(app, "gnss-solve", [str(d / "obs.rnx"), str(d / "nav.rnx"), "--method", "wls", "--lag", "3", "-q"])
    assert exc.value.code == 2
    assert "--lag: only with --method stls or smoother" in capsys.readouterr().err


# ------------------------------------------------------------------ real data
def test_rtklib_0759_static_and_lag3(rinex_dir: Path) -> None:
    d = rinex_dir / "rtklib-0759"
    if not d.is_dir():
        pytest.skip("rtklib-0759 missing")
    base = [str(d / "07590920.05o"), str(d / "07590920.05n"), "--method", "ls,stls",
            "--reference", ",".join(str(v) for v in RTKLIB_0759_ECEF_M)]
    rows = _cli_positions([*base, "--lag", "3"])
    assert len(rows["stls"]) == 120 and (rows["stls"]["status"] == "ok").all()
    rms = {m: float(np.sqrt(np.mean(g["err_3d_m"] ** 2))) for m, g in rows.items()}
    print(f"rtklib-0759 static: stls lag 3 {rms['stls']:.3f} m, LS {rms['ls']:.3f} m")
    assert rms["stls"] <= rms["ls"]


def _read_rtklib_pos_ecef(path: Path) -> tuple[np.ndarray, np.ndarray]:
    rows = [line.split() for line in path.read_text().splitlines() if line.strip() and not line.startswith("%")]
    t = np.array([int(r[0]) * 604800.0 + float(r[1]) for r in rows])
    x = np.array([[float(v) for v in r[2:5]] for r in rows])
    return t, x


def test_yamatogawa_kinematic_lag3(rinex_dir: Path) -> None:
    d = rinex_dir / "yamatogawa-2010006-kinematic"
    if not d.is_dir():
        pytest.skip("yamatogawa-2010006-kinematic missing")
    t_ref, x_ref = _read_rtklib_pos_ecef(d / "rtk_ref_rover.pos")
    cfg = load_config(None, {"methods": "ls,wls"})
    data = load_epochs(d / "yamatogawa_rover.obs", [d / "brdc0060.10n"], cfg)
    ls = solve_method(data, "ls", cfg)
    wls = solve_method(data, "wls", cfg)
    # the fixes alone (no measurements): nothing tests a window's behavior, so fixed windows
    sol, _ = smooth(data, wls, _smoothing(cfg, lag=3, window=15))
    k = np.clip(np.searchsorted(t_ref, data.time_gps_s), 0, t_ref.size - 1)
    ref = np.where((np.abs(t_ref[k] - data.time_gps_s) < 0.5)[:, None], x_ref[k], np.nan)
    lat, lon, _ = ecef2geodetic(x_ref[0])
    rot = ecef2enu_rotation(float(lat), float(lon))
    stats = {}
    for name, x in (("ls", ls.x_ecef_m), ("stls", sol.x_ecef_m)):
        e = (x - ref) @ rot.T
        e = e[np.all(np.isfinite(e), axis=1)]
        stats[name] = (float(np.sqrt(np.mean(np.sum(e**2, axis=1)))), np.sqrt(np.mean(e**2, axis=0)))
    for name, (r3, enu) in stats.items():
        print(f"yamatogawa {name}: 3D RMS {r3:.3f} m, E/N/U {enu[0]:.3f} / {enu[1]:.3f} / {enu[2]:.3f} m")
    assert stats["stls"][0] <= stats["ls"][0]
    assert np.all(sol.gdop[sol.status == "ok"] <= wls.gdop[sol.status == "ok"] * (1 + 1e-6))
