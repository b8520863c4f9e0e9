"""The ``stls --lag L`` windows in the measurement domain: kernel and trajectory by alternation.

The paper's joint problem (DESIGN.md section 6), per sliding window of ``[stls] window`` epochs
(the windows of :mod:`gnss_cli.pipeline.behavioral`; :mod:`gnss_cli.pipeline.spans` tests each
result, :func:`behavior_tests`, and solves the epochs of a rejected window again in shorter ones):
unknowns the trajectory ``w^``, the receiver clocks (one per epoch and system, and a drift per
epoch with Doppler) and the shared kernel ``r(z) I_3`` with its root at ``z = 1``; data the
pseudoranges and, as ``--measurements`` gives them, the range rates and the time-differenced
carrier phase -- the rows, weights, variance factors and residual gate of ``smoother`` and
``kf`` (:mod:`gnss_cli.pipeline.measurements`, :mod:`gnss_cli.pipeline.phase_rows`); cost the
weighted measurement misfit ``J(w^)`` with every epoch's clocks eliminated, subject to
``R H_{l+1}(w^) = 0``.

Start: today's position-domain result (the STLS projection of the WLS fixes and its kernel).
Each iteration, for every window at once:

1. linearize the rows at the window's trajectory and evaluate ``J`` there (the misfit of the
   iterate); stop when it no longer decreases (relative decrease below :data:`RTOL`);
2. (a) identify a kernel by weighted Hankel STLS (:func:`~gnss_cli.behavior.batch.identify_windows`)
   on the current trajectory's free per-epoch corrections -- the position each epoch's own
   clock-reduced pseudorange normals give, with their inverse as covariance, and with Doppler the
   velocity each epoch's range rates give as three more channels (the velocity of a behavior of
   ``r(z) I_3`` is in the same behavior). These free fixes ``x + M^-1 r`` do not depend on the
   iterate (to the linearization), so the kernel is identified once per residual gate. With
   range rates a root the identification puts on the negative real axis (an alternating mode:
   no velocity, so the range rates could not be used) is moved to ``z = 1``
   (:func:`~gnss_cli.behavior.behavior_solve.sampled_motion_kernels`): before, such windows kept
   their position-domain result without the range rates -- 41 of the 109 windows of a simulated
   training flight in 15-epoch windows; in whole segments this took that flight's 3D RMS from
   1.07 to 0.93 m and the six training flights and drives 3-21 % lower;
3. (b) with the kernel fixed, solve for the window's trajectory in its behavior from all the
   rows (:func:`~gnss_cli.behavior.behavior_solve.solve_in_behavior`; velocities from the modes
   ``s_i = log(z_i) / dt``, :func:`~gnss_cli.behavior.behavior_solve.shared_modes`), once with
   the identified kernel and once with the current one; the lower linearized misfit wins.

An iterate whose misfit (step 1, at its own linearization) exceeds its predecessor's is not
taken: the window keeps the predecessor and stops. So the misfit is non-increasing by
construction; every window's record carries its iterations, whether it converged and the misfit
of its returned kernel and trajectory. Step 2 needs the safeguard: STLS identifies from the
corrections' quadratic model, which the range rates and phase pairs do not enter.

The residual gate (as ``smoother``'s, :func:`~gnss_cli.pipeline.measurements.gate_rows`) is set at
the starting trajectory and fixed while alternating (a cost that changes under the iterates could
not be monotone); after convergence it is evaluated again and, if it changed, the alternation
continues under the new gate (at most :data:`GATE_PASSES` gates; the misfit history restarts).

A window whose normals are singular, whose kernel has no velocity where Doppler is used, or that
does not converge in :data:`MAX_ALTERNATIONS` iterations keeps its position-domain result; its
record says so. Full kernels are not alternated (their windows keep the position-domain result).

Why alternation and not variable projection over ``r``: step (b) is the exact minimizer for a
fixed kernel and is linear, step (a) reuses the batched STLS of the position-domain method (all
windows at once), and the misfit check makes the iteration safe whatever (a) returns. Variable
projection was built and measured (Newton steps with finite-difference derivatives in the
coefficients of ``r(z) / (z - 1)`` about ``z = 1``, from four starts, with the windows of a run
tied into one trajectory): 3D RMS with range rates on an in-class semicircle 1.30 -> 0.32 m
(``smoother`` 0.36 m), on the 600 s standard flight 1.25 -> 0.66 m (``smoother`` 0.38 m), but
about 9 times slower (the Yamatogawa walk 2.7 -> 24.7 s: every trial kernel needs the matrix
logarithms of its modes), so it is not in (docs/results.md). Since the spans are tied (with
range rates), the kernels no longer limit the result on the simulated manoeuvring tracks: the
kernels that best fit the true track on each span's window give the identified ones' RMS
(0.434 against 0.435 m on the training runs, ``benchmarks/stls_structure.py``), so a descent over
``r`` has nothing left to find there. What this
alternation can and cannot do: its kernels are the position-domain one and the STLS kernel of
the free fixes (with the range rates' velocities), re-identified when the gate changes; the
measurement misfit chooses between them and the trajectory is the exact measurement-domain
solution in the chosen behavior. A kernel that minimizes the measurement misfit itself (where
the range rates and phase pairs act on ``r`` directly) would need that descent over ``r``. Most
iterations in the records are those of the residual gates (one to three per window).

After the spans are chosen (:mod:`gnss_cli.pipeline.spans`), with range rates or phase, the
kernels of this alternation are kept and the trajectories of consecutive spans are solved
together in their piecewise behavior (:mod:`gnss_cli.pipeline.tied`): alone, a window holds
its position only from its own pseudoranges.

Measured before the behavior test of :mod:`gnss_cli.pipeline.spans` (``stls --lag 3``, windows
of 15 epochs; 3D / horizontal RMS, m): pseudoranges alone, the joint
problem with block-diagonal clock-reduced normals *is* the weighted STLS of the per-epoch fixes
(the simulated 1 m-noise 600 s flight: 1.4225 m either way with ``integrity = "off"``); with
Doppler, flight 1.33 / 0.91 (``smoother`` 0.38 / 0.21), the Yamatogawa walk 2.81 / 0.75
(``smoother`` 2.72 / 0.57): a window held its position only from its own pseudoranges. The
numbers of the method as it is now, beside ``kf`` and ``smoother`` on equal information, are
those of ``benchmarks/multi_epoch_fair.py`` (docs/results.md).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from gnss_cli.behavior import StlsStatus
from gnss_cli.behavior.batch import identify_windows
from gnss_cli.behavior.kernel import shared_kernel_coefficients
from gnss_cli.behavior.behavior_solve import behavior_misfit, sampled_motion_kernels, shared_modes, solve_in_behavior
from gnss_cli.behavior.multi_epoch import shared_behavior_bases
from gnss_cli.behavior.records import shared_kernel_records
from gnss_cli.behavior.window_solve import EpochNormals, reduce_epochs
from gnss_cli.config import ProcessingConfig
from gnss_cli.pipeline.behavioral import Fit, Segment, WindowJob
from gnss_cli.pipeline.integrity import take_epochs
from gnss_cli.pipeline.kalman import nominal_trajectory
from gnss_cli.pipeline.kalman_rows import gate_threshold
from gnss_cli.pipeline.measurements import (
    factors_from_totals,
    free_misfit_totals,
    gate_rows,
    kinds_text,
    measurement_rows,
    standardized,
)
from gnss_cli.pipeline.phase_rows import phase_pair_rows
from gnss_cli.pipeline.results import PASSED_FIX, EpochData, MethodSolution, as_wls_used

__all__ = ["alternate_windows", "behavior_tests", "WindowRun", "window_rows", "RTOL", "MAX_ALTERNATIONS", "GATE_PASSES"]

F64 = NDArray[np.float64]

#: Relative decrease of the measurement misfit below which the alternation stops.
RTOL = 1e-6
#: Iterations (accepted steps) after which a window that has not converged falls back.
MAX_ALTERNATIONS = 30
#: Residual gates evaluated per window (the first at the starting trajectory).
GATE_PASSES = 3
_RISE_RTOL = 1e-10  # a misfit rise below this (relative) is rounding


@dataclass(slots=True)
class WindowRun:
    """The alternation of ``B`` windows of ``N`` epochs (arrays with a leading window axis).

    Attributes
    ----------
    jobs : indices of the windows (into the job list).
    epochs : ``(B, N)`` epoch indices.
    origin : ``(B, 3)`` ECEF origin of the segment (m); ``rot`` ``(B, 3, 3)`` its ENU rotation.
    dt_s : ``(B,)`` sampling interval.
    r : ``(B, l+1)`` kernel coefficients; ``c`` ``(B, l, 3)`` window coefficients.
    x : ``(B, N, 3)`` positions relative to ``origin`` (ECEF, m); ``v`` velocities (m/s).
    misfit : ``(B,)`` measurement misfit of the current iterate; ``history`` per window.
    iterations, done, converged, failed : per window; ``message`` why a window stopped.
    mult : ``(3, B, N, n)`` gate (and robust) multipliers of pseudoranges, range rates, pairs.
    gates : residual gates evaluated; ``gate_final``: the last gate left the rows unchanged.
    r_identified : ``(B, l+1)`` the kernels of step (a) under the current gate (NaN: none);
        ``stale`` where they are to be identified again (module docstring).
    test_stat, test_dof : the behavior test of the result (:func:`behavior_tests`; NaN and 0
        where it was not evaluated).
    roots_moved : the kernel of step (a) under the current gate had a root on the negative real
        axis, moved to ``z = 1`` (:func:`~gnss_cli.behavior.behavior_solve.sampled_motion_kernels`).
    """

    jobs: NDArray[np.intp]
    epochs: NDArray[np.intp]
    origin: F64
    rot: F64
    dt_s: F64
    r: F64
    c: F64
    x: F64
    v: F64
    misfit: F64
    history: list[list[float]]
    iterations: NDArray[np.int64]
    done: NDArray[np.bool_]
    converged: NDArray[np.bool_]
    failed: NDArray[np.bool_]
    message: list[str]
    mult: F64
    gated: NDArray[np.bool_]
    gates: NDArray[np.int64]
    gate_final: NDArray[np.bool_]
    r_identified: F64
    stale: NDArray[np.bool_]
    test_stat: F64
    test_dof: NDArray[np.int64]
    roots_moved: NDArray[np.bool_]


def _colors(spans: list[tuple[int, int]]) -> list[int]:
    """A colour per window (epoch ranges ``(first, last + 1)``) such that windows of a colour do not overlap."""
    ends: list[int] = []
    out = []
    for a, b in spans:
        for c, e in enumerate(ends):
            if e <= a:
                ends[c] = b
                out.append(c)
                break
        else:
            ends.append(b)
            out.append(len(ends) - 1)
    return out


def window_rows(data: EpochData, config: ProcessingConfig, kinds: frozenset[str], base: F64,
                runs: list[WindowRun], colors: list[list[int]]) -> list[dict[str, F64]]:
    """The rows of every window linearized at its own trajectory (``runs[i].x``), per run:
    pseudoranges ``P w y C``, range rates ``H wd yd``, phase pairs ``P6 pw py`` (zero weight
    for the pair that ends at a window's first epoch). ``colors[i][k]``: colour of window ``k``
    of run ``i`` (:func:`_colors`); ``base`` ``(T, 3)``: the nominal of the other epochs."""
    doppler, phase = "doppler" in kinds, "phase" in kinds
    n_color = 1 + max((max(c) for c in colors if c), default=0)
    out: list[dict[str, F64]] = [{} for _ in runs]
    for color in range(n_color):
        nominal = base.copy()
        members = []
        for run, col in zip(runs, colors):
            sel = np.flatnonzero((np.asarray(col) == color) & ~run.done)  # windows done need no rows
            members.append(sel)
            if sel.size:
                nominal[run.epochs[sel]] = run.origin[sel, None, :] + run.x[sel]
        union = np.unique(np.concatenate([run.epochs[sel].ravel() for run, sel in zip(runs, members)]))
        if not union.size:
            continue
        # the epochs of this colour's windows only (a window's pairs are consecutive epochs of it; the
        # pair ending at its first epoch is not used, whatever precedes it in the union)
        sub = take_epochs(data, union)
        rows = measurement_rows(sub, nominal[union], config, doppler)
        phr = phase_pair_rows(sub, rows, config) if phase else None
        for run, sel, dst in zip(runs, members, out):
            if not sel.size:
                continue
            ep = np.searchsorted(union, run.epochs[sel])
            got = {k: rows[k][ep] for k in ("P", "w", "y", "C") + (("H", "wd", "yd") if doppler else ())}
            if phr is not None:
                got.update(P6=phr["P6"][ep], pw=phr["w"][ep].copy(), py=phr["y"][ep], pC=phr["C"][ep])
                got["pw"][:, 0] = 0.0
            for k, val in got.items():
                if k not in dst:
                    dst[k] = np.zeros((run.epochs.shape[0], *val.shape[1:]))
                dst[k][sel] = val
    for run, dst in zip(runs, out):  # every key present even when no window of a run needed rows
        n_b, n_t = run.epochs.shape
        n, k = data.sv.size, len(data.systems)
        shapes = {"P": (n, 3), "w": (n,), "y": (n,), "C": (n, k)}
        if doppler:
            shapes.update(H=(n, 3), wd=(n,), yd=(n,))
        if phase:
            shapes.update(P6=(n, 6), pw=(n,), py=(n,), pC=(n, k))
        for key, shp in shapes.items():
            if key not in dst:
                dst[key] = np.zeros((n_b, n_t, *shp))
    return out


def _normals(rows: dict[str, F64], mult: F64, factors: tuple[float, ...]) -> tuple[EpochNormals, EpochNormals | None,
                                                                                   EpochNormals | None]:
    """Clock-reduced normals of every window epoch (flattened ``B N``), gate and factors applied."""
    def flat(a: F64) -> F64:
        return a.reshape(-1, *a.shape[2:])
    pr = reduce_epochs(flat(rows["P"]), flat(rows["w"] * mult[0] / factors[0]), flat(rows["y"]), flat(rows["C"]))
    rr = reduce_epochs(flat(rows["H"]), flat(rows["wd"] * mult[1] / factors[1]), flat(rows["yd"])) if "H" in rows else None
    ph = reduce_epochs(flat(rows["P6"]), flat(rows["pw"] * mult[2] / factors[2]), flat(rows["py"]),
                       flat(rows["pC"])) if "P6" in rows else None
    return pr, rr, ph


def _gate(run: WindowRun, rows: dict[str, F64], factors: tuple[float, ...],
          config: ProcessingConfig) -> tuple[F64, NDArray[np.bool_]]:
    """Gate multipliers ``(3, B, N, n)`` at the current iterate (standardized residuals, clocks re-estimated)."""
    n_b, n_t = run.epochs.shape
    gate = _threshold(config)
    flat = lambda a: a.reshape(-1, *a.shape[2:])  # noqa: E731
    zero = np.zeros((n_b * n_t, 3))
    u_pr = standardized(flat(rows["P"]), flat(rows["w"]) / factors[0], flat(rows["y"]), flat(rows["C"]), zero)
    none = np.zeros_like(u_pr)
    u_rr = none
    if "H" in rows:
        v = flat(run.v)
        if not np.isfinite(v).all():  # a kernel without velocities: each epoch's own range-rate solution there
            rr = reduce_epochs(flat(rows["H"]), flat(rows["wd"]) / factors[1], flat(rows["yd"]))
            reg = 1e-9 * np.maximum(np.einsum("tii->t", rr.M), 1e-30)[:, None, None] * np.eye(3)
            v = np.where(np.isfinite(v), v, np.linalg.solve(rr.M + reg, rr.r[..., None])[..., 0])
        u_rr = standardized(flat(rows["H"]), flat(rows["wd"]) / factors[1], flat(rows["yd"]), None, v)
    u_ph = standardized(flat(rows["P6"]), flat(rows["pw"]) / factors[2], flat(rows["py"]), flat(rows["pC"]),
                        np.zeros((n_b * n_t, 6)), flat(run.mult[2])) if "P6" in rows else none
    used = (flat(rows["w"]) > 0, flat(rows["wd"]) > 0 if "H" in rows else none > 0,
            flat(rows["pw"]) > 0 if "P6" in rows else none > 0)
    mult, gated = gate_rows((u_pr, u_rr, u_ph), used, gate, config)
    return mult.reshape(3, n_b, n_t, -1), gated.reshape(3, n_b, n_t, -1)


def _take(nrm: EpochNormals, sel: NDArray[np.intp], n_t: int) -> EpochNormals:
    """The normals of the windows ``sel`` (flattened window-major, ``n_t`` epochs each)."""
    idx = (sel[:, None] * n_t + np.arange(n_t)).ravel()
    return EpochNormals(nrm.M[idx], nrm.r[idx], nrm.s[idx], nrm.n_rows[idx], nrm.n_free[idx])


def _identify(run: WindowRun, pr: EpochNormals, rr: EpochNormals | None, lag: int, tol: float,
              max_iter: int) -> tuple[F64, NDArray[np.bool_]]:
    """Step (a): kernels identified on the free per-epoch corrections of the current iterate (NaN:
    none) and, with range rates, where a root on the negative real axis was moved to ``z = 1``
    (:func:`~gnss_cli.behavior.behavior_solve.sampled_motion_kernels`: such a kernel has no velocity)."""
    n_b, n_t = run.epochs.shape
    M = pr.M.reshape(n_b, n_t, 3, 3)
    scale = np.einsum("btii->b", M) / (3 * n_t)
    reg = M + 1e-8 * scale[:, None, None, None] * np.eye(3)  # an epoch with < 4 satellites: huge variance, not singular
    cov = np.linalg.inv(reg)
    z = np.einsum("btij,btj->bti", cov, pr.r.reshape(n_b, n_t, 3))
    w = np.einsum("bij,btj->bti", run.rot, run.x + z)
    sig = np.einsum("bij,btjk,blk->btil", run.rot, cov, run.rot)
    if rr is not None:
        Md = rr.M.reshape(n_b, n_t, 3, 3)
        sd = np.einsum("btii->b", Md) / (3 * n_t)
        cov_v = np.linalg.inv(Md + 1e-8 * sd[:, None, None, None] * np.eye(3))
        vel = np.einsum("btij,btj->bti", cov_v, rr.r.reshape(n_b, n_t, 3))
        w = np.concatenate([w, np.einsum("bij,btj->bti", run.rot, vel)], axis=2)
        sig6 = np.zeros((n_b, n_t, 6, 6))
        sig6[..., :3, :3] = sig
        sig6[..., 3:, 3:] = np.einsum("bij,btjk,blk->btil", run.rot, cov_v, run.rot)
        sig = sig6
    sig = 0.5 * (sig + np.swapaxes(sig, -1, -2))
    good = np.all(np.isfinite(w), axis=(1, 2)) & np.all(np.isfinite(sig), axis=(1, 2, 3))
    out = np.full((n_b, lag + 1), np.nan)
    if lag == 1:  # the root at 1 is the whole kernel, z - 1: nothing to identify (and no dense window projection)
        out[good] = shared_kernel_coefficients((1.0,))
    elif good.any():
        fits = identify_windows(w[good], lag, sig[good], fixed_roots=(1.0,), tol=tol, max_iter=max_iter)
        out[good] = np.where((fits.status >= 0)[:, None], fits.r, np.nan)
    if rr is None:
        return out, np.zeros(n_b, dtype=bool)
    return sampled_motion_kernels(out)


_Modes = dict[tuple[bytes, float, int, bool], tuple[F64, F64, bool, bool]]


def _modes(r: F64, n_t: int, dt_s: F64, velocity: bool,
           cache: _Modes) -> tuple[F64, F64, NDArray[np.bool_], NDArray[np.bool_]]:
    """:func:`~gnss_cli.behavior.behavior_solve.shared_modes`, each kernel computed once per run
    (a window's kernels recur from one alternation to the next)."""
    keys = [(row.tobytes(), float(d), n_t, velocity) for row, d in zip(r, dt_s)]
    miss = [i for i, k in enumerate(keys) if k not in cache]
    if miss:
        y, yv, ok, hv = shared_modes(r[miss], n_t, dt_s[miss], velocity)
        for j, i in enumerate(miss):
            cache[keys[i]] = (y[j], yv[j], bool(ok[j]), bool(hv[j]))
    got = [cache[k] for k in keys]
    lag = r.shape[1] - 1
    if not got:
        return np.zeros((0, n_t, lag)), np.zeros((0, n_t, lag)), np.zeros(0, bool), np.zeros(0, bool)
    return (np.stack([g[0] for g in got]), np.stack([g[1] for g in got]), np.array([g[2] for g in got]),
            np.array([g[3] for g in got]))


def _solve(r: F64, run: WindowRun, normals: tuple[EpochNormals, EpochNormals | None, EpochNormals | None],
           cache: _Modes) -> tuple[F64, F64, F64, F64, NDArray[np.bool_]]:
    """Step (b) for kernels ``r``: coefficients, positions, velocities, linearized misfit and where it worked."""
    n_t = run.epochs.shape[1]
    pr, rr, ph = normals
    valid = np.all(np.isfinite(r), axis=1)
    y, yv, ok, has_v = _modes(np.where(valid[:, None], r, run.r), n_t, run.dt_s, rr is not None, cache)
    ok &= valid & (has_v if rr is not None else True)
    c, mis, solved = solve_in_behavior(y, yv if rr is not None else None, run.x, pr, rr, ph)
    ok &= solved
    x = np.einsum("btj,bja->bta", y, c)
    v = np.einsum("btj,bja->bta", np.nan_to_num(yv), c)
    return c, x, np.where(has_v[:, None, None], v, np.nan), np.where(ok, mis, np.inf), ok


def _spread(res: tuple[F64, ...], sel: NDArray[np.intp], n_b: int) -> tuple[F64, ...]:
    """Results of the windows ``sel`` as arrays over all ``n_b`` windows (NaN / inf / False elsewhere)."""
    out = []
    for a in res:
        fill = False if a.dtype == bool else (np.inf if a.ndim == 1 else np.nan)
        full = np.full((n_b, *a.shape[1:]), fill, dtype=a.dtype)
        full[sel] = a
        out.append(full)
    return tuple(out)


def _start(jobs: NDArray[np.intp], segs: list[Segment], all_jobs: list[WindowJob], fits: list[Fit],
           data: EpochData, n_sv: int) -> WindowRun:
    """The alternation's start: the position-domain projections and kernels of windows ``jobs``."""
    js = [all_jobs[k] for k in jobs]
    epochs = np.stack([segs[j.segment].epochs[j.a : j.b] for j in js])
    origin = np.stack([segs[j.segment].origin for j in js])
    rot = np.stack([segs[j.segment].rot for j in js])
    r = np.stack([np.asarray(fits[k].kernel.shared_coefficients, dtype=np.float64) for k in jobs])  # type: ignore[union-attr]
    w_hat = np.stack([fits[k].w_hat for k in jobs])  # type: ignore[misc]
    x = np.einsum("bji,btj->bti", rot, w_hat)  # ENU -> ECEF directions, relative to the origin
    dt = np.median(np.diff(data.time_gps_s[epochs], axis=1), axis=1)
    n_b, n_t = epochs.shape
    lag = r.shape[1] - 1
    return WindowRun(jobs, epochs, origin, rot, dt, r, np.zeros((n_b, lag, 3)), x, np.full((n_b, n_t, 3), np.nan),
                     np.full(n_b, np.inf), [[] for _ in range(n_b)], np.zeros(n_b, np.int64), np.zeros(n_b, bool),
                     np.zeros(n_b, bool), np.zeros(n_b, bool), [""] * n_b, np.ones((3, n_b, n_t, n_sv)),
                     np.zeros((3, n_b, n_t, n_sv), bool), np.zeros(n_b, np.int64), np.zeros(n_b, bool),
                     np.full_like(r, np.nan), np.ones(n_b, bool), np.full(n_b, np.nan), np.zeros(n_b, np.int64),
                     np.zeros(n_b, bool))


def _project_start(run: WindowRun, velocity: bool) -> None:
    """The start in the behavior of its kernel: ``x`` projected on the basis, velocities from the modes."""
    y, yv, ok, has_v = shared_modes(run.r, run.epochs.shape[1], run.dt_s, velocity)
    run.c = np.einsum("btj,bta->bja", y, run.x)
    run.x = np.where(ok[:, None, None], np.einsum("btj,bja->bta", y, run.c), run.x)
    run.v = np.where(has_v[:, None, None], np.einsum("btj,bja->bta", np.nan_to_num(yv), run.c), np.nan)
    bad = ~ok
    run.failed |= bad
    run.done |= bad
    for b in np.flatnonzero(bad):
        run.message[b] = "the position-domain kernel has dependent free responses"


def _iterate(run: WindowRun, rows: dict[str, F64], factors: tuple[float, ...], config: ProcessingConfig,
             kinds: frozenset[str], previous: dict[str, F64], cache: _Modes) -> None:
    """One alternation step of the windows not done (in place); ``previous``: the last accepted state."""
    n_b, n_t = run.epochs.shape
    doppler = "doppler" in kinds
    normals = _normals(rows, run.mult, factors)
    m_now = behavior_misfit(np.nan_to_num(run.v) if doppler else None, *normals, shape=(n_b, n_t))
    act = ~run.done
    # a start kernel without a velocity (a root on the negative real axis) cannot be evaluated with
    # range rates: its window goes straight to a step, with the identified kernel only
    nov = act & ~np.all(np.isfinite(run.v), axis=(1, 2)) if doppler else np.zeros(n_b, dtype=bool)
    act &= ~nov
    first = act & ~np.isfinite(run.misfit)
    rose = act & ~first & (m_now > run.misfit * (1 + _RISE_RTOL) + 1e-12)
    if rose.any():  # a rise: back to the last accepted iterate, which stops
        for name in ("r", "c", "x", "v"):
            getattr(run, name)[rose] = previous[name][rose]
    small = act & ~first & ~rose & (run.misfit - m_now <= RTOL * np.abs(run.misfit))
    keep = act & ~rose
    run.misfit = np.where(keep, m_now, run.misfit)
    for b in np.flatnonzero(keep):
        run.history[b].append(float(m_now[b]))
    stop = rose | small
    run.done |= stop
    run.converged |= stop
    for b in np.flatnonzero(stop):
        run.message[b] = ("converged: relative misfit decrease below tol" if small[b] else
                          "converged: no further decrease of the misfit")
    act &= ~stop
    over = act & (run.iterations >= MAX_ALTERNATIONS)
    run.failed |= over
    run.done |= over
    for b in np.flatnonzero(over):
        run.message[b] = f"no convergence in {MAX_ALTERNATIONS} alternations"
    act &= ~over
    act |= nov & (run.iterations < MAX_ALTERNATIONS)
    if not act.any():
        return
    for name in ("r", "c", "x", "v"):
        previous[name] = getattr(run, name).copy()
    opts = config.stls
    # (a) on the free per-epoch corrections x + M^-1 r: the free fixes, which do not depend on the
    # iterate (to the linearization), so identified once per gate
    fresh = np.flatnonzero(act & run.stale)
    if fresh.size:
        sub = replace(run, epochs=run.epochs[fresh], rot=run.rot[fresh], x=run.x[fresh])
        run.r_identified[fresh], run.roots_moved[fresh] = _identify(
            sub, *(None if n is None else _take(n, fresh, n_t) for n in normals[:2]), opts.lag, opts.tolerance,
            opts.max_iterations)
        run.stale[fresh] = False
    r_new = np.where(act[:, None], run.r_identified, np.nan)
    sel = np.flatnonzero(act)
    sub = replace(run, epochs=run.epochs[sel], rot=run.rot[sel], x=run.x[sel])
    part = replace(sub, r=run.r[sel], dt_s=run.dt_s[sel])
    taken = tuple(None if n is None else _take(n, sel, n_t) for n in normals)
    solved = [_solve(kernels[sel], part, taken, cache) for kernels in (run.r, r_new)]  # (b) for the current and new kernels
    (c0, x0, v0, m0, ok0), (c1, x1, v1, m1, ok1) = (_spread(res, sel, n_b) for res in solved)
    sing = act & ~ok0 & ~ok1
    run.failed |= sing
    run.done |= sing
    for b in np.flatnonzero(sing):
        run.message[b] = ("no kernel with a velocity for the range rates (a root on the negative real axis)"
                          if nov[b] else "the measurement-domain normals are singular in the behavior")
    act &= ~sing
    take_new = ok1 & (m1 < m0)
    for name, a0, a1 in (("c", c0, c1), ("x", x0, x1), ("v", v0, v1)):
        val = np.where(take_new[:, None, None], a1, a0)
        getattr(run, name)[act] = val[act]
    run.r[act] = np.where(take_new[:, None], r_new, run.r)[act]
    run.iterations[act] += 1


def _threshold(config: ProcessingConfig) -> float:
    """The residual gate's limit on a standardized residual
    (:func:`~gnss_cli.pipeline.kalman_rows.gate_threshold`; inf: no gate)."""
    limit = gate_threshold(config)
    return np.inf if limit is None else limit


def _pseudo_inverse(M: F64) -> tuple[F64, NDArray[np.int64]]:
    """``M^+`` and the rank of each symmetric ``M (K, p, p)`` (singular values below 1e-10 of the
    largest dropped)."""
    u, sv, _ = np.linalg.svd(M, hermitian=True)
    keep = sv > 1e-10 * np.maximum(sv[:, :1], 1e-300)
    inv = np.where(keep, 1.0 / np.where(keep, sv, 1.0), 0.0)
    return np.einsum("kij,kj,klj->kil", u, inv, u), keep.sum(axis=1).astype(np.int64)


def _free_gain(M: F64, r: F64) -> tuple[F64, NDArray[np.int64]]:
    """``r^T M^+ r`` and the rank of each ``M (K, p, p)``: the misfit a free unknown of the rows takes away."""
    inv, rank = _pseudo_inverse(M)
    return np.einsum("ki,kij,kj->k", r, inv, r), rank


MIN_PAIR_ROWS = 5
"""A phase pair with fewer rows kept by the gate than this has its free displacement fitted to all its
rows (four unknowns, the displacement and the clock change, and one row to test them)."""


def _test_mult(run: WindowRun, rows: dict[str, F64], factors: tuple[float, ...], gate: float) -> F64:
    """The multipliers of the behavior test: the gate's, except that a phase-pair row the gate left
    out comes back where the pair's own free displacement fits it.

    The gate leaves out every pair row above it (:func:`~gnss_cli.pipeline.measurements.gate_rows`,
    for cycle slips), so where a window's behavior cannot follow the antenna to the millimetres of
    the differences, it leaves out whole pairs: the rows that say the behavior is wrong. Left out
    of the test too, they hid that misfit from it (the Yamatogawa walk with phase, stls as chosen
    on the training runs: 231 of its 1,647 pair rows gated, against 9-19 for the smoothers; with
    them counted, the walk's windows split down to 8 epochs and 9 rows are gated). A slip stays
    out: it is inconsistent with the other rows of its pair whatever the displacement. Each pair's
    displacement and clock change are fitted to the rows the gate kept (a pair with fewer than
    :data:`MIN_PAIR_ROWS` of them: to all its rows) and every used row is tested there at the
    gate's limit. The pseudoranges and range rates need no such rule: their gate keeps all of an
    epoch's rows when more than half exceed it.
    """
    mult = run.mult.copy()
    if "P6" not in rows:
        return mult
    flat = lambda a: a.reshape(-1, *a.shape[2:])  # noqa: E731
    w, used = flat(rows["pw"]) / factors[2], flat(rows["pw"]) > 0
    gated = flat(run.gated[2])
    fit = np.where(gated, 0.0, 1.0)
    fit = np.where(((used & ~gated).sum(axis=1) < MIN_PAIR_ROWS)[:, None], 1.0, fit)
    pairs = reduce_epochs(flat(rows["P6"]), w * fit, flat(rows["py"]), flat(rows["pC"]))
    inv, _ = _pseudo_inverse(pairs.M[:, 3:, 3:])  # the rows are [-P3, P3] on [z_{t-1}, z_t]
    d = np.einsum("kij,kj->ki", inv, pairs.r[:, 3:])
    u = standardized(flat(rows["P6"]), w, flat(rows["py"]), flat(rows["pC"]), np.hstack([np.zeros_like(d), d]), fit)
    back = gated & used & (np.abs(u) <= gate)
    mult[2] = np.where(back.reshape(mult[2].shape), 1.0, mult[2])
    return mult


def behavior_tests(run: WindowRun, rows: dict[str, F64], factors: tuple[float, ...],
                   gate: float) -> tuple[F64, NDArray[np.int64]]:
    """The windows' behavior test: statistic and degrees of freedom, ``(B,)`` each.

    Generalized likelihood ratio of the result (positions in the identified behavior) against the
    relaxed model where every epoch's position, every epoch's velocity (with range rates) and every
    phase pair's displacement is free, with ``rows`` linearized at the result and the gate's
    multipliers (phase-pair rows that only the behavior could not fit counted again,
    :func:`_test_mult`; ``gate`` the gate's limit) and the variance factors applied (so the
    statistic is in units of the file's own noise): ``D = J_behavior - J_free``, the sum over
    epochs of ``r^T M^+ r`` for the pseudoranges and the pairs (whose corrections are zero at the
    result) and ``(v - v_free)^T M (v - v_free)`` for the range rates. Under the behavior
    ``D ~ chi2(d)`` with ``d`` the free unknowns the rows determine (ranks of the epochs' normals)
    minus the behavior's ``3 l`` coefficients and the kernel's ``l - 1`` identified ones. ``d`` is
    0 where the test cannot be evaluated (a kernel without velocities under range rates, or no
    redundancy).
    """
    n_b, n_t = run.epochs.shape
    lag = run.r.shape[1] - 1
    pr, rr, ph = _normals(rows, _test_mult(run, rows, factors, gate), factors)
    stat, rank = _free_gain(pr.M, pr.r)
    stat, dof = stat.reshape(n_b, n_t).sum(axis=1), rank.reshape(n_b, n_t).sum(axis=1)
    if rr is not None:
        v = run.v.reshape(n_b * n_t, 3)
        g, k = _free_gain(rr.M, rr.r)
        q = np.einsum("kp,kpq,kq->k", v, rr.M, v) - 2 * np.einsum("kp,kp->k", v, rr.r) + g
        stat = stat + q.reshape(n_b, n_t).sum(axis=1)
        dof = dof + k.reshape(n_b, n_t).sum(axis=1)
    if ph is not None:  # the displacement's normals: the pair rows are [-P3, P3] on [z_{t-1}, z_t]
        g, k = _free_gain(ph.M[:, 3:, 3:], ph.r[:, 3:])
        stat, dof = stat + g.reshape(n_b, n_t).sum(axis=1), dof + k.reshape(n_b, n_t).sum(axis=1)
    dof = dof - 3 * lag - (lag - 1)
    ok = np.isfinite(stat) & (dof > 0)
    return np.where(ok, np.maximum(stat, 0.0), np.nan), np.where(ok, dof, 0)


def alternate_windows(data: EpochData, wls: MethodSolution, config: ProcessingConfig, segs: list[Segment],
                      jobs: list[WindowJob], fits: list[Fit], kinds: frozenset[str],
                      factors: tuple[float, ...] | None = None) -> tuple[list[Fit], list[WindowRun], tuple[float, ...]]:
    """Every shared-kernel window of ``fits`` solved in the measurement domain (module docstring).

    Parameters
    ----------
    data, wls, config : the prepared epochs, their WLS solution, the configuration.
    segs, jobs, fits : the segments, windows and position-domain fits of
        :func:`gnss_cli.pipeline.behavioral.fit_all`.
    kinds : the measurement kinds (``pseudorange`` and any of ``doppler``, ``phase``).
    factors : variance factors (pseudoranges, range rates, pairs); default: estimated on ``data``
        at the WLS fixes (:func:`~gnss_cli.pipeline.measurements.free_misfit_totals`).

    Returns
    -------
    fits : one per window: the alternation's result, or the position-domain fit with the reason
        it was kept in its message.
    runs : the alternation state of each group of equal-length windows.
    factors : the variance factors used.
    """
    data = as_wls_used(data, wls)  # its satellites and weights
    if factors is None:
        factors = factors_from_totals(free_misfit_totals(data, wls, config, kinds))
    factors = (*factors, 1.0, 1.0, 1.0)[:3]
    out = list(fits)
    groups: dict[int, list[int]] = {}
    for k, (job, fit) in enumerate(zip(jobs, fits)):
        if fit.w_hat is None or fit.kernel is None or fit.kernel.shared_coefficients is None:
            continue
        groups.setdefault(job.b - job.a, []).append(k)
    if not groups:
        return out, [], factors
    n_sv = data.sv.size
    runs = [_start(np.asarray(g, dtype=np.intp), segs, jobs, fits, data, n_sv) for g in groups.values()]
    for run in runs:
        _project_start(run, "doppler" in kinds)
    spans = sorted((int(run.epochs[b, 0]), int(run.epochs[b, -1]) + 1, i, b) for i, run in enumerate(runs)
                   for b in range(run.epochs.shape[0]))
    colors: list[list[int]] = [[0] * run.epochs.shape[0] for run in runs]
    for (a, e, i, b), c in zip(spans, _colors([(a, e) for a, e, _, _ in spans])):
        colors[i][b] = c
    fix = np.isin(wls.status, PASSED_FIX) & np.isfinite(wls.x_ecef_m).all(axis=1)
    base = nominal_trajectory(data.time_gps_s, np.where(fix[:, None], wls.x_ecef_m, np.nan))
    previous: list[dict[str, F64]] = [{} for _ in runs]
    cache: _Modes = {}
    for _ in range(GATE_PASSES * (MAX_ALTERNATIONS + 2)):
        rows = window_rows(data, config, kinds, base, runs, colors)
        for run, rw, prev in zip(runs, rows, previous):
            new = run.gates == 0
            if new.any():  # the first gate, at the start
                mult, gated = _gate(run, rw, factors, config)
                run.mult[:, new], run.gated[:, new] = mult[:, new], gated[:, new]
                run.gates[new] = 1
            _iterate(run, rw, factors, config, kinds, prev, cache)
            regate = run.done & run.converged & ~run.failed & ~run.gate_final
            if regate.any():  # after convergence: the gate at the result; a new gate continues the alternation
                mult, gated = _gate(run, rw, factors, config)
                changed = regate & np.any(gated != run.gated, axis=(0, 2, 3))
                run.gate_final |= regate & (~changed | (run.gates >= GATE_PASSES))
                changed &= run.gates < GATE_PASSES
                if changed.any():
                    run.mult[:, changed], run.gated[:, changed] = mult[:, changed], gated[:, changed]
                    run.gates[changed] += 1
                    run.done[changed] = run.converged[changed] = False
                    run.stale[changed] = True
                    run.misfit[changed] = np.inf
                    for b in np.flatnonzero(changed):
                        run.history[b] = []
        if all(run.done.all() for run in runs):
            break
    if config.stls.behavior_pfa > 0:  # the behavior test, at the results (rows of every window that finished)
        done = [run.done.copy() for run in runs]
        for run in runs:
            run.done = ~(run.converged & ~run.failed)
        for run, rw in zip(runs, window_rows(data, config, kinds, base, runs, colors)):
            run.test_stat, run.test_dof = behavior_tests(run, rw, factors, _threshold(config))
        for run, d in zip(runs, done):
            run.done = d
    for run in runs:
        _finish(run, out, kinds)
    return out, runs, factors


def _finish(run: WindowRun, out: list[Fit], kinds: frozenset[str]) -> None:
    """The fits of the windows of ``run`` (in place into ``out``)."""
    n_b, n_t = run.epochs.shape
    used = kinds_text(kinds)
    good = np.flatnonzero(run.converged & ~run.failed)
    recs = dict(zip(good.tolist(), shared_kernel_records(run.r[good], 3) if good.size else []))
    bases = dict(zip(good.tolist(), shared_behavior_bases(run.r[good], n_t, 3) if good.size else []))
    for b, k in enumerate(run.jobs):
        if b not in recs or bases[b] is None:
            old = out[k]
            why = run.message[b] or "the alternation did not finish"
            out[k] = replace(old, message=f"{old.message}; measurement domain ({used}) not used: {why}; "
                                          "position-domain result kept", iterations=int(run.iterations[b]),
                             converged=False, domain="position")
            continue
        w_hat = np.einsum("ij,btj->bti", run.rot[b], run.x[b][None])[0]
        moved = ("; the kernel identified under the last gate had a root on the negative real axis, moved to z = 1"
                 if run.roots_moved[b] else "")
        out[k] = Fit(w_hat, recs[b], float(run.misfit[b]), StlsStatus.CONVERGED,
                     f"measurement domain ({used}), alternation: {run.message[b]} after {run.iterations[b]} "
                     f"iterations under the last of {int(run.gates[b])} residual gates{moved}", bases[b],
                     iterations=int(run.iterations[b]), converged=True, domain="measurement",
                     test_stat=float(run.test_stat[b]) if run.test_dof[b] > 0 else None,
                     test_dof=int(run.test_dof[b]) if run.test_dof[b] > 0 else None)
