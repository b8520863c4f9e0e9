"""Multi-epoch geometry of a behavior (DESIGN.md section 5): bases, information, covariance, DOP.

Over a window whose trajectories are ``O x0`` (``O`` an orthonormal basis of the behavior,
clocks free per epoch), ``Q = (G_N^T W G_N)^{-1}`` with ``G_N = [blkdiag(A_t^pos) O,
blkdiag(C_t)]`` (``C_t`` the clock columns); epoch ``t``'s (position, clocks) block of ``Q``
gives its multi-epoch covariance and, with unit weights, its DOPs. Adding the behavior
constraint can only shrink ``Q``'s blocks, so the multi-epoch GDOP never exceeds the
snapshot GDOP.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from gnss_cli.behavior.kernel import KernelRepresentation

__all__ = ["behavior_basis", "shared_behavior_bases", "epoch_information", "multi_epoch_cov", "window_covs",
           "epoch_information_root", "TargetCovs", "target_covs"]

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
        basis = shared_behavior_bases(kernel.blocks[:, 0, 0][None, :], n_t, q)[0]
        assert basis is not None  # r_lag != 0, and the sweep spans every mode
        return basis
    a = kernel.transition()  # (q, q*lag): w(t+lag) = a [w(t); ...; w(t+lag-1)]
    k = q * lag
    traj = np.zeros((max(n_t, lag), q, k))
    traj[:lag] = np.eye(k).reshape(lag, q, k)
    with np.errstate(over="ignore", invalid="ignore"):
        for t in range(lag, n_t):
            traj[t] = a @ traj[t - lag : t].reshape(k, k)
    flat = traj[:n_t].reshape(n_t * q, k)
    if np.all(np.isfinite(flat)):
        u, s, _ = np.linalg.svd(flat, full_matrices=False)
        rank = int(np.sum(s > s[0] * 1e-10)) if s.size and s[0] > 0 else 0
        if rank == min(k, n_t * q):
            return u[:, :rank].reshape(n_t, q, rank)
    return _swept_free_responses(a, n_t)


def _swept_free_responses(a: F64, n_t: int) -> F64:
    """Orthonormal basis of the free responses of ``w(t+l) = a [w(t); ...; w(t+l-1)]`` over ``n_t`` epochs.

    The recursion run once from unit initial conditions loses modes over a long window: a root
    outside the unit circle (or, run backwards, one near 0) grows until it swamps the others
    below the rank threshold, or overflows. Here the responses are extended one epoch at a time
    and kept orthonormal at every step (continuous orthonormalization, as in shooting methods for
    stiff boundary-value problems): the columns of ``[B; V]``, ``B`` orthonormal, times
    ``(I + V^T V)^(-1/2)`` are orthonormal again and span the same responses, so no mode is lost
    and nothing overflows. ``O(n_t^2 k^2)`` flops: used where the one-pass recursion fails.

    Parameters
    ----------
    a : ndarray, shape (q, q*l)
        The transition (``KernelRepresentation.transition``; for a shared kernel ``q = 1`` and
        ``a = -r_{0..l-1} / r_l``).
    n_t : int
        Epochs, ``>= l``.

    Returns
    -------
    O : ndarray, shape (n_t, q, q*l)
        Orthonormal columns that span every free response (the behavior has dimension ``q l``).
    """
    q, k = a.shape
    lag = k // q
    basis = np.zeros((max(n_t, lag) * q, k))
    basis[:k] = np.eye(k)
    for t in range(lag, n_t):
        v = a @ basis[(t - lag) * q : t * q]  # (q, k): the next epoch of every response
        w, vec = np.linalg.eigh(np.eye(k) + v.T @ v)
        basis[t * q : (t + 1) * q] = v
        basis[: (t + 1) * q] = basis[: (t + 1) * q] @ ((vec / np.sqrt(w)) @ vec.T)
    u, _ = np.linalg.qr(basis[: n_t * q])  # rounding of the n_t updates: orthonormal to the last bit
    return u.reshape(n_t, q, k)


def shared_behavior_bases(r: F64, n_t: int, q: int) -> list[F64 | None]:
    """Orthonormal behavior bases ``(n_t, q, k)`` of shared kernels ``(B, l+1)`` (:func:`behavior_basis` batched).

    None where ``r_l`` is negligible (no recursion for ``w(t+l)``, as ``transition`` refuses).
    The responses are run forwards and backwards at once for the whole batch. Where that leaves a
    kernel's modes incomplete or overflowed (roots far on both sides of the unit circle over a long
    window), its responses are swept instead (:func:`_swept_free_responses`), so every basis has
    ``q l`` columns.
    """
    n_b, n_blk = r.shape
    lag = n_blk - 1
    lead = r[:, -1]
    regular = np.abs(lead) > 1e-10 * np.abs(r).max(axis=1)
    monic = r / np.where(regular, lead, 1.0)[:, None]
    scalar = np.zeros((n_b, max(n_t, lag), lag))
    scalar[:, :lag] = np.eye(lag)
    with np.errstate(over="ignore", invalid="ignore"):
        for t in range(lag, n_t):
            scalar[:, t] = -np.einsum("bk,bkj->bj", monic[:, :lag], scalar[:, t - lag : t])
    # The responses from the window's end as well, run backwards where r_0 allows: a root far
    # outside the unit circle (|z| = 14 in a 15-epoch window grows 1e16-fold) swamps every forward
    # response, and the slow modes would fall below the rank threshold; backwards it decays. Each
    # column scaled to unit size, the union spans the behavior with its small modes intact.
    back = np.zeros((n_b, max(n_t, lag), lag))
    first = monic[:, 0]
    reversible = np.abs(first) > 1e-10
    back[:, max(n_t, lag) - lag:] = np.eye(lag)
    with np.errstate(over="ignore", invalid="ignore"):  # overflow: found below, swept instead
        for t in range(n_t - lag - 1, -1, -1):
            back[:, t] = -np.einsum("bk,bkj->bj", monic[:, 1:], back[:, t + 1 : t + 1 + lag]) / np.where(
                reversible, first, 1.0)[:, None]
        back = np.where(reversible[:, None, None], back, 0.0)
        both = np.concatenate([scalar[:, :n_t], back[:, :n_t]], axis=2)
        size = np.max(np.abs(both), axis=1, keepdims=True)
        both = np.where(size > 0, both / np.where(size > 0, size, 1.0), 0.0)
    out: list[F64 | None] = [None] * n_b
    finite = np.all(np.isfinite(both), axis=(1, 2))
    good = np.flatnonzero(regular & finite)
    eye = np.eye(q)
    if good.size:
        u, sv, _ = np.linalg.svd(both[good], full_matrices=False)
        rank = np.minimum(np.sum(sv > sv[:, :1] * 1e-10, axis=1), lag)  # the two sets span one space
        for i, k in enumerate(good):
            if rank[i] == min(lag, n_t):
                out[k] = np.einsum("tj,ac->tajc", u[i, :, : rank[i]], eye).reshape(n_t, q, rank[i] * q)
    for k in np.flatnonzero(regular):  # modes swamped or overflowed, at both ends: the sweep
        if out[k] is None and n_t >= lag:
            scalar_basis = _swept_free_responses(-monic[k, :lag][None, :], n_t)[:, 0, :]
            out[k] = np.einsum("tj,ac->tajc", scalar_basis, eye).reshape(n_t, q, lag * q)
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


def epoch_information_root(p_m: F64, weight: F64, clock_cols: F64 | None = None) -> tuple[F64, F64, F64]:
    """Square-root form of :func:`epoch_information`: ``root_t^T root_t = info_t``, without forming ``info``.

    Parameters
    ----------
    p_m, weight, clock_cols : ndarrays
        As for :func:`epoch_information`: ``(T, n, 3)``, ``(T, n)`` (0 for unused rows, whose
        position entries may then be NaN), ``(T, n, k)`` or None (one clock for every row).

    Returns
    -------
    root : ndarray, shape (T, 3, 3)
        Upper triangular R factor of the clock-reduced rows ``sqrt(w_i) (a_i - h_{j(i)})``.
    h : ndarray, shape (T, k, 3)
        ``P^T W c_j / (c_j^T W c_j)`` (``k = 1`` without ``clock_cols``).
    clock_var : ndarray, shape (T, k)
        ``1 / (c_j^T W c_j)``; 0 for a clock without weighted rows.

    Notes
    -----
    Eliminating clock ``j`` subtracts its weighted mean row from each of its rows; the QR of
    the reduced rows gives the position information's factor with the condition number of
    the rows, not of the normal matrix (STYLE: covariance from the R factor).
    """
    w = np.asarray(weight, dtype=np.float64)
    on = w > 0
    p = np.where(on[..., None], p_m, 0.0)
    c = np.ones((*w.shape, 1)) if clock_cols is None else np.broadcast_to(clock_cols, (*w.shape, clock_cols.shape[-1]))
    cw = c * np.where(on, w, 0.0)[..., None]
    sw = cw.sum(axis=1)
    inv = np.where(sw > 0, 1.0 / np.where(sw > 0, sw, 1.0), 0.0)
    h = np.einsum("tnk,tni->tki", cw, p) * inv[..., None]
    reduced = np.sqrt(np.where(on, w, 0.0))[..., None] * (p - np.einsum("tnk,tki->tni", c, h))
    if reduced.shape[1] < 3:  # QR needs as many rows as columns for a (3, 3) factor
        reduced = np.concatenate([reduced, np.zeros((w.shape[0], 3 - reduced.shape[1], 3))], axis=1)
    return np.linalg.qr(reduced, mode="r")[:, :3], h, inv


@dataclass(frozen=True, slots=True)
class TargetCovs:
    """(position, clocks) covariance blocks of target epochs of multi-epoch windows.

    Attributes
    ----------
    cov : ``(M, 3 + k, 3 + k)`` blocks of ``(G_N^T W G_N)^+`` for ``[x_t (ECEF), clocks_t]``;
        NaN where the target is not determined. A clock without rows has 0 on its diagonal.
    determined : ``(M,)`` the target's position is an estimable function of the window's data.
    cond : ``(M,)`` condition number ``s_max / s_min`` of the window's clock-reduced stacked
        geometry (the square root of its information's); inf when it is rank deficient.
    full_rank : ``(M,)`` every trajectory of the window's behavior is observed (``s_min`` above
        the rank tolerance).
    """

    cov: F64
    determined: NDArray[np.bool_]
    cond: F64
    full_rank: NDArray[np.bool_]


def _inverse_factors(stacked: F64, tol: float) -> tuple[F64, F64, F64]:
    """``X`` with ``X X^T = (S^T S)^+`` for stacked rows ``S`` ``(b, m, d)``, the null vectors of ``S``
    (``(b, d, d)``, zero columns elsewhere) and ``||S||_F ||S^+||_F`` (inf when rank deficient).

    QR first (``X = R^-1``); the windows whose condition number reaches ``1 / tol`` go through an
    SVD of ``R`` (``X = V diag(1/s)`` with ``s <= tol s_max`` dropped)."""
    b, _, d = stacked.shape
    r = np.linalg.qr(stacked, mode="r")
    fro = np.linalg.norm(r, axis=(1, 2))
    x = np.zeros((b, d, d))
    null = np.zeros((b, d, d))
    cond = np.full(b, np.inf)
    diag = np.abs(np.diagonal(r, axis1=1, axis2=2))
    fast = np.flatnonzero(diag.min(axis=1) > tol * fro)
    if fast.size:
        x[fast] = np.linalg.inv(r[fast])
        cond[fast] = fro[fast] * np.linalg.norm(x[fast], axis=(1, 2))
    slow = np.flatnonzero(~(cond * tol < 1.0))
    if slow.size:
        _, sv, vt = np.linalg.svd(r[slow])
        v = np.swapaxes(vt, -1, -2)
        kept = sv > tol * sv[:, :1]
        inv_s = np.where(kept, 1.0 / np.where(kept, sv, 1.0), 0.0)
        x[slow] = v * inv_s[:, None, :]
        null[slow] = np.where(kept[:, None, :], 0.0, v)
        cond[slow] = np.where(kept.all(axis=1), fro[slow] * np.linalg.norm(inv_s, axis=1), np.inf)
    return x, null, cond


def target_covs(root: F64, h: F64, clock_var: F64, spans: NDArray[np.intp], bases: F64, basis_of: NDArray[np.intp],
                window_of: NDArray[np.intp], position: NDArray[np.intp], *, rcond: float | None = None,
                chunk: int = 4096) -> TargetCovs:
    """(position, clocks) covariance of chosen epochs of windows, each window with its behavior basis.

    Parameters
    ----------
    root, h, clock_var : ndarrays
        Per-epoch geometry from :func:`epoch_information_root`: ``(T, 3, 3)``, ``(T, k, 3)``, ``(T, k)``.
    spans : ndarray of int, shape (B, N)
        Epoch indices (into ``root``) of each window, in time order.
    bases : ndarray, shape (U, N, 3, d)
        Behavior bases: a window's positions are ``x_t = O_t x0`` (ECEF directions; orthonormal
        columns, e.g. :func:`behavior_basis` rotated to ECEF; ``I_3`` with ``N = 1`` is the snapshot).
    basis_of : ndarray of int, shape (B,)
        Index into ``bases`` of each window's basis.
    window_of, position : ndarrays of int, shape (M,)
        Target epochs: window index and position in it (``0 <= position < N``).
    rcond : float, optional
        Singular values of the stacked geometry up to ``rcond * s_max`` count as zero
        (default ``max(3 N, d) * eps``, as :func:`numpy.linalg.matrix_rank`).
    chunk : int
        Windows factored at once (memory ``chunk * N * 3 * d`` floats).

    Returns
    -------
    TargetCovs
        ``cond`` is the Frobenius-norm condition number ``||S||_F ||S^+||_F`` of the window's
        stacked rows (between the 2-norm one and ``d`` times it).

    Notes
    -----
    Eliminating each epoch's clocks leaves ``x0`` observed through the stacked rows
    ``S = [root_t O_t]_t`` (``3 N x d``), ``S^T S = sum_t O_t^T M_t O_t``; with ``S = Q R``,
    ``C_t = O_t R^-1 R^-T O_t^T``. A window whose ``R`` is (nearly) singular is factored by an SVD
    ``R = U diag(s) V^T`` and ``C_t = O_t V diag(s)^-2 V^T O_t^T`` over the kept ``s`` (the
    pseudo-inverse): a target ``x_t`` is still determined when ``O_t`` is orthogonal to the null
    vectors, and then every generalized inverse gives this ``C_t``. The clock blocks are those of
    :func:`multi_epoch_cov`.
    """
    n_b, n_ep = spans.shape
    n_t, d = position.size, bases.shape[-1]
    k = clock_var.shape[-1]
    cov = np.full((n_t, 3 + k, 3 + k), np.nan)
    determined = np.zeros(n_t, dtype=bool)
    cond = np.full(n_t, np.inf)
    full_rank = np.zeros(n_t, dtype=bool)
    tol = rcond if rcond is not None else max(3 * n_ep, d) * np.finfo(np.float64).eps
    order = np.argsort(window_of, kind="stable")
    cuts = np.searchsorted(window_of[order], np.arange(0, n_b + chunk, chunk))
    for c, w0 in enumerate(range(0, n_b, chunk)):
        sel = order[cuts[c] : cuts[c + 1]]
        if not sel.size:
            continue
        w1 = min(n_b, w0 + chunk)
        basis = bases[0] if bases.shape[0] == 1 else bases[basis_of[w0:w1]]  # one basis: broadcast, no copies
        stacked = np.matmul(root[spans[w0:w1]], basis).reshape(w1 - w0, 3 * n_ep, d)
        x, null, kappa = _inverse_factors(stacked, tol)
        win = window_of[sel] - w0
        o = bases[basis_of[window_of[sel]], position[sel]]  # (m, 3, d)
        y = np.matmul(o, x[win])  # O_t X, X X^T = (S^T S)^+
        c_pos = np.matmul(y, np.swapaxes(y, -1, -2))
        # determined: O_t has no component along the null vectors of S
        hidden = np.max(np.abs(np.matmul(o, null[win])), axis=(1, 2))
        ok = hidden <= 1e-8 * np.maximum(np.max(np.abs(o), axis=(1, 2)), np.finfo(np.float64).tiny)
        epoch = spans[window_of[sel], position[sel]]
        ch = np.einsum("tij,tcj->tic", c_pos, h[epoch])  # C_t h_tc
        blk = np.empty((sel.size, 3 + k, 3 + k))
        blk[:, :3, :3] = c_pos
        blk[:, :3, 3:] = -ch
        blk[:, 3:, :3] = -np.swapaxes(ch, -1, -2)
        blk[:, 3:, 3:] = np.einsum("tci,tid->tcd", h[epoch], ch)
        blk[:, 3 + np.arange(k), 3 + np.arange(k)] += clock_var[epoch]
        cov[sel] = np.where(ok[:, None, None], blk, np.nan)
        determined[sel] = ok
        full_rank[sel] = np.isfinite(kappa[win])
        cond[sel] = kappa[win]
    return TargetCovs(cov, determined, cond, full_rank)
