"""Broadcast ephemerides of one system behind one interface: record selection, satellite
states at transmit time, frequency scale of the ionospheric delay, orbit sigma, group delays.

The orbit-and-clock sigma of a record (URA, SISA) is read here, as RTKLIB's ``var_uraeph`` and
``MAX_VAR_EPH`` in ``ephemeris.c``: a property of the broadcast record, which the pseudorange
variance model of :mod:`gnss_cli.gnss.range_model` then adds to the row variances.
"""

from __future__ import annotations

import numpy as np
import xarray as xr
from numpy.typing import NDArray

from gnss_cli.constants import FREQ_B1I_HZ, FREQ_L1_HZ
from gnss_cli.gnss.ephemeris import KeplerEphemeris
from gnss_cli.gnss.glonass import GlonassEphemeris, glonass_clock_s, glonass_states, select_glonass_ephemeris
from gnss_cli.gnss.multi_gnss import ephemeris_for_system, select_system_ephemeris, system_states
from gnss_cli.gnss.orbits import SatelliteStates

__all__ = ["GlonassRecords", "KeplerRecords", "system_records", "ephemeris_sigma_m", "MAX_EPHEMERIS_SIGMA_M"]

F64 = NDArray[np.float64]

URA_TABLE_M = np.array([2.4, 3.4, 4.85, 6.85, 9.65, 13.65, 24.0, 48.0, 96.0, 192.0, 384.0, 768.0, 1536.0, 3072.0, 6144.0])
"""URA index table of IS-GPS-200 (m), as RTKLIB uses it for the ephemeris variance."""


def ura_from_index_table(ura_m: F64) -> F64:
    """Broadcast URA (m) rounded up to the IS-GPS-200 URA table, as RTKLIB does; NaN -> 2.4 m."""
    u = np.where(np.isfinite(ura_m), ura_m, 0.0)
    k = np.searchsorted(URA_TABLE_M, u - 1e-9)
    return np.where(k < URA_TABLE_M.size, URA_TABLE_M[np.minimum(k, URA_TABLE_M.size - 1)], 6144.0)


MAX_EPHEMERIS_SIGMA_M = 300.0
"""A satellite whose broadcast orbit-and-clock sigma (URA, SISA) exceeds this (m) is not used, as
RTKLIB's ``MAX_VAR_EPH`` (URA index 10 and above, Galileo NAPA). Weighted instead, such a
satellite adds nothing to the position but a degree of freedom to the residual test: a record
with a damaged URA of 266 km let six reflected GPS signals in the urban canyon pass the test
100-180 m off (benchmarks/fuzz.py)."""
GLONASS_EPHEMERIS_SIGMA_M = 5.0
"""GLONASS broadcast orbit-and-clock error sigma (RTKLIB ``ERREPH_GLO``): RINEX 3 records carry no URA."""
GALILEO_NAPA_SIGMA_M = 500.0
"""Galileo SISA 'no accuracy prediction available' (RTKLIB ``STD_GAL_NAPA``)."""


def ephemeris_sigma_m(system: str, accuracy_m: F64) -> F64:
    """Orbit-and-clock error sigma (m) of broadcast records, as RTKLIB's ``var_uraeph``.

    GPS, QZSS, BeiDou: the URA field rounded up to the IS-GPS-200 table (blank: 2.4 m).
    Galileo: the SISA field, 0 < SISA <= 6 m; larger or negative values mean NAPA (500 m);
    blank: 2.4 m. GLONASS: 5 m for every record.
    """
    acc = np.asarray(accuracy_m, dtype=np.float64)
    if system == "R":
        return np.full(acc.shape, GLONASS_EPHEMERIS_SIGMA_M)
    if system == "E":
        napa = np.isfinite(acc) & ((acc <= 0.0) | (acc > 6.0))
        return np.where(np.isfinite(acc), np.where(napa, GALILEO_NAPA_SIGMA_M, acc), URA_TABLE_M[0])
    return ura_from_index_table(acc)


class GlonassRecords:
    """GLONASS broadcast records of the run: state-vector integration, FDMA frequencies."""

    def __init__(self, eph: GlonassEphemeris) -> None:
        self.eph = eph
        self.freq = eph.g1_frequency_hz()

    def select(self, sv: NDArray[np.str_], t: F64, healthy_only: bool) -> NDArray[np.intp]:
        return select_glonass_ephemeris(self.eph, sv, t, healthy_only=healthy_only)

    def states(self, i: NDArray[np.intp], t: F64) -> SatelliteStates:
        return glonass_states(self.eph, i, t)

    def clock_s(self, i: NDArray[np.intp], t: F64) -> F64:
        return glonass_clock_s(self.eph, i, t)

    def iono_scale(self, i: NDArray[np.intp]) -> F64:
        return (FREQ_L1_HZ / self.freq[np.where(i >= 0, i, 0)]) ** 2

    def sigma_m(self, i: NDArray[np.intp]) -> F64:
        return ephemeris_sigma_m("R", np.full(i.shape, np.nan))

    def delays(self, i: NDArray[np.intp]) -> dict[str, object]:
        return {"tgd_s": np.zeros(i.shape), "glonass_channel": self.eph.freq_num[i]}


class KeplerRecords:
    """Keplerian broadcast records of one system (G, E, C, J)."""

    def __init__(self, eph: KeplerEphemeris, system: str) -> None:
        self.eph = eph
        self.system = system
        self.factor = (FREQ_L1_HZ / FREQ_B1I_HZ) ** 2 if system == "C" else 1.0

    def select(self, sv: NDArray[np.str_], t: F64, healthy_only: bool) -> NDArray[np.intp]:
        return select_system_ephemeris(self.eph, sv, t, self.system, healthy_only=healthy_only)

    def states(self, i: NDArray[np.intp], t: F64) -> SatelliteStates:
        return system_states(self.eph, i, t, self.system)

    def clock_s(self, i: NDArray[np.intp], t: F64) -> F64:
        return system_states(self.eph, i, t, self.system, clock_only=True).clock_s

    def iono_scale(self, i: NDArray[np.intp]) -> F64:
        return np.full(i.shape, self.factor)

    def sigma_m(self, i: NDArray[np.intp]) -> F64:
        e = self.eph
        return ephemeris_sigma_m(self.system, e.ura_m[np.where(i >= 0, i, 0)] if e.ura_m is not None else np.full(i.shape, np.nan))

    def delays(self, i: NDArray[np.intp]) -> dict[str, object]:
        e = self.eph
        return {
            "tgd_s": e.tgd_s[i],
            "tgd2_s": None if e.tgd2_s is None else e.tgd2_s[i],
            "fnav": None if e.fnav is None else e.fnav[i],
        }


def system_records(nav: xr.Dataset, system: str) -> tuple[GlonassRecords | KeplerRecords | None, F64]:
    """The broadcast records of ``system`` (None when there are none) and their ``toe`` (s, GPS)."""
    if system == "R":
        geph = GlonassEphemeris.from_dataset(nav)
        return (GlonassRecords(geph) if len(geph) else None), geph.toe_gps_s
    keph = ephemeris_for_system(nav, system)
    return (KeplerRecords(keph, system) if len(keph) else None), keph.toe_gps_s
