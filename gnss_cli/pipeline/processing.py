"""The whole run of ``gnss-solve``: snapshot solutions, then the behavioral smoothing when configured."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

from gnss_cli.config import ProcessingConfig
from gnss_cli.errors import ConfigError
from gnss_cli.pipeline.results import Progress, RunResult
from gnss_cli.pipeline.smoothing import smooth
from gnss_cli.pipeline.snapshot import run

__all__ = ["process"]


def process(
    obs_path: str | Path,
    nav_paths: Sequence[str | Path],
    config: ProcessingConfig,
    progress: Progress | None = None,
) -> RunResult:
    """Read, validate and solve every epoch with every configured method.

    With ``config.smoothing.lag == 0`` this is :func:`~gnss_cli.pipeline.snapshot.run`.
    With ``lag >= 1`` the other methods (and WLS) are solved epoch by epoch, and the stls
    rows are the behavioral smoothing of the WLS fixes
    (:func:`~gnss_cli.pipeline.smoothing.smooth`); ``RunResult.models`` then holds one
    :class:`~gnss_cli.pipeline.results.WindowModel` per window.

    Raises
    ------
    ConfigError
        ``smoothing.lag >= 1`` without ``stls`` in ``config.methods``, or invalid smoothing options.
    InputError
        Bad input files.
    NoSolutionError
        No epoch could be solved by any method.
    """
    lag = config.smoothing.lag
    if lag == 0:
        return run(obs_path, nav_paths, config, progress=progress)
    if "stls" not in config.methods:
        raise ConfigError(f"smoothing.lag = {lag} needs the stls method (the smoothed rows are the stls rows)")
    config.smoothing.validated()
    others = tuple(m for m in config.methods if m != "stls")
    snapshot = replace(config, methods=others + (() if "wls" in others else ("wls",)))
    result = run(obs_path, nav_paths, snapshot, progress=progress)
    if progress is not None:
        progress(f"stls: smoothing, lag {lag}", 0.0)
    sol, models = smooth(result.epochs, result.solutions["wls"], config)
    solutions = {m: (sol if m == "stls" else result.solutions[m]) for m in config.methods}
    return replace(result, solutions=solutions, models=models)
