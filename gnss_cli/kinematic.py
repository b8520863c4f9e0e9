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

The receiver clock is re-estimated per epoch at the smoothed position (one weighted
clock-only least-squares solve). DOPs are the multi-epoch DOPs of section 5: over a window
whose trajectories are ``O x0`` (``O`` an orthonormal basis of the behavior, clocks free
per epoch), ``Q = (G_N^T G_N)^{-1}`` with ``G_N = [blkdiag(A_t^pos) O, blkdiag(1_t)]`` and unit
weights; epoch ``t``'s DOPs come from its (position, clock) block. For an identified kernel
the basis is the free response of the identified behavior (first order: the kernel is held
fixed). Adding the behavior constraint can only shrink ``Q``'s blocks, so the multi-epoch
GDOP never exceeds the snapshot GDOP.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from gnss_cli.behavior import KernelRepresentation, SingularGramError, StlsStatus, misfit, stls
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
0.54 / 0.51 / 0.48 / 0.44 / 0.42 / 0.56 / 0.78 for windows of 8 / 10 / 12 / 15 / 20 / 25 / 30
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
    idx = np.arange(n)
    owner = np.argmin(np.abs(idx[:, None] - centres[None, :]), axis=1).astype(np.intp)
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


def _epoch_information(p_m: F64, weight: F64) -> tuple[F64, F64, F64]:
    """Position information after eliminating the clock, per epoch.

    Parameters
    ----------
    p_m : ndarray, shape (T, n, 3)
        Position columns of the design matrix (zero rows for unused satellites).
    weight : ndarray, shape (T, n)
        Row weights (zero for unused satellites), 1/m^2 or unitless.

    Returns
    -------
    info : ndarray, shape (T, 3, 3)
        ``P^T W P - (P^T W 1)(1^T W P) / (1^T W 1)``.
    h : ndarray, shape (T, 3)
        ``P^T W 1 / (1^T W 1)``.
    clock_var : ndarray, shape (T,)
        ``1 / (1^T W 1)``.
    """
    sw = weight.sum(axis=1)
    sw = np.where(sw > 0, sw, 1.0)
    pw = p_m * weight[..., None]
    info = np.einsum("tni,tnj->tij", pw, p_m)
    g = pw.sum(axis=1)
    info = info - g[:, :, None] * g[:, None, :] / sw[:, None, None]
    return info, g / sw[:, None], 1.0 / sw


def multi_epoch_cov(basis_ecef: F64, info: F64, h: F64, clock_var: F64) -> F64:
    """Per-epoch (position, clock) covariance blocks of the stacked multi-epoch solution.

    Parameters
    ----------
    basis_ecef : ndarray, shape (N, 3, k)
        Behavior basis: window positions ``x_t = O_t x0`` (ECEF directions, m per unit of x0).
    info, h, clock_var : ndarrays, shapes (N, 3, 3), (N, 3), (N,)
        From the per-epoch geometry (see ``_epoch_information``).

    Returns
    -------
    cov : ndarray, shape (N, 4, 4)
        Blocks of ``(G_N^T W G_N)^{-1}`` for ``[x_t (ECEF), clock_t]``; unit of ``1 / W``.

    Notes
    -----
    Eliminating each epoch's clock leaves ``x0``'s information ``sum_t O_t^T M_t O_t`` with
    ``M_t`` the clock-reduced position information. Then ``C_t = O_t (sum ...)^{-1} O_t^T``,
    ``cov(x_t, b_t) = -C_t h_t`` and ``var(b_t) = 1 / (1^T W 1) + h_t^T C_t h_t``.
    """
    big = np.einsum("tik,tij,tjl->kl", basis_ecef, info, basis_ecef)
    chol = np.linalg.cholesky(big)
    half = np.linalg.solve(chol, basis_ecef.transpose(0, 2, 1))  # (N, k, 3): L^{-1} O_t^T
    c = np.einsum("tki,tkj->tij", half, half)
    ch = np.einsum("tij,tj->ti", c, h)
    out = np.empty((basis_ecef.shape[0], 4, 4))
    out[:, :3, :3] = c
    out[:, :3, 3] = -ch
    out[:, 3, :3] = -ch
    out[:, 3, 3] = clock_var + np.einsum("ti,ti->t", h, ch)
    return out


def _fit_window(w: F64, cov: F64, model: str, lag: int, kernel: str, order: int | None, tol: float,
                max_iter: int) -> tuple[F64, KernelRepresentation, float, str, str]:
    if model == "static":
        ker = KernelRepresentation.static(3)
        m, w_hat = misfit(w, ker, cov)
        return w_hat, ker, m, StlsStatus.DIRECT.name.lower(), "fixed kernel (z-1) I"
    if model == "pva":
        ker = KernelRepresentation.pva(3)
        m, w_hat = misfit(w, ker, cov)
        return w_hat, ker, m, StlsStatus.DIRECT.name.lower(), "fixed kernel (z-1)^3 I"
    fixed = (1.0,) if kernel == "shared" else ()
    res = stls(w, lag, order, cov, tol=tol, max_iter=max_iter, structure=kernel, fixed_roots=fixed)
    if res.status < 0:
        raise SingularGramError(res.message)
    return res.w_hat, res.kernel, float(res.misfit), res.status.name.lower(), res.message


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
        pole_list = [[float(z.real), float(z.imag)] for z in poles]
    except GnssError:
        pole_list = []
    rec: dict[str, object] = {"p": ker.p, "q": ker.q, "lag": ker.lag, "order": ker.order,
                              "kernel_R": np.asarray(ker.R).tolist(), "poles": pole_list}
    if ker.is_shared(1e-9):
        rec["shared_coefficients"] = ker.shared_coefficients().tolist()
    return rec


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
    basis_of: list[tuple[NDArray[np.intp], F64]] = []  # (epochs of a window, ECEF basis) for DOP
    owner_of: list[tuple[NDArray[np.intp], int]] = []  # (epochs whose estimate came from window j, j)
    models: list[dict[str, object]] = []

    for si, seg in enumerate(segments(data.time_gps_s, solved, gap_factor)):
        if seg.size < need:
            status[seg] = STATUS_FALLBACK
            continue
        origin = wls.x_ecef_m[seg[0]]
        lat, lon, _ = ecef2geodetic(origin)
        rot = ecef2enu_rotation(float(lat), float(lon))
        w = (wls.x_ecef_m[seg] - origin) @ rot.T
        cov = np.einsum("ij,tjk,lk->til", rot, wls.cov_m2[seg, :3, :3], rot)
        cov = 0.5 * (cov + cov.transpose(0, 2, 1))
        bounds, owner = windows(seg.size, int(window), step)
        for wi, (a, b) in enumerate(bounds):
            mine = seg[owner == wi]
            rec: dict[str, object] = {"segment": si, "window": wi,
                                      "start_time_gps_s": float(data.time_gps_s[seg[a]]),
                                      "end_time_gps_s": float(data.time_gps_s[seg[b - 1]]),
                                      "n_epochs": int(b - a), "model": model,
                                      "structure": kernel if model == "identify" else "shared"}
            try:
                w_hat, ker, m, st, msg = _fit_window(w[a:b], cov[a:b], model, eff_lag, kernel, order, tol, max_iter)
                basis = behavior_basis(ker.normalized(), b - a) if ker.p == ker.q else None
            except (GnssError, np.linalg.LinAlgError) as exc:
                status[mine] = STATUS_FALLBACK
                rec.update({"status": "failed", "message": str(exc), "misfit": None})
                models.append(rec)
                continue
            rec.update(_kernel_record(ker))
            rec.update({"misfit": float(m), "status": st, "message": msg})
            models.append(rec)
            pos = origin + w_hat @ rot
            local = np.flatnonzero(owner == wi)
            x_s[seg[local]] = pos[local - a]
            smoothed[seg[local]] = True
            status[seg[local]] = STATUS_OK
            if basis is not None and basis.shape[2] > 0:
                basis_of.append((seg[a:b], np.einsum("ji,tjk->tik", rot, basis)))
                owner_of.append((seg[local], len(basis_of) - 1))

    return _finish(data, wls, config, x_s, status, smoothed, basis_of, owner_of, method), models


def _finish(data: EpochData, wls: MethodSolution, config: ProcessingConfig, x_s: F64, status: NDArray[np.str_],
            smoothed: NDArray[np.bool_], basis_of: list[tuple[NDArray[np.intp], F64]],
            owner_of: list[tuple[NDArray[np.intp], int]], method: str) -> MethodSolution:
    T = data.time_gps_s.size
    clock = wls.clock_m.copy()
    cov = wls.cov_m2.copy()
    dops = {k: getattr(wls, k).copy() for k in ("gdop", "pdop", "hdop", "vdop", "tdop")}
    residuals = wls.residuals_m.copy()
    n_sat = wls.n_sat.copy()
    rows = np.flatnonzero(smoothed)
    if rows.size:
        lin = _linearize(data, rows, x_s[rows], np.zeros(rows.size), config)
        wgt = np.where(lin.mask, 1.0 / lin.var_m2, 0.0)
        sw = wgt.sum(axis=1)
        clock[rows] = (wgt * lin.q).sum(axis=1) / np.where(sw > 0, sw, 1.0)
        residuals[rows] = np.where(lin.mask, lin.q - clock[rows, None], np.nan)
        n_sat[rows] = lin.mask.sum(axis=1)
        p_m = lin.A[..., :3]
        info_w = np.full((T, 3, 3), np.nan)
        info_u = np.full((T, 3, 3), np.nan)
        h_w = np.full((T, 3), np.nan)
        h_u = np.full((T, 3), np.nan)
        cv_w = np.full(T, np.nan)
        cv_u = np.full(T, np.nan)
        info_w[rows], h_w[rows], cv_w[rows] = _epoch_information(p_m, wgt)
        info_u[rows], h_u[rows], cv_u[rows] = _epoch_information(p_m, lin.mask.astype(np.float64))
        rot_local = np.full((T, 3, 3), np.nan)
        rot_local[rows] = lin.rot
        gain_q = np.full((T, 4, 4), np.nan)
        for mine, j in owner_of:
            span, basis = basis_of[j]
            pos = np.searchsorted(span, mine)
            try:
                cw = multi_epoch_cov(basis, info_w[span], h_w[span], cv_w[span])
                cu = multi_epoch_cov(basis, info_u[span], h_u[span], cv_u[span])
            except np.linalg.LinAlgError:
                continue
            cov[mine] = cw[pos]
            gain_q[mine] = cu[pos]
        have = np.flatnonzero(np.all(np.isfinite(gain_q.reshape(T, 16)), axis=1))
        if have.size:
            d = dop_from_cov(gain_q[have], rot_local[have])
            for k in dops:
                dops[k][have] = getattr(d, k)
    bad = np.isin(status, [STATUS_OK, STATUS_FALLBACK], invert=True)
    x_out = np.where(bad[:, None], np.nan, x_s)
    return replace(wls, method=method, x_ecef_m=x_out, clock_m=np.where(bad, np.nan, clock), n_sat=n_sat,
                   cov_m2=np.where(bad[:, None, None], np.nan, cov), status=status,
                   residuals_m=np.where(bad[:, None], np.nan, residuals), gdop_paper=None, **dops)
