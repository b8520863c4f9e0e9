"""Carrier phase between consecutive epochs: where it may have slipped.

A time-differenced carrier phase ``lambda (phi_t - phi_{t-1})`` is the change of the range (plus
the change of the receiver clock, the satellite clock and the atmosphere) to millimetres --
unless the receiver lost count of whole cycles in between (a cycle slip). A difference is not
trusted when

- the receiver says so: the loss-of-lock indicator's bit 0 at ``t`` (RINEX 2/3/4: "lost lock
  between the previous and this observation"); bit 1 (half-cycle ambiguity, opposite wavelength
  factor) does not break the count;
- it disagrees with the Doppler: the range change the two range rates predict by the trapezoid,
  ``dt (rr_{t-1} + rr_t) / 2``, differs from the phase's by more than ``threshold_m`` once the
  median over the epoch pair's satellites (the receiver clock's change) is removed. Only pairs
  with at least :data:`MIN_SATELLITES` such differences are checked (a median of two cannot tell
  which one slipped). The Doppler predicts the range change to a few cm over 1 s at walking
  dynamics (a median of 5 cm, at most 0.9 m on the Yamatogawa walk, u-blox), so this catches
  slips of several cycles; smaller ones are left to the residual gate of the solution that uses
  the differences (:mod:`gnss_cli.pipeline.phase_rows`).
"""

from __future__ import annotations

import warnings

import numpy as np
from numpy.typing import NDArray

__all__ = ["phase_slips", "MIN_SATELLITES"]

F64 = NDArray[np.float64]

MIN_SATELLITES = 3
"""Fewest phase differences of an epoch pair for the Doppler check."""


def phase_slips(time_s: F64, phase_m: F64, range_rate_m_s: F64, lli: F64, threshold_m: float) -> NDArray[np.bool_]:
    """``(T, n)`` True where the phase difference from epoch ``t - 1`` to ``t`` is not to be used (module docstring).

    Parameters
    ----------
    time_s : ``(T,)`` epochs, s.
    phase_m : ``(T, n)`` carrier phase times wavelength, m (NaN: none).
    range_rate_m_s : ``(T, n)`` range rates ``-lambda D``, m/s (NaN: none; then only the indicator counts).
    lli : ``(T, n)`` loss-of-lock indicators (0 where unknown).
    threshold_m : largest disagreement with the Doppler, m (inf: no Doppler check).

    Returns
    -------
    ``(T, n)`` bool; row 0 is False (no previous epoch).

    >>> t = np.arange(4.0)
    >>> rr = np.tile([100.0, -50.0, 20.0], (4, 1))
    >>> phi = t[:, None] * rr + [0.0, 3.0, 7.0]
    >>> phi[2:, 1] += 10 * 0.19                                # a 10-cycle slip at epoch 2
    >>> lli = np.zeros((4, 3)); lli[3, 2] = 1                  # the receiver flags epoch 3
    >>> phase_slips(t, phi, rr, lli, 1.0).astype(int).tolist()
    [[0, 0, 0], [0, 0, 0], [0, 1, 0], [0, 0, 1]]
    """
    slip = np.zeros(phase_m.shape, dtype=bool)
    slip[1:] = (np.nan_to_num(lli[1:]).astype(np.int64) & 1) == 1
    dt = np.diff(time_s)[:, None]
    gap = np.diff(phase_m, axis=0) - dt * 0.5 * (range_rate_m_s[1:] + range_rate_m_s[:-1])
    have = np.isfinite(gap)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # pairs without a difference
        common = np.nanmedian(np.where(have, gap, np.nan), axis=1, keepdims=True)
    checked = have & (have.sum(axis=1, keepdims=True) >= MIN_SATELLITES)
    slip[1:] |= checked & (np.abs(np.where(checked, gap - common, 0.0)) > threshold_m)
    return slip
