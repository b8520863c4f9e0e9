"""The misfit test of the ``smoother``'s and the ``kf``'s segments: a segment whose pseudoranges do
not fit its trajectory is solved again in halves, and at the shortest keeps the WLS fixes.

A motion model holds a trajectory only as well as the receiver follows it: a static model on a
moving receiver, or a manoeuvre far outside the kf's process noise, leaves residuals that no
gate removes, because every row of an epoch is off alike (the gate keeps them all when more than
half exceed it). The test is on the pseudoranges the method used, at its own positions and
clocks: ``u = r / sigma`` with ``sigma`` the method's sigmas (the WLS sigmas times the
pseudoranges' variance factor, so ``u`` is in units of the file's own noise), and the segment's
misfit per degree of freedom ``m = sum u^2 / sum (n_t - k_t)`` (``n_t`` pseudoranges and ``k_t``
clocks of epoch ``t``: the position is fixed by the segment, not by the epoch).

``m`` is not compared with a chi-square quantile: real pseudoranges carry errors correlated over
seconds (multipath), which one epoch's fix absorbs and a trajectory does not, so a valid segment
of a real receiver sits above 1 (the Yamatogawa walk's smoother: 1.23 over 4,000 degrees of
freedom, far beyond any chi-square limit), while a model that does not hold sits far above it
(a static model on a moving receiver: 11 on the walk, 360-1,350 on simulated drives).
``[processing] max_segment_misfit`` is the limit between the two (``inf``: no test). A segment
above it is solved again as two halves, each tested in turn; a segment shorter than
:data:`MIN_EPOCHS` that still fails keeps the WLS fixes, status ``fallback_wls`` (``ok`` WLS
epochs; the others keep their WLS status). Each rejected segment adds a model record (status
``rejected``) that says what became of its epochs, in place of the records of the solution it
rejected. Not run with ``integrity = "off"``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from gnss_cli.behavior.windows import segments
from gnss_cli.config import ProcessingConfig
from gnss_cli.pipeline.integrity import merge_epochs, take_epochs
from gnss_cli.pipeline.results import EpochData, EpochStatus, MethodSolution, WindowModel, take_solution

__all__ = ["segment_misfit", "tested_segments", "MIN_EPOCHS"]

MIN_EPOCHS = 10
"""A failing segment shorter than twice this is not halved again: its epochs keep the WLS fixes."""

Solve = Callable[[EpochData, MethodSolution], tuple[MethodSolution, tuple[WindowModel, ...]]]
"""The method on a subset of epochs and their WLS solution: its rows and model records."""


def segment_misfit(data: EpochData, sol: MethodSolution, seg: NDArray[np.intp]) -> tuple[float, int]:
    """The misfit per degree of freedom of the pseudoranges ``sol`` used over the epochs ``seg``
    (module docstring) and its degrees of freedom (NaN and 0 without any)."""
    if sol.sigma_m is None:
        return float("nan"), 0
    r, s = sol.residuals_m[seg], sol.sigma_m[seg]
    used = np.isfinite(r) & np.isfinite(s) & (s > 0)
    system_index = data.clock_index
    clocks = np.zeros((seg.size, int(system_index.max(initial=0)) + 1), dtype=bool)
    rows, cols = np.nonzero(used)
    clocks[rows, system_index[cols]] = True
    dof = int(used.sum() - clocks.sum())
    if dof <= 0:
        return float("nan"), 0
    u = np.where(used, np.nan_to_num(r) / np.where(used, s, 1.0), 0.0)
    return float((u**2).sum() / dof), dof


def tested_segments(method: str, data: EpochData, wls: MethodSolution, config: ProcessingConfig,
                    sol: MethodSolution, models: tuple[WindowModel, ...], solve: Solve, gap_factor: float = 1.5
                    ) -> tuple[MethodSolution, tuple[WindowModel, ...]]:
    """``sol`` with every segment that fails the misfit test solved again shorter (module
    docstring); ``models`` with a record per rejected segment and the records of the halves.
    ``gap_factor``: the method's own segments (:func:`~gnss_cli.behavior.windows.segments`)."""
    limit = config.max_segment_misfit
    if config.integrity == "off" or not np.isfinite(limit):
        return sol, models
    t = data.time_gps_s
    records = list(models)
    sol = replace(sol, status=sol.status.astype("<U24"))  # room for fallback_wls
    queue = list(enumerate(segments(t, np.isfinite(sol.x_ecef_m).all(axis=1), gap_factor)))
    while queue:
        number, seg = queue.pop(0)
        m, dof = segment_misfit(data, sol, seg)
        if not m > limit:
            continue
        why = f"misfit per degree of freedom {m:.4g} > {limit:g} ({dof} degrees of freedom)"
        t0, t1 = float(t[seg[0]]), float(t[seg[-1]])
        records = [r for r in records  # the records of the rejected solution give way to the halves'
                   if r.status == "rejected" or not t0 <= r.start_time_gps_s <= r.end_time_gps_s <= t1]
        if seg.size >= 2 * MIN_EPOCHS:
            halves = [seg[: seg.size // 2], seg[seg.size // 2:]]
            for half in halves:
                sub, sub_models = solve(take_epochs(data, half), take_solution(wls, half))
                sol = merge_epochs(sol, half, sub)
                records += sub_models
            queue = [(number, h) for h in halves] + queue
            what = f"its epochs solved again as two segments of {halves[0].size} and {halves[1].size} epochs"
        else:
            fixed = take_solution(wls, seg)
            status = np.where(fixed.status == EpochStatus.OK.value, EpochStatus.FALLBACK_WLS.value, fixed.status)
            sol = merge_epochs(sol, seg, _as_fallback(sol, fixed, status))
            what = "its epochs keep the WLS fix"
        records.append(WindowModel(segment=number, window=0, start_time_gps_s=t0,
                                   end_time_gps_s=t1, n_epochs=int(seg.size),
                                   model=f"{method} segment", structure="full", kernel=None, misfit=m,
                                   status="rejected", message=f"{why}; {what}", method=method))
    return sol, tuple(records)


def _as_fallback(sol: MethodSolution, fixed: MethodSolution, status: NDArray[np.str_]) -> MethodSolution:
    """The WLS rows ``fixed`` as rows of the method ``sol`` (its arrays' kinds), with ``status``."""
    out = replace(fixed, status=status)
    if sol.vel_ecef_m_s is not None and out.vel_ecef_m_s is None:
        out = replace(out, vel_ecef_m_s=np.full((status.size, 3), np.nan))
    return out
