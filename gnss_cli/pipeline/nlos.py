"""Persistent NLOS reflections: satellites excluded over the spans where their C/N0 or their
pseudorange residuals say the signal arrives by reflection (``[nlos] detector = "arcs"``).

A reflected (non-line-of-sight) signal travels a longer path: its pseudorange carries a positive
delay of metres to tens of metres for as long as the reflection lasts (seconds to minutes), and
it arrives weaker than a direct signal at that elevation. Both signs hold over a span, so the
tests run over each satellite's track in time, not epoch by epoch, and a satellite is excluded
from the first to the last epoch of the span:

1. **C/N0 deficit.** A line-of-sight template ``C/N0_los(system, el)`` is estimated from the
   file itself: per system (one tracked signal each) and elevation bin of ``template_bin_deg``,
   the ``template_quantile`` of the C/N0 of the bin (bins with fewer than ``template_min_count``
   values are interpolated in elevation from the others). An upper quantile is a line-of-sight
   value as long as a bin holds some direct signals: reflections are 8-20 dB weaker. The
   deficit ``d = C/N0_los(el) - C/N0`` (dB) is large over a reflection; a span is a run of
   epochs with ``d > cn0_exit_db`` that holds at least ``cn0_min_epochs`` epochs with
   ``d > cn0_enter_db`` (a hysteresis: one weak epoch neither starts nor ends a reflection).
   With a finite ``cn0_min_delay_m`` a span stays only when its pseudoranges are longer by at
   least that much on average over the span (a reflection lengthens the path; an attenuated
   direct signal does not), as the fix without the span predicts them (``cn0_delay_source =
   "fix"``) or, with ``"doppler"``, against the satellite's own range rates
   (:func:`code_minus_doppler_m`, :func:`doppler_span_delays_m`): a reflection's pseudoranges
   step up at its start against the range the Doppler integrates and step down at its end, so
   their mean over the span less that over the direct epochs beside it is the delay, free of the
   fix (which the epoch's other reflections pull). The fix leaves the tested spans out and weighs
   the spans redundancy keeps in (below) at ``variance_factor`` times their variance. With
   ``cn0_delay_sigmas = z > 0`` a span measured by the fix is kept in only when its delay plus
   ``z`` standard deviations (:func:`prediction_sigma_m`, :func:`span_sigma_m`) is still short of
   the threshold -- surely early -- and a span neither surely late nor surely early is
   down-weighted like those redundancy keeps.
2. **Persistent positive residuals.** At the WLS fix without the C/N0 spans, the standardized
   post-fit residual ``u = r / sigma`` (``sigma`` the a-priori pseudorange sigma) of each
   satellite; a one-sided CUSUM over runs of ``u > residual_k``: a run is a span when
   ``sum (u - residual_k) >= residual_h`` (``residual_h = inf``: no residual test). A reflection
   only lengthens the path, so only positive residuals count.

An epoch keeps its redundancy: satellites are excluded most suspicious first (largest ``d``
over ``cn0_enter_db``, or ``u`` over ``residual_k``), and no further once the epoch would keep
fewer than ``3 + k + min_dof`` satellites (``k`` its clocks) or fewer than ``min_satellites``.
The excluded satellites are in the WLS solution's ``excluded`` mask (with FDE's); every method
that starts from the WLS fix leaves them out too. The C/N0 spans that redundancy keeps in are
down-weighted instead: their pseudorange variance is multiplied by ``variance_factor`` (100: a
hundredth of the weight; 1: full weight), in the WLS solution's ``variance_scale``, and every
method that starts from the WLS fix weighs them alike
(:func:`~gnss_cli.pipeline.results.as_wls_used`). With ``failed_epochs = "retry"`` an epoch
that is not ``ok`` after the exclusions is solved again with every satellite, every span
down-weighted by the same factor (:func:`monitor_without_nlos`). With ``min_direct_dof > 0`` an
``ok`` epoch whose satellites at full weight (those the detector takes as direct) leave its fix
fewer redundant measurements than that becomes ``nlos_dependent`` (:func:`direct_dof`): only
suspected reflections test it. The detector runs with ``integrity = "check"`` or ``"fde"``;
``"off"`` is the plain fix. The template is the solved part's (a file of at most
``stream_above_epochs`` epochs is one part).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from gnss_cli.config import ProcessingConfig
from gnss_cli.constants import C_M_S
from gnss_cli.gnss.frames import satellite_azimuth_elevation_deg
from gnss_cli.pipeline.integrity import check_fixes, merge_epochs, monitor, take_epochs
from gnss_cli.pipeline.results import EpochData, EpochStatus, MethodSolution, take_solution

__all__ = ["code_minus_doppler_m", "doppler_span_delays_m", "NEIGHBOUR_S", "los_cn0_template_dbhz",
           "persistent_spans", "cusum_spans", "multi_epoch_spans", "span_means", "keep_redundancy",
           "span_sigma_m", "prediction_sigma_m", "cn0_spans", "residual_spans", "prediction_residuals_m",
           "exclude_nlos", "direct_dof", "monitor_without_nlos"]

F64 = NDArray[np.float64]
#: The direct epochs that give a C/N0 span's code-minus-Doppler level are at most this far (s)
#: before its first and after its last epoch: the Doppler's white noise (0.05-0.1 m/s) integrates
#: to 0.3-0.5 m over it, the ionosphere's code-carrier divergence to millimetres.
NEIGHBOUR_S = 30.0
Fit = Callable[[EpochData], MethodSolution]
"""Gauss-Newton of the ls/wls method on the given epochs (no exclusion)."""
Refit = Callable[..., MethodSolution]
"""Gauss-Newton of the ls/wls method on ``(epochs, x0 (t, 3) or None, clocks0 (t, k) or None)``."""


def los_cn0_template_dbhz(snr_dbhz: F64, el_deg: F64, groups: NDArray[np.int64], *, bin_deg: float = 5.0,
                          quantile: float = 0.9, min_count: int = 10, rounds: int = 2) -> F64:
    """The line-of-sight C/N0 ``(T, n)`` (dB-Hz) of every satellite-epoch from the file itself.

    Parameters
    ----------
    snr_dbhz : ``(T, n)`` C/N0, dB-Hz (NaN: none).
    el_deg : ``(T, n)`` elevation, deg (NaN: unknown).
    groups : ``(n,)`` group of each satellite (a system: one tracked signal each).
    bin_deg : width of the elevation bins, deg.
    quantile : the quantile of a bin's C/N0 taken as its line-of-sight value.
    min_count : values a bin (and a satellite's own level) needs; emptier bins are interpolated
        linearly in elevation from the group's other bins (held constant beyond the first and last).
    rounds : alternations of the group's bins and the satellites' own levels.

    Returns
    -------
    F64
        ``L_g(el) + o_s``: the group's level at each satellite-epoch's elevation (interpolated
        between bin centres) plus the satellite's own offset ``o_s <= 0``, the ``quantile`` of
        its C/N0 less its group's level over its track (transmit power, satellite block, FDMA
        channel; a satellite with fewer than ``min_count`` values has none). The bins are taken
        again from the C/N0 less the offsets, ``rounds`` times, so that a bin held by a weaker
        satellite does not lower the others' level. NaN where the group has no bin with
        ``min_count`` values, or C/N0 or elevation are NaN.
    """
    edges = np.arange(0.0, 90.0 + bin_deg, bin_deg)
    centres = 0.5 * (edges[:-1] + edges[1:])
    ok = np.isfinite(snr_dbhz) & np.isfinite(el_deg)
    b = np.where(ok, np.clip(np.digitize(np.nan_to_num(el_deg), edges) - 1, 0, centres.size - 1), -1)
    offset = np.zeros(snr_dbhz.shape[1])
    level = np.full(snr_dbhz.shape, np.nan)
    for _ in range(rounds):
        level[:] = np.nan
        own = snr_dbhz - offset
        for g in np.unique(groups):
            cols = groups == g
            values, bins = own[:, cols], b[:, cols]
            per_bin = np.full(centres.size, np.nan)
            for i in np.unique(bins[bins >= 0]):
                in_bin = values[bins == i]
                if in_bin.size >= min_count:
                    per_bin[i] = np.quantile(in_bin, quantile)
            have = np.isfinite(per_bin)
            if have.any():
                level[:, cols] = np.where(ok[:, cols], np.interp(el_deg[:, cols], centres[have], per_bin[have]), np.nan)
        below = snr_dbhz - level
        has = np.isfinite(below).sum(axis=0) >= min_count
        offset = np.zeros(snr_dbhz.shape[1])
        if has.any():
            offset[has] = np.minimum(np.nanquantile(below[:, has], quantile, axis=0), 0.0)
    return level + offset


def _span_ids(active: NDArray[np.bool_]) -> tuple[NDArray[np.intp], int]:
    """``(n, T)`` index of the run of consecutive ``active`` epochs (``(T, n)``, along axis 0)
    each epoch of each satellite belongs to (-1 outside), and the number of runs."""
    T, n = active.shape
    a = active.T
    start = a & ~np.concatenate([np.zeros((n, 1), dtype=bool), a[:, :-1]], axis=1)
    return np.where(a, np.cumsum(start.ravel()).reshape(n, T) - 1, -1), int(start.sum())


def persistent_spans(active: NDArray[np.bool_], score: F64, threshold: float) -> NDArray[np.bool_]:
    """The runs of consecutive ``active`` epochs of each satellite (``(T, n)``, along axis 0)
    whose summed ``score`` reaches ``threshold``: their epochs are True.

    >>> a = np.array([[1], [1], [0], [1]], bool)
    >>> persistent_spans(a, np.array([[2.0], [2.0], [9.0], [3.0]]), 4.0)[:, 0].tolist()
    [True, True, False, False]
    """
    if not active.any():
        return np.zeros_like(active)
    run, count = _span_ids(active)
    a = run >= 0
    total = np.bincount(run[a], weights=score.T[a], minlength=count)
    return (a & (total >= threshold)[np.maximum(run, 0)]).T


def cusum_spans(u: F64, k: float, h: float) -> NDArray[np.bool_]:
    """The spans ``(T, n)`` of a one-sided CUSUM of each satellite's ``u`` (along axis 0).

    ``S_t = max(0, S_{t-1} + u_t - k)``, back to 0 where ``u`` is NaN (the satellite not used); an
    excursion of ``S`` above 0 whose largest value reaches ``h`` is a span, from its first epoch to
    the epoch of that largest value (after it ``S`` only falls: the bias has ended). Unlike a run of
    ``u > k`` (:func:`persistent_spans`), one epoch whose noise takes ``u`` below ``k`` does not end it.

    >>> u = np.array([[3.0], [0.0], [3.0], [-9.0], [0.2]])
    >>> cusum_spans(u, 0.5, 4.0)[:, 0].tolist()
    [True, True, True, False, False]
    """
    T, n = u.shape
    step = np.nan_to_num(u - k, nan=-np.inf)
    S, peak = np.zeros(n), np.zeros(n)
    start, peak_t = np.zeros(n, dtype=np.intp), np.zeros(n, dtype=np.intp)
    found: list[tuple[int, int, int]] = []
    for t in range(T):
        new = np.maximum(S + step[t], 0.0)
        begin = (S == 0.0) & (new > 0.0)
        start[begin], peak[begin] = t, 0.0
        higher = new > peak
        peak[higher], peak_t[higher] = new[higher], t
        for j in np.flatnonzero((S > 0.0) & (new == 0.0) & (peak >= h)):
            found.append((int(j), int(start[j]), int(peak_t[j])))
        S = new
    for j in np.flatnonzero((S > 0.0) & (peak >= h)):
        found.append((int(j), int(start[j]), int(peak_t[j])))
    out = np.zeros((T, n), dtype=bool)
    for j, a, b in found:
        out[a:b + 1, j] = True
    return out


def multi_epoch_spans(data: EpochData, sol: MethodSolution, sigma_m: F64, config: ProcessingConfig
                      ) -> NDArray[np.bool_]:
    """The satellite-epochs ``(T, n)`` a multi-epoch method leaves out as persistent reflections:
    the :func:`cusum_spans` (``[nlos] multi_epoch_k``, ``multi_epoch_h``) of ``u = r / sigma``, with
    ``r`` each usable pseudorange's residual (m) at the method's positions and clocks ``sol``
    (:func:`prediction_residuals_m`) and ``sigma_m`` the a-priori sigmas of the WLS solution
    (NaN: not a candidate); every epoch keeps its redundancy (:func:`keep_redundancy` with
    ``multi_epoch_min_dof``, largest ``u`` first). Several epochs pin a trajectory, so a
    reflection's delay shows in its residuals where a single epoch's fix absorbs much of it."""
    cfg = config.nlos
    cand = data.usable & np.isfinite(sigma_m)
    u = prediction_residuals_m(data, sol, cand, config) / sigma_m
    spans = cusum_spans(u, cfg.multi_epoch_k, cfg.multi_epoch_h)
    system_index = data.clock_index
    return keep_redundancy(spans, np.nan_to_num(u), cand, system_index, len(data.systems), cfg.multi_epoch_min_dof,
                           config.min_satellites)


def span_means(spans: NDArray[np.bool_], values: F64) -> F64:
    """``(T, n)``: the mean of the finite ``values`` over the run of ``spans`` each epoch belongs to
    (NaN outside the runs, and for a run without a finite value)."""
    out = np.full(spans.shape, np.nan)
    if not spans.any():
        return out
    run, count = _span_ids(spans)
    v = values.T
    has = (run >= 0) & np.isfinite(v)
    total = np.bincount(run[has], weights=v[has], minlength=count)
    n = np.bincount(run[has], minlength=count)
    mean = np.where(n > 0, total / np.maximum(n, 1), np.nan)
    out.T[run >= 0] = mean[run[run >= 0]]
    return out


def span_sigma_m(spans: NDArray[np.bool_], prediction_sigma_m: F64, sigma_m: F64 | None) -> F64:
    """``(T, n)``: the standard deviation (m) of a span's mean delay as a fix predicts it, over each
    run of ``spans``: ``sqrt(mean(s_p^2) + mean(s^2) / m)`` with ``s_p`` the prediction's sigma
    (its errors follow the fix's geometry, which changes slowly: they do not average out over the
    run), ``s`` the pseudoranges' own sigma (white: divided by the run's ``m`` epochs) and ``m``
    the epochs with both (NaN outside the runs).

    >>> s = np.array([[True], [True], [False]])
    >>> span_sigma_m(s, np.array([[3.0], [4.0], [np.nan]]), np.array([[2.0], [2.0], [1.0]]))[:, 0].round(6).tolist()
    [3.807887, 3.807887, nan]
    """
    own = np.full(spans.shape, np.nan) if sigma_m is None else sigma_m
    both = spans & np.isfinite(prediction_sigma_m) & np.isfinite(own)
    m = np.full(spans.shape, np.nan)
    if spans.any():
        run, count = _span_ids(spans)
        per = np.bincount(run[both.T], minlength=count)
        m.T[run >= 0] = per[run[run >= 0]]
    var = (span_means(spans, np.where(both, prediction_sigma_m**2, np.nan))
           + span_means(spans, np.where(both, own**2, np.nan)) / np.where(m > 0, m, np.nan))
    return np.sqrt(var)


def keep_redundancy(flagged: NDArray[np.bool_], suspicion: F64, used: NDArray[np.bool_],
                    system_index: NDArray[np.int64], n_systems: int, min_dof: int,
                    min_satellites: int) -> NDArray[np.bool_]:
    """The ``flagged`` satellites ``(T, n)`` each epoch can drop: most ``suspicion`` first, while
    the epoch keeps ``used`` satellites for ``dof = n_used - 3 - k >= min_dof`` (``k``: systems
    with a satellite left) and ``n_used >= min_satellites``."""
    T = flagged.shape[0]
    flagged = flagged & used
    order = np.argsort(np.where(flagged, -suspicion, np.inf), axis=1, kind="stable")
    members = np.zeros((T, n_systems), dtype=np.int64)
    np.add.at(members, (np.nonzero(used)[0], system_index[np.nonzero(used)[1]]), 1)
    n_used = used.sum(axis=1)
    going = np.ones(T, dtype=bool)
    out = np.zeros_like(flagged)
    rows = np.arange(T)
    for j in range(int(flagged.sum(axis=1).max(initial=0))):
        sv = order[:, j]
        s = system_index[sv]
        left = members.copy()
        left[rows, s] -= 1
        dof = n_used - 1 - 3 - (left > 0).sum(axis=1)
        go = going & flagged[rows, sv] & (dof >= min_dof) & (n_used - 1 >= min_satellites)
        going &= go
        out[rows[go], sv[go]] = True
        members[rows[go], s[go]] -= 1
        n_used -= go
    return out


def _elevation_deg(data: EpochData, sol: MethodSolution) -> F64:
    """Elevations ``(T, n)`` at the fixes of ``sol``; an epoch without a fix takes the nearest
    earlier (else later) fix, or the header position; NaN without any."""
    x = sol.x_ecef_m
    good = np.isfinite(x).all(axis=1)
    if not good.any():
        if data.approx_ecef_m is None:
            return np.full(data.usable.shape, np.nan)
        x, good = np.broadcast_to(data.approx_ecef_m, x.shape), np.ones(good.size, dtype=bool)
    idx = np.maximum.accumulate(np.where(good, np.arange(good.size), -1))
    idx = np.where(idx < 0, np.flatnonzero(good)[0], idx)
    return satellite_azimuth_elevation_deg(data.sat_ecef_m, x[idx])[1]


def cn0_spans(data: EpochData, sol: MethodSolution, config: ProcessingConfig) -> tuple[NDArray[np.bool_], F64]:
    """The C/N0 spans ``(T, n)`` of the satellites ``sol`` used (module docstring, test 1), and
    the deficit ``d`` (dB; NaN where there is no template or C/N0)."""
    cfg = config.nlos
    used = np.isfinite(sol.residuals_m)
    if data.snr_dbhz is None:
        return np.zeros_like(used), np.full(used.shape, np.nan)
    groups = np.unique([sv[0] for sv in data.sv.astype(str)], return_inverse=True)[1]
    snr = np.where(used, data.snr_dbhz, np.nan)
    template = los_cn0_template_dbhz(snr, _elevation_deg(data, sol), groups, bin_deg=cfg.template_bin_deg,
                                     quantile=cfg.template_quantile, min_count=cfg.template_min_count)
    deficit = template - snr
    active = used & (np.nan_to_num(deficit, nan=-np.inf) > cfg.cn0_exit_db)
    strong = (np.nan_to_num(deficit, nan=-np.inf) > cfg.cn0_enter_db).astype(np.float64)
    return persistent_spans(active, strong, cfg.cn0_min_epochs), deficit


def residual_spans(sol: MethodSolution, config: ProcessingConfig) -> tuple[NDArray[np.bool_], F64]:
    """The residual spans ``(T, n)`` of ``sol`` (module docstring, test 2) and ``u = r / sigma``."""
    cfg = config.nlos
    sigma = sol.sigma_m if sol.sigma_m is not None else np.full(sol.residuals_m.shape, np.nan)
    u = sol.residuals_m / sigma
    active = np.nan_to_num(u, nan=-np.inf) > cfg.residual_k
    if not np.isfinite(cfg.residual_h):
        return np.zeros_like(active), u
    return persistent_spans(active, np.where(active, u - cfg.residual_k, 0.0), cfg.residual_h), u


def prediction_residuals_m(data: EpochData, sol: MethodSolution, which: NDArray[np.bool_],
                           config: ProcessingConfig) -> F64:
    """``(T, n)`` observed minus modelled pseudorange (m) of the satellites ``which`` at the fixes of
    ``sol`` that left them out (:func:`~gnss_cli.pipeline.integrity.check_fixes`); NaN elsewhere and
    where ``sol`` has no fix."""
    out = np.full(which.shape, np.nan)
    rows = np.flatnonzero(np.isfinite(sol.x_ecef_m).all(axis=1) & np.isfinite(sol.clocks_m).all(axis=1) & which.any(axis=1))
    if rows.size:
        sigma = np.where(which[rows], 1.0, np.nan)
        out[rows] = check_fixes(take_epochs(data, rows), sol.x_ecef_m[rows], sol.clocks_m[rows], sigma, config).residuals_m
    return out


def prediction_sigma_m(data: EpochData, sol: MethodSolution, which: NDArray[np.bool_]) -> F64:
    """``(T, n)`` standard deviation (m) of the range that the fix ``sol`` predicts for the satellites
    ``which`` it left out: ``sqrt(g P g^T)`` with ``P`` the fix's position-and-clock covariance
    (``cov_m2``) and ``g = [-e, 1_clock]`` the satellite's line of sight ``e`` (unit, receiver to
    satellite) and its system's clock column. NaN elsewhere, where ``sol`` has no fix and where its
    covariance is not finite."""
    out = np.full(which.shape, np.nan)
    rows = np.flatnonzero(np.isfinite(sol.x_ecef_m).all(axis=1) & which.any(axis=1))
    if not rows.size:
        return out
    los = data.sat_ecef_m[rows] - sol.x_ecef_m[rows, None, :]
    los /= np.linalg.norm(los, axis=2, keepdims=True)
    k = sol.cov_m2.shape[1] - 3
    clock = data.clock_index
    g = np.concatenate([-los, np.broadcast_to(np.eye(k)[clock], (rows.size, data.sv.size, k))], axis=2)
    var = np.einsum("tni,tij,tnj->tn", g, sol.cov_m2[rows], g)
    out[rows] = np.where(which[rows], np.sqrt(np.maximum(var, 0.0)), np.nan)
    return out


def code_minus_doppler_m(data: EpochData) -> tuple[F64, NDArray[np.int64]] | None:
    """``(T, n)`` each satellite's pseudorange less the range its Doppler integrates since the
    first epoch of its unbroken run (m), and ``(T, n)`` the index of that run (along each column);
    None without Doppler.

    The step from epoch ``t-1`` to ``t`` is ``p_t - p_{t-1} - dt (d_{t-1} + d_t) / 2`` with ``p`` the
    pseudorange with its satellite clock applied and ``d`` the range rate with its satellite
    clock drift applied (both then hold the receiver clock alike); the median step of the epoch's
    satellites is taken off every step where at least three have one (what is common to them: a
    receiver clock jump). A run is unbroken while both epochs have a pseudorange and a range rate
    and are at most 1.5 sampling intervals apart. What is left is a reflection's delay (a step up where it starts, down where
    it ends), code noise and the Doppler's noise integrated. NaN where either is missing."""
    if data.range_rate_m_s is None or data.time_gps_s.size < 2:
        return None
    rate = data.range_rate_m_s
    if data.sat_clock_drift_s_s is not None:
        rate = rate + C_M_S * data.sat_clock_drift_s_s
    have = np.isfinite(data.pr_corrected_m) & np.isfinite(rate)
    dt = np.diff(data.time_gps_s)[:, None]
    step = np.diff(data.pr_corrected_m, axis=0) - 0.5 * dt * (rate[1:] + rate[:-1])
    linked = have[1:] & have[:-1] & (dt <= 1.5 * np.median(dt))
    common = np.zeros(step.shape[0])
    rows = linked.sum(axis=1) >= 3  # fewer satellites cannot tell which one stepped
    common[rows] = np.nanmedian(np.where(linked[rows], step[rows], np.nan), axis=1)
    step = np.where(linked, step - common[:, None], 0.0)
    total = np.vstack([np.zeros((1, step.shape[1])), np.cumsum(step, axis=0)])
    starts = np.vstack([np.ones((1, step.shape[1]), dtype=bool), ~linked])
    first = np.maximum.accumulate(np.where(starts, np.arange(total.shape[0])[:, None], 0), axis=0)
    return np.where(have, total - np.take_along_axis(total, first, axis=0), np.nan), np.cumsum(starts, axis=0)


def doppler_span_delays_m(data: EpochData, runs: NDArray[np.bool_], spans: NDArray[np.bool_]) -> F64 | None:
    """``(T, n)``: over each run of ``runs``, the mean of :func:`code_minus_doppler_m` less its mean
    over the satellite's epochs outside ``spans`` within :data:`NEIGHBOUR_S` before the run's first
    and after its last epoch, in the same unbroken run of code and Doppler (m). NaN outside the
    runs and for a run without such neighbours; None without Doppler.

    >>> import numpy as np
    >>> from types import SimpleNamespace as NS
    >>> t = np.arange(8.0)
    >>> pr = np.c_[1e7 + 100 * t + [0, 0, 0, 9, 9, 9, 0, 0], 2e7 - 50 * t, 2e7 + 0 * t]  # 9 m for 3 s
    >>> d = NS(time_gps_s=t, pr_corrected_m=pr + 3 * t[:, None],    # a receiver clock drifting 3 m/s ...
    ...        range_rate_m_s=np.tile([100.0, -50.0, 0.0], (8, 1)) + 3,    # ... in the range rates too
    ...        sat_clock_drift_s_s=None)
    >>> run = np.zeros((8, 3), bool); run[3:6, 0] = True
    >>> doppler_span_delays_m(d, run, run)[3:6, 0].round(6).tolist()
    [9.0, 9.0, 9.0]
    """
    got = code_minus_doppler_m(data)
    if got is None:
        return None
    level, unbroken = got
    out = np.full(runs.shape, np.nan)
    t = data.time_gps_s
    direct = np.isfinite(level) & ~spans
    for j in np.flatnonzero(runs.any(axis=0)):
        edges = np.flatnonzero(np.diff(np.concatenate([[0], runs[:, j].astype(np.int8), [0]])))
        for a, b in zip(edges[::2], edges[1::2]):
            inside = np.isfinite(level[a:b, j])
            if not inside.any():
                continue
            near = direct[:, j] & (t >= t[a] - NEIGHBOUR_S) & (t <= t[b - 1] + NEIGHBOUR_S)
            near &= np.isin(unbroken[:, j], unbroken[a:b, j][inside])
            if near.any():
                out[a:b, j] = level[a:b, j][inside].mean() - level[near, j].mean()
    return out


def exclude_nlos(data: EpochData, first: MethodSolution, fit: Fit, config: ProcessingConfig
                 ) -> tuple[NDArray[np.bool_], NDArray[np.bool_]]:
    """The satellite-epochs ``(T, n)`` to exclude as persistent reflections (module docstring):
    the C/N0 spans at the fix ``first`` of every satellite (those whose pseudoranges are late by
    ``cn0_min_delay_m`` or more on average over the span, as the fix without them predicts them
    or, with ``cn0_delay_source = "doppler"``, :func:`doppler_span_delays_m` where it has a
    value), then the
    residual spans at the fix ``fit`` gives without them; each stage keeps every epoch's redundancy.
    The fix that measures the delays leaves the spans out and weighs those redundancy keeps in at
    ``variance_factor`` times their variance. Also returns the satellite-epochs to down-weight:
    the spans redundancy kept (used, flagged, not excluded) and, with ``cn0_delay_sigmas > 0``,
    the spans whose fix-measured delay is short of ``cn0_min_delay_m`` but not by that many of its
    standard deviations (:func:`span_sigma_m`)."""
    cfg = config.nlos
    k = len(data.systems)
    system_index = data.clock_index

    def allowed(flagged: NDArray[np.bool_], suspicion: F64, used: NDArray[np.bool_]) -> NDArray[np.bool_]:
        return keep_redundancy(flagged, np.nan_to_num(suspicion), used, system_index, k, cfg.min_dof,
                               config.min_satellites)

    def without(out: NDArray[np.bool_], kept: NDArray[np.bool_] | None = None) -> MethodSolution:
        scale = None if kept is None or cfg.variance_factor <= 1.0 else np.where(kept, cfg.variance_factor, 1.0)
        return fit(replace(data, usable=data.usable & ~out, variance_scale=scale))

    used = np.isfinite(first.residuals_m)
    spans, deficit = cn0_spans(data, first, config)
    out = allowed(spans, deficit / cfg.cn0_enter_db, used)
    kept_by_redundancy = spans & used & ~out
    second: MethodSolution | None = None
    if np.isfinite(cfg.cn0_min_delay_m) and out.any():
        delay = doppler_span_delays_m(data, out, spans) if cfg.cn0_delay_source == "doppler" else None
        margin = np.zeros(out.shape)
        if delay is None or np.isnan(delay[out]).any():  # the fix measures the spans the Doppler cannot
            second = without(out, kept_by_redundancy)
            by_fix = span_means(out, prediction_residuals_m(data, second, out, config))
            if cfg.cn0_delay_sigmas > 0.0:
                sigma = span_sigma_m(out, prediction_sigma_m(data, second, out), first.sigma_m)
                margin = cfg.cn0_delay_sigmas * np.nan_to_num(sigma, nan=np.inf)
            if delay is not None:
                margin = np.where(np.isfinite(delay), 0.0, margin)
                delay = np.where(np.isfinite(delay), delay, by_fix)
            else:
                delay = by_fix
        delay = np.nan_to_num(delay, nan=np.inf)
        late = out & (delay >= cfg.cn0_min_delay_m)
        unsure = out & ~late & (delay + margin >= cfg.cn0_min_delay_m)  # not surely early: down-weighted
        kept_by_redundancy = kept_by_redundancy | unsure
        second, out = (second if late.sum() == out.sum() else None), late
    if not np.isfinite(cfg.residual_h):
        return out, kept_by_redundancy
    second = second if second is not None else without(out, kept_by_redundancy)
    spans, u = residual_spans(second, config)
    return out | allowed(spans, u / cfg.residual_k, np.isfinite(second.residuals_m)), kept_by_redundancy


def direct_dof(sol: MethodSolution, system_index: NDArray[np.int64]) -> NDArray[np.int64]:
    """The redundancy ``(T,)`` of each epoch's fix in its satellites at full weight: those used
    (finite residual, not excluded) whose variance the detector did not scale up
    (``variance_scale`` 1), less 3 and less the clocks of their systems -- the degrees of freedom
    the fix of those satellites alone would have (negative: they cannot fix the epoch alone).
    ``system_index``: ``(n,)`` clock of each satellite."""
    used = np.isfinite(sol.residuals_m)
    if sol.excluded is not None:
        used &= ~sol.excluded
    direct = used if sol.variance_scale is None else used & (np.nan_to_num(sol.variance_scale, nan=1.0) <= 1.0)
    k = int(system_index.max()) + 1 if system_index.size else 0
    clocks = (direct[:, :, None] & (system_index[None, :, None] == np.arange(k))).any(axis=1).sum(axis=1)
    return direct.sum(axis=1) - 3 - clocks


def monitor_without_nlos(data: EpochData, first: MethodSolution, fit: Refit, config: ProcessingConfig) -> MethodSolution:
    """:func:`~gnss_cli.pipeline.integrity.monitor` (the test, FDE, protection levels) of the fixes
    without the reflections :func:`exclude_nlos` finds from the plain fix ``first``; ``fit`` solves a
    subset of epochs from given starting fixes. The excluded satellites join FDE's in ``excluded``.

    The spans redundancy keeps in get ``variance_factor`` times their variance (the solution's
    ``variance_scale``). With ``[nlos] failed_epochs = "retry"`` an epoch that is not ``ok`` after
    the exclusions (its test fails and FDE, short of redundancy, cannot repair it) is solved again
    with every satellite, every span down-weighted alike, and takes that solution when it is ``ok``.
    Last, with ``min_direct_dof > 0``, an ``ok`` epoch with fewer redundant measurements than that in
    its satellites at full weight (:func:`direct_dof`) becomes ``nlos_dependent``."""
    reflected, kept = exclude_nlos(data, first, lambda sub: fit(sub, None, None), config)
    scale = np.where(kept, config.nlos.variance_factor, 1.0) if config.nlos.variance_factor > 1.0 else None
    reduced = replace(data, usable=data.usable & ~reflected, variance_scale=scale)
    sol = monitor(reduced, fit(reduced, None, None), config, fit)
    sol = replace(sol, excluded=reflected if sol.excluded is None else sol.excluded | reflected,
                  variance_scale=scale)
    retry = np.flatnonzero((sol.status != EpochStatus.OK) & (reflected | kept).any(axis=1))
    if config.nlos.failed_epochs == "retry" and retry.size:
        every = None if scale is None else np.where(reflected | kept, config.nlos.variance_factor, 1.0)
        sub = take_epochs(replace(data, variance_scale=every), retry)
        again = monitor(sub, take_solution(first, retry), config, fit)
        better = np.flatnonzero(again.status == EpochStatus.OK)
        if better.size:
            if every is not None:  # every satellite again, the reflections down-weighted
                again = replace(again, variance_scale=every[retry])
            sol = merge_epochs(sol, retry[better], take_solution(again, better))
    if config.nlos.min_direct_dof > 0:
        weak = (sol.status == EpochStatus.OK) & (direct_dof(sol, data.clock_index) < config.nlos.min_direct_dof)
        sol = replace(sol, status=np.where(weak, EpochStatus.NLOS_DEPENDENT.value, sol.status).astype(sol.status.dtype))
    return sol
