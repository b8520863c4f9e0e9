"""Segments and sliding windows of a uniformly sampled series (the smoothing schedule's numerics).

A series of epochs is split into *segments*: runs of consecutive solved epochs at the
nominal sampling interval. Each segment is cut into half-overlapping *windows*; every epoch
keeps the estimate of the window whose centre is nearest to it.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

__all__ = ["nominal_step", "segments", "windows"]

F64 = NDArray[np.float64]


def segments(time_gps_s: F64, solved: NDArray[np.bool_], gap_factor: float = 1.5,
             nominal_s: float | None = None) -> list[NDArray[np.intp]]:
    """Split epochs into runs of consecutive solved epochs at a uniform sampling interval.

    Parameters
    ----------
    time_gps_s : ndarray, shape (T,)
        Epoch times, s.
    solved : ndarray of bool, shape (T,)
        Epochs with a usable fix.
    gap_factor : float
        A time step larger than ``gap_factor`` times the median step (or not positive) starts
        a new segment.
    nominal_s : float, optional
        The nominal step (s) instead of the median step of ``time_gps_s`` (a part of a longer
        series is split as the whole series is).

    Returns
    -------
    list of ndarray of int
        Epoch indices of each segment, in time order.
    """
    t = np.asarray(time_gps_s, dtype=np.float64)
    ok = np.flatnonzero(solved)
    if ok.size == 0:
        return []
    nominal = float(nominal_s) if nominal_s is not None else nominal_step(t)
    out: list[NDArray[np.intp]] = []
    start = 0
    for k in range(1, ok.size):
        a, b = ok[k - 1], ok[k]
        step = t[b] - t[a]
        if b != a + 1 or step <= 0 or abs(step - nominal) > (gap_factor - 1.0) * nominal:
            out.append(ok[start:k])
            start = k
    out.append(ok[start:])
    return out


def nominal_step(time_gps_s: NDArray[np.float64]) -> float:
    """The nominal sampling interval of a series, s: the median of its positive steps (1 s without any).

    >>> nominal_step(np.array([0.0, 1.0, 2.0, 5.0, 6.0]))
    1.0
    """
    dt = np.diff(np.asarray(time_gps_s, dtype=np.float64))
    return float(np.median(dt[dt > 0])) if np.any(dt > 0) else 1.0


def windows(n: int, window: int, step: int | None = None) -> tuple[list[tuple[int, int]], NDArray[np.intp]]:
    """Sliding windows over ``n`` epochs and the window that supplies each epoch's estimate.

    Parameters
    ----------
    n : int
        Segment length, epochs.
    window : int
        Window length, epochs; ``0`` (or ``window >= n``) = one window over the whole segment.
    step : int, optional
        Shift between window starts (default ``max(1, window // 2)``: half-overlapping windows).
        The last window is aligned with the segment's end.

    Returns
    -------
    bounds : list of (start, stop)
        Half-open epoch ranges of the windows.
    owner : ndarray of int, shape (n,)
        For each epoch, the window whose centre is nearest (the centre-most estimate is kept;
        ties go to the earlier window).
    """
    if window <= 0 or window >= n:
        return [(0, n)], np.zeros(n, dtype=np.intp)
    step = max(1, window // 2) if step is None else max(1, int(step))
    starts = list(range(0, n - window + 1, step))
    if starts[-1] != n - window:
        starts.append(n - window)
    bounds = [(s, s + window) for s in starts]
    centres = np.array([s + (window - 1) / 2.0 for s in starts])
    # nearest centre: the windows' centres increase, so the owner changes at the midpoints
    # between consecutive centres (an epoch exactly half-way stays with the earlier window)
    owner = np.searchsorted(0.5 * (centres[:-1] + centres[1:]), np.arange(n), side="left").astype(np.intp)
    return bounds, owner
