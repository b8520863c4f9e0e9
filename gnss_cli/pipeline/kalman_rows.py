"""What the ``kf`` method is given: the kinds of measurement, their variance factors, its gate, and the
time-differenced carrier phase as rows of the filter.

The kinds (``measurements``, a subset of :data:`KINDS` with ``"pseudorange"``) are the information
every multi-epoch method gets alike (DESIGN.md section 6); the caller resolves the default (every
kind present in the file). A kind the file lacks is not used (the smoother does the same with
phase). The variance factors are the smoother's
(:func:`~gnss_cli.pipeline.measurements.free_misfit_totals`: the misfit per degree of
freedom of every kind, the epochs solved one at a time at the WLS fixes), and so is the gate's
threshold (the two-sided normal quantile of ``integrity_pfa``; none with ``integrity = "off"``).
The phase rows are those of :func:`~gnss_cli.pipeline.phase_rows.phase_pair_rows` (same pairs,
slip screening and sigmas), written on the absolute positions of the two epochs.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from gnss_cli.config import ProcessingConfig
from gnss_cli.errors import ConfigError
from gnss_cli.pipeline.phase_rows import phase_pair_rows
from gnss_cli.pipeline.results import EpochData, MethodSolution

if TYPE_CHECKING:
    from gnss_cli.pipeline.kalman import Measurements

__all__ = ["KINDS", "PhaseRows", "measurement_kinds", "variance_factors", "gate_threshold", "filter_phase_rows"]

F64 = NDArray[np.float64]

KINDS = ("pseudorange", "doppler", "phase")


@dataclass(frozen=True)
class PhaseRows:
    """Time-differenced carrier phase of every epoch pair ``(t - 1, t)``, rows indexed by ``t``.

    ``H6 (T, n, 6)``: coefficients of ``[x_{t-1}, x_t]`` (ECEF m: ``[e_{t-1}, -e_t]``, ``e`` the lines
    of sight); ``y (T, n)``: the phase difference minus its computed value plus ``H6 . [x_nom_{t-1},
    x_nom_t]``, so that ``y = H6 . [x_{t-1}, x_t] + (b_t - b_{t-1}) + noise`` with one free clock
    change per system; ``var_m2 (T, n)``: the configured variances (before the variance factor);
    ``used (T, n)``.
    """

    H6: F64
    y: F64
    var_m2: F64
    used: NDArray[np.bool_]


def measurement_kinds(data: EpochData, config: ProcessingConfig, measurements: Iterable[str] | None) -> frozenset[str]:
    """The kinds the filter uses: ``measurements`` (validated) less the kinds ``data`` lacks.

    None: ``[processing] measurements`` (:meth:`~gnss_cli.config.ProcessingConfig.uses`).

    Raises
    ------
    ConfigError
        ``measurements`` has an unknown kind or lacks ``"pseudorange"``.
    """
    if measurements is None:
        asked = {k for k in KINDS if config.uses(k)}
    else:
        asked = set(measurements)
        unknown = sorted(asked - set(KINDS))
        if unknown or "pseudorange" not in asked:
            raise ConfigError(f"measurements: expected a set of {', '.join(KINDS)} with pseudorange; "
                              f"received {', '.join(sorted(asked)) or 'none'}")
    present = {"pseudorange"} | ({"doppler"} if data.range_rate_m_s is not None else set()) | (
        {"phase"} if data.phase_m is not None and data.phase_slip is not None else set())
    return frozenset(asked & present)


def kinds_config(config: ProcessingConfig, kinds: frozenset[str]) -> ProcessingConfig:
    """``config`` with the switches of the row builders set to ``kinds`` (range rates, phase pairs)."""
    return replace(config, measurements=tuple(k for k in KINDS if k in kinds))


def variance_factors(data: EpochData, wls: MethodSolution, config: ProcessingConfig) -> tuple[float, float, float]:
    """Variance factors of the pseudoranges, range rates and phase pairs of every kind ``data`` has,
    as the smoother estimates them (:func:`~gnss_cli.pipeline.measurements.free_misfit_totals`;
    1 for a kind without degrees of freedom)."""
    from gnss_cli.pipeline.measurements import factors_from_totals, free_misfit_totals

    present = measurement_kinds(data, kinds_config(config, frozenset(KINDS)), None)
    f = factors_from_totals(free_misfit_totals(data, wls, config, present))
    return float(f[0]), float(f[1]), float(f[2])


def gate_threshold(config: ProcessingConfig) -> float | None:
    """The limit of the multi-epoch gates (the kf's innovations, the smoother's and stls's
    residuals): the two-sided normal quantile of ``integrity_pfa`` (3.29 for 1e-3); None (no gate)
    with ``integrity = "off"``."""
    if config.integrity == "off":
        return None
    from scipy.stats import norm

    return float(norm.isf(config.integrity_pfa / 2))


def pseudorange_rows(data: EpochData, meas: Measurements, nominal: F64) -> dict[str, F64]:
    """The pseudorange rows of the smoother's form at ``nominal``: coefficients ``P`` of the position
    correction, weights ``w`` (0: not used), ``y`` the pseudorange minus its value at ``nominal``,
    clock columns ``C``, and ``iono`` the modelled ionospheric delay in that value, m
    (:func:`~gnss_cli.pipeline.phase_rows.phase_pair_rows` takes them)."""
    k = len(data.systems)
    sysidx = data.clock_index
    return {"P": -meas.unit, "w": np.where(meas.used, 1.0 / meas.var_pr, 0.0),
            "y": meas.y_pr + np.einsum("tni,ti->tn", meas.unit, nominal),
            "C": np.broadcast_to((sysidx[:, None] == np.arange(k)).astype(np.float64), (*meas.used.shape, k)),
            "iono": meas.iono_m}


def filter_phase_rows(data: EpochData, meas: Measurements, nominal: F64, config: ProcessingConfig) -> PhaseRows | None:
    """The phase pairs of :func:`~gnss_cli.pipeline.phase_rows.phase_pair_rows` at ``nominal`` on the
    absolute positions (:class:`PhaseRows`); None without phase (or without ``phase`` in the measurements)."""
    phr = phase_pair_rows(data, pseudorange_rows(data, meas, nominal), config)
    if phr is None:
        return None
    used = phr["w"] > 0
    previous = np.vstack([nominal[:1], nominal[:-1]])
    H6 = phr["P6"]
    y = phr["y"] + np.einsum("tni,ti->tn", H6[..., :3], previous) + np.einsum("tni,ti->tn", H6[..., 3:], nominal)
    return PhaseRows(H6, np.where(used, y, 0.0), np.where(used, 1.0 / np.where(used, phr["w"], 1.0), 1.0), used)
