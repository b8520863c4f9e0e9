"""The behavioral smoothing (:func:`~gnss_cli.pipeline.smoothing.smooth`) of a file that
arrives in parts, with the result of the whole file's run.

The schedule of the whole file is rebuilt from what has arrived: segments split where the
whole file splits them (the file's nominal step; unsolved epochs), windows at the starts
``0, s, 2s, ...`` of each segment (``s = window // 2``) and, once the segment has ended, the
last window aligned with its end (:func:`~gnss_cli.behavior.windows.windows`). In a segment
that is still open, a window is *certain* when it fits in the epochs so far; every epoch up
to the centre of the last certain window has its owner (the window centred nearest to it):
a later window, the end-aligned one included, is centred further on. An epoch's smoothed
row also depends, through the multi-epoch covariance of its window, on the smoothed fixes of
every epoch of that window, so an epoch is handed out once every epoch of its window has
its owner. Each part is the epochs not yet handed out plus the new ones, starting at the
window before the first one not finished: that window supplies the smoothed fixes of the
first epochs of the next one. Windows are fitted one by one or in batches of equal length,
each with its own data, so a refit gives the same numbers.

Memory is one part plus about two windows, whatever the file's length.
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace

import numpy as np
from numpy.typing import NDArray

from gnss_cli.behavior.windows import segments, windows
from gnss_cli.config import ProcessingConfig
from gnss_cli.pipeline.results import EPOCH_AXIS_FIELDS, EpochStatus, MethodSolution, RunResult
from gnss_cli.pipeline.smoothing import Segment, WindowJob, segment_frame, smooth_windows

__all__ = ["StreamSmoother", "take_solution", "concat_results"]

F64 = NDArray[np.float64]
_OK, _FALLBACK = EpochStatus.OK.value, EpochStatus.FALLBACK_WLS.value


def take_solution(sol: MethodSolution, rows: NDArray[np.intp] | slice) -> MethodSolution:
    """The epochs ``rows`` of ``sol`` (every per-epoch array)."""
    return replace(sol, **{f.name: getattr(sol, f.name)[rows] for f in fields(MethodSolution)
                           if isinstance(getattr(sol, f.name), np.ndarray)})


def _concat_solution(a: MethodSolution, b: MethodSolution) -> MethodSolution:
    return replace(a, **{f.name: np.concatenate((getattr(a, f.name), getattr(b, f.name)))
                         for f in fields(MethodSolution) if isinstance(getattr(a, f.name), np.ndarray)})


def concat_results(a: RunResult, b: RunResult) -> RunResult:
    """The epochs of ``a`` then those of ``b`` (one satellite axis, the same methods)."""
    parts = {f: np.concatenate((getattr(a.epochs, f), getattr(b.epochs, f)))
             for f in EPOCH_AXIS_FIELDS if getattr(a.epochs, f) is not None}
    sols = {m: _concat_solution(s, b.solutions[m]) for m, s in a.solutions.items()}
    return RunResult(replace(a.epochs, **parts), sols, a.models + b.models)


def take_result(result: RunResult, rows: slice, copy: bool = False) -> RunResult:
    """The epochs ``rows`` of ``result`` (no window models): views, or copies with ``copy``
    (that do not keep the whole of ``result``'s arrays alive)."""
    def cut(a: np.ndarray) -> np.ndarray:
        return a[rows].copy() if copy else a[rows]

    epochs = replace(result.epochs, **{f: cut(getattr(result.epochs, f)) for f in EPOCH_AXIS_FIELDS
                                       if getattr(result.epochs, f) is not None})
    sols = {m: replace(s, **{f.name: cut(getattr(s, f.name)) for f in fields(MethodSolution)
                             if isinstance(getattr(s, f.name), np.ndarray)}) for m, s in result.solutions.items()}
    return RunResult(epochs, sols)


@dataclass
class _Open:
    """The segment still open at the end of the epochs kept for the next part."""

    offset: int  # segment-relative index of the first kept epoch (a window start)
    emitted: int  # segment-relative index of the first epoch not yet handed out
    origin: F64 | None = None  # ENU origin (first fix), once the segment has a certain window
    seg_id: int | None = None
    next_window: int = 0  # window index whose model record is not yet handed out


@dataclass
class _Plan:
    """The windows of one segment of a part, and where its handed-out epochs end."""

    frame: Segment | None
    jobs: list[tuple[int, int, int, int, int, bool]]  # (window index, a, b, lo, hi, model handed out), frame-relative
    emit_end: int  # buffer index
    keep_from: int | None  # buffer index of the first epoch to keep (open segment), else None
    open: _Open | None


class StreamSmoother:
    """Smooth a run's parts in time order (:meth:`push`); the rows handed out are those of
    :func:`~gnss_cli.pipeline.smoothing.smooth` on the whole file.

    Parameters
    ----------
    config : ProcessingConfig
        ``config.smoothing`` with ``lag >= 1``, ``window >= 1`` and a window model (not
        ``kinematic``).
    nominal_step_s : float
        The median epoch step of the whole file (s), as :func:`~gnss_cli.behavior.windows.segments`
        computes it.
    gap_factor : float
        As :func:`~gnss_cli.pipeline.smoothing.smooth`.
    """

    def __init__(self, config: ProcessingConfig, nominal_step_s: float, gap_factor: float = 1.5) -> None:
        self.config = config
        self.opts = config.smoothing.validated()
        self.nominal = nominal_step_s
        self.gap_factor = gap_factor
        self.window = self.opts.window_epochs
        self.step = max(1, self.window // 2)
        self.kept: RunResult | None = None
        self.kept_emitted = 0  # kept epochs already handed out
        self.open: _Open | None = None
        self.next_segment = 0

    def push(self, parts: list[RunResult], last: bool = False) -> RunResult | None:
        """Add the next part (snapshot solutions with ``wls``), taken out of the one-element list
        ``parts`` (so that it is freed once joined to the kept epochs); returns the epochs now
        final, with the smoothed ``stls`` solution and the window models finished, or None.
        ``last``: the file ends here (``parts`` may then be empty): every segment is closed."""
        part = parts.pop() if parts else None
        if part is None and self.kept is None:
            return None
        buf = (self.kept if part is None else part if self.kept is None else concat_results(self.kept, part))
        del part
        wls = buf.solutions["wls"]
        T = buf.epochs.time_gps_s.size
        solved = (wls.status == _OK) & np.all(np.isfinite(wls.x_ecef_m), axis=1) \
            & np.all(np.isfinite(wls.cov_m2[:, :3, :3].reshape(T, 9)), axis=1)
        status = wls.status.astype("<U24").copy()
        segs: list[Segment] = []
        seg_ids: list[int] = []
        jobs: list[WindowJob] = []
        handed: list[bool] = []
        emit_end, keep_from, new_open = T, T, None
        for k, seg in enumerate(segments(buf.epochs.time_gps_s, solved, self.gap_factor, self.nominal)):
            cont = self.open if (k == 0 and seg[0] == 0 and self.open is not None) else None
            plan = self._plan(wls, seg, cont, closed=last or seg[-1] != T - 1, status=status)
            if plan.frame is not None:
                if plan.open is not None and plan.open.seg_id is None:
                    plan.open.seg_id = self.next_segment
                    self.next_segment += 1
                for wi, a, b, lo, hi, out in plan.jobs:
                    jobs.append(WindowJob(len(segs), wi, a, b, lo, hi))
                    handed.append(out)
                segs.append(plan.frame)
                seg_ids.append(plan.open.seg_id if plan.open is not None else -1)
            if plan.keep_from is not None:
                emit_end, keep_from, new_open = plan.emit_end, plan.keep_from, plan.open
        sol, models = smooth_windows(buf.epochs, wls, self.config, segs, jobs, status, "stls", seg_ids)
        models = tuple(m for m, out in zip(models, handed) if out)
        start = self.kept_emitted
        full = replace(buf, solutions={m: (sol if m == "stls" else buf.solutions[m]) for m in self.config.methods})
        self.kept = take_result(buf, slice(keep_from, None), copy=True) if keep_from < T else None
        self.kept_emitted = emit_end - keep_from if keep_from < T else 0
        self.open = new_open
        if emit_end <= start and not models:
            return None
        return replace(take_result(full, slice(start, max(start, emit_end))), models=models)

    def _plan(self, wls: MethodSolution, seg: NDArray[np.intp], cont: _Open | None, closed: bool,
              status: NDArray[np.str_]) -> _Plan:
        """The windows of one segment in the buffer (``seg``: its buffer indices)."""
        state = cont if cont is not None else _Open(0, 0)
        offset, n = state.offset, state.offset + seg.size  # segment-relative: buffer start, epochs so far
        if state.origin is None:
            state.origin = wls.x_ecef_m[seg[0]]
        if closed and n < self.opts.min_window():
            status[seg] = _FALLBACK
            return _Plan(None, [], int(seg[-1]) + 1, None, None)
        if closed:
            bounds, owner = windows(n, self.window, self.step)
            starts = np.array([a for a, _ in bounds])
            edges = np.searchsorted(owner, np.arange(len(bounds) + 1), side="left")
            index = np.arange(len(bounds))
            finished = index >= state.next_window
        else:
            if n < self.window:  # no certain window yet: keep the whole segment
                return _Plan(None, [], int(seg[0]), int(seg[0]), state)
            starts = np.arange(offset, n - self.window + 1, self.step)
            centres = starts + (self.window - 1) / 2.0
            # window j owns the epochs i with mid_{j-1} < i <= mid_j (a tie stays with the earlier window)
            edges = np.concatenate(([offset], np.floor(0.5 * (centres[:-1] + centres[1:])).astype(np.int64) + 1,
                                    [starts[-1] + self.window]))
            known = int(np.floor(centres[-1])) + 1  # epochs before this have their owner
            index = starts // self.step
            finished = (starts + self.window <= known) & (index >= state.next_window)
        keep = starts >= offset
        jobs = [(int(index[j]), int(starts[j]) - offset, int(starts[j]) + self.window - offset if not closed
                 else int(bounds[j][1]) - offset, max(int(edges[j]), offset) - offset, int(edges[j + 1]) - offset,
                 bool(finished[j])) for j in np.flatnonzero(keep)]
        frame = segment_frame(wls, seg, state.origin)
        if closed:
            return _Plan(frame, jobs, int(seg[-1]) + 1, None, state)
        done = np.flatnonzero(finished)
        if done.size:
            last_done = int(done[-1])
            state.next_window = int(index[last_done]) + 1
            state.emitted = max(state.emitted, int(edges[last_done + 1]))
            keep_rel = int(starts[last_done])
        else:
            keep_rel = offset
        emit_end = int(seg[0]) + state.emitted - offset
        keep_from = int(seg[0]) + keep_rel - offset
        return _Plan(frame, jobs, emit_end, keep_from, _Open(keep_rel, state.emitted, state.origin, state.seg_id,
                                                              state.next_window))
