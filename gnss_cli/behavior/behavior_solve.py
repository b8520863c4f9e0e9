"""A trajectory in the behavior of a fixed shared kernel, from clock-reduced normals (numerics only).

The measurement-domain step of the identified method (DESIGN.md section 6): with ``r(z) I_3``
fixed, the positions of a window of ``N`` epochs are ``x_t - o = sum_j Y_tj c_j`` where the
columns of ``Y`` (``N x l``, orthonormal) span the scalar free responses of ``r`` and
``c_j`` are 3-vectors (the shared kernel acts on each coordinate alike, so any frame will
do, ECEF included). Their velocities are ``v_t = sum_j Yv_tj c_j`` (:func:`shared_modes`).
The epochs' clock-reduced normals (:mod:`gnss_cli.behavior.window_solve`) make the misfit a
quadratic in ``c`` (:func:`solve_in_behavior`).

Velocity of the behavior: the samples ``y(t) = e_1^T A^t s_0`` (``A`` the companion matrix of
``r``) are read as those of the continuous-time system ``s' = F s`` with ``A = exp(F dt)``,
so ``y'(t) = e_1^T A^t F s_0``: the derivative of each mode ``z_i^t`` is
``s_i z_i^t`` with ``s_i = log(z_i) / dt`` (repeated roots included: ``log A`` of a Jordan
block), exact for polynomials (``(z - 1)^3``: quadratic positions, linear velocities) and for
constant-rate turns. A kernel with a root on the negative real axis (a mode that alternates
sign from epoch to epoch) has no real ``log A``: no sampled continuous motion, no velocity.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from gnss_cli.behavior.window_solve import EpochNormals

__all__ = ["shared_modes", "mode_derivatives", "sampled_motion_kernels", "solve_in_behavior", "behavior_misfit", "MIN_RCOND"]

F64 = NDArray[np.float64]

#: Normals of the window coefficients with a smaller ratio of extreme eigenvalues are singular.
MIN_RCOND = 1e-13
_SERIES_RADIUS = 0.5  # |z - 1| below this for every root: log(I + X) by its series
_SERIES_TERMS = 80


def _companion(r: F64) -> F64:
    """``(B, l, l)`` companion matrices of monic-normalized ``r (B, l+1)``: ``s(t+1) = A s(t)``."""
    n_b, lag = r.shape[0], r.shape[1] - 1
    a = np.zeros((n_b, lag, lag))
    a[:, np.arange(lag - 1), np.arange(1, lag)] = 1.0
    a[:, -1, :] = -r[:, :lag] / r[:, lag:]
    return a


def _sqrtm(a: F64, iterations: int = 60) -> tuple[F64, NDArray[np.bool_]]:
    """Principal square roots of ``a (B, l, l)`` (Denman--Beavers iteration) and where it converged."""
    y, z = a.copy(), np.broadcast_to(np.eye(a.shape[-1]), a.shape).copy()
    done = np.zeros(a.shape[0], dtype=bool)
    with np.errstate(all="ignore"):
        for _ in range(iterations):
            y_new = 0.5 * (y + np.linalg.inv(z))
            z = 0.5 * (z + np.linalg.inv(y))
            done = np.all(np.abs(y_new - y) <= 1e-15 * np.maximum(1.0, np.abs(y_new).max(axis=(1, 2)))[:, None, None],
                          axis=(1, 2))
            y = y_new
            if done.all():
                break
    return y, done & np.all(np.isfinite(y), axis=(1, 2))


def _log_companion(a: F64) -> tuple[F64, NDArray[np.bool_]]:
    """Real matrix logarithms of ``a (B, l, l)`` and where one exists.

    Inverse scaling and squaring, batched: square roots (:func:`_sqrtm`) until every eigenvalue
    is within :data:`_SERIES_RADIUS` of 1, then the series of ``log(I + X)``, times ``2^k``.
    Close roots (two near ``z = 1`` and a far third are the rule for identified kernels) need no
    special care, unlike ``V log(L) V^-1``. No real logarithm where a root is on ``(-inf, 0]``.
    """
    n_b, lag, _ = a.shape
    finite = np.all(np.isfinite(a), axis=(1, 2))
    ev = np.linalg.eigvals(np.where(finite[:, None, None], a, np.eye(lag))).astype(np.complex128)  # complex even when
    # the first batch's roots are all real: a later square root's are stored into it
    real = finite & np.all((np.abs(ev.imag) > 1e-12) | (ev.real > 0.0), axis=1)  # no root on (-inf, 0]
    out = np.full_like(a, np.nan)
    m = np.where(real[:, None, None], a, np.eye(lag))
    scale = np.zeros(n_b)
    for _ in range(40):
        far = real & ~np.all(np.abs(ev - 1.0) < _SERIES_RADIUS, axis=1)
        if not far.any():
            break
        root, ok = _sqrtm(m[far])
        idx = np.flatnonzero(far)
        real[idx[~ok]] = False
        m[idx[ok]] = root[ok]
        scale[idx[ok]] += 1
        ev[idx] = np.linalg.eigvals(np.where(ok[:, None, None], root, np.eye(lag)))
    near = real & np.all(np.abs(ev - 1.0) < _SERIES_RADIUS, axis=1)
    x = m[near] - np.eye(lag)
    term = np.broadcast_to(np.eye(lag), x.shape).copy()
    acc = np.zeros_like(x)
    for k in range(1, _SERIES_TERMS + 1):
        term = term @ x
        acc += (-1.0) ** (k + 1) / k * term
    out[near] = acc * (2.0 ** scale[near])[:, None, None]
    return out, np.all(np.isfinite(out), axis=(1, 2))


def shared_modes(r: F64, n_t: int, dt_s: F64,
                 velocity: bool = True) -> tuple[F64, F64, NDArray[np.bool_], NDArray[np.bool_]]:
    """Orthonormal free-response bases of shared kernels and their time derivatives.

    Parameters
    ----------
    r : ``(B, l+1)``
        Ascending coefficients of ``r(z)`` (``r_l != 0``).
    n_t : int
        Epochs per window, ``>= l``.
    dt_s : ``(B,)``
        Sampling interval of each window, s.
    velocity : bool
        Whether to compute ``Yv`` (False: NaN and ``has_velocity`` False).

    Returns
    -------
    Y : ``(B, n_t, l)``
        Orthonormal columns spanning the free responses (positions: ``Y c``).
    Yv : ``(B, n_t, l)``
        Their time derivatives, 1/s (velocities: ``Yv c``); NaN where ``has_velocity`` is False.
    ok : ``(B,)``
        ``r_l`` not negligible and the responses independent (rank ``l``).
    has_velocity : ``(B,)``
        ``ok`` and the companion matrix has a real logarithm (module docstring).

    Examples
    --------
    >>> Y, Yv, ok, hv = shared_modes(np.array([[-1.0, 3.0, -3.0, 1.0]]), 5, np.array([1.0]))  # (z - 1)^3
    >>> t = np.arange(5.0)
    >>> c = np.linalg.lstsq(Y[0], t**2, rcond=None)[0]   # t^2 lies in the behavior ...
    >>> bool(np.allclose(Yv[0] @ c, 2 * t))             # ... and its velocity is 2 t
    True
    """
    n_b, lag = r.shape[0], r.shape[1] - 1
    ok = np.abs(r[:, -1]) > 1e-10 * np.abs(r).max(axis=1) if n_b else np.zeros(0, dtype=bool)
    safe = np.where(ok[:, None], r, np.eye(1, lag + 1, lag))
    a = _companion(safe)
    scalar = np.zeros((n_b, max(n_t, lag), lag))
    scalar[:, :lag] = np.eye(lag)
    for t in range(lag, n_t):
        scalar[:, t] = np.einsum("bk,bkj->bj", a[:, -1, :], scalar[:, t - lag : t])
    scalar = scalar[:, :n_t]
    ok &= np.all(np.isfinite(scalar), axis=(1, 2))
    scalar = np.where(ok[:, None, None], scalar, 0.0)
    q, rq = np.linalg.qr(scalar + np.where(ok, 0.0, 1.0)[:, None, None] * np.eye(n_t, lag))
    d = np.abs(np.einsum("bii->bi", rq))
    ok &= d.min(axis=1) > 1e-10 * d.max(axis=1)
    if velocity:
        log_a, real = _log_companion(a)
    else:
        log_a, real = np.zeros_like(a), np.zeros(n_b, dtype=bool)
    has_v = ok & real
    f = np.where(has_v[:, None, None], log_a, 0.0) / dt_s[:, None, None]
    rq_safe = np.where(ok[:, None, None], rq, np.eye(lag))
    yv = np.linalg.solve(np.swapaxes(rq_safe, 1, 2), np.swapaxes(scalar @ f, 1, 2)).swapaxes(1, 2)  # scalar F R^-1
    return q, np.where(has_v[:, None, None], yv, np.nan), ok, has_v


def mode_derivatives(r: F64, dt_s: F64) -> tuple[F64, NDArray[np.bool_]]:
    """``F = log(A) / dt`` ``(B, l, l)`` of shared kernels ``r (B, l+1)`` and where it exists.

    The velocity of a trajectory of the behavior at epoch ``t0 + j`` (``0 <= j < l``) is
    ``F[j] @ x[t0 : t0 + l]`` (module docstring: the state ``s(t0)`` of the companion form is
    the ``l`` positions from ``t0``, and ``y'(t0 + j) = e_j^T F s(t0)``). NaN where no real
    logarithm exists (a root on ``(-inf, 0]``) or ``r_l`` is negligible.

    >>> F, ok = mode_derivatives(np.array([[-1.0, 3.0, -3.0, 1.0]]), np.array([1.0]))  # (z - 1)^3
    >>> x = np.arange(3.0) ** 2                                                        # t^2 ...
    >>> bool(ok[0]) and bool(np.allclose(F[0] @ x, 2 * np.arange(3.0)))                # ... velocity 2 t
    True
    """
    n_b, lag = r.shape[0], r.shape[1] - 1
    ok = np.all(np.isfinite(r), axis=1) & (np.abs(r[:, -1]) > 1e-10 * np.abs(np.nan_to_num(r)).max(axis=1, initial=0.0))
    safe = np.where(ok[:, None], r, np.eye(1, lag + 1, lag))
    log_a, real = _log_companion(_companion(safe))
    ok &= real
    return np.where(ok[:, None, None], log_a / dt_s[:, None, None], np.nan), ok


def sampled_motion_kernels(r: F64) -> tuple[F64, NDArray[np.bool_]]:
    """Shared kernels ``r (B, l+1)`` (ascending coefficients) with every real root on ``(-inf, 0]``
    moved to ``z = 1``, and where a root moved.

    Such a root is a mode that changes sign from one epoch to the next (or a zero mode): no sampled
    continuous motion has one, and its kernel has no velocity (module docstring), so range rates
    cannot be used with it. An identified kernel gets one where its window's noise is fitted
    better by an alternation than by a motion (on the simulated training flights and drives with
    range rates, 41 of a flight's 109 windows of 15 epochs). Moving the root to 1 keeps the
    kernel's other roots and puts one more polynomial degree in its place (``(z - 1)^2 (z - z_2)`` for ``(z - 1)
    (z + a) (z - z_2)``; ``(z - 1)^3`` when both free roots are negative), which has a velocity.
    Kernels without such a root are returned unchanged; NaN rows stay NaN.

    >>> from gnss_cli.behavior.kernel import shared_kernel_coefficients as coefficients
    >>> r, moved = sampled_motion_kernels(np.stack([coefficients((1.0, -0.5, 0.9)), coefficients((1.0, 0.8, 0.9))]))
    >>> np.allclose(r[0], coefficients((1.0, 1.0, 0.9))), moved.tolist()
    (True, [True, False])
    """
    out = np.array(r, dtype=np.float64, copy=True)
    moved = np.zeros(out.shape[0], dtype=bool)
    for b in np.flatnonzero(np.all(np.isfinite(out), axis=1) & (np.abs(out[:, -1]) > 0)):
        roots = np.roots(out[b, ::-1])
        bad = (np.abs(roots.imag) <= 1e-9 * np.maximum(1.0, np.abs(roots))) & (roots.real <= 0.0)
        if bad.any():
            roots = np.where(bad, 1.0, roots)
            monic = np.real(np.poly(roots))[::-1]
            out[b] = monic * out[b, -1]
            moved[b] = True
    return out, moved


def _pair_blocks(y: F64) -> F64:
    """``(B, N, 2, l)`` rows ``[Y_{t-1}; Y_t]`` of each epoch pair (row 0: zeros)."""
    out = np.zeros((y.shape[0], y.shape[1], 2, y.shape[2]))
    out[:, 1:, 0], out[:, 1:, 1] = y[:, :-1], y[:, 1:]
    return out


def _stacked(nrm: EpochNormals, shape: tuple[int, int], width: int) -> tuple[F64, F64, F64]:
    n_b, n_t = shape
    return (nrm.M.reshape(n_b, n_t, width, width), nrm.r.reshape(n_b, n_t, width), nrm.s.reshape(n_b, n_t))


def solve_in_behavior(y: F64, yv: F64 | None, d: F64, pr: EpochNormals, rr: EpochNormals | None = None,
                      ph: EpochNormals | None = None) -> tuple[F64, F64, NDArray[np.bool_]]:
    """The window coefficients minimizing the measurement misfit in the behavior (module docstring).

    Parameters
    ----------
    y, yv : ``(B, N, l)``
        Position and velocity bases (:func:`shared_modes`); ``yv`` only with ``rr``.
    d : ``(B, N, 3)``
        Linearization points relative to the window origin ``o``, m: the epochs' pseudorange
        normals are in ``z_t = x_t - o - d_t``.
    pr : EpochNormals
        Pseudorange normals of the ``B N`` epochs (window-major), clocks reduced.
    rr : EpochNormals, optional
        Range-rate normals in the absolute velocity (drift reduced).
    ph : EpochNormals, optional
        Phase-pair normals ``(6, 6)`` on ``[z_{t-1}, z_t]``, zero weight at each window's first epoch.

    Returns
    -------
    c : ``(B, l, 3)``
        Coefficients: positions ``o + y c``, velocities ``yv c``.
    misfit : ``(B,)``
        The misfit of the linearized rows at ``c`` (``inf`` where singular).
    ok : ``(B,)``
        Normals regular (reciprocal condition above :data:`MIN_RCOND`) and finite.

    Notes
    -----
    ``J(c) = sum_t s_t - 2 z_t^T r_t + z_t^T M_t z_t`` (plus the range-rate and pair terms) is
    minimized by ``H c = g`` with ``H = sum_t (Y_t^T Y_t) (x) M_t``, ``g = sum_t Y_t^T (r_t + M_t d_t)``.
    """
    n_b, n_t, lag = y.shape
    M, r, s = _stacked(pr, (n_b, n_t), 3)
    H = np.einsum("btj,btk,btpq->bjpkq", y, y, M).reshape(n_b, 3 * lag, 3 * lag)
    g = np.einsum("btj,btp->bjp", y, r + np.einsum("btpq,btq->btp", M, d)).reshape(n_b, 3 * lag)
    const = s.sum(axis=1) + 2 * np.einsum("btp,btp->b", d, r) + np.einsum("btp,btpq,btq->b", d, M, d)
    if rr is not None:
        assert yv is not None
        Md, rd, sd = _stacked(rr, (n_b, n_t), 3)
        yv0 = np.nan_to_num(yv)
        H += np.einsum("btj,btk,btpq->bjpkq", yv0, yv0, Md).reshape(n_b, 3 * lag, 3 * lag)
        g += np.einsum("btj,btp->bjp", yv0, rd).reshape(n_b, 3 * lag)
        const += sd.sum(axis=1)
    if ph is not None:
        Mp, rp, sp_ = _stacked(ph, (n_b, n_t), 6)
        y6 = _pair_blocks(y)
        d6 = np.zeros((n_b, n_t, 6))
        d6[:, 1:, :3], d6[:, 1:, 3:] = d[:, :-1], d[:, 1:]
        Mp4 = Mp.reshape(n_b, n_t, 2, 3, 2, 3)
        H += np.einsum("btej,btfk,btepfq->bjpkq", y6, y6, Mp4).reshape(n_b, 3 * lag, 3 * lag)
        rhs6 = (rp + np.einsum("btij,btj->bti", Mp, d6)).reshape(n_b, n_t, 2, 3)
        g += np.einsum("btej,btep->bjp", y6, rhs6).reshape(n_b, 3 * lag)
        const += sp_.sum(axis=1) + 2 * np.einsum("bti,bti->b", d6, rp) + np.einsum("bti,btij,btj->b", d6, Mp, d6)
    H = 0.5 * (H + H.transpose(0, 2, 1))
    finite = np.all(np.isfinite(H), axis=(1, 2)) & np.all(np.isfinite(g), axis=1)
    Hs = np.where(finite[:, None, None], H, np.eye(3 * lag))
    ev = np.linalg.eigvalsh(Hs)
    ok = finite & (ev[:, 0] > MIN_RCOND * np.abs(ev[:, -1]))
    Hs = np.where(ok[:, None, None], Hs, np.eye(3 * lag))
    u = np.linalg.solve(Hs, np.where(ok[:, None], g, 0.0)[..., None])[..., 0]
    misfit = np.where(ok, const - np.einsum("bi,bi->b", g, u), np.inf)
    return u.reshape(n_b, lag, 3), misfit, ok


def behavior_misfit(v: F64 | None, pr: EpochNormals, rr: EpochNormals | None = None,
                    ph: EpochNormals | None = None, shape: tuple[int, int] | None = None) -> F64:
    """Misfit ``(B,)`` of windows at their linearization points (positions: ``z = 0``) with velocities
    ``v (B, N, 3)``: ``sum_t s_t`` of the pseudoranges and pairs plus the range rates' ``s - 2 v.r + v M v``."""
    n_b, n_t = shape if shape is not None else (v.shape[0], v.shape[1])  # type: ignore[union-attr]
    out = pr.s.reshape(n_b, n_t).sum(axis=1)
    if rr is not None:
        assert v is not None
        Md, rd, sd = _stacked(rr, (n_b, n_t), 3)
        out = out + sd.sum(axis=1) - 2 * np.einsum("btp,btp->b", v, rd) + np.einsum("btp,btpq,btq->b", v, Md, v)
    if ph is not None:
        out = out + ph.s.reshape(n_b, n_t).sum(axis=1)
    return out
