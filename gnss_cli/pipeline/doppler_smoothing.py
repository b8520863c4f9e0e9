"""Smoothing model ``"doppler"``: pseudoranges and range rates of whole segments in the measurement domain,
positions and velocities tied by a kinematic kernel (DESIGN.md section 6).

Unknowns, per segment of uniformly sampled epochs with at least one usable satellite: the
trajectory ``(x_t, v_t)`` (ECEF m, m/s) in the behavior of the kinematic kernel of lag ``l``
(:mod:`gnss_cli.behavior.kinematic_solve`: ``x_{t+1} - x_t`` equals ``dt`` times an
interpolation of the velocities, exact for velocities polynomial of degree ``l``), one clock per
epoch and system and one clock drift per epoch. Observations: every pseudorange the WLS solution
used (its satellites, elevation mask, weights and FDE exclusions) and the range rates of those
satellites, of every epoch, 1-3 satellites included, and with carrier phase in the file
(``smoothing.carrier_phase``) the time-differenced phase of consecutive epochs
(:mod:`gnss_cli.pipeline.phase_rows`; on the Yamatogawa walk 2.72 -> 2.49 m 3D RMS, on the urban
tst2 set 2.52 -> 1.37 m) (such an epoch is ``ok`` and ``n_sat`` says how
many pseudoranges it had; with a single satellite its clock absorbs the pseudorange and the
position comes from the kernel and its neighbours).

Weights: the configured pseudorange, Doppler (and phase) sigmas give their shape; each kind is scaled by
a variance factor estimated from the data -- the misfit per degree of freedom of the epochs
solved one at a time (free position, velocity, clocks, drift), which does not depend on the
kernel -- so the balance between pseudoranges and range rates is not tuned per data set.

Fault exclusion, as the snapshot solution's (``integrity`` not ``"off"``): a pseudorange or range
rate whose standardized residual exceeds the two-sided normal quantile of ``integrity_pfa``
(3.29 for 1e-3) is excluded -- unless more than half of its epoch's rows do; of the phase pairs
(:mod:`gnss_cli.pipeline.phase_rows`) the largest of each pair, one more per pass -- and the segment
solved again, until the excluded set no longer changes (an excluded row comes back when the
new solution fits it). The variance factors stay those of the first pass (estimated again on
the kept rows, the gate would tighten itself pass after pass). Excluded pseudoranges are added
to the ``excluded`` column with the WLS exclusions; ``n_sat`` counts the pseudoranges used.
Measured on the urban tst2 set (157 truth epochs; kf 2.14 m, WLS 6.81 m): 9.06 m without the
gate, 2.52 m with it; it costs 1-2 % on the simulated flights (0.313 -> 0.317, 0.774 -> 0.78 x
the truth-tuned KF+RTS) and on the Yamatogawa walk (2.67 -> 2.72 m). With ``robust = "huber"`` or
``"cauchy"`` every row is also reweighted by the M-estimator of its standardized residual
(:func:`~gnss_cli.solvers.robust.m_estimator_weights`), as in the snapshot solution (tst2 with
Huber: 1.90 m).

Gauss-Newton (with the robust weights: IRLS): linearize at the current trajectory (first the WLS
fixes, interpolated in time where an epoch has none), solve every segment, repeat until no
position moves more than 1 mm, no robust weight by more than 1e-3 and the excluded set is the
same (at most :data:`MAX_PASSES`).

Output: positions, velocities and re-estimated clocks of every epoch of a segment. Covariance:
the position blocks of the constrained estimator's covariance (the inverse KKT matrix, with the
weights as used: factors and robust weights; :func:`~gnss_cli.behavior.kinematic_solve.kinematic_position_cov`),
the clocks eliminated per epoch as in :func:`~gnss_cli.behavior.multi_epoch.multi_epoch_cov`. The
DOP columns are that covariance over the median variance of the used pseudoranges (as for
``kf``): the multi-epoch DOP, in which the range rates and the kernel add geometry. One :class:`~gnss_cli.pipeline.results.WindowModel`
per segment (misfit, degrees of freedom and variance factors in ``message``).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray
from scipy.stats import chi2, norm

from gnss_cli.behavior import KernelRepresentation
from gnss_cli.behavior.kinematic_solve import STEP_OFFSETS, Motion, kinematic_position_cov, solve_kinematic, step_weights
from gnss_cli.behavior.multi_epoch import epoch_information
from gnss_cli.behavior.records import kernel_record
from gnss_cli.behavior.window_solve import EpochNormals, free_misfit, reduce_epochs
from gnss_cli.behavior.windows import segments
from gnss_cli.config import ProcessingConfig
from gnss_cli.errors import ConfigError
from gnss_cli.gnss.frames import ecef2enu_rotation, ecef2geodetic
from gnss_cli.pipeline.kalman import linearized_measurements, nominal_trajectory
from gnss_cli.pipeline.phase_rows import phase_pair_rows
from gnss_cli.pipeline.results import EpochData, EpochStatus, MethodSolution, WindowModel
from gnss_cli.pipeline.smoothing import finish_smoothing
from gnss_cli.solvers.dop import dop_from_cov
from gnss_cli.solvers.robust import m_estimator_weights

__all__ = ["doppler_smooth", "solve_doppler_segments", "doppler_kernel", "DopplerRun", "MAX_PASSES"]

F64 = NDArray[np.float64]

MAX_PASSES = 10
_CONVERGED_M = 1e-3
_WEIGHT_TOL = 1e-3


@dataclass(frozen=True, slots=True)
class DopplerRun:
    """The measurement-domain solution of every segment.

    Attributes
    ----------
    x_ecef_m, vel_ecef_m_s : ``(T, 3)``, NaN outside the segments.
    n_sat : ``(T,)`` pseudoranges of each epoch in the solve (robust weights aside).
    segments : epoch indices of each segment solved.
    cov_m2 : ``(T, 3 + k, 3 + k)`` covariance of ``[x (ECEF), clocks]`` (m^2; NaN outside the segments).
    var0_m2 : median variance of the used pseudoranges (weights with their factor): the DOPs are
        ``cov_m2 / var0_m2``.
    gated : ``(T, n)`` pseudoranges the residual gate excluded.
    phase : time-differenced carrier phase was used (:mod:`gnss_cli.pipeline.phase_rows`).
    misfit, dof : per segment, weighted residual square sum and its degrees of freedom.
    factors : variance factors of the pseudoranges, the range rates and the phase pairs (1 without phase).
    passes : Gauss-Newton (IRLS) passes.
    """

    x_ecef_m: F64
    vel_ecef_m_s: F64
    n_sat: NDArray[np.int64]
    segments: list[NDArray[np.intp]]
    misfit: list[float]
    dof: list[int]
    factors: tuple[float, ...]
    passes: int
    cov_m2: F64
    var0_m2: float
    gated: NDArray[np.bool_]
    phase: bool = False


def doppler_kernel(dt_s: float, lag: int) -> KernelRepresentation:
    """The kinematic kernel of lag ``lag`` (1-3) on ``w = (x, v)`` (position m, velocity m/s), interior rule.

    >>> k = doppler_kernel(1.0, 3)
    >>> t = np.arange(8.0)[:, None]
    >>> w = np.hstack([t**4 / 4 * [1, 2, 3], t**3 * [1, 2, 3]])  # cubic velocity
    >>> bool(k.annihilates(w, rtol=1e-12))
    True
    """
    offs = STEP_OFFSETS[min(max(lag, 1), 3)]
    wts = step_weights(offs)
    first = min(offs)
    blocks = [np.zeros((3, 6)) for _ in range(max(offs) - first + 1)]
    blocks[-first][:, :3] -= np.eye(3)
    blocks[1 - first][:, :3] += np.eye(3)
    for o, w in zip(offs, wts):
        blocks[o - first][:, 3:] -= w * dt_s * np.eye(3)
    return KernelRepresentation(np.hstack(blocks), q=6)


def _rows(data: EpochData, nominal: F64, config: ProcessingConfig) -> dict[str, F64]:
    """Rows of every epoch at ``nominal``: pseudorange ``(P, w, y, C)`` and range rate ``(H, w, y)``."""
    meas = linearized_measurements(data, nominal, config)
    k = len(data.systems)
    sysidx = data.system_index if data.system_index is not None else np.zeros(data.sv.size, dtype=np.int64)
    assert meas.used_rr is not None and meas.H_rr is not None and meas.y_rr is not None and meas.var_rr is not None
    return {"P": -meas.unit, "w": np.where(meas.used, 1.0 / meas.var_pr, 0.0),
            "y": meas.y_pr + np.einsum("tni,ti->tn", meas.unit, nominal),  # pseudorange minus its value at nominal
            "C": np.broadcast_to((sysidx[:, None] == np.arange(k)).astype(np.float64), (*meas.used.shape, k)),
            "H": meas.H_rr[..., :3], "wd": np.where(meas.used_rr, 1.0 / meas.var_rr, 0.0), "yd": meas.y_rr}


def _normals(rows: dict[str, F64], scale: tuple[F64, F64]) -> tuple[EpochNormals, EpochNormals]:
    return (reduce_epochs(rows["P"], rows["w"] * scale[0], rows["y"], rows["C"]),
            reduce_epochs(rows["H"], rows["wd"] * scale[1], rows["yd"]))


def _standardized(p: F64, w: F64, y: F64, c: F64 | None, z: F64, fit: F64 | None = None) -> F64:
    """Residuals times the square root of their weights, nuisance columns re-estimated (0 where unused)
    from the rows weighted ``w * fit`` (default ``w``; the phase pairs: without the excluded rows, so
    that a slip does not move its pair's clock change and with it the other rows)."""
    c = np.ones((*w.shape, 1)) if c is None else c
    e = np.where(w > 0, y - np.einsum("tni,ti->tn", np.where(w[..., None] > 0, p, 0.0), np.nan_to_num(z)), 0.0)
    cw = c * (w if fit is None else w * fit)[..., None]
    sw = cw.sum(axis=1)
    b = np.einsum("tnk,tn->tk", cw, e) / np.where(sw > 0, sw, 1.0)
    return np.where(w > 0, (e - np.einsum("tnk,tk->tn", c, b)) * np.sqrt(w), 0.0)


def misfit_totals(pr: EpochNormals, rr: EpochNormals, ph: EpochNormals | None = None) -> tuple[float, ...]:
    """Misfit and degrees of freedom of the epochs solved alone, summed: pseudoranges, range rates,
    phase pairs (each pair alone: its displacement and clock change free; zeros without phase).

    The phase pairs' misfit is their robust factor times their degrees of freedom: the median over
    the pairs of ``misfit / median(chi2(dof))``. An undetected cycle slip puts ``(0.19 m / 1 cm)^2 ~
    360`` into one pair's misfit; in the sum it weakened every difference (measured: a one-cycle slip
    on a simulated flight with exact phase raised the summed factor 47-fold and moved the track by
    0.11 m), the median does not see it."""
    out: list[float] = []
    for j, nrm in enumerate((pr, rr, ph)):
        if nrm is None:
            out += [0.0, 0.0]
            continue
        mis, rank = free_misfit(nrm)
        dof = nrm.n_rows - nrm.n_free - rank
        good = dof > 0
        if j == 2 and good.any():
            robust = float(np.median(np.clip(mis[good], 0.0, None) / chi2.median(dof[good])))
            out += [robust * float(dof[good].sum()), float(dof[good].sum())]
        else:
            out += [float(mis[good].sum()), float(dof[good].sum())]
    return tuple(out)


def factors_from_totals(totals: tuple[float, ...]) -> tuple[float, ...]:
    """Variance factors (misfit per degree of freedom) of :func:`misfit_totals`, one per kind; 1 where undefined."""
    return tuple(m / f if f > 0 and m > 0 else 1.0 for m, f in zip(totals[::2], totals[1::2]))


def free_misfit_totals(data: EpochData, wls: MethodSolution, config: ProcessingConfig) -> tuple[float, ...]:
    """:func:`misfit_totals` of ``data`` at the WLS fixes (what the variance factors are estimated
    from), so that a file arriving in parts can sum them before smoothing any part."""
    if wls.excluded is not None:
        data = replace(data, usable=data.usable & ~wls.excluded)
    fix = (wls.status == EpochStatus.OK.value) & np.isfinite(wls.x_ecef_m).all(axis=1)
    if not fix.any() or data.range_rate_m_s is None:
        return (0.0,) * 6
    nominal = nominal_trajectory(data.time_gps_s, np.where(fix[:, None], wls.x_ecef_m, np.nan))
    rows = _rows(data, nominal, config)
    return misfit_totals(*_normals(rows, (np.ones_like(rows["w"]), np.ones_like(rows["wd"]))),
                         _pairs_alone(phase_pair_rows(data, rows, config), np.ones_like(rows["w"])))


def _pairs_alone(phr: dict[str, F64] | None, mult: F64) -> EpochNormals | None:
    """Normals of each phase pair for its displacement alone (the variance factor's)."""
    return None if phr is None else reduce_epochs(phr["P3"], phr["w"] * mult, phr["y"], phr["C"])


def solve_doppler_segments(data: EpochData, wls: MethodSolution, config: ProcessingConfig, lag: int, *,
                           gap_factor: float = 1.5, factors: tuple[float, ...] | None = None) -> DopplerRun | None:
    """Solve every segment (module docstring); None when WLS solved no epoch or the file has no range rates.

    ``data`` should carry the WLS exclusions in ``usable`` (:func:`doppler_smooth` does).
    ``factors``: the variance factors, when they were estimated beforehand (a whole file's, for
    a piece of it); else they are estimated from ``data``.
    """
    t = data.time_gps_s
    fix = (wls.status == EpochStatus.OK.value) & np.isfinite(wls.x_ecef_m).all(axis=1)
    if not fix.any() or data.range_rate_m_s is None or not config.kalman.doppler:
        return None
    segs = [s for s in segments(t, data.usable.any(axis=1), gap_factor) if s.size >= 2 and fix[s].any()]
    nominal = nominal_trajectory(t, np.where(fix[:, None], wls.x_ecef_m, np.nan))
    T = t.size
    x, v = np.full((T, 3), np.nan), np.full((T, 3), np.nan)
    mult = np.ones((3, T, data.sv.size))  # robust weights times the gate (0: excluded): pr, rr, phase pairs
    gated = np.zeros((3, T, data.sv.size), dtype=bool)
    mis, dof = [0.0] * len(segs), [0] * len(segs)
    gate = float(norm.isf(config.integrity_pfa / 2)) if config.integrity != "off" else np.inf
    passes = 0
    given = factors
    factors = (1.0, 1.0, 1.0) if given is None else (*given, 1.0, 1.0)[:3]
    for passes in range(1, MAX_PASSES + 1):
        rows = _rows(data, nominal, config)
        phr = phase_pair_rows(data, rows, config)
        if passes == 1 and given is None:  # before any exclusion: re-estimated on the kept rows, the gate would tighten itself
            factors = factors_from_totals(misfit_totals(*_normals(rows, (mult[0], mult[1])), _pairs_alone(phr, mult[2])))
        scale = (mult[0] / factors[0], mult[1] / factors[1])
        pr, rr = _normals(rows, scale)
        ph = None if phr is None else reduce_epochs(phr["P6"], phr["w"] * mult[2] / factors[2], phr["y"], phr["C"])
        moved = 0.0
        for i, seg in enumerate(segs):
            sub = [EpochNormals(n.M[seg], n.r[seg], n.s[seg], n.n_rows[seg], n.n_free[seg]) for n in (pr, rr)]
            sol = solve_kinematic(sub[0], sub[1], np.diff(nominal[seg], axis=0), np.diff(t[seg]), Motion("quadrature", lag),
                                  None if ph is None else _segment_pairs(ph, seg))
            x[seg], v[seg] = nominal[seg] + sol.z, sol.v
            mis[i], dof[i] = sol.misfit, sol.dof
            moved = max(moved, float(np.abs(sol.z).max()))
        have = np.isfinite(x).all(axis=1)
        z = np.where(have[:, None], x - nominal, 0.0)
        u = (_standardized(rows["P"], rows["w"] / factors[0], rows["y"], rows["C"], z),
             _standardized(rows["H"], rows["wd"] / factors[1], rows["yd"], None, np.where(have[:, None], v, 0.0)),
             np.zeros_like(rows["w"]) if phr is None else
             _standardized(phr["P6"], phr["w"] / factors[2], phr["y"], phr["C"], np.hstack([np.roll(z, 1, axis=0), z]),
                           mult[2]))
        nominal[have] = x[have]
        new_mult, new_gated = _reweight(u, (rows["w"] > 0, rows["wd"] > 0, np.zeros_like(rows["w"], dtype=bool)
                                            if phr is None else phr["w"] > 0), gate, config, gated)
        changed = float(np.abs(new_mult - mult).max())
        same_gate = bool(np.array_equal(new_gated, gated))
        mult, gated = new_mult, new_gated
        if moved < _CONVERGED_M and changed < _WEIGHT_TOL and same_gate:
            break
    assert factors is not None
    w_pr = rows["w"] * scale[0]
    cov = _covariance(rows["P"], w_pr, rows["C"], rr.M, segs, t, lag, None if ph is None else ph.M)
    var0 = float(np.median(1.0 / w_pr[w_pr > 0])) if (w_pr > 0).any() else 1.0
    n_sat = ((rows["w"] > 0) & ~gated[0]).sum(axis=1).astype(np.int64)
    return DopplerRun(x, v, n_sat, segs, mis, dof, factors, passes, cov, var0, gated[0], phr is not None)


def _segment_pairs(ph: EpochNormals, seg: NDArray[np.intp]) -> EpochNormals:
    """The pair normals of a segment's epochs, the pair ending at its first epoch (from outside) left out."""
    keep = np.ones(seg.size)
    keep[0] = 0.0
    return EpochNormals(ph.M[seg] * keep[:, None, None], ph.r[seg] * keep[:, None], ph.s[seg] * keep,
                        ph.n_rows[seg] * keep.astype(np.int64), ph.n_free[seg] * keep.astype(np.int64))


def _reweight(u: tuple[F64, ...], used: tuple[NDArray[np.bool_], ...], gate: float,
              config: ProcessingConfig, before: NDArray[np.bool_] | None = None) -> tuple[F64, NDArray[np.bool_]]:
    """Robust weights (``config.robust``) times the residual gate, from standardized residuals ``u``.

    Pseudoranges and range rates: a row whose ``|u|`` exceeds ``gate`` is excluded, unless more
    than half of its epoch's rows do (then the fit, not the rows, failed there: all are kept).
    Phase pairs (``u[2]``): one row per pair and pass, the largest above the gate, joins the rows
    excluded ``before`` that are still above it. A slip of one cycle among differences good to
    millimetres leaves most of its pair's rows above the gate (the pair's displacement and clock
    change absorb part of it), so the rule of the half would keep it; its own row stays the largest.
    """
    mult = np.ones((len(u), *u[0].shape))
    gated = np.zeros((len(u), *u[0].shape), dtype=bool)
    for j in range(len(u)):
        if config.robust != "off":
            tuning = config.robust_huber_k if config.robust == "huber" else config.robust_cauchy_c
            mult[j] = m_estimator_weights(u[j], config.robust, tuning)
        out = used[j] & (np.abs(u[j]) > gate)
        if j == 2:
            kept = out & (before[j] if before is not None else False)
            rest = np.where(out & ~kept, np.abs(u[j]), 0.0)
            worst = np.zeros_like(out)
            worst[np.arange(out.shape[0]), np.argmax(rest, axis=1)] = True
            gated[j] = kept | (worst & (rest > 0))
        else:
            most = out.sum(axis=1) * 2 > used[j].sum(axis=1)
            gated[j] = out & ~most[:, None]
        mult[j] = np.where(gated[j], 0.0, mult[j])
    return mult, gated


def _covariance(p_m: F64, w_pr: F64, clock_cols: F64, M_rr: F64, segs: list[NDArray[np.intp]], t: F64,
                lag: int, M_ph: F64 | None = None) -> F64:
    """``(T, 3 + k, 3 + k)`` covariance of positions and clocks: the multi-epoch position blocks
    (:func:`~gnss_cli.behavior.kinematic_solve.kinematic_position_cov`), the clocks by eliminating
    them per epoch (as :func:`~gnss_cli.behavior.multi_epoch.multi_epoch_cov`)."""
    T, k = w_pr.shape[0], clock_cols.shape[-1]
    info, h, clock_var = epoch_information(p_m, w_pr, clock_cols)
    out = np.full((T, 3 + k, 3 + k), np.nan)
    for seg in segs:
        c = kinematic_position_cov(info[seg], M_rr[seg], np.diff(t[seg]), Motion("quadrature", lag),
                                   M_ph=None if M_ph is None else M_ph[seg])
        ch = np.einsum("tij,tcj->tic", c, h[seg])
        blk = np.empty((seg.size, 3 + k, 3 + k))
        blk[:, :3, :3] = c
        blk[:, :3, 3:] = -ch
        blk[:, 3:, :3] = -ch.transpose(0, 2, 1)
        blk[:, 3:, 3:] = np.einsum("tci,tid->tcd", h[seg], ch)
        blk[:, 3 + np.arange(k), 3 + np.arange(k)] += np.where(clock_var[seg] > 0, clock_var[seg], np.nan)
        out[seg] = blk
    return out


def doppler_smooth(data: EpochData, wls: MethodSolution, config: ProcessingConfig, *, method: str = "stls",
                   gap_factor: float = 1.5, factors: tuple[float, ...] | None = None,
                   ) -> tuple[MethodSolution, tuple[WindowModel, ...]]:
    """The ``"doppler"`` smoothing model's rows and one model record per segment (module docstring).

    Raises
    ------
    ConfigError
        The observation file has no Doppler (or ``[kalman] doppler = false``).
    """
    if wls.excluded is not None:
        data = replace(data, usable=data.usable & ~wls.excluded)
    lag = config.smoothing.lag
    run = solve_doppler_segments(data, wls, config, lag, gap_factor=gap_factor, factors=factors)
    if run is None:
        if data.range_rate_m_s is None or not config.kalman.doppler:
            raise ConfigError(f"smoothing.model = 'doppler' needs Doppler observations; {data.obs_path} has none")
        return replace(wls, method=method), ()
    T = data.time_gps_s.size
    smoothed = np.isfinite(run.x_ecef_m).all(axis=1)
    status = np.where(smoothed, EpochStatus.OK.value, wls.status.astype("<U24"))
    x_s = np.where(smoothed[:, None], run.x_ecef_m, wls.x_ecef_m)
    kept = replace(data, usable=data.usable & ~run.gated)  # clocks and residuals from the rows used
    sol = _with_covariance(finish_smoothing(kept, wls, config, x_s, status, smoothed, [], method), run, smoothed)
    sol = replace(sol, excluded=run.gated if wls.excluded is None else (wls.excluded | run.gated))
    vel = np.where(smoothed[:, None], run.vel_ecef_m_s, sol.vel_ecef_m_s if sol.vel_ecef_m_s is not None else np.nan)
    models = []
    for k, seg in enumerate(run.segments):
        dt = float(np.median(np.diff(data.time_gps_s[seg])))
        models.append(WindowModel(
            segment=k, window=0, start_time_gps_s=float(data.time_gps_s[seg[0]]),
            end_time_gps_s=float(data.time_gps_s[seg[-1]]), n_epochs=int(seg.size), model="doppler", structure="full",
            kernel=kernel_record(doppler_kernel(dt, lag)), misfit=run.misfit[k], status="converged",
            message=(f"measurement domain, {run.dof[k]} degrees of freedom; variance factors: pseudoranges "
                     f"{run.factors[0]:.4g}, range rates {run.factors[1]:.4g}"
                     + (f", phase pairs {run.factors[2]:.4g}" if run.phase else "") + f" ({run.passes} passes)"),
        ))
    assert vel.shape == (T, 3)
    return replace(sol, vel_ecef_m_s=vel), tuple(models)


def _with_covariance(sol: MethodSolution, run: DopplerRun, smoothed: NDArray[np.bool_]) -> MethodSolution:
    """The multi-epoch covariance and DOPs (``cov / var0``) on the smoothed rows; a clock without
    pseudoranges at an epoch has no TDOP."""
    rows = np.flatnonzero(smoothed & np.isfinite(run.cov_m2[:, :3, :3]).all(axis=(1, 2)))
    if not rows.size:
        return sol
    cov = sol.cov_m2.copy()
    cov[rows] = np.nan_to_num(run.cov_m2[rows], nan=0.0)
    lat, lon, _ = ecef2geodetic(sol.x_ecef_m[rows])
    q = cov[rows] / run.var0_m2
    d = dop_from_cov(q, ecef2enu_rotation(lat, lon))
    k = q.shape[-1] - 3
    clk = run.cov_m2[rows][:, 3 + np.arange(k), 3 + np.arange(k)]
    dops = {}
    for name in ("gdop", "pdop", "hdop", "vdop", "tdop"):
        col = getattr(sol, name).copy()
        col[rows] = getattr(d, name)
        dops[name] = col
    dops["tdop"][rows] = np.where(np.isfinite(clk[:, 0]), dops["tdop"][rows], np.nan)
    tdops = None
    if sol.tdops is not None:
        tdops = sol.tdops.copy()
        tdops[rows] = np.where(np.isfinite(clk), np.sqrt(np.clip(np.nan_to_num(clk), 0.0, None) / run.var0_m2), np.nan)
    return replace(sol, cov_m2=cov, tdops=tdops, **dops)
