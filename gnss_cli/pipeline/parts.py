"""One part of an observation file (consecutive epochs): its epochs on the whole file's axes,
and its snapshot solution, wherever it runs (:class:`~gnss_cli.pipeline.run.Run`,
in this process or a forked one)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import xarray as xr

from gnss_cli.config import ProcessingConfig
from gnss_cli.gnss.observables import align_pseudoranges, select_pseudoranges
from gnss_cli.pipeline.epochs import Coverage, EpochSetup, build_epochs, finish_epochs
from gnss_cli.pipeline.methods import with_settings
from gnss_cli.pipeline.results import EpochData, RunResult
from gnss_cli.pipeline.snapshot import solve_methods, status_counts
from gnss_cli.pipeline.velocity import with_velocity

__all__ = ["part_epochs", "solve_part", "split_epochs"]


def split_epochs(obs: xr.Dataset, n: int) -> list[xr.Dataset]:
    """``obs`` cut in ``n`` runs of consecutive epochs of (nearly) equal length."""
    bounds = np.linspace(0, obs.sizes["time"], n + 1).round().astype(int)
    return [obs.isel(time=slice(int(a), int(b))) for a, b in zip(bounds[:-1], bounds[1:])]


def part_epochs(obs: xr.Dataset, setup: EpochSetup, systems: list[str], sv: np.ndarray,
                 used: tuple[str, ...]) -> tuple[EpochData, Coverage]:
    """The epochs of one part on the whole file's satellite axis ``sv``, and the part's coverage."""
    obs = obs.reindex(sv=np.union1d(np.asarray(obs["sv"].values).astype(str), sv))
    prs = align_pseudoranges(select_pseudoranges(obs, systems, setup.priority), sv)
    data, part_cov = build_epochs(obs, prs, setup, systems)
    return finish_epochs(data, used, qzss_own_clock=setup.config.qzss_own_clock), part_cov


def solve_part(obs: xr.Dataset, setup: EpochSetup, systems: list[str], sv: np.ndarray, used: tuple[str, ...],
                config: ProcessingConfig, finish: Callable[[RunResult], Any]) -> tuple[Any, Coverage, dict[str, dict[str, int]]]:
    """One part with snapshot methods, wherever it runs: ``finish`` of its result, its coverage and
    its status counts."""
    data, part_cov = part_epochs(obs, setup, systems, sv, used)
    solutions = solve_methods(data, config)
    return finish(with_velocity(with_settings(RunResult(data, solutions), config), config)), part_cov, status_counts(solutions)
