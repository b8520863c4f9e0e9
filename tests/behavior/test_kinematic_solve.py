"""The segment solve of every motion against independent computations: dense null-space least squares
(quadrature), a linear Kalman filter with an RTS smoother (cv, ca), one position (static)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import null_space

from gnss_cli.behavior import kinematic_solve
from gnss_cli.behavior.kinematic_solve import (
    JERK_SIGMA_M_S3,
    Motion,
    kinematic_position_cov,
    motion_terms,
    solve_kinematic,
    step_rule,
)
from gnss_cli.behavior.window_solve import EpochNormals, reduce_epochs
from gnss_cli.errors import ConfigError
from gnss_cli.solvers.kalman import kalman_filter, rts_smooth


def _epochs(rng: np.random.Generator, n_t: int, n: int, k: int, n_sats: list[int]) -> tuple[np.ndarray, ...]:
    """Random unit line-of-sight rows, weights (0 beyond each epoch's satellite count), values, clock columns."""
    e = rng.normal(size=(n_t, n, 3))
    e /= np.linalg.norm(e, axis=-1, keepdims=True)
    w = rng.uniform(0.5, 2.0, size=(n_t, n)) * (np.arange(n)[None, :] < np.array(n_sats)[:, None])
    y = rng.normal(size=(n_t, n))
    sys_of = np.arange(n) % k
    c = np.broadcast_to((sys_of[:, None] == np.arange(k)).astype(float), (n_t, n, k)).copy()
    return -e, w, y, c


def _kinematic_dense(pr, rr, step_m, dt_s, lag):  # type: ignore[no-untyped-def]
    """The quadrature problem through the null space of the constraints (dense)."""
    n = pr.M.shape[0]
    G = np.zeros((3 * (n - 1), 6 * n))
    cvec = -step_m.ravel()
    for t in range(n - 1):
        offs, wts = step_rule(t, n, lag)
        for a in range(3):
            G[3 * t + a, 3 * (t + 1) + a] += 1.0
            G[3 * t + a, 3 * t + a] -= 1.0
            for o, wt in zip(offs, wts):
                G[3 * t + a, 3 * n + 3 * (t + o) + a] -= wt * dt_s[t]
    H = np.zeros((6 * n, 6 * n))
    for t in range(n):
        H[3 * t : 3 * t + 3, 3 * t : 3 * t + 3] = pr.M[t]
        H[3 * n + 3 * t : 3 * n + 3 * t + 3, 3 * n + 3 * t : 3 * n + 3 * t + 3] = rr.M[t]
    d2 = np.diff(np.eye(n), 2, axis=0)  # v_{t+1} - 2 v_t + v_{t-1} (uniform steps here)
    H[3 * n :, 3 * n :] += np.kron(d2.T @ d2 / (JERK_SIGMA_M_S3 * dt_s[0] ** 2) ** 2, np.eye(3))
    g = np.concatenate([pr.r.ravel(), rr.r.ravel()])
    u0, *_ = np.linalg.lstsq(G, cvec, rcond=None)
    N = null_space(G)
    a = np.linalg.solve(N.T @ H @ N, N.T @ (g - H @ u0))
    u = u0 + N @ a
    return u[: 3 * n].reshape(n, 3), u[3 * n :].reshape(n, 3)


@pytest.mark.parametrize("lag", [1, 2, 3])
def test_quadrature_segment_equals_the_null_space_solution(lag: int) -> None:
    rng = np.random.default_rng(10 + lag)
    n_t = 12
    p, w, y, c = _epochs(rng, n_t, 8, 1, [8] * n_t)
    h, wd, yd, _ = _epochs(rng, n_t, 8, 1, [8] * n_t)
    pr, rr = reduce_epochs(p, w, y, c), reduce_epochs(h, wd, yd)
    step = rng.normal(size=(n_t - 1, 3))
    dt = np.full(n_t - 1, 0.5)
    sol = solve_kinematic(pr, rr, step, dt, Motion("quadrature", lag))
    z, v = _kinematic_dense(pr, rr, step, dt, lag)
    assert np.allclose(sol.z, z, rtol=1e-8, atol=1e-9) and np.allclose(sol.v, v, rtol=1e-8, atol=1e-9)
    assert sol.dof == 2 * 8 * n_t - 2 * n_t - 3 * n_t - 3
    assert 1e-6 < sol.rcond <= 1.0


@pytest.mark.parametrize("lag, exact", [(1, False), (3, True)])
def test_quadrature_rule_of_lag_3_is_exact_for_cubic_velocity(lag: int, exact: bool, monkeypatch: pytest.MonkeyPatch) -> None:
    """Noise-free rows of a trajectory with a polynomial velocity: the lag-3 rule (one-sided at the ends) returns it, the
    trapezoid does not (its step error is dt^3 x''' / 12)."""
    monkeypatch.setattr(kinematic_solve, "JERK_SIGMA_M_S3", 1e6)  # the prior (3 m/s^3) pulls 1e-4 m here
    rng = np.random.default_rng(5)
    n_t, dt = 40, 1.0
    t = np.arange(n_t) * dt
    coef = np.array([[0.3, -0.2, 0.05], [0.02, 0.01, -0.03], [-0.004, 0.002, 0.001]])
    vel = 10.0 + np.stack([np.polyval(np.r_[coef[:, i], 0.0][::-1], t) for i in range(3)], axis=1)
    pos = np.stack([np.polyval(np.polyint(np.r_[coef[:, i], 0.0][::-1]), t) for i in range(3)], axis=1) + 10.0 * t[:, None]
    p, w, _, c = _epochs(rng, n_t, 8, 1, [8] * n_t)
    h, wd, _, _ = _epochs(rng, n_t, 8, 1, [8] * n_t)
    nominal = pos + rng.normal(scale=3.0, size=pos.shape)
    y = np.einsum("tni,ti->tn", p, pos - nominal)  # rows of the truth relative to the nominal, clock 0
    yd = np.einsum("tni,ti->tn", h, vel)
    w[5:8, 2:] = 0.0  # three epochs with two satellites
    sol = solve_kinematic(reduce_epochs(p, w, y, c), reduce_epochs(h, wd, yd), np.diff(nominal, axis=0),
                          np.full(n_t - 1, dt), Motion("quadrature", lag))
    err = np.abs(nominal + sol.z - pos).max()
    # lag 3: 1e-9 m, the trapezoid 7e-4 m
    assert (err < 1e-7) if exact else (err > 1e-4)


@pytest.mark.parametrize("lag", [1, 2, 3])
def test_quadrature_rows_are_exact_at_uneven_steps(lag: int) -> None:
    """Steps of 1, 2 and 4 s (missed epochs): a trajectory whose velocity is a polynomial of degree
    ``lag`` satisfies every row ``x_{t+1} - x_t - dt sum_k c_k v_{t+k}`` (weights at the epochs' own
    times); the weights of even steps are off there by centimetres to metres (lag 1, the trapezoid,
    has no other node and is exact either way)."""
    dt = np.array([2.0, 1.0, 1.0, 1.0, 4.0, 1.0, 1.0, 2.0, 1.0, 1.0])
    t = np.r_[0.0, np.cumsum(dt)] + 3.0
    pos_coef = np.array([0.0, 2.0, -0.25, 0.1, -0.01])[: lag + 2]  # degree lag + 1
    pos = np.polyval(pos_coef[::-1], t)
    vel = np.polyval(np.polyder(pos_coef[::-1]), t)
    hard = motion_terms(Motion("quadrature", lag), dt).hard
    assert np.abs(hard @ np.r_[pos, vel]).max() < 1e-9 * np.abs(pos).max()
    even = []
    for k in range(dt.size):
        offs, wts = step_rule(k, dt.size + 1, lag)
        even.append(pos[k + 1] - pos[k] - dt[k] * wts @ vel[k + offs])
    off = np.abs(even).max()
    assert (off > 1e-2) if lag > 1 else (off < 1e-9), off


def _process_noise(dt: float, n_kin: int, psd: float) -> tuple[np.ndarray, np.ndarray]:
    """Transition and covariance of white acceleration (2) / jerk (3) over ``dt``, integrated here from
    ``Q = int_0^dt F(s) B B^T F(s)^T psd ds`` with ``B`` the last unit vector (Simpson on a fine grid)."""
    def f(s: float) -> np.ndarray:
        return np.array([[1.0, s, s * s / 2], [0.0, 1.0, s], [0.0, 0.0, 1.0]])[3 - n_kin :, 3 - n_kin :]

    grid = np.linspace(0.0, dt, 2001)
    vals = np.array([f(s)[:, -1:] @ f(s)[:, -1:].T for s in grid]) * psd
    wts = np.ones(grid.size)
    wts[1:-1:2], wts[2:-1:2] = 4.0, 2.0
    return f(dt), np.einsum("s,sij->ij", wts, vals) * (grid[1] - grid[0]) / 3


@pytest.mark.parametrize("name", ["cv", "ca"])
def test_process_information_is_the_inverse_of_the_integrated_process_noise(name: str) -> None:
    motion = Motion(name, accel_psd_m2_s3=2.5, jerk_psd_m2_s5=0.7)
    dt = np.array([0.2, 1.0, 3.0])
    terms = motion_terms(motion, dt)
    k = motion.n_kin
    w = terms.soft_weight.toarray()
    for i, d in enumerate(dt):
        _, Q = _process_noise(float(d), k, 2.5 if name == "cv" else 0.7)
        np.testing.assert_allclose(w[k * i : k * i + k, k * i : k * i + k] @ Q, np.eye(k), atol=1e-9)


def _normals(P: np.ndarray, w: np.ndarray, y: np.ndarray) -> EpochNormals:
    """Normals of rows without nuisance columns: ``(T, n, 3)`` coefficients, weights, values."""
    return EpochNormals(np.einsum("tni,tn,tnj->tij", P, w, P), np.einsum("tni,tn,tn->ti", P, w, y),
                        np.einsum("tn,tn,tn->t", w, y, y), (w > 0).sum(axis=1), np.zeros(w.shape[0], dtype=np.int64))


@pytest.mark.parametrize("name", ["cv", "ca"])
@pytest.mark.parametrize("doppler", [True, False])
def test_cv_and_ca_equal_a_kalman_filter_with_rts_smoother(name: str, doppler: bool) -> None:
    """A linear model (position rows, velocity rows with Doppler, irregular steps): the batch solution and its
    position covariance equal the RTS smoother's. The filter's prior on the first position and velocity
    (sigma 100 m, m/s) is given to the batch as rows of the first epoch; the batch has none on the
    acceleration (ca), the filter a diffuse one (sigma 1e3 m/s^2 with Doppler, 1e4 without: its own
    rounding grows with it), which moves the track by less than 1e-6 m here."""
    rng = np.random.default_rng(7)
    n_t, n = 30, 5
    k = 2 if name == "cv" else 3
    psd = 4.0 if name == "cv" else 1.0
    dt = rng.uniform(0.5, 1.5, n_t - 1)
    P = rng.normal(size=(n_t, n, 3))
    P /= np.linalg.norm(P, axis=-1, keepdims=True)
    H = rng.normal(size=(n_t, n, 3))
    H /= np.linalg.norm(H, axis=-1, keepdims=True)
    w, wd = rng.uniform(0.2, 2.0, (n_t, n)), rng.uniform(50.0, 200.0, (n_t, n)) * doppler
    w[10:13, 2:] = 0.0  # epochs with two position rows
    y, yd = rng.normal(scale=5.0, size=(n_t, n)), rng.normal(scale=2.0, size=(n_t, n))
    nominal = np.cumsum(rng.normal(scale=10.0, size=(n_t, 3)), axis=0)
    var0 = 1e4  # the filter's prior on x_0 and v_0: mean 0
    pr = _normals(P, w, y - np.einsum("tni,ti->tn", P, nominal))
    rr = _normals(H, wd, yd)
    pr.M[0] += np.eye(3) / var0
    pr.r[0] -= nominal[0] / var0
    rr.M[0] += np.eye(3) / var0
    motion = Motion(name, accel_psd_m2_s3=psd, jerk_psd_m2_s5=psd)
    sol = solve_kinematic(pr, rr, np.diff(nominal, axis=0), dt, motion)
    cov = kinematic_position_cov(pr.M, rr.M, dt, motion)

    m = 3 * k
    F, Q = np.zeros((n_t, m, m)), np.zeros((n_t, m, m))
    for j in range(1, n_t):
        f1, q1 = _process_noise(float(dt[j - 1]), k, psd)
        F[j], Q[j] = np.kron(f1, np.eye(3)), np.kron(q1, np.eye(3))
    rows, vals, var = [], [], []
    for t in range(n_t):
        use, used = w[t] > 0, wd[t] > 0
        r = np.zeros((use.sum() + used.sum(), m))
        r[: use.sum(), :3] = P[t, use]
        r[use.sum() :, 3:6] = H[t, used]
        rows.append(r)
        vals.append(np.concatenate([y[t, use], yd[t, used]]))
        var.append(np.concatenate([1.0 / w[t, use], 1.0 / wd[t, used]]))
    P0 = np.diag([var0] * 6 + [1e6 if doppler else 1e8] * (m - 6))
    xs, Ps = rts_smooth(kalman_filter(np.zeros(m), P0, F, Q, rows, vals, var), F)
    np.testing.assert_allclose(nominal + sol.z, xs[:, :3], rtol=0, atol=1e-6)
    np.testing.assert_allclose(sol.v, xs[:, 3:6], rtol=0, atol=1e-6)
    np.testing.assert_allclose(cov, Ps[:, :3, :3], rtol=1e-6, atol=1e-9)
    assert sol.dof == int((w > 0).sum() + (wd > 0).sum()) + m * (n_t - 1) - m * n_t


def test_static_is_one_position_and_no_velocity() -> None:
    rng = np.random.default_rng(8)
    n_t = 9
    p, w, y, c = _epochs(rng, n_t, 6, 2, [6, 3, 2, 1, 6, 6, 4, 5, 6])
    pr = reduce_epochs(p, w, y, c)
    nominal = rng.normal(scale=5.0, size=(n_t, 3))
    sol = solve_kinematic(pr, None, np.diff(nominal, axis=0), np.ones(n_t - 1), Motion("static"))
    x = nominal + sol.z
    d = nominal - nominal[0]  # z_t = z_0 - d_t
    z0 = np.linalg.solve(pr.M.sum(axis=0), pr.r.sum(axis=0) + np.einsum("tij,tj->i", pr.M, d))
    np.testing.assert_allclose(x, np.broadcast_to(nominal[0] + z0, x.shape), atol=1e-9)
    assert np.all(sol.v == 0.0) and sol.dof == int((w > 0).sum() - pr.n_free.sum()) - 3


def test_two_epochs_of_pseudoranges_are_degenerate_under_quadrature_and_ca() -> None:
    """Two epochs, no range rates: the quadrature rule (one step, two velocities, no jerk prior) and ca
    (six states per axis, five rows) leave a direction free; cv and static do not."""
    rng = np.random.default_rng(9)
    p, w, y, c = _epochs(rng, 2, 8, 1, [8, 8])
    pr = reduce_epochs(p, w, y, c)
    rcond = {}
    for name in ("quadrature", "ca", "cv", "static"):
        sol = solve_kinematic(pr, None, rng.normal(size=(1, 3)), np.ones(1), Motion(name))
        rcond[name] = sol.rcond
        assert np.isfinite(sol.z).all() or sol.rcond == 0.0
    assert rcond["quadrature"] < 1e-14 and rcond["ca"] < 1e-14
    assert rcond["cv"] > 1e-6 and rcond["static"] > 1e-6


@pytest.mark.parametrize(("motion", "match"), [(Motion("pva"), "motion"), (Motion("quadrature", 0), "lag"),
                                               (Motion("cv", accel_psd_m2_s3=0.0), "accel_psd_m2_s3")])
def test_bad_motions_are_config_errors(motion: Motion, match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        motion.validated()
