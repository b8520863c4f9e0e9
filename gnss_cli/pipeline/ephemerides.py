"""Broadcast ephemerides of one system behind one interface: record selection, satellite
states at transmit time, frequency scale of the ionospheric delay, orbit sigma, group delays."""

from __future__ import annotations

import numpy as np
import xarray as xr
from numpy.typing import NDArray

from gnss_cli.constants import FREQ_B1I_HZ, FREQ_L1_HZ
from gnss_cli.gnss.ephemeris import KeplerEphemeris
from gnss_cli.gnss.glonass import GlonassEphemeris, glonass_clock_s, glonass_states, select_glonass_ephemeris
from gnss_cli.gnss.multi_gnss import ephemeris_for_system, select_system_ephemeris, system_states
from gnss_cli.gnss.orbits import SatelliteStates
from gnss_cli.gnss.weights import ephemeris_sigma_m

__all__ = ["GlonassRecords", "KeplerRecords", "system_records"]

F64 = NDArray[np.float64]


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
