"""The whole run of ``gnss-solve``: snapshot solutions, the behavioral smoothing and the Kalman
filter when configured, and the Doppler velocity of every row when the file has Doppler."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

import xarray as xr

from gnss_cli.config import ProcessingConfig
from gnss_cli.errors import ConfigError
from gnss_cli.pipeline.kalman import run_kalman
from gnss_cli.pipeline.results import MethodSolution, Progress, RunResult
from gnss_cli.pipeline.smoothing import smooth
from gnss_cli.pipeline.snapshot import run
from gnss_cli.pipeline.velocity import solve_velocity

__all__ = ["process", "with_velocity"]


def process(
    obs_path: str | Path,
    nav_paths: Sequence[str | Path],
    config: ProcessingConfig,
    progress: Progress | None = None,
    obs: list[xr.Dataset] | None = None,
) -> RunResult:
    """Read, validate and solve every epoch with every configured method.

    With ``config.smoothing.lag == 0`` this is :func:`~gnss_cli.pipeline.snapshot.run`.
    With ``lag >= 1`` the other methods (and WLS) are solved epoch by epoch, and the stls
    rows are the behavioral smoothing of the WLS fixes
    (:func:`~gnss_cli.pipeline.smoothing.smooth`), or with ``model = "doppler"`` (the default
    ``"auto"`` on a file with Doppler) the measurement-domain solution of
    :func:`~gnss_cli.pipeline.smoother.smooth_segments` (motion ``quadrature``); ``RunResult.models`` then holds one
    :class:`~gnss_cli.pipeline.results.WindowModel` per window.

    ``obs``: the observation file already read (:func:`~gnss_cli.io.rinex.read_obs`) in a
    one-element list, emptied when it is used (the dataset is then freed); else it is read here.

    ``kf`` (:func:`~gnss_cli.pipeline.kalman.run_kalman`) runs on the WLS solution (solved
    for it when not asked for). With Doppler in the observation file, every other method's
    rows get the Doppler velocity at their fixes (:func:`~gnss_cli.pipeline.velocity.solve_velocity`),
    the kf rows their filter's velocity.

    Raises
    ------
    ConfigError
        ``smoothing.lag >= 1`` without ``stls`` in ``config.methods``, or invalid smoothing options.
    InputError
        Bad input files.
    NoSolutionError
        No epoch could be solved by any method.
    """
    if "kf" not in config.methods:
        return with_velocity(_process_snapshot(obs_path, nav_paths, config, progress, obs), config)
    others = tuple(m for m in config.methods if m != "kf")
    snapshot = others + (() if "wls" in others else ("wls",))
    result = _process_snapshot(obs_path, nav_paths, replace(config, methods=snapshot), progress, obs)
    if progress is not None:
        progress(f"kf: Kalman filter ({config.kalman.model}, smoother {config.kalman.smoother})", 0.0)
    kf = run_kalman(result.epochs, result.solutions["wls"], config)
    solutions = {m: (kf if m == "kf" else result.solutions[m]) for m in config.methods}
    return with_velocity(replace(result, solutions=solutions), config)


def with_velocity(result: RunResult, config: ProcessingConfig) -> RunResult:
    """Every solution without a velocity gets the Doppler velocity at its fixes (file with Doppler)."""
    if result.epochs.range_rate_m_s is None:
        return result
    out: dict[str, MethodSolution] = {}
    for m, s in result.solutions.items():
        if s.vel_ecef_m_s is None:
            sigma = s.sigma_m if s.sigma_m is not None else result.solutions.get("wls", s).sigma_m
            vel = solve_velocity(result.epochs, s.x_ecef_m, sigma if sigma is not None else result.epochs.usable * 1.0, config)
            if vel is not None:
                s = replace(s, vel_ecef_m_s=vel.vel_ecef_m_s, clock_drift_m_s=vel.clock_drift_m_s, gdop_vel=vel.gdop_vel)
        out[m] = s
    return replace(result, solutions=out)


def _process_snapshot(obs_path: str | Path, nav_paths: Sequence[str | Path], config: ProcessingConfig,
                      progress: Progress | None, obs: list[xr.Dataset] | None = None) -> RunResult:
    """The snapshot methods, and the stls smoothing with ``lag >= 1``."""
    lag = config.smoothing.lag
    if lag == 0:
        return run(obs_path, nav_paths, config, progress=progress, obs=obs)
    if "stls" not in config.methods:
        raise ConfigError(f"smoothing.lag = {lag} needs the stls method (the smoothed rows are the stls rows)")
    config.smoothing.validated()
    others = tuple(m for m in config.methods if m != "stls")
    snapshot = replace(config, methods=others + (() if "wls" in others else ("wls",)))
    result = run(obs_path, nav_paths, snapshot, progress=progress, obs=obs)
    if progress is not None:
        progress(f"stls: smoothing, lag {lag}", 0.0)
    has_doppler = result.epochs.range_rate_m_s is not None and config.kalman.doppler
    config = replace(config, smoothing=config.smoothing.resolved(has_doppler))
    if config.smoothing.model == "kinematic":
        from gnss_cli.pipeline.kinematic import kinematic_smooth

        sol, models = kinematic_smooth(result.epochs, result.solutions["wls"], config)
    elif config.smoothing.model == "doppler":
        from gnss_cli.pipeline.smoother import default_measurements, smooth_segments  # scipy: imported when it runs

        sol, models = smooth_segments(result.epochs, result.solutions["wls"], config, motion="quadrature", lag=lag,
                                      measurements=default_measurements(result.epochs, config))
    else:
        sol, models = smooth(result.epochs, result.solutions["wls"], config)
    solutions = {m: (sol if m == "stls" else result.solutions[m]) for m in config.methods}
    return replace(result, solutions=solutions, models=models)
