"""Smoothing windows chosen from the data: the chi-square ladder of ``window = "auto"`` with the
static kernel (:func:`ladder_schedule`, used by :func:`gnss_cli.pipeline.smoothing.smooth`)."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from gnss_cli.config import SmoothingConfig
from gnss_cli.pipeline.results import EpochData, MethodSolution
from gnss_cli.pipeline.smoothing import FALLBACK, Fit, Segment, WindowJob, fit_all, framed_segments, window_jobs

__all__ = ["ladder_schedule", "ladder_lengths"]


def ladder_lengths(n: int, shortest: int) -> list[int]:
    """Window lengths (epochs) tried on a segment of ``n`` epochs, longest first: the whole
    segment, then halving while at least ``shortest``."""
    out = [n]
    while out[-1] // 2 >= shortest:
        out.append(out[-1] // 2)
    return out


def _chi2_limit(dof: NDArray[np.float64], pfa: float) -> NDArray[np.float64]:
    """The misfit above which a window's model is rejected: the upper ``pfa`` quantile of the
    chi-square distribution with ``dof`` degrees of freedom (unitless)."""
    from scipy.special import chdtri  # not on the default path (lag 0): imported when a ladder runs

    return np.asarray(chdtri(dof, pfa), dtype=np.float64)


def ladder_schedule(data: EpochData, wls: MethodSolution, solved: NDArray[np.bool_], status: NDArray[np.str_],
                    opts: SmoothingConfig, gap_factor: float) -> tuple[list[Segment], list[WindowJob], list[Fit]]:
    """Windows chosen from the data (``window = "auto"`` with the static kernel).

    Each segment is tried whole, then in half-overlapping windows of half the length, and so
    on down to the model's shortest window (:func:`ladder_lengths`). A window *passes* when its
    misfit (the ``Sigma^{-1}``-weighted squared distance of the fixes from the behavior, unitless)
    is at most the upper ``opts.window_pfa`` quantile of the chi-square distribution with
    ``3 (N - L)`` degrees of freedom (``N`` epochs, ``L`` the kernel's lag: the behavior leaves
    ``3 L`` free initial conditions). Each epoch takes the longest passing window of the
    ladder among those centred nearest to it at each length; an epoch that no window passes
    (the model is rejected down to the shortest window) keeps its WLS fix (``fallback_wls``).

    Returns the segments, the chosen windows (one job per run of the epochs a window
    supplies) and their fits, for :func:`smooth_windows`.
    """
    need = opts.min_window()
    lag = opts.effective_lag
    segs: list[Segment] = []
    jobs: list[WindowJob] = []
    fits: list[Fit] = []
    for si, n in framed_segments(data, wls, solved, status, need, gap_factor, segs):
        open_ = np.ones(n, dtype=bool)  # epochs without a passing window yet
        for length in ladder_lengths(n, need):
            level = [job for job in window_jobs(si, n, length) if open_[job.lo : job.hi].any()]
            if not level:
                break
            level_fits = fit_all(segs, level, opts)
            mis = np.array([f.misfit if f.w_hat is not None and f.misfit is not None else np.inf for f in level_fits])
            limit = _chi2_limit(np.array([3.0 * (j.b - j.a - lag) for j in level]), opts.window_pfa)
            for job, fit, passed in zip(level, level_fits, mis <= limit):
                if not passed:
                    continue
                mine = np.zeros(n, dtype=bool)
                mine[job.lo : job.hi] = open_[job.lo : job.hi]
                open_[job.lo : job.hi] = False
                for lo, hi in _runs(mine):
                    jobs.append(WindowJob(si, len(jobs), job.a, job.b, lo, hi))
                    fits.append(fit)
        status[segs[si].epochs[open_]] = FALLBACK
    return segs, jobs, fits


def _runs(mask: NDArray[np.bool_]) -> list[tuple[int, int]]:
    """Half-open index ranges of the runs of True in ``mask``."""
    edges = np.flatnonzero(np.diff(np.concatenate(([0], mask.astype(np.int8), [0]))))
    return list(zip(edges[::2].tolist(), edges[1::2].tolist()))
