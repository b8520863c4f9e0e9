"""What each method of a run computes, resolved from the configuration and the file's measurements.

One vocabulary (DESIGN.md section 6), written into ``summary.csv``, the report, ``--model-out``
and the closing stderr lines, so that a number can always be traced to the estimator behind it:

========  ==============================================================================
method    estimator
========  ==============================================================================
ls ...    the single-epoch family (``ls wls tls dls mtls wtls``, and ``stls`` with lag 0)
stls      with ``[stls] lag >= 1``: the paper's identified Hankel STLS in the measurement
          domain -- per sliding window, a shared kernel and the trajectory in its behavior by
          alternation (:mod:`gnss_cli.pipeline.identified`), from the pseudoranges and the
          Doppler and phase the measurements give; started from the STLS of the WLS fixes
smoother  a batch least-squares smoother of whole segments in the measurement domain with
          a fixed motion model (``[smoother] motion``)
kf        an extended Kalman filter with a Rauch-Tung-Striebel smoother (``[kalman]``)
========  ==============================================================================
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, replace

import numpy as np

from gnss_cli.config import MEASUREMENT_KINDS, ProcessingConfig
from gnss_cli.pipeline.results import EpochData, MethodSolution, RunResult, WindowModel, as_wls_used

__all__ = ["MethodSettings", "method_settings", "resolved_measurements", "settings_warnings", "with_settings", "motion_words",
           "snapshot_config", "solve_multi_epoch", "tested", "SINGLE_EPOCH_ESTIMATORS"]

SINGLE_EPOCH_ESTIMATORS = {
    "ls": "least squares", "wls": "weighted least squares", "tls": "total least squares",
    "dls": "data least squares", "mtls": "mixed LS-TLS", "stls": "structured TLS", "wtls": "weighted TLS",
}
"""The estimator of each single-epoch method key (one epoch at a time)."""


@dataclass(frozen=True)
class MethodSettings:
    """The resolved settings of one method of a run (strings, as written to the tables).

    Attributes
    ----------
    method : the method key (``--method``).
    estimator : what computes the rows, in words.
    model : motion model or kernel (``motion cv``, ``kernel shared r(z) I3``); empty for single epochs.
    lag : the kernel's or quadrature rule's lag (epochs), empty where none.
    window : ``1 epoch``, ``15 epochs`` or ``whole segments``; ``stls --lag L`` adds ``, untested``
        where no behavior test chooses its spans (``[stls] behavior_pfa = 0``, or ``kernel = "full"``).
    measurements : the measurement kinds used, ``+``-joined (``pseudorange+doppler``).
    integrity : how the rows are tested (``fde``, ``check``, ``gate``, ``off``, ...; ls/wls add
        ``robust huber`` and ``nlos arcs`` when those run).
    """

    method: str
    estimator: str
    model: str
    lag: str
    window: str
    measurements: str
    integrity: str

    def to_dict(self) -> dict[str, str]:
        return asdict(self)

    def line(self) -> str:
        """One line for stderr: ``estimator (model, lag L, window, measurements; integrity)``."""
        parts = [p for p in (self.model, f"lag {self.lag}" if self.lag else "", self.window, self.measurements) if p]
        return f"{self.estimator} ({', '.join(parts)}; integrity {self.integrity})"


def resolved_measurements(config: ProcessingConfig, has_doppler: bool, has_phase: bool) -> tuple[str, ...]:
    """The measurement kinds the multi-epoch methods use: ``config.measurements`` (empty: every
    kind) among those the observation file has; the phase needs the Doppler's wavelengths."""
    present = {"pseudorange": True, "doppler": has_doppler, "phase": has_phase}
    return tuple(k for k in MEASUREMENT_KINDS if present[k] and config.uses(k))


def measurement_warnings(config: ProcessingConfig, has_doppler: bool, has_phase: bool) -> list[str]:
    """A warning when ``--measurements`` names kinds the observation file does not give the
    multi-epoch methods (they then run on the others: :func:`resolved_measurements`).

    >>> from gnss_cli.config import load_config
    >>> config = load_config(None, {"methods": "kf", "measurements": "pseudorange,doppler,phase"})
    >>> measurement_warnings(config, True, False)
    ['--measurements pseudorange,doppler,phase: the observation file has no carrier phase; kf uses pseudorange+doppler']
    >>> measurement_warnings(config, True, True)
    []
    """
    multi = config.multi_epoch_methods
    if not multi or not config.measurements:
        return []
    used = resolved_measurements(config, has_doppler, has_phase)
    missing = [k for k in config.measurements if k not in used]
    if not missing:
        return []
    words = {"doppler": "Doppler", "phase": "carrier phase"}
    what = " or ".join(words[k] for k in missing)
    if "phase" in missing and not has_doppler:
        what += " (the phase is used with the Doppler: its wavelengths and slip check)"
    verb = "uses" if len(multi) == 1 else "use"
    return [f"--measurements {','.join(config.measurements)}: the observation file has no {what}; "
            f"{', '.join(multi)} {verb} {'+'.join(used)}"]


def method_settings(config: ProcessingConfig, has_doppler: bool, has_phase: bool) -> dict[str, MethodSettings]:
    """The :class:`MethodSettings` of every method of ``config.methods`` for a file with (or
    without) Doppler and carrier phase."""
    kinds = "+".join(resolved_measurements(config, has_doppler, has_phase))
    snapshot_integrity = config.integrity + (f", robust {config.robust}" if config.robust != "off" else "")
    if config.integrity != "off" and config.nlos.detector != "off":  # the reflections left out first
        snapshot_integrity += f", nlos {config.nlos.detector}"
        delay = []
        if np.isfinite(config.nlos.cn0_min_delay_m):
            if config.nlos.cn0_delay_source == "doppler" and has_doppler:  # without Doppler they come from the fix
                delay.append("span delays from the Doppler")
            if config.nlos.cn0_delay_sigmas > 0.0:  # the fix's delays: unsure spans down-weighted
                delay.append(f"delay margin {config.nlos.cn0_delay_sigmas:g} sigma")
        if delay:
            snapshot_integrity += f" ({', '.join(delay)})"
        if config.nlos.min_direct_dof > 0:  # fixes the direct satellites cannot test are nlos_dependent
            snapshot_integrity += f", min direct dof {config.nlos.min_direct_dof}"
    tested = "off" if config.integrity == "off" else "check"  # the residual test at the method's own fix
    spans = (", reflection spans" if config.integrity != "off" and config.nlos.multi_epoch != "off" else "")
    tested += spans
    segment_tests = spans  # smoother and kf: the spans, then the segments' misfit test
    if config.integrity != "off" and np.isfinite(config.max_segment_misfit):
        segment_tests += f", segment misfit {config.max_segment_misfit:g}"
    out: dict[str, MethodSettings] = {}
    for m in config.methods:
        if m == "stls" and config.stls.lag > 0:
            s = config.stls
            kernel = "kernel shared r(z) I3" if s.kernel == "shared" else f"kernel full order {s.full_order}"
            tested_spans = s.behavior_pfa > 0 and s.kernel == "shared"  # the full kernel has no behavior test
            window = (f"{s.window} epochs" if s.window else "whole segments") + ("" if tested_spans else ", untested")
            if s.kernel == "shared":
                from gnss_cli.behavior.piecewise import velocity_rule  # scipy: imported when stls runs
                from gnss_cli.pipeline.behavioral import spans_tied

                tied = ", overlapping windows cross-faded" if not spans_tied(frozenset(kinds.split("+"))) else \
                    f", spans tied ({velocity_rule(s.lag, 'doppler' in kinds.split('+'))})"  # gnss_cli.pipeline.tied
                if tied and s.latency_m > 0:
                    tied += f", latency {s.latency_m:g} m"
                out[m] = MethodSettings(m, "identified Hankel STLS (measurement domain, alternation)",
                                        f"{kernel} identified per window{tied}", str(s.lag), window, kinds, tested)
            else:  # the alternation is for shared kernels: the full kernel stays with the fixes
                out[m] = MethodSettings(m, "identified Hankel STLS (position domain)",
                                        f"{kernel} identified per window, overlapping windows cross-faded",
                                        str(s.lag), window, "pseudorange (WLS fixes)", tested)
        elif m == "smoother":
            motion = config.smoother.motion
            lag = str(config.smoother.lag) if motion == "quadrature" else ""
            out[m] = MethodSettings(m, "fixed-model batch smoother", motion_words(motion, config), lag, "whole segments", kinds,
                                    "off" if config.integrity == "off" else "residual gate, check" + segment_tests)
        elif m == "kf":
            k = config.kalman
            estimator = "extended Kalman filter" + (" + RTS smoother" if k.output == "smoothed" else "")
            out[m] = MethodSettings(m, estimator, motion_words(k.model, config), "", "whole segments", kinds,
                                    "off" if config.integrity == "off" else "innovation gate, check" + segment_tests)
        else:
            integrity = snapshot_integrity if m in ("ls", "wls") else tested
            out[m] = MethodSettings(m, SINGLE_EPOCH_ESTIMATORS[m] + " (single epoch)", "", "", "1 epoch",
                                    "pseudorange", integrity)
    return out


def motion_words(motion: str, config: ProcessingConfig) -> str:
    """A fixed motion model as the ``model`` setting says it, with the process noise it ran with
    (``cv`` / ``ca``: the ``[kalman]`` PSD of the white acceleration / jerk, which ``smoother`` and
    ``kf`` share).

    >>> from gnss_cli.config import load_config
    >>> motion_words("ca", load_config(None, {"kalman.jerk_psd_m2_s5": 0.01})), motion_words("quadrature", load_config(None))
    ('motion ca (jerk PSD 0.01 m^2/s^5)', 'motion quadrature')
    """
    k = config.kalman
    psd = {"cv": f" (acceleration PSD {k.accel_psd_m2_s3:g} m^2/s^3)", "ca": f" (jerk PSD {k.jerk_psd_m2_s5:g} m^2/s^5)"}
    return f"motion {motion}{psd.get(motion, '')}"


def settings_warnings(config: ProcessingConfig) -> list[str]:
    """Warnings a run's settings call for before any file is read.

    ``stls --lag L`` (L >= 2) in whole segments (``[stls] window = 0``, the default) relies on the
    behavior test to split a segment where one kernel does not hold
    (:mod:`gnss_cli.pipeline.spans`). Where nothing is tested (``[stls] behavior_pfa = 0``, or the
    full kernel, which smooths the fixes in the position domain) a whole segment is one kernel:
    right for a static antenna (L = 1), metres off on a moving receiver. (``integrity = "off"``
    leaves the behavior test on: it chooses the spans.)

    >>> from gnss_cli.config import load_config
    >>> settings_warnings(load_config(None, {"methods": "stls", "stls.lag": 3, "stls.behavior_pfa": 0}))[0][:58]
    'stls --lag 3 --window 0 with [stls] behavior_pfa = 0: no b'
    >>> settings_warnings(load_config(None, {"methods": "stls", "stls.lag": 3, "integrity": "off"}))
    []
    >>> settings_warnings(load_config(None, {"methods": "stls", "stls.lag": 3, "stls.window": 15, "stls.behavior_pfa": 0}))
    []
    """
    s = config.stls
    if "stls" not in config.methods or s.lag < 2 or s.window != 0:
        return []
    why = [w for w, on in (("[stls] behavior_pfa = 0", s.behavior_pfa == 0), ("--kernel full", s.kernel == "full")) if on]
    if not why:
        return []
    return [f"stls --lag {s.lag} --window 0 with {' and '.join(why)}: no behavior test splits a segment, so each "
            f"whole segment is one lag-{s.lag} kernel; on a moving receiver give --window N (epochs)"]


def with_settings(result: RunResult, config: ProcessingConfig) -> RunResult:
    """``result`` with the resolved settings of each of its methods (:func:`method_settings`)."""
    epochs = result.epochs
    settings = method_settings(config, epochs.range_rate_m_s is not None, epochs.phase_m is not None)
    return replace(result, settings={m: settings[m] for m in result.solutions if m in settings})


def snapshot_config(config: ProcessingConfig) -> ProcessingConfig:
    """``config`` with its single-epoch methods only, and WLS when a multi-epoch method needs it."""
    multi = config.multi_epoch_methods
    methods = tuple(m for m in config.methods if m not in multi)
    if multi and "wls" not in methods:
        methods += ("wls",)
    return replace(config, methods=methods)


def solve_multi_epoch(method: str, data: EpochData, wls: MethodSolution, config: ProcessingConfig,
                      factors: tuple[float, ...] | None = None) -> tuple[MethodSolution, tuple[WindowModel, ...]]:
    """One multi-epoch method over the epochs ``data``, from their ``wls`` solution: its rows and
    its window models. ``factors``: the variance factors of the measurement kinds when they were
    estimated on the whole file (a file solved in pieces), else they are estimated on ``data``;
    once reflection spans are left out, they are estimated again on ``data`` without them.

    The DOP columns of every multi-epoch row are geometry: the unit-weight pseudorange geometry
    over a window under the method's motion model (:mod:`gnss_cli.pipeline.multi_epoch_dop`;
    for ``stls`` the window's identified kernel), never the covariance of all the measurements,
    which stays in ``cov_m2`` (``sde_m``... columns)."""
    data = as_wls_used(data, wls)  # WLS's satellites (FDE and NLOS exclusions out) and weights
    if method not in ("stls", "smoother", "kf"):
        raise ValueError(f"solve_multi_epoch: {method!r} is not a multi-epoch method")
    sol, models = _solve_one(method, data, wls, config, factors)
    solved = data  # the satellites the method was given: less the reflection spans, once found
    if config.integrity != "off" and config.nlos.multi_epoch != "off" and wls.sigma_m is not None:
        from gnss_cli.pipeline.nlos import multi_epoch_spans

        spans = np.zeros(data.usable.shape, dtype=bool)
        for _ in range(config.nlos.multi_epoch_rounds):
            new = multi_epoch_spans(replace(data, usable=data.usable & ~spans), sol, wls.sigma_m, config)
            if not new.any():
                break
            spans |= new
            # the factors again without the spans (a reflection is no noise): a piece of a long file
            # estimates its own, as the whole file would after its spans
            sol, models = _solve_one(method, replace(data, usable=data.usable & ~spans), wls, config, None)
        if spans.any():
            sol = replace(sol, excluded=spans if sol.excluded is None else sol.excluded | spans)
            solved = replace(data, usable=data.usable & ~spans)
    if method in ("smoother", "kf"):  # stls tests each window's behavior itself (pipeline.spans)
        from gnss_cli.pipeline.segment_misfit import tested_segments
        from gnss_cli.pipeline.smoother import GAP_FACTOR

        sol, models = tested_segments(method, solved, wls, config, sol, models,
                                      lambda sub, sub_wls: _solve_one(method, sub, sub_wls, config, factors),
                                      GAP_FACTOR if method == "smoother" else 1.5)
    no_levels = np.full(sol.status.size, np.nan)  # built from the WLS rows: their levels are WLS's, not this method's
    return tested(data, replace(sol, hpl_m=no_levels, vpl_m=no_levels.copy()), wls, config), models


def _solve_one(method: str, data: EpochData, wls: MethodSolution, config: ProcessingConfig,
               factors: tuple[float, ...] | None) -> tuple[MethodSolution, tuple[WindowModel, ...]]:
    """The rows and window models of ``method`` on ``data`` (its ``usable`` satellites), before the test."""
    from gnss_cli.pipeline.multi_epoch_dop import with_geometry_dops

    kinds = resolved_measurements(config, data.range_rate_m_s is not None, data.phase_m is not None)
    if method == "stls":
        from gnss_cli.pipeline.behavioral import smooth

        return smooth(data, wls, config, measurements=frozenset(kinds) if config.stls.kernel == "shared" else None,
                      factors=factors)
    if method == "smoother":
        from gnss_cli.pipeline.smoother import smooth_segments  # scipy: imported when it runs

        sol, models = smooth_segments(data, wls, config, motion=config.smoother.motion, lag=config.smoother.lag,
                                      measurements=kinds, factors=factors)
        return with_geometry_dops(data, sol, config, config.smoother.motion), models
    from gnss_cli.pipeline.kalman import run_kalman

    sol = run_kalman(data, wls, config, measurements=frozenset(kinds), factors=factors)
    return with_geometry_dops(data, sol, config, config.kalman.model), ()


def tested(data: EpochData, sol: MethodSolution, wls: MethodSolution, config: ProcessingConfig) -> MethodSolution:
    """A multi-epoch method's rows after the residual test of WLS at their own estimates
    (:func:`~gnss_cli.pipeline.integrity.monitor_fixes`, unless ``integrity = "off"``): the
    chi-square statistic of the pseudoranges the method used (those with a residual), with the
    WLS sigmas; its degrees of freedom are the pseudoranges less the epoch's clocks (the position
    is fixed by several epochs, not fitted to this epoch's pseudoranges), then the GDOP limit,
    then its own protection levels (:func:`~gnss_cli.pipeline.integrity.estimate_levels`: from
    the WLS epoch's fault-free subsets) against the alert limits. An ``ok`` epoch that fails
    becomes ``integrity_fail`` (``gdop_limit``, ``hpl_limit``, ``vpl_limit``), keeping its
    position; one without levels is ``untested``."""
    if config.integrity == "off" or wls.sigma_m is None:
        return sol
    from gnss_cli.pipeline.integrity import estimate_levels, monitor_fixes

    sigma = np.where(np.isfinite(sol.residuals_m), wls.sigma_m, np.nan)
    levels = estimate_levels(data, wls, sol.x_ecef_m, config)
    checked = monitor_fixes(data, replace(sol, sigma_m=sigma), wls.status, config, position_unknowns=0,
                            levels=levels)
    return replace(checked, sigma_m=sol.sigma_m)
