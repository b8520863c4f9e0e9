"""Kinematic positioning the behavioral way: per-epoch fixes smoothed by a Hankel STLS model.

The per-epoch WLS fixes ``x_t`` and their position covariances ``Sigma_t`` are rotated to a
local ENU frame (origin: the first solved fix of each segment), split into segments of
uniformly sampled, solved epochs, cut into sliding windows and projected onto a linear
time-invariant behavior (DESIGN.md section 5):

- ``model="identify"``: the kernel is identified in each window by weighted Hankel STLS
  (``stls(..., structure=kernel)``; the shared kernel keeps a fixed root at ``z = 1`` so the
  result does not depend on the ENU origin);
- ``model="pva"`` / ``model="static"``: the fixed kernels ``(z-1)^3 I`` / ``(z-1) I``; the
  trajectory is the ``Sigma^{-1}``-weighted projection of the fixes onto the behavior.

Each window is fitted with a single descent from the better of the WTLS and polynomial
starts (``stls(..., max_starts=1, restarts=False)``). The extra starts and restarts of the
default ``stls`` changed the 3D RMS of the simulated flights (1 m noise) by little: 1.39
instead of 1.42 m over 10 minutes, 1.34 m either way over an hour. Windows of up to
``BATCH_MAX_EPOCHS`` epochs with a shared or fixed kernel are fitted all at once
(:mod:`gnss_cli.behavior.batch`, the same algorithm with a leading window axis): a day of
1 s epochs is twelve thousand 15-epoch windows, and one at a time their cost would be the
Python overhead of many tiny array operations. Full kernels and longer windows go one at a
time through the banded O(T) STLS.

The receiver clocks (one per system, as in the snapshot solution) are re-estimated per
epoch at the smoothed position (one weighted clock-only least-squares solve; a system
without satellites keeps its clock-fixing constraint row). DOPs are the multi-epoch DOPs of
section 5: over a window whose trajectories are ``O x0`` (``O`` an orthonormal basis of the
behavior, clocks free per epoch), ``Q = (G_N^T G_N)^{-1}`` with
``G_N = [blkdiag(A_t^pos) O, blkdiag(C_t)]`` (``C_t`` the clock columns) and unit weights;
epoch ``t``'s DOPs come from its (position, clocks) block. For an identified kernel
the basis is the free response of the identified behavior (first order: the kernel is held
fixed). Adding the behavior constraint can only shrink ``Q``'s blocks, so the multi-epoch
GDOP never exceeds the snapshot GDOP.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from gnss_cli.behavior import STATUS_MESSAGES, KernelRepresentation, SingularGramError, StlsStatus, misfit, stls
from gnss_cli.behavior.batch import identify_windows, project_windows
from gnss_cli.config import ProcessingConfig
from gnss_cli.errors import GnssError, UsageError
from gnss_cli.gnss.frames import ecef2enu_rotation, ecef2geodetic
from gnss_cli.pipeline import STATUS_OK, EpochData, MethodSolution, _linearize
from gnss_cli.solvers.dop import dop_from_cov

__all__ = ["smooth", "segments", "windows", "behavior_basis", "multi_epoch_cov", "MODELS", "KERNELS",
           "DEFAULT_WINDOW", "STATUS_FALLBACK"]

F64 = NDArray[np.float64]

MODELS = ("identify", "pva", "static")
KERNELS = ("shared", "full")
DEFAULT_WINDOW = 15
"""Default window length, epochs. Measured on the simulated 1 Hz flight (1 m white noise, GPS,
seed 3, ``benchmarks/bench_kinematic.py``), 3D RMS of the shared lag-3 kernel over the LS fixes:
0.55 / 0.50 / 0.47 / 0.45 / 0.41 / 0.56 / 0.78 for windows of 8 / 10 / 12 / 15 / 20 / 25 / 30
epochs. Longer windows average more noise until one recurrence no longer fits the manoeuvres;
15 keeps a margin below that edge."""
STATUS_FALLBACK = "fallback_wls"
"""Status word of an epoch whose segment (or window fit) could not be smoothed: the WLS fix is kept."""


def segments(time_gps_s: F64, solved: NDArray[np.bool_], gap_factor: float = 1.5) -> list[NDArray[np.intp]]:
    """Split epochs into runs of consecutive solved epochs at a uniform sampling interval.

    Parameters
    ----------
    time_gps_s : ndarray, shape (T,)
        Epoch times, s.
    solved : ndarray of bool, shape (T,)
        Epochs with a usable fix.
    gap_factor : float
        A time step larger than ``gap_factor`` times the median step (or not positive) starts
        a new segment.

    Returns
    -------
    list of ndarray of int
        Epoch indices of each segment, in time order.
    """
    t = np.asarray(time_gps_s, dtype=np.float64)
    ok = np.flatnonzero(solved)
    if ok.size == 0:
        return []
    dt = np.diff(t)
    nominal = float(np.median(dt[dt > 0])) if np.any(dt > 0) else 1.0
    out: list[NDArray[np.intp]] = []
    start = 0
    for k in range(1, ok.size):
        a, b = ok[k - 1], ok[k]
        step = t[b] - t[a]
        if b != a + 1 or step <= 0 or abs(step - nominal) > (gap_factor - 1.0) * nominal:
            out.append(ok[start:k])
            start = k
    out.append(ok[start:])
    return out


def windows(n: int, window: int, step: int | None = None) -> tuple[list[tuple[int, int]], NDArray[np.intp]]:
    """Sliding windows over ``n`` epochs and the window that supplies each epoch's estimate.

    Parameters
    ----------
    n : int
        Segment length, epochs.
    window : int
        Window length, epochs; ``0`` (or ``window >= n``) = one window over the whole segment.
    step : int, optional
        Shift between window starts (default ``max(1, window // 2)``: half-overlapping windows).
        The last window is aligned with the segment's end.

    Returns
    -------
    bounds : list of (start, stop)
        Half-open epoch ranges of the windows.
    owner : ndarray of int, shape (n,)
        For each epoch, the window whose centre is nearest (the centre-most estimate is kept;
        ties go to the earlier window).
    """
    if window <= 0 or window >= n:
        return [(0, n)], np.zeros(n, dtype=np.intp)
    step = max(1, window // 2) if step is None else max(1, int(step))
    starts = list(range(0, n - window + 1, step))
    if starts[-1] != n - window:
        starts.append(n - window)
    bounds = [(s, s + window) for s in starts]
    centres = np.array([s + (window - 1) / 2.0 for s in starts])
    # nearest centre: the windows' centres increase, so the owner changes at the midpoints
    # between consecutive centres (an epoch exactly half-way stays with the earlier window)
    owner = np.searchsorted(0.5 * (centres[:-1] + centres[1:]), np.arange(n), side="left").astype(np.intp)
    return bounds, owner


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


def _epoch_information(p_m: F64, weight: F64, clock_cols: F64 | None = None) -> tuple[F64, F64, F64]:
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
        From the per-epoch geometry (see ``_epoch_information``): shapes (..., N, 3, 3),
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


def _min_length(model: str, lag: int, kernel: str) -> int:
    if model == "static":
        return 2
    if model == "pva":
        return 5
    if kernel == "shared":
        return 2 * lag + 2
    return 3 * (lag + 1) + 1


def _kernel_record(ker: KernelRepresentation) -> dict[str, object]:
    try:
        poles = ker.poles()
        pole_list = np.stack([poles.real, poles.imag], axis=1).tolist()
    except GnssError:
        pole_list = []
    rec: dict[str, object] = {"p": ker.p, "q": ker.q, "lag": ker.lag, "order": ker.order,
                              "kernel_R": np.asarray(ker.R).tolist(), "poles": pole_list}
    if ker.is_shared(1e-9):
        rec["shared_coefficients"] = ker.blocks[:, 0, 0].tolist()
    return rec


def _shared_records(r: F64, q: int) -> list[dict[str, object]]:
    """The kernel part of the window records for shared kernels ``r(z) I_q`` ``(B, l+1)`` (as ``_kernel_record``)."""
    n_b, n_blk = r.shape
    lag = n_blk - 1
    big_r = (r[:, None, :, None] * np.eye(q)[None, :, None, :]).reshape(n_b, q, n_blk * q)
    nonzero = r != 0.0
    degree = np.where(nonzero.any(axis=1), n_blk - 1 - np.argmax(nonzero[:, ::-1], axis=1), -1)
    out: list[dict[str, object]] = []
    roots = _shared_roots(r)
    for k in range(n_b):
        poles = np.sort_complex(np.repeat(roots[k], q)) if roots[k] is not None else np.zeros(0, complex)
        out.append({"p": q, "q": q, "lag": lag, "order": int(q * max(degree[k], 0)),
                    "kernel_R": big_r[k].tolist(), "poles": np.stack([poles.real, poles.imag], axis=1).tolist(),
                    "shared_coefficients": r[k].tolist()})
    return out


def _shared_roots(r: F64) -> list[NDArray[np.complex128] | None]:
    """Roots of every ``r`` ``(B, l+1)`` (companion eigenvalues, batched when ``r_l != 0``)."""
    n_b, n_blk = r.shape
    lag = n_blk - 1
    out: list[NDArray[np.complex128] | None] = [None] * n_b
    regular = np.flatnonzero(r[:, -1] != 0.0)
    if regular.size and lag > 0:
        comp = np.zeros((regular.size, lag, lag))
        comp[:, 1:, :-1] = np.eye(lag - 1)
        comp[:, :, -1] = -r[regular, :lag] / r[regular, -1:]
        ev = np.linalg.eigvals(comp)
        for k, j in enumerate(regular):
            out[j] = ev[k]
    for j in np.flatnonzero(r[:, -1] == 0.0):
        out[j] = np.roots(r[j, ::-1]) if np.any(r[j] != 0.0) else np.zeros(0, complex)
    return out


def _shared_basis(r: F64, n_t: int, q: int) -> list[F64 | None]:
    """Orthonormal behavior bases ``(n_t, q, k)`` of shared kernels ``(B, l+1)`` (``behavior_basis`` batched).

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


@dataclass(slots=True)
class _Segment:
    """A run of epochs in its local ENU frame."""

    epochs: NDArray[np.intp]
    origin: F64
    rot: F64
    w: F64
    cov: F64


@dataclass(slots=True)
class _Job:
    """One window of a segment and the epochs whose estimate it supplies (``lo:hi``, segment-local)."""

    segment: int
    window: int
    a: int
    b: int
    lo: int
    hi: int


@dataclass(slots=True)
class _Fit:
    """The result of one window: corrected ENU trajectory, kernel, record fields, DOP basis (ENU)."""

    w_hat: F64 | None
    record: dict[str, object]
    basis: F64 | None


#: Windows up to this many epochs are fitted together (:mod:`gnss_cli.behavior.batch`, dense
#: per-window factors); longer ones (e.g. ``window=0``) one at a time by the banded O(T) STLS.
BATCH_MAX_EPOCHS = 64
FIXED_KERNELS = {"static": ([-1.0, 1.0], "fixed kernel (z-1) I"), "pva": ([-1.0, 3.0, -3.0, 1.0], "fixed kernel (z-1)^3 I")}


def _fit_group(segs: list[_Segment], jobs: list[_Job], model: str, lag: int, tol: float,
               max_iter: int) -> list[_Fit]:
    """Fixed or identified shared kernels for windows of equal length, all at once."""
    n_t = jobs[0].b - jobs[0].a
    w = np.stack([segs[j.segment].w[j.a : j.b] for j in jobs])
    cov = np.stack([segs[j.segment].cov[j.a : j.b] for j in jobs])
    if model in FIXED_KERNELS:
        coef, message = FIXED_KERNELS[model]
        misfit, w_hat = project_windows(w, coef, cov)
        r = np.broadcast_to(np.asarray(coef), (len(jobs), len(coef))).copy()
        status = np.where(np.isfinite(misfit), int(StlsStatus.DIRECT), int(StlsStatus.INFEASIBLE))
        messages = [message if st > 0 else STATUS_MESSAGES[StlsStatus.INFEASIBLE] for st in status]
    else:
        fits = identify_windows(w, lag, cov, fixed_roots=(1.0,), tol=tol, max_iter=max_iter)
        misfit, w_hat, r, status = fits.misfit, fits.w_hat, fits.r, fits.status
        messages = [STATUS_MESSAGES[StlsStatus(int(st))] for st in status]
    ok = np.flatnonzero(status >= 0)
    bases = _shared_basis(r[ok], n_t, 3) if ok.size else []
    rec_of = dict(zip(ok.tolist(), _shared_records(r[ok], 3) if ok.size else []))
    basis_of = dict(zip(ok.tolist(), bases))
    out: list[_Fit] = []
    for k in range(len(jobs)):
        if status[k] < 0 or basis_of.get(k) is None:
            message = messages[k] if status[k] < 0 else "kernel: R_lag is singular; cannot solve for w(t+lag)"
            out.append(_Fit(None, {"status": "failed", "message": message, "misfit": None}, None))
            continue
        rec = dict(rec_of[k])
        rec.update({"misfit": float(misfit[k]), "status": StlsStatus(int(status[k])).name.lower(), "message": messages[k]})
        out.append(_Fit(w_hat[k], rec, basis_of[k]))
    return out


def _fit_single(seg: _Segment, job: _Job, model: str, lag: int, kernel: str, order: int | None, tol: float,
                max_iter: int) -> _Fit:
    """One window with the banded per-series path (full kernels and long windows)."""
    w, cov = seg.w[job.a : job.b], seg.cov[job.a : job.b]
    try:
        if model in FIXED_KERNELS:
            coef, message = FIXED_KERNELS[model]
            ker = KernelRepresentation.shared(coef, 3)
            m, w_hat = misfit(w, ker, cov)
            st = StlsStatus.DIRECT.name.lower()
        else:
            fixed = (1.0,) if kernel == "shared" else ()
            res = stls(w, lag, order, cov, tol=tol, max_iter=max_iter, structure=kernel, fixed_roots=fixed,
                       max_starts=1, restarts=False)
            if res.status < 0:
                raise SingularGramError(res.message)
            ker, m, w_hat, st, message = res.kernel, res.misfit, res.w_hat, res.status.name.lower(), res.message
        basis = behavior_basis(ker.normalized(), job.b - job.a) if ker.p == ker.q else None
    except (GnssError, np.linalg.LinAlgError) as exc:
        return _Fit(None, {"status": "failed", "message": str(exc), "misfit": None}, None)
    rec = _kernel_record(ker)
    rec.update({"misfit": float(m), "status": st, "message": message})
    return _Fit(w_hat, rec, basis)


def smooth(
    data: EpochData,
    wls: MethodSolution,
    config: ProcessingConfig,
    lag: int,
    model: str = "identify",
    kernel: str = "shared",
    order: int | None = None,
    window: int = DEFAULT_WINDOW,
    step: int | None = None,
    gap_factor: float = 1.5,
    method: str = "stls",
    tol: float = 1e-6,
    max_iter: int = 200,
) -> tuple[MethodSolution, list[dict[str, object]]]:
    """Smooth per-epoch WLS fixes with a behavioral (kernel) model over sliding windows.

    Parameters
    ----------
    data : EpochData
        The prepared epochs (from :func:`gnss_cli.pipeline.load_epochs`).
    wls : MethodSolution
        Per-epoch WLS fixes of ``data`` with covariances ``cov_m2`` (m^2).
    config : ProcessingConfig
        Processing options (weights, masks, atmosphere models for the clock solve).
    lag : int
        Lag ``l >= 1`` of the identified kernel (``model="identify"``); the fixed models
        have their own lag (static 1, pva 3).
    model : {"identify", "pva", "static"}
        Identified kernel or one of the fixed kernels.
    kernel : {"shared", "full"}
        Structure of the identified kernel: ``r(z) I_3`` with a fixed root at 1, or a full
        ``3 x 3(l+1)`` kernel.
    order : int, optional
        Order of the full kernel (default ``3 l``).
    window : int
        Window length, epochs; ``0`` = whole segments.
    step : int, optional
        Window shift (default ``window // 2``). Each epoch keeps the estimate of the window
        whose centre is nearest to it (the centre-most estimate).
    gap_factor : float
        Segments split where the time step exceeds ``gap_factor`` times the median step,
        and at unsolved epochs.
    method : str
        Method key written into the result.
    tol, max_iter : float, int
        Stopping tolerance (relative misfit decrease or step) and iteration limit of the
        identification in each window (see :func:`gnss_cli.behavior.stls`). The default
        ``1e-6`` gave the same 3D RMS as ``1e-10`` on the simulated flight, 10-15 % faster.

    Returns
    -------
    solution : MethodSolution
        Smoothed positions (ECEF, m), re-estimated clocks (m), estimator covariances
        ``cov_m2`` (ECEF + clock, m^2) and multi-epoch DOPs. Status ``ok`` for smoothed
        epochs, ``fallback_wls`` where a segment is too short or the window fit failed
        (the WLS fix, covariance and DOPs are kept), the WLS status word elsewhere.
    models : list of dict
        One record per window: segment, window, time span (s, GPS), epochs, model, kernel
        coefficients, order, poles ``[re, im]``, misfit (dimensionless), status and message.

    Raises
    ------
    UsageError
        Invalid ``lag``, ``model``, ``kernel``, ``window`` or mismatching shapes.

    Notes
    -----
    Each window solves ``min sum_t (w_t - w^_t)^T Sigma_t^{-1} (w_t - w^_t)`` subject to
    ``R H_{l+1}(w^) = 0`` with ``w_t = E (x_t - x_origin)`` the ENU position of the fix and
    ``Sigma_t = E C_t E^T`` its rotated WLS covariance.
    """
    if model not in MODELS:
        raise UsageError(f"model: expected one of {', '.join(MODELS)}, received {model!r}")
    if kernel not in KERNELS:
        raise UsageError(f"kernel: expected one of {', '.join(KERNELS)}, received {kernel!r}")
    if isinstance(lag, bool) or not isinstance(lag, (int, np.integer)) or lag < 1:
        raise UsageError(f"lag: expected an integer >= 1, received {lag!r}")
    if isinstance(window, bool) or not isinstance(window, (int, np.integer)) or window < 0:
        raise UsageError(f"window: expected an integer >= 0 (0 = whole segments), received {window!r}")
    T = data.time_gps_s.size
    if wls.x_ecef_m.shape != (T, 3):
        raise UsageError(f"wls: expected positions of shape ({T}, 3), received {wls.x_ecef_m.shape}")
    eff_lag = {"static": 1, "pva": 3}.get(model, int(lag))
    if model == "identify" and kernel == "full" and order is None:
        order = 3 * eff_lag
    need = max(_min_length(model, eff_lag, kernel), 2)
    if 0 < window < need:
        raise UsageError(f"window: expected 0 or >= {need} epochs for model {model} (lag {eff_lag}), received {window}")

    solved = (wls.status == STATUS_OK) & np.all(np.isfinite(wls.x_ecef_m), axis=1) \
        & np.all(np.isfinite(wls.cov_m2[:, :3, :3].reshape(T, 9)), axis=1)
    x_s = wls.x_ecef_m.copy()
    status = wls.status.astype("<U24").copy()
    smoothed = np.zeros(T, dtype=bool)

    segs: list[_Segment] = []
    jobs: list[_Job] = []
    for seg in segments(data.time_gps_s, solved, gap_factor):
        if seg.size < need:
            status[seg] = STATUS_FALLBACK
            continue
        origin = wls.x_ecef_m[seg[0]]
        lat, lon, _ = ecef2geodetic(origin)
        rot = ecef2enu_rotation(float(lat), float(lon))
        cov_enu = np.einsum("ij,tjk,lk->til", rot, wls.cov_m2[seg, :3, :3], rot)
        segs.append(_Segment(seg, origin, rot, (wls.x_ecef_m[seg] - origin) @ rot.T,
                             0.5 * (cov_enu + cov_enu.transpose(0, 2, 1))))
        bounds, owner = windows(seg.size, int(window), step)
        edges = np.searchsorted(owner, np.arange(len(bounds) + 1), side="left")  # owner is non-decreasing
        jobs += [_Job(len(segs) - 1, wi, a, b, int(edges[wi]), int(edges[wi + 1])) for wi, (a, b) in enumerate(bounds)]

    fits: list[_Fit | None] = [None] * len(jobs)
    by_length: dict[int, list[int]] = {}
    for k, job in enumerate(jobs):
        if (model == "identify" and kernel == "full") or job.b - job.a > BATCH_MAX_EPOCHS:
            fits[k] = _fit_single(segs[job.segment], job, model, eff_lag, kernel, order, tol, max_iter)
        else:
            by_length.setdefault(job.b - job.a, []).append(k)
    for group in by_length.values():
        for k, fit in zip(group, _fit_group(segs, [jobs[k] for k in group], model, eff_lag, tol, max_iter)):
            fits[k] = fit

    models: list[dict[str, object]] = []
    dop_windows: list[tuple[NDArray[np.intp], F64, NDArray[np.intp]]] = []  # (window epochs, ECEF basis, owned)
    for job, fit in zip(jobs, fits):
        assert fit is not None
        seg = segs[job.segment]
        mine = seg.epochs[job.lo : job.hi]
        rec: dict[str, object] = {"segment": job.segment, "window": job.window,
                                  "start_time_gps_s": float(data.time_gps_s[seg.epochs[job.a]]),
                                  "end_time_gps_s": float(data.time_gps_s[seg.epochs[job.b - 1]]),
                                  "n_epochs": int(job.b - job.a), "model": model,
                                  "structure": kernel if model == "identify" else "shared"}
        rec.update(fit.record)
        models.append(rec)
        if fit.w_hat is None:
            status[mine] = STATUS_FALLBACK
            continue
        x_s[mine] = seg.origin + fit.w_hat[job.lo - job.a : job.hi - job.a] @ seg.rot
        smoothed[mine] = True
        status[mine] = STATUS_OK
        if fit.basis is not None and fit.basis.shape[2] > 0:
            dop_windows.append((seg.epochs[job.a : job.b], np.einsum("ji,tjk->tik", seg.rot, fit.basis), mine))

    return _finish(data, wls, config, x_s, status, smoothed, dop_windows, method), models


def _finish(data: EpochData, wls: MethodSolution, config: ProcessingConfig, x_s: F64, status: NDArray[np.str_],
            smoothed: NDArray[np.bool_], dop_windows: list[tuple[NDArray[np.intp], F64, NDArray[np.intp]]],
            method: str) -> MethodSolution:
    T, n = data.time_gps_s.size, data.sv.size
    clocks = (wls.clocks_m if wls.clocks_m is not None else wls.clock_m[:, None]).copy()
    n_clk = clocks.shape[1]
    cov = wls.cov_m2.copy()
    dops = {k: getattr(wls, k).copy() for k in ("gdop", "pdop", "hdop", "vdop", "tdop")}
    tdops = wls.tdops.copy() if wls.tdops is not None else None
    residuals = wls.residuals_m.copy()
    n_sat = wls.n_sat.copy()
    rows = np.flatnonzero(smoothed)
    present = np.ones((T, n_clk), dtype=bool)
    if rows.size:
        # One clock per system: rows [satellites (n), constraints of absent systems (k > 1)].
        lin = _linearize(data, rows, x_s[rows], np.zeros((rows.size, n_clk)), config)
        clock_cols = lin.A[..., 3:]
        wgt = np.where(lin.mask, 1.0 / lin.var_m2, 0.0)
        sw = np.einsum("tn,tnk->tk", wgt, clock_cols)
        clocks[rows] = np.einsum("tn,tnk,tn->tk", wgt, clock_cols, lin.q) / np.where(sw > 0, sw, 1.0)
        fitted = lin.q - np.einsum("tnk,tk->tn", clock_cols, clocks[rows])
        residuals[rows] = np.where(lin.mask[:, :n], fitted[:, :n], np.nan)
        n_sat[rows] = lin.mask[:, :n].sum(axis=1)
        if n_clk > 1:
            present[rows] = ~lin.mask[:, n:]  # a set constraint row marks a system without satellites
        p_m = lin.A[..., :3]
        sat_rows = lin.mask.astype(np.float64)
        sat_rows[:, n:] = 0.0  # the DOP gain is from satellite noise only, as for the snapshot methods
        geometry = {}
        for name, weights in (("w", wgt), ("u", sat_rows)):
            info, h, cv = np.full((T, 3, 3), np.nan), np.full((T, n_clk, 3), np.nan), np.full((T, n_clk), np.nan)
            info[rows], h[rows], cv[rows] = _epoch_information(p_m, weights, clock_cols)
            geometry[name] = (info, h, cv)
        rot_local = np.full((T, 3, 3), np.nan)
        rot_local[rows] = lin.rot
        gain_q = np.full((T, 3 + n_clk, 3 + n_clk), np.nan)
        groups: dict[tuple[int, int], list[int]] = {}
        for j, (span, basis, _) in enumerate(dop_windows):
            groups.setdefault(basis.shape[::2], []).append(j)
        for members in groups.values():
            spans = np.stack([dop_windows[j][0] for j in members])
            bases = np.stack([dop_windows[j][1] for j in members])
            cw = _window_covs(bases, spans, *geometry["w"])
            cu = _window_covs(bases, spans, *geometry["u"])
            for i, j in enumerate(members):
                if cw[i] is None or cu[i] is None:
                    continue
                span, _, mine = dop_windows[j]
                pos = mine - span[0]
                cov[mine] = cw[i][pos]
                gain_q[mine] = cu[i][pos]
        have = np.flatnonzero(np.all(np.isfinite(gain_q.reshape(T, -1)), axis=1))
        if have.size:
            d = dop_from_cov(gain_q[have], rot_local[have])
            for k in dops:
                dops[k][have] = getattr(d, k)
            dops["tdop"][have] = np.where(present[have, 0], dops["tdop"][have], np.nan)
            if tdops is not None:
                q_clk = gain_q[have][:, 3 + np.arange(n_clk), 3 + np.arange(n_clk)]
                tdops[have] = np.where(present[have], np.sqrt(np.clip(q_clk, 0.0, None)), np.nan)
    bad = np.isin(status, [STATUS_OK, STATUS_FALLBACK], invert=True)
    x_out = np.where(bad[:, None], np.nan, x_s)
    clocks = np.where(bad[:, None], np.nan, clocks)
    return replace(wls, method=method, x_ecef_m=x_out, clock_m=clocks[:, 0],
                   clocks_m=clocks if wls.clocks_m is not None else None, tdops=tdops, n_sat=n_sat,
                   cov_m2=np.where(bad[:, None, None], np.nan, cov), status=status,
                   residuals_m=np.where(bad[:, None], np.nan, residuals), gdop_paper=None, **dops)


def _window_covs(bases: F64, spans: NDArray[np.intp], info: F64, h: F64, cv: F64) -> list[F64 | None]:
    """``multi_epoch_cov`` of windows with equal shapes; None for a window whose information is singular."""
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
