"""The receiver's environment, open sky or street canyon, judged from the file itself
(``[processing] environment``, ``--environment``).

Street canyons need settings that cost elsewhere (docs/integrity.md, "The environment"): the
NLOS detector (``[nlos] detector = "arcs"``), fixes that only suspected reflections test made
``nlos_dependent`` (``[nlos] min_direct_dof = 1``) and protection levels that monitor several
faulty satellites at once (``max_simultaneous_faults = 3`` at ``prior_fault_satellite = 1e-2``):
the ``[urban]`` table (``ProcessingConfig.urban``), which ``environment = "urban"`` and
``configs/urban.toml`` take. With ``environment = "auto"`` (the
default) a run takes them when its pseudoranges disagree with one another far more than their
noise model says, as reflections make them do:

- the **variance factor** of an epoch is its WLS chi-square statistic over its degrees of
  freedom, ``T / dof`` with ``T = sum_i r_i^2 / sigma_i^2`` (``sigma_i`` the a-priori sigma of
  ``[weights]``, ``dof = n - 3 - clocks``), of the plain WLS fix (no test, exclusion or NLOS
  detector: a satellite that one epoch's test would exclude moves one epoch of the median);
- the file's is the median over the epochs with ``dof >= 1`` among its first
  :data:`HEAD_EPOCHS` epochs (the whole file when shorter; a file read in parts is judged on the
  same epochs, whatever its parts and processes);
- above ``urban_variance_factor`` the run is ``urban``, else ``open``; with no epoch to judge
  (no redundancy) it stays ``open``.

Measured on training data (``benchmarks/choose_environment.py``, which sets the threshold, 0.6):
0.04-0.07 on the real open-sky stations, 0.15-0.37 on simulated open-sky drives and flights (the
simulator's noise is larger than the weights assume), 1.05-3.87 on simulated street-canyon drives,
23.4 on tst2 and 12.8 on smartloc-berlin.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from gnss_cli.config import ProcessingConfig
from gnss_cli.pipeline.integrity import take_epochs
from gnss_cli.pipeline.results import EpochData, MethodSolution

__all__ = ["HEAD_EPOCHS", "variance_factor", "head_variance_factor", "with_environment", "judged", "describe"]

HEAD_EPOCHS = 500
"""Epochs at the start of a file that judge its environment (the first part of a file read in
parts holds at least this many: ``PART_MIN_EPOCHS``, ``chunk_epochs``)."""


def variance_factor(sol: MethodSolution, data: EpochData) -> float:
    """The median over epochs of the WLS variance factor ``T / dof`` of ``sol`` (module
    docstring), ``T = sum_i (r_i / sigma_i)^2`` over the satellites the fix used (finite
    residual, not excluded); NaN when no epoch has ``dof >= 1``."""
    if sol.sigma_m is None:
        return float("nan")
    used = np.isfinite(sol.residuals_m) & np.isfinite(sol.sigma_m)
    if sol.excluded is not None:
        used &= ~sol.excluded
    stat = np.sum(np.where(used, (np.nan_to_num(sol.residuals_m) / np.where(used, sol.sigma_m, 1.0)) ** 2, 0.0), axis=1)
    clocks = np.zeros(used.shape[0], dtype=np.int64)
    for c in np.unique(data.clock_index):
        clocks += used[:, data.clock_index == c].any(axis=1)
    dof = used.sum(axis=1) - 3 - clocks
    good = dof >= 1
    return float(np.median(stat[good] / dof[good])) if good.any() else float("nan")


def head_variance_factor(config: ProcessingConfig, data: EpochData) -> float:
    """:func:`variance_factor` of the plain WLS fix (``config``'s weights and robust option; no
    test, exclusion or NLOS detector: the judgement needs the residuals, not the levels, which
    would take longer than the fix) of the first :data:`HEAD_EPOCHS` epochs of ``data``: what
    ``auto`` judges by."""
    from gnss_cli.pipeline.snapshot import solve_methods  # the snapshot solvers import this module's users

    head = take_epochs(data, np.arange(min(data.time_gps_s.size, HEAD_EPOCHS)))
    plain = replace(config, methods=("wls",), integrity="off", nlos=replace(config.nlos, detector="off"))
    return variance_factor(solve_methods(head, plain)["wls"], head)


def with_environment(config: ProcessingConfig, environment: str, judgement: str = "") -> ProcessingConfig:
    """``config`` in ``environment`` (``open``: as it is; ``urban``: its ``[urban]`` table over
    ``[processing]`` and ``[nlos]``), with the words that judged it (empty: as given)."""
    out = replace(config, environment=environment, environment_judgement=judgement)
    if environment != "urban":
        return out
    u = config.urban
    return replace(out, max_simultaneous_faults=u.max_simultaneous_faults, prior_fault_satellite=u.prior_fault_satellite,
                   nlos=replace(config.nlos, detector=u.nlos_detector, min_direct_dof=u.nlos_min_direct_dof))


def judged(config: ProcessingConfig, data: EpochData | None) -> ProcessingConfig:
    """``config`` with its environment resolved: ``open`` and ``urban`` as they are, ``auto`` from
    the first :data:`HEAD_EPOCHS` epochs of ``data`` (module docstring). With ``integrity = "off"``
    nothing is tested or excluded, so ``auto`` is ``open``; so is a run without an epoch to judge
    (``data`` None, or no epoch with redundancy)."""
    if config.environment != "auto":
        return with_environment(config, config.environment)
    if config.integrity == "off":
        return with_environment(config, "open", "auto: integrity off")
    if data is None:
        return with_environment(config, "open", "auto: no epoch to judge")
    factor = head_variance_factor(config, data)
    if not np.isfinite(factor):
        return with_environment(config, "open", "auto: no epoch with redundancy to judge")
    urban = factor > config.urban_variance_factor
    return with_environment(config, "urban" if urban else "open",
                            f"auto: variance factor {factor:.2f} {'>' if urban else '<='} {config.urban_variance_factor:g}")


def describe(config: ProcessingConfig) -> str:
    """The environment a run took and why, for ``summary.csv`` and stderr: ``urban (auto:
    variance factor 1.62 > 0.6)``, ``open (auto: variance factor 0.06 <= 0.6)``, ``open (auto:
    no epoch to judge)``, or ``open`` / ``urban`` as given; ``auto`` before a run judges it."""
    return f"{config.environment} ({config.environment_judgement})" if config.environment_judgement else config.environment
