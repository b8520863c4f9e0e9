"""Time-differenced carrier phase as rows of the measurement-domain methods (the ``smoother``).

Between consecutive epochs ``t - 1`` and ``t`` of a segment, a satellite whose carrier phase has
not slipped (:func:`~gnss_cli.gnss.carrier.phase_slips`) gives the row::

    (q_phi_t - q_phi_{t-1})  =  p_t . z_t  -  p_{t-1} . z_{t-1}  +  (b_t - b_{t-1})  +  e

with ``q_phi = lambda phi + c dt_sv - (range + troposphere - ionosphere)`` at the linearization
point (the pseudorange's computed value, so the geometry, Sagnac term and satellite clock are
those of the pseudorange row, with the modelled ionospheric delay turned into the advance the
carrier sees), ``p = -e_LOS`` the pseudorange row's coefficients, ``z`` the corrections to the
linearization points and ``b_t - b_{t-1}`` the change of the receiver clock (one per system, free:
it is not tied to the pseudorange clocks). The unknown ambiguity cancels. The sign of the
ionosphere matters at 30 s: the Klobuchar delay changes by up to a few centimetres a pair there,
the same in every pair of a morning, and with the pseudorange's sign twice that change would
accumulate into the track (measured on the 24 h ESBC day: ``docs/results.md``). What the model
does not follow of the real ionosphere's and troposphere's change over an epoch remains in ``e``.

Weights: satellite ``i`` gets the sigma ``phase_sigma_m x sigma_i / median_j sigma_j`` (the
pseudorange sigmas of epoch ``t``, as the range rates get theirs), scaled by a variance factor
(:mod:`gnss_cli.pipeline.measurements`). Rows are indexed by the epoch ``t`` that ends
the pair; row 0 and pairs across a segment boundary are unused (weight 0). Whether to use them
is the caller's choice (``measurements``).
"""

from __future__ import annotations

import warnings

import numpy as np
from numpy.typing import NDArray

from gnss_cli.config import ProcessingConfig
from gnss_cli.pipeline.results import EpochData

__all__ = ["phase_pair_rows"]

F64 = NDArray[np.float64]


def phase_pair_rows(data: EpochData, rows: dict[str, F64], config: ProcessingConfig) -> dict[str, F64] | None:
    """Rows ``(P6, w, y, C, P3)`` of every epoch pair (module docstring); None when ``data`` has no phase.

    ``rows``: the pseudorange rows of :func:`~gnss_cli.pipeline.kalman_rows.pseudorange_rows` at the
    linearization points (``P`` ``(T, n, 3)``, weights ``w`` (0: not used), ``y`` the pseudorange
    minus its computed value, clock columns ``C``, ``iono`` the modelled ionospheric delay in that
    value, m). ``P6 (T, n, 6)`` are the coefficients of
    ``[z_{t-1}, z_t]``; ``P3 = P_t`` those of the displacement ``z_t - z_{t-1}`` alone (the
    difference ``P_t - P_{t-1}`` of the lines of sight over one epoch is ~1e-4: the pair solved for
    its displacement alone, for the variance factor).
    """
    if data.phase_m is None or data.phase_slip is None:
        return None
    w_pr = rows["w"]
    q = np.where(w_pr > 0, rows["y"] + data.phase_m - data.pr_corrected_m + 2.0 * rows["iono"], np.nan)
    T, n = w_pr.shape
    y = np.zeros((T, n))
    y[1:] = q[1:] - q[:-1]
    used = np.zeros((T, n), dtype=bool)
    used[1:] = np.isfinite(y[1:]) & ~data.phase_slip[1:]
    sigma_pr = np.where(w_pr > 0, 1.0 / np.sqrt(np.where(w_pr > 0, w_pr, 1.0)), np.nan)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # epochs without a used row
        sigma = config.phase_sigma_m * sigma_pr / np.nanmedian(sigma_pr, axis=1, keepdims=True)
    used &= np.isfinite(sigma)
    P6 = np.zeros((T, n, 6))
    P6[1:, :, :3] = -rows["P"][:-1]
    P6[1:, :, 3:] = rows["P"][1:]
    return {"P6": np.where(used[..., None], P6, 0.0), "w": np.where(used, 1.0 / np.where(used, sigma, 1.0) ** 2, 0.0),
            "y": np.where(used, y, 0.0), "C": rows["C"], "P3": np.where(used[..., None], rows["P"], 0.0)}
