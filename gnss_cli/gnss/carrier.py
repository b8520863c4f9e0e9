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
  the differences (:mod:`gnss_cli.pipeline.phase_rows`);
- without a range rate (a file without Doppler, as many 30 s station files are), it disagrees
  with the pseudoranges: the change of code minus carrier, ``(P - lambda phi)_t - (P - lambda
  phi)_{t-1}``, which a slip of ``N`` cycles moves by ``N lambda`` and otherwise holds only the
  code's noise and multipath (and twice the ionosphere's change), differs from the epoch pair's
  median by more than :data:`CODE_SLIP_M`. That is a coarse check: it catches slips of some 50
  cycles and more, and leaves the rest to the residual gate.
"""

from __future__ import annotations

import warnings

import numpy as np
from numpy.typing import NDArray

__all__ = ["phase_slips", "MIN_SATELLITES", "CODE_SLIP_M"]

F64 = NDArray[np.float64]

MIN_SATELLITES = 3
"""Fewest phase differences of an epoch pair for the Doppler or pseudorange check."""

CODE_SLIP_M = 10.0
"""Largest change of code minus carrier between two epochs (m, after the pair's median) taken for
noise where there is no range rate. Measured on the pairs the Doppler check passes: 99.9 % within
2.4 m on the ESBC day (30 s, GPS), 5.2 m on the Yamatogawa walk (u-blox, largest 5.3 m), 2.0 m on
tst2 (GPS, urban; largest 4.0 m)."""


def phase_slips(time_s: F64, phase_m: F64, range_rate_m_s: F64, lli: F64, threshold_m: float,
                pseudorange_m: F64 | None = None) -> NDArray[np.bool_]:
    """``(T, n)`` True where the phase difference from epoch ``t - 1`` to ``t`` is not to be used (module docstring).

    Parameters
    ----------
    time_s : ``(T,)`` epochs, s.
    phase_m : ``(T, n)`` carrier phase times wavelength, m (NaN: none).
    range_rate_m_s : ``(T, n)`` range rates ``-lambda D``, m/s (NaN: none; then the pseudoranges
        check the pair, if given, else only the indicator counts).
    lli : ``(T, n)`` loss-of-lock indicators (0 where unknown).
    threshold_m : largest disagreement with the Doppler, m (inf: no Doppler check).
    pseudorange_m : ``(T, n)`` the pseudoranges of the same signals, m (NaN: none), for the pairs
        without range rates (:data:`CODE_SLIP_M`); None: no such check.

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

    Without Doppler the pseudoranges see a slip of 100 cycles, not one of 10:

    >>> no_rr = np.full(rr.shape, np.nan)
    >>> phi[3:, 0] += 100 * 0.19
    >>> phase_slips(t, phi, no_rr, np.zeros((4, 3)), 1.0, t[:, None] * rr + 2e7).astype(int).tolist()
    [[0, 0, 0], [0, 0, 0], [0, 0, 0], [1, 0, 0]]
    """
    slip = np.zeros(phase_m.shape, dtype=bool)
    slip[1:] = (np.nan_to_num(lli[1:]).astype(np.int64) & 1) == 1
    dt = np.diff(time_s)[:, None]
    doppler_gap = np.diff(phase_m, axis=0) - dt * 0.5 * (range_rate_m_s[1:] + range_rate_m_s[:-1])
    slip[1:] |= _off_the_median(doppler_gap, threshold_m)
    if pseudorange_m is not None:
        code_gap = np.where(np.isfinite(doppler_gap), np.nan, np.diff(pseudorange_m - phase_m, axis=0))
        slip[1:] |= _off_the_median(code_gap, CODE_SLIP_M)
    return slip


def _off_the_median(gap: F64, limit_m: float) -> NDArray[np.bool_]:
    """``gap (T - 1, n)`` farther than ``limit_m`` from its epoch pair's median (the receiver
    clock's change), where the pair has at least :data:`MIN_SATELLITES` finite values."""
    have = np.isfinite(gap)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # pairs without a difference
        common = np.nanmedian(np.where(have, gap, np.nan), axis=1, keepdims=True)
    checked = have & (have.sum(axis=1, keepdims=True) >= MIN_SATELLITES)
    return checked & (np.abs(np.where(checked, gap - common, 0.0)) > limit_m)
