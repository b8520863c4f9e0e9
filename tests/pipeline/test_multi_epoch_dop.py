"""Geometry DOPs of multi-epoch rows (DESIGN.md sections 5-6): ``multi_epoch_dops`` against a
dense ``(G_N^T G_N)^-1`` built here, the snapshot bound, the static identity, the fallback of
short windows and degenerate windows.

The dense reference builds ``G_N`` row by row with hand-written behavior bases (``x_s = B_s theta``:
polynomials or powers of the kernel's roots), inverts its normal matrix and rotates the
position block with an ENU rotation written from the geodetic latitude and longitude.
"""

from __future__ import annotations

import numpy as np
import pytest

from gnss_cli.behavior import KernelRepresentation
from gnss_cli.errors import UsageError
from gnss_cli.pipeline.multi_epoch_dop import motion_kernel, multi_epoch_dops

A_WGS84, F_WGS84 = 6378137.0, 1.0 / 298.257223563


def _enu(lat: float, lon: float) -> np.ndarray:
    sl, cl, so, co = np.sin(lat), np.cos(lat), np.sin(lon), np.cos(lon)
    return np.array([[-so, co, 0.0], [-sl * co, -sl * so, cl], [cl * co, cl * so, sl]])


def _ecef(lat: float, lon: float, h: float) -> np.ndarray:
    e2 = F_WGS84 * (2 - F_WGS84)
    n = A_WGS84 / np.sqrt(1 - e2 * np.sin(lat) ** 2)
    return np.array([(n + h) * np.cos(lat) * np.cos(lon), (n + h) * np.cos(lat) * np.sin(lon), (n * (1 - e2) + h) * np.sin(lat)])


def _scene(rng: np.random.Generator, n_t: int, n_sv: int, k: int = 1, same: bool = False):
    """Positions along a short track, ``A_pos = -e`` above 5 deg elevation, one-hot clock columns."""
    lat = np.deg2rad(34.7) + 1e-5 * np.arange(n_t)
    lon = np.deg2rad(135.5) + 2e-5 * np.arange(n_t)
    x = np.stack([_ecef(a, b, 50.0) for a, b in zip(lat, lon)])
    az = rng.uniform(0, 2 * np.pi, size=(1 if same else n_t, n_sv))
    el = rng.uniform(np.deg2rad(5), np.deg2rad(85), size=az.shape)
    e_enu = np.stack([np.cos(el) * np.sin(az), np.cos(el) * np.cos(az), np.sin(el)], axis=-1)
    e_enu = np.broadcast_to(e_enu, (n_t, n_sv, 3))
    a_pos = -np.stack([e_enu[t] @ _enu(lat[t], lon[t]) for t in range(n_t)])
    clocks = np.zeros((n_sv, k))
    clocks[np.arange(n_sv), np.arange(n_sv) % k] = 1.0
    return a_pos, clocks, x, lat, lon


def _dense(a_pos, clocks, used, lat, lon, span, blocks, t):
    """DOPs of epoch ``t`` from ``(G^T G)^-1`` over the epochs ``span`` with ``x_s = blocks[s] theta``."""
    d, k = blocks[0].shape[1], clocks.shape[-1]
    rows, clock_ids = [], [(s, j) for s in range(len(span)) for j in range(k) if np.any(used[span[s]] & (clocks[:, j] > 0))]
    for s, e in enumerate(span):
        for i in np.flatnonzero(used[e]):
            row = np.zeros(d + len(clock_ids))
            row[:d] = a_pos[e, i] @ blocks[s]
            row[d + clock_ids.index((s, int(np.argmax(clocks[i]))))] = 1.0
            rows.append(row)
    g = np.array(rows)
    q = np.linalg.inv(g.T @ g)
    s_t = list(span).index(t)
    mine = [j for j in range(k) if (s_t, j) in clock_ids]
    jac = np.zeros((3 + len(mine), q.shape[0]))
    jac[:3, :d] = blocks[s_t]
    for r, j in enumerate(mine):
        jac[3 + r, d + clock_ids.index((s_t, j))] = 1.0
    qt = jac @ q @ jac.T
    rot = _enu(lat[t], lon[t])
    q_enu = np.diag(rot @ qt[:3, :3] @ rot.T)
    tdops = np.full(k, np.nan)
    tdops[mine] = np.sqrt(np.diag(qt)[3:])
    return {"gdop": np.sqrt(np.trace(qt)), "pdop": np.sqrt(q_enu.sum()), "hdop": np.sqrt(q_enu[:2].sum()),
            "vdop": np.sqrt(q_enu[2]), "tdops": tdops}


def _poly_blocks(n: int, degree: int) -> list[np.ndarray]:
    return [np.hstack([s**p * np.eye(3) for p in range(degree + 1)]) for s in range(n)]


def _root_blocks(n: int, roots: list[float]) -> list[np.ndarray]:
    return [np.hstack([r**s * np.eye(3) for r in roots]) for s in range(n)]


def _window(t_local: int, seg_len: int, n_win: int) -> tuple[int, int]:
    n = min(n_win, seg_len)
    a = min(max(t_local - (n_win - 1) // 2, 0), seg_len - n)
    return a, n


def _check(got, ref, t):
    for name in ("gdop", "pdop", "hdop", "vdop"):
        assert getattr(got, name)[t] == pytest.approx(ref[name], rel=1e-9), (name, t)
    np.testing.assert_allclose(got.tdops[t], ref["tdops"], rtol=1e-9)
    np.testing.assert_equal(got.tdop[t], got.tdops[t, 0])


# ------------------------------------------------------------------ (1) equals the dense computation
def test_fixed_kernels_equal_the_dense_stacked_inverse() -> None:
    rng = np.random.default_rng(11)
    n_t, n_sv, n_win = 14, 9, 5
    a_pos, clocks, x, lat, lon = _scene(rng, n_t, n_sv, k=2)
    used = rng.random((n_t, n_sv)) > 0.15
    used[:, :4] = True  # at least two satellites of each system
    used[3, 1::2] = False  # system 1 absent at epoch 3: its clock is not estimated there
    used[3, 0:8:2] = True
    segs = [np.arange(0, 8), np.arange(8, 12)]  # 12, 13 outside: snapshot
    for motion, degree in (("static", 0), ("cv", 1), ("ca", 2)):
        got = multi_epoch_dops(a_pos, clocks, used, x, segs, motion_kernel(motion), n_win)
        for t in range(n_t):
            seg = next((s for s in segs if t in s), None)
            if seg is None:
                span, blocks = [t], [np.eye(3)]
            else:
                a, n = _window(int(np.flatnonzero(seg == t)[0]), seg.size, n_win)
                span, blocks = list(seg[a:a + n]), _poly_blocks(n, degree)
            _check(got, _dense(a_pos, clocks, used, lat, lon, span, blocks, t), t)
            assert got.window_epochs[t] == len(span)
        assert np.isnan(got.tdops[3, 1]) and not got.degenerate.any() and got.n_degenerate_windows == 0


def test_per_epoch_identified_kernels_equal_the_dense_stacked_inverse() -> None:
    """Shared kernels with roots (1, r1, r2), one per run of 3 epochs, and None (snapshot)."""
    rng = np.random.default_rng(12)
    n_t, n_sv, n_win = 12, 8, 6
    a_pos, clocks, x, lat, lon = _scene(rng, n_t, n_sv)
    used = np.ones((n_t, n_sv), dtype=bool)
    roots = [[1.0, 0.9, 0.7], [1.0, 0.95, -0.5], [1.0, 0.8, 0.6], None]
    kernels = [None if r is None else KernelRepresentation.shared(np.poly(r)[::-1], 3) for r in roots]
    per_epoch = [kernels[t // 3] for t in range(n_t)]
    got = multi_epoch_dops(a_pos, None, used, x, [np.arange(n_t)], per_epoch, n_win)
    for t in range(n_t):
        if roots[t // 3] is None:
            span, blocks = [t], [np.eye(3)]
        else:
            a, n = _window(t, n_t, n_win)
            span, blocks = list(range(a, a + n)), _root_blocks(n, roots[t // 3])
        _check(got, _dense(a_pos, clocks, used, lat, lon, span, blocks, t), t)
    # the same kernel object for every epoch is the fixed kernel
    same = multi_epoch_dops(a_pos, None, used, x, [np.arange(n_t)], [kernels[0]] * n_t, n_win)
    fixed = multi_epoch_dops(a_pos, None, used, x, [np.arange(n_t)], kernels[0], n_win)
    np.testing.assert_array_equal(same.gdop, fixed.gdop)


def test_a_full_kernel_acts_in_the_segment_enu_frame() -> None:
    """``diag(z(z-1), z(z-1), (z-1)^2)``: east and north constant after the window's first epoch, up linear."""
    rng = np.random.default_rng(13)
    n_t, n_sv, n_win = 7, 7, 5
    a_pos, clocks, x, lat, lon = _scene(rng, n_t, n_sv)
    used = np.ones((n_t, n_sv), dtype=bool)
    blocks = np.zeros((3, 3, 3))
    blocks[0] = np.diag([0.0, 0.0, 1.0])
    blocks[1] = np.diag([-1.0, -1.0, -2.0])
    blocks[2] = np.eye(3)
    ker = KernelRepresentation(blocks)
    got = multi_epoch_dops(a_pos, None, used, x, [np.arange(n_t)], ker, n_win)
    frame = _enu(lat[0], lon[0])
    for t in range(n_t):
        a, n = _window(t, n_t, n_win)
        enu = [np.array([[s == 0, s >= 1, 0, 0, 0, 0], [0, 0, s == 0, s >= 1, 0, 0], [0, 0, 0, 0, 1, s]], dtype=float)
               for s in range(n)]
        _check(got, _dense(a_pos, clocks, used, lat, lon, list(range(a, a + n)), [frame.T @ b for b in enu], t), t)


# ------------------------------------------------------------------ (2) never above the snapshot
def test_never_exceeds_the_snapshot_dop() -> None:
    rng = np.random.default_rng(14)
    kernels = [motion_kernel(m) for m in ("static", "cv", "ca")]
    kernels += [KernelRepresentation.shared(np.poly([1.0, *rng.uniform(-0.9, 1.0, 2)])[::-1], 3) for _ in range(3)]
    for trial in range(60):
        k = 1 + trial % 3
        n_t, n_sv = int(rng.integers(4, 20)), int(rng.integers(3 + 2 * k, 12))
        a_pos, clocks, x, _, _ = _scene(rng, n_t, n_sv, k=k)
        used = rng.random((n_t, n_sv)) > 0.2
        used[:, : 2 * k + 2] = True
        ker = kernels[trial % len(kernels)]
        n_win = int(rng.integers(2, 16))
        multi = multi_epoch_dops(a_pos, clocks, used, x, [np.arange(n_t)], ker, n_win)
        snap = multi_epoch_dops(a_pos, clocks, used, x, [], ker, n_win)
        assert np.all(snap.window_epochs == 1) and np.all(np.isfinite(snap.gdop))
        for name in ("gdop", "pdop", "hdop", "vdop", "tdop"):
            assert np.all(getattr(multi, name) <= getattr(snap, name) * (1 + 1e-9)), (trial, name)
        present = np.isfinite(snap.tdops)
        assert np.array_equal(present, np.isfinite(multi.tdops))
        assert np.all(multi.tdops[present] <= snap.tdops[present] * (1 + 1e-9))


# ------------------------------------------------------------------ (3) the static identity
@pytest.mark.parametrize("k", [1, 2])
def test_static_kernel_over_identical_geometry(k: int) -> None:
    """Same satellites at every epoch, free clocks: ``x`` is seen N times, each clock once, so
    ``PDOP_N = PDOP_1 / sqrt(N)`` (and HDOP, VDOP) while ``TDOP_N^2 - 1/n_j = (TDOP_1^2 - 1/n_j) / N``."""
    rng = np.random.default_rng(15)
    n_win, n_sv = 6, 9
    a_pos, clocks, _, _, _ = _scene(rng, n_win, n_sv, k=k, same=True)
    x = np.broadcast_to(_ecef(np.deg2rad(34.7), np.deg2rad(135.5), 50.0), (n_win, 3))
    a_pos = np.broadcast_to(a_pos[0], a_pos.shape)
    used = np.ones((n_win, n_sv), dtype=bool)
    multi = multi_epoch_dops(a_pos, clocks, used, x, [np.arange(n_win)], motion_kernel("static"), n_win)
    snap = multi_epoch_dops(a_pos, clocks, used, x, [], motion_kernel("static"), n_win)
    for name in ("pdop", "hdop", "vdop"):
        np.testing.assert_allclose(getattr(multi, name), getattr(snap, name) / np.sqrt(n_win), rtol=1e-10)
    n_j = clocks.sum(axis=0)
    np.testing.assert_allclose(multi.tdops**2 - 1 / n_j, (snap.tdops**2 - 1 / n_j) / n_win, rtol=1e-9, atol=1e-14)
    np.testing.assert_allclose(multi.gdop**2, multi.pdop**2 + (multi.tdops**2).sum(axis=1), rtol=1e-10)
    assert np.all(multi.tdops > snap.tdops / np.sqrt(n_win))  # the clocks do not gain sqrt(N)


# ------------------------------------------------------------------ (4) short windows: the snapshot
def test_a_kernel_without_recursion_gives_the_snapshot() -> None:
    """``r_lag = 0`` (an identification that failed that way): no behavior basis, the snapshot DOP."""
    rng = np.random.default_rng(22)
    a_pos, _, x, _, _ = _scene(rng, 6, 7)
    used = np.ones((6, 7), dtype=bool)
    flat = KernelRepresentation.shared([-1.0, 1.0, 0.0], 3)
    got = multi_epoch_dops(a_pos, None, used, x, [np.arange(6)], [flat] * 3 + [motion_kernel("cv")] * 3, 5)
    snap = multi_epoch_dops(a_pos, None, used, x, [], flat, 5)
    assert got.window_epochs.tolist() == [1, 1, 1, 5, 5, 5]
    np.testing.assert_array_equal(got.gdop[:3], snap.gdop[:3])


def test_windows_shorter_than_the_kernel_needs_fall_back_to_the_snapshot() -> None:
    rng = np.random.default_rng(16)
    n_t, n_sv = 10, 7
    a_pos, clocks, x, lat, lon = _scene(rng, n_t, n_sv)
    used = np.ones((n_t, n_sv), dtype=bool)
    segs = [np.arange(0, 3), np.arange(3, 10)]
    ca = multi_epoch_dops(a_pos, None, used, x, segs, motion_kernel("ca"), 15)  # needs 4 epochs
    assert ca.window_epochs.tolist() == [1, 1, 1] + [7] * 7
    for t in range(3):
        _check(ca, _dense(a_pos, clocks, used, lat, lon, [t], [np.eye(3)], t), t)
    short = multi_epoch_dops(a_pos, None, used, x, segs, motion_kernel("ca"), 3)  # window 3 < 4 everywhere
    snap = multi_epoch_dops(a_pos, None, used, x, [], motion_kernel("ca"), 3)
    assert np.all(short.window_epochs == 1)
    np.testing.assert_array_equal(short.gdop, snap.gdop)
    cv = multi_epoch_dops(a_pos, None, used, x, segs, motion_kernel("cv"), 3)  # exactly the 3 epochs cv needs
    assert np.all(cv.window_epochs == 3) and np.all(cv.pdop < snap.pdop)


def test_epochs_without_position_are_nan_and_their_rows_still_count() -> None:
    rng = np.random.default_rng(17)
    n_t, n_sv = 6, 7
    a_pos, clocks, x, lat, lon = _scene(rng, n_t, n_sv)
    used = np.ones((n_t, n_sv), dtype=bool)
    x = x.copy()
    x[2] = np.nan
    got = multi_epoch_dops(a_pos, None, used, x, [np.arange(n_t)], motion_kernel("static"), 3)
    assert np.isnan(got.gdop[2]) and np.isnan(got.tdops[2]).all() and got.window_epochs[2] == 0
    assert np.all(np.isfinite(np.delete(got.gdop, 2)))
    _check(got, _dense(a_pos, clocks, used, lat, lon, [2, 3, 4], _poly_blocks(3, 0), 3), 3)
    # an unsolved epoch outside the segments, without rows: NaN, and not a degenerate window
    x[5], used[5] = np.nan, False
    out = multi_epoch_dops(a_pos, None, used, x, [np.arange(5)], motion_kernel("static"), 3)
    assert np.isnan(out.gdop[5]) and np.isnan(out.cond[5]) and not out.degenerate[5] and out.n_degenerate_windows == 0


# ------------------------------------------------------------------ (5) degenerate windows
def test_a_three_satellite_epoch_inside_a_window_is_determined_by_the_window() -> None:
    rng = np.random.default_rng(18)
    n_t, n_sv = 7, 8
    a_pos, clocks, x, lat, lon = _scene(rng, n_t, n_sv)
    used = np.ones((n_t, n_sv), dtype=bool)
    used[3, 3:] = False  # 3 satellites, one clock: no snapshot position
    snap = multi_epoch_dops(a_pos, None, used, x, [], motion_kernel("static"), 5)
    assert np.isinf(snap.pdop[3]) and snap.degenerate.tolist() == [False] * 3 + [True] + [False] * 3
    assert snap.n_degenerate_windows == 1 and np.isinf(snap.cond[3])
    got = multi_epoch_dops(a_pos, None, used, x, [np.arange(n_t)], motion_kernel("static"), 5)
    assert not got.degenerate.any() and np.all(np.isfinite(got.cond))
    for t in range(n_t):
        a, n = _window(t, n_t, 5)
        _check(got, _dense(a_pos, clocks, used, lat, lon, list(range(a, a + n)), _poly_blocks(n, 0), t), t)


def test_a_window_that_leaves_a_trajectory_unobserved_is_reported() -> None:
    """The same 3 satellites at every epoch: the static window leaves one direction unobserved."""
    rng = np.random.default_rng(19)
    n_t = 6
    a_pos, clocks, x, _, _ = _scene(rng, n_t, 3, same=True)
    a_pos = np.broadcast_to(a_pos[0], a_pos.shape)
    used = np.ones((n_t, 3), dtype=bool)
    got = multi_epoch_dops(a_pos, None, used, x, [np.arange(n_t)], motion_kernel("static"), 4)
    assert got.degenerate.all() and np.all(np.isinf(got.pdop)) and np.all(np.isinf(got.gdop))
    assert not np.isnan(got.gdop).any() and np.all(np.isinf(got.cond))
    assert got.n_degenerate_windows == 3  # windows starting at 0, 1, 2


def test_invalid_arguments_raise_usage_errors() -> None:
    rng = np.random.default_rng(20)
    a_pos, clocks, x, _, _ = _scene(rng, 4, 6)
    used = np.ones((4, 6), dtype=bool)
    ker = motion_kernel("cv")
    with pytest.raises(UsageError, match="segments"):
        multi_epoch_dops(a_pos, None, used, x, [np.arange(3), np.arange(2, 4)], ker, 3)
    with pytest.raises(UsageError, match="used"):
        multi_epoch_dops(a_pos, None, used.astype(int), x, [], ker, 3)
    with pytest.raises(UsageError, match="window_epochs"):
        multi_epoch_dops(a_pos, None, used, x, [], ker, 0)
    with pytest.raises(UsageError, match="kernels"):
        multi_epoch_dops(a_pos, None, used, x, [], [ker] * 3, 3)
    with pytest.raises(UsageError, match="square"):
        multi_epoch_dops(a_pos, None, used, x, [], KernelRepresentation(np.ones((2, 6))), 3)
    with pytest.raises(UsageError, match="motion"):
        motion_kernel("jerk")
    bad = a_pos.copy()
    bad[1, 2] = np.nan
    with pytest.raises(UsageError, match="non-finite"):
        multi_epoch_dops(bad, None, used, x, [], ker, 3)


def test_epoch_blocks_do_not_change_the_result(monkeypatch: pytest.MonkeyPatch) -> None:
    import gnss_cli.pipeline.multi_epoch_dop as mod

    rng = np.random.default_rng(21)
    a_pos, clocks, x, _, _ = _scene(rng, 11, 8, k=2)
    used = rng.random((11, 8)) > 0.1
    whole = multi_epoch_dops(a_pos, clocks, used, x, [np.arange(11)], motion_kernel("ca"), 5)
    monkeypatch.setattr(mod, "_EPOCH_BLOCK", 3)
    parts = multi_epoch_dops(a_pos, clocks, used, x, [np.arange(11)], motion_kernel("ca"), 5)
    np.testing.assert_allclose(parts.gdop, whole.gdop, rtol=1e-13)
    np.testing.assert_allclose(parts.tdops, whole.tdops, rtol=1e-13)


# ------------------------------------------------------------------ real data: the snapshot is the LS DOP
@pytest.mark.parametrize("folder, obs, nav", [
    ("yamatogawa-2010006-kinematic", "yamatogawa_rover.obs", "brdc0060.10n"),
    ("kms3-2022159-rinex4", "KMS300DNK_R_20221591000_01H_30S_MO.crx", "KMS300DNK_R_20221591000_01H_MN.rnx.gz"),
])
def test_snapshot_rows_are_the_ls_dops_and_windows_only_lower_them(rinex_dir, folder: str, obs: str, nav: str) -> None:
    """The LS DOPs are unit-weight ``(A^T A)^-1``: rebuilt here from the satellites LS used (its
    finite residuals) and plain line-of-sight vectors (no Earth rotation during the signal's
    flight: ~5e-6 rad, hence the 1e-4 tolerance)."""
    from gnss_cli.behavior.windows import segments
    from gnss_cli.config import load_config
    from gnss_cli.pipeline import load_epochs, solve_method

    cfg = load_config(overrides={"methods": "ls"})
    data = load_epochs(rinex_dir / folder / obs, [rinex_dir / folder / nav], cfg)
    ls = solve_method(data, "ls", cfg)
    used = np.isfinite(ls.residuals_m)
    los = data.sat_ecef_m - ls.x_ecef_m[:, None, :]
    a_pos = -los / np.linalg.norm(los, axis=2, keepdims=True)
    sysidx = data.system_index if data.system_index is not None else np.zeros(data.sv.size, dtype=np.int64)
    clocks = np.eye(len(data.systems))[sysidx]
    solved = np.isfinite(ls.x_ecef_m).all(axis=1)
    snap = multi_epoch_dops(a_pos, clocks, used, ls.x_ecef_m, [], motion_kernel("ca"), 15)
    for name in ("gdop", "pdop", "hdop", "vdop", "tdop"):
        np.testing.assert_allclose(getattr(snap, name)[solved], getattr(ls, name)[solved], rtol=1e-4)
    if ls.tdops is not None:
        np.testing.assert_allclose(snap.tdops[solved], ls.tdops[solved], rtol=1e-4)
    multi = multi_epoch_dops(a_pos, clocks, used, ls.x_ecef_m, segments(data.time_gps_s, solved), motion_kernel("ca"), 15)
    assert np.all(multi.pdop[solved] <= snap.pdop[solved] * (1 + 1e-9)) and np.median(multi.pdop[solved] / snap.pdop[solved]) < 0.8
    assert np.all(np.isnan(multi.gdop[~solved])) and not multi.degenerate.any()


def test_dop_columns_of_smoother_and_kf_rows_are_geometry(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """The DOP columns of smoother and kf rows do not depend on the Doppler (only the pseudorange
    geometry and the motion model), never exceed the snapshot DOP, and shrink from cv to static."""
    from pathlib import Path

    from gnss_cli.pipeline import process
    from gnss_cli.config import load_config

    sample = Path(__file__).resolve().parents[2] / "sample_rinex" / "static"
    runs = {}
    for kinds in ("pseudorange", "pseudorange,doppler"):
        cfg = load_config(None, {"methods": "wls,kf", "measurements": kinds, "integrity": "off"})
        runs[kinds] = process(sample / "obs.rnx", [sample / "nav.rnx"], cfg).solutions
    for m in ("kf",):
        a, b = runs["pseudorange"][m], runs["pseudorange,doppler"][m]
        assert not np.allclose(a.x_ecef_m, b.x_ecef_m, atol=1e-4, rtol=0)  # the Doppler changes the estimate ...
        np.testing.assert_allclose(a.gdop, b.gdop, rtol=1e-6)  # ... not the geometry (lines of sight move by cm)
        np.testing.assert_allclose(a.pdop, b.pdop, rtol=1e-6)
        assert np.all(a.gdop <= runs["pseudorange"]["wls"].gdop * (1 + 1e-9))
    kf = runs["pseudorange"]["kf"]
    cv_pdop = kf.pdop
    from gnss_cli.pipeline.multi_epoch_dop import with_geometry_dops
    from gnss_cli.pipeline import load_epochs

    cfg = load_config(None, {"methods": "wls,kf"})
    data = load_epochs(sample / "obs.rnx", [sample / "nav.rnx"], cfg)
    static_pdop = with_geometry_dops(data, kf, cfg, "static").pdop
    # a static receiver's behavior is smaller than constant velocity's: more geometry per position
    assert np.all(static_pdop <= cv_pdop * (1 + 1e-9)) and np.mean(static_pdop) < np.mean(cv_pdop)
