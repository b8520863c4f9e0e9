"""Multi-epoch geometry of a behavior (DESIGN.md section 5): bases, information, covariance, DOP.

Over a window whose trajectories are ``O x0`` (``O`` an orthonormal basis of the behavior,
clocks free per epoch), ``Q = (G_N^T W G_N)^{-1}`` with ``G_N = [blkdiag(A_t^pos) O,
blkdiag(C_t)]`` (``C_t`` the clock columns); epoch ``t``'s (position, clocks) block of ``Q``
gives its multi-epoch covariance and, with unit weights, its DOPs. Adding the behavior
constraint can only shrink ``Q``'s blocks, so the multi-epoch GDOP never exceeds the
snapshot GDOP.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from gnss_cli.behavior.kernel import KernelRepresentation

__all__ = ["behavior_basis", "shared_behavior_bases", "epoch_information", "multi_epoch_cov", "window_covs"]

F64 = NDArray[np.float64]


def behavior_basis(kernel: KernelRepresentation, n_t: int) -> F64:
    """Orthonormal basis of the trajectories of a square kernel over ``n_t`` epochs.

    Parameters
    ----------
    kernel : KernelRepresentation
        Square kernel (``p = q``) with invertible ``R_lag``.
    n_t : int
        Epochs, ``>= lag``.

    Returns
    -------
    O : ndarray, shape (n_t, q, k)
        ``vec(w) = O x0`` spans the behavior (free responses from every initial condition),
        orthonormalized (``k = q * lag`` columns, fewer if the responses are dependent).

    Raises
    ------
    UsageError
        Non-square kernel or singular ``R_lag``.
    """
    q, lag = kernel.q, kernel.lag
    if kernel.is_shared() and kernel.blocks[-1, 0, 0] != 0.0:
        # r(z) I_q: the scalar free responses times I_q span the same space
        r = kernel.blocks[:, 0, 0] / kernel.blocks[-1, 0, 0]
        scalar = np.zeros((max(n_t, lag), lag))
        scalar[:lag] = np.eye(lag)
        for t in range(lag, n_t):
            scalar[t] = -(r[:lag] @ scalar[t - lag : t])
        u, s, _ = np.linalg.svd(scalar[:n_t], full_matrices=False)
        rank = int(np.sum(s > s[0] * 1e-10)) if s.size and s[0] > 0 else 0
        return np.einsum("tj,ab->tajb", u[:, :rank], np.eye(q)).reshape(n_t, q, rank * q)
    a = kernel.transition()  # (q, q*lag): w(t+lag) = a [w(t); ...; w(t+lag-1)]
    k = q * lag
    traj = np.zeros((max(n_t, lag), q, k))
    traj[:lag] = np.eye(k).reshape(lag, q, k)
    for t in range(lag, n_t):
        traj[t] = a @ traj[t - lag : t].reshape(k, k)
    flat = traj[:n_t].reshape(n_t * q, k)
    u, s, _ = np.linalg.svd(flat, full_matrices=False)
    rank = int(np.sum(s > s[0] * 1e-10)) if s.size and s[0] > 0 else 0
    return u[:, :rank].reshape(n_t, q, rank)


def shared_behavior_bases(r: F64, n_t: int, q: int) -> list[F64 | None]:
    """Orthonormal behavior bases ``(n_t, q, k)`` of shared kernels ``(B, l+1)`` (:func:`behavior_basis` batched).

    None where ``r_l`` is negligible (no recursion for ``w(t+l)``, as ``transition`` refuses).
    """
    n_b, n_blk = r.shape
    lag = n_blk - 1
    lead = r[:, -1]
    regular = np.abs(lead) > 1e-10 * np.abs(r).max(axis=1)
    monic = r / np.where(regular, lead, 1.0)[:, None]
    scalar = np.zeros((n_b, max(n_t, lag), lag))
    scalar[:, :lag] = np.eye(lag)
    for t in range(lag, n_t):
        scalar[:, t] = -np.einsum("bk,bkj->bj", monic[:, :lag], scalar[:, t - lag : t])
    out: list[F64 | None] = [None] * n_b
    good = np.flatnonzero(regular & np.all(np.isfinite(scalar), axis=(1, 2)))
    if good.size == 0:
        return out
    u, sv, _ = np.linalg.svd(scalar[good, :n_t], full_matrices=False)
    rank = np.sum(sv > sv[:, :1] * 1e-10, axis=1)
    eye = np.eye(q)
    for i, k in enumerate(good):
        out[k] = np.einsum("tj,ac->tajc", u[i, :, : rank[i]], eye).reshape(n_t, q, rank[i] * q)
    return out


def epoch_information(p_m: F64, weight: F64, clock_cols: F64 | None = None) -> tuple[F64, F64, F64]:
    """Position information after eliminating the receiver clock(s), per epoch.

    Parameters
    ----------
    p_m : ndarray, shape (T, n, 3)
        Position columns of the design matrix (zero rows for unused satellites).
    weight : ndarray, shape (T, n)
        Row weights (zero for unused satellites), 1/m^2 or unitless.
    clock_cols : ndarray, shape (T, n, k), optional
        Clock columns of the design matrix (one per system: 1 where the row belongs to the
        system). ``None``: one clock for every row.

    Returns
    -------
    info : ndarray, shape (T, 3, 3)
        ``P^T W P - sum_j (P^T W c_j)(c_j^T W P) / (c_j^T W c_j)``.
    h : ndarray, shape (T, k, 3), or (T, 3) without ``clock_cols``
        ``P^T W c_j / (c_j^T W c_j)``.
    clock_var : ndarray, shape (T, k), or (T,) without ``clock_cols``
        ``1 / (c_j^T W c_j)``; 0 for a clock without weighted rows (it is not estimated
        from these rows).
    """
    single = clock_cols is None
    c = np.ones((*weight.shape, 1)) if single else clock_cols
    cw = c * weight[..., None]  # (T, n, k)
    sw = cw.sum(axis=1)  # (T, k): the clock columns of one epoch do not overlap
    inv = np.where(sw > 0, 1.0 / np.where(sw > 0, sw, 1.0), 0.0)
    g = np.einsum("tnk,tni->tki", cw, p_m)
    info = np.einsum("tni,tn,tnj->tij", p_m, weight, p_m) - np.einsum("tki,tk,tkj->tij", g, inv, g)
    h = g * inv[..., None]
    return (info, h[:, 0], inv[:, 0]) if single else (info, h, inv)


def multi_epoch_cov(basis_ecef: F64, info: F64, h: F64, clock_var: F64) -> F64:
    """Per-epoch (position, clocks) covariance blocks of the stacked multi-epoch solution.

    Parameters
    ----------
    basis_ecef : ndarray, shape (..., N, 3, k)
        Behavior basis: window positions ``x_t = O_t x0`` (ECEF directions, m per unit of x0);
        leading axes are windows solved independently.
    info, h, clock_var : ndarrays
        From the per-epoch geometry (see :func:`epoch_information`): shapes (..., N, 3, 3),
        (..., N, c, 3), (..., N, c) with c receiver clocks, or (..., N, 3), (..., N) for one.

    Returns
    -------
    cov : ndarray, shape (..., N, 3 + c, 3 + c)
        Blocks of ``(G_N^T W G_N)^{-1}`` for ``[x_t (ECEF), clocks_t]``; unit of ``1 / W``.

    Raises
    ------
    numpy.linalg.LinAlgError
        If the information of ``x0`` is singular (for any window).

    Notes
    -----
    Eliminating each epoch's clocks leaves ``x0``'s information ``sum_t O_t^T M_t O_t`` with
    ``M_t`` the clock-reduced position information. Then ``C_t = O_t (sum ...)^{-1} O_t^T``,
    ``cov(x_t, b_tj) = -C_t h_tj`` and ``cov(b_ti, b_tj) = delta_ij / (c_j^T W c_j) +
    h_ti^T C_t h_tj`` (the clock columns of one epoch do not overlap).
    """
    if clock_var.ndim == info.ndim - 2:  # one clock
        h, clock_var = h[..., None, :], clock_var[..., None]
    *lead, n_ep, _, k = basis_ecef.shape
    n_clk = clock_var.shape[-1]
    mo = np.matmul(info, basis_ecef)  # M_t O_t
    big = np.einsum("...tik,...til->...kl", basis_ecef, mo)
    chol = np.linalg.cholesky(0.5 * (big + np.swapaxes(big, -1, -2)))
    # L^{-1} O_t^T for all epochs of a window in one solve: (..., k, N*3)
    o_t = np.swapaxes(basis_ecef.reshape(*lead, n_ep * 3, k), -1, -2)
    half = np.linalg.solve(chol, o_t).reshape(*lead, k, n_ep, 3)
    c = np.einsum("...kti,...ktj->...tij", half, half)
    ch = np.einsum("...tij,...tcj->...tic", c, h)  # C_t h_tc: (..., N, 3, n_clk)
    out = np.empty((*lead, n_ep, 3 + n_clk, 3 + n_clk))
    out[..., :3, :3] = c
    out[..., :3, 3:] = -ch
    out[..., 3:, :3] = -np.swapaxes(ch, -1, -2)
    out[..., 3:, 3:] = np.einsum("...tci,...tid->...tcd", h, ch)
    out[..., 3 + np.arange(n_clk), 3 + np.arange(n_clk)] += clock_var
    return out


def window_covs(bases: F64, spans: NDArray[np.intp], info: F64, h: F64, cv: F64) -> list[F64 | None]:
    """:func:`multi_epoch_cov` of windows with equal shapes; None for a window whose information is singular.

    ``bases`` ``(B, N, 3, k)``; ``spans`` ``(B, N)`` epoch indices into the per-epoch
    ``info``, ``h``, ``cv`` (:func:`epoch_information`).
    """
    args = (bases, info[spans], h[spans], cv[spans])
    try:
        return list(multi_epoch_cov(*args))
    except np.linalg.LinAlgError:  # at least one window: fall back to one at a time
        out: list[F64 | None] = []
        for i in range(bases.shape[0]):
            try:
                out.append(multi_epoch_cov(*(x[i] for x in args)))
            except np.linalg.LinAlgError:
                out.append(None)
        return out
