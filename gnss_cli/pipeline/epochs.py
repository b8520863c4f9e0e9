"""Files -> epochs: read and validate the RINEX files, select pseudoranges, satellite states.

:func:`load_epochs` produces the :class:`~gnss_cli.pipeline.results.EpochData` every
estimator works on. Observations are padded to a common satellite axis; rows of unusable
satellites are masked, so every epoch is one slice of stacked ``(T, n, ...)`` arrays.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import xarray as xr
from numpy.typing import NDArray

from gnss_cli.config import SYSTEM_LETTERS, ProcessingConfig
from gnss_cli.constants import C_M_S, FREQ_B1I_HZ, FREQ_L1_HZ
from gnss_cli.errors import RinexFormatError
from gnss_cli.gnss.atmosphere import KLOBUCHAR_DEFAULT_ALPHA, KLOBUCHAR_DEFAULT_BETA
from gnss_cli.gnss.ephemeris import KeplerEphemeris
from gnss_cli.gnss.geometry import EARTH_SURFACE_BAND_M
from gnss_cli.gnss.glonass import GlonassEphemeris, glonass_clock_s, glonass_states, select_glonass_ephemeris
from gnss_cli.gnss.multi_gnss import ephemeris_for_system, select_system_ephemeris, system_states
from gnss_cli.gnss.observables import (
    DEFAULT_SECOND_SIGNAL_PRIORITY,
    DEFAULT_SIGNAL_PRIORITY,
    Pseudoranges,
    align_pseudoranges,
    codes_for,
    doppler_code,
    select_dopplers,
    select_pseudoranges,
)
from gnss_cli.gnss.orbits import SatelliteStates
from gnss_cli.gnss.signals import carrier_frequency_hz, iono_free_pseudorange_m, signal_of
from gnss_cli.gnss.time import gps_s2datetime
from gnss_cli.gnss.weights import ephemeris_sigma_m
from gnss_cli.io.rinex import klobuchar_coefficients, nav_leap_seconds, read_nav, read_obs
from gnss_cli.pipeline.results import EpochData

__all__ = ["load_epochs"]

F64 = NDArray[np.float64]
_COMMON_SPAN_MARGIN_S = 4 * 3600.0  # observations this far outside the ephemerides' toe span share no time


class _GlonassRecords:
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


class _KeplerRecords:
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


def _system_records(nav: xr.Dataset, system: str) -> tuple[_GlonassRecords | _KeplerRecords | None, F64]:
    """The broadcast records of ``system`` (None when there are none) and their ``toe`` (s, GPS)."""
    if system == "R":
        geph = GlonassEphemeris.from_dataset(nav)
        return (_GlonassRecords(geph) if len(geph) else None), geph.toe_gps_s
    keph = ephemeris_for_system(nav, system)
    return (_KeplerRecords(keph, system) if len(keph) else None), keph.toe_gps_s


@dataclass
class _SatelliteArrays:
    """Per-observation satellite quantities ``(T, n[, 3])``, filled one system at a time."""

    sat: F64
    clk: F64
    tgd: F64
    ura: F64
    iono_scale: F64
    usable: NDArray[np.bool_]
    p_if: F64
    vel: F64 | None = None
    drift: F64 | None = None
    freq: F64 | None = None

    @classmethod
    def empty(cls, t_n: int, n: int, rates: bool = False) -> _SatelliteArrays:
        """NaN arrays; with ``rates`` also velocity, clock drift and carrier frequency (for Doppler)."""
        nan = np.full((t_n, n), np.nan)
        return cls(
            sat=np.full((t_n, n, 3), np.nan), clk=nan.copy(), tgd=nan.copy(),
            ura=nan.copy(), iono_scale=np.ones((t_n, n)), usable=np.zeros((t_n, n), dtype=bool),
            p_if=nan.copy(), vel=np.full((t_n, n, 3), np.nan) if rates else None,
            drift=nan.copy() if rates else None, freq=nan.copy() if rates else None,
        )


def _fill_system(out: _SatelliteArrays, records: _GlonassRecords | _KeplerRecords, system: str,
                 prs: Pseudoranges, prs2: Pseudoranges | None, cols: NDArray[np.intp],
                 have_obs: NDArray[np.bool_], healthy_only: bool) -> None:
    """Satellite states of one system's observations, at ``t - P/c`` moved by ``-dt_sv`` along the velocity."""
    t = prs.time_gps_s
    pr = prs.pr_m[:, cols]
    idx = records.select(prs.sv[cols], t, healthy_only)
    ii, jj = np.nonzero(have_obs[:, cols] & (idx >= 0))
    kk, cc = idx[ii, jj], cols[jj]
    st = records.states(kk, t[ii] - pr[ii, jj] / C_M_S)
    out.sat[ii, cc] = st.pos_ecef_m - st.vel_ecef_m_s * st.clock_s[:, None]
    out.clk[ii, cc] = st.clock_s
    out.tgd[ii, cc] = np.nan_to_num(st.tgd_s)
    out.ura[ii, cc] = records.sigma_m(kk)
    out.iono_scale[ii, cc] = records.iono_scale(kk)
    out.usable[ii, cc] = np.isfinite(st.clock_s) & np.isfinite(out.sat[ii, cc]).all(axis=-1)
    if out.vel is not None:
        _fill_rates(out, records, system, prs.code[ii, cc], (ii, cc, kk), t[ii] - pr[ii, jj] / C_M_S, st)
    if prs2 is not None:
        out.p_if[ii, cc] = iono_free_pseudorange_m(
            system, prs.code[ii, cc], pr[ii, jj], prs2.code[ii, cc], prs2.pr_m[ii, cc], **records.delays(kk)
        )


_DRIFT_STEP_S = 1.0  # forward difference of the broadcast clock: af2 and relativistic curvature < 1e-15 s/s


def _fill_rates(out: _SatelliteArrays, records: _GlonassRecords | _KeplerRecords, system: str, code: NDArray[np.str_],
                where: tuple[NDArray[np.intp], NDArray[np.intp], NDArray[np.intp]], t_tx: F64, st: SatelliteStates) -> None:
    """Satellite velocity (m/s), clock drift (s/s, forward difference of the broadcast clock with its
    relativistic term) and the carrier frequency (Hz; GLONASS per channel) of each chosen code."""
    assert out.vel is not None and out.drift is not None and out.freq is not None
    ii, cc, kk = where
    out.vel[ii, cc] = st.vel_ecef_m_s
    out.drift[ii, cc] = (records.clock_s(kk, t_tx + _DRIFT_STEP_S) - st.clock_s) / _DRIFT_STEP_S
    channel = np.asarray(records.delays(kk).get("glonass_channel", np.zeros(kk.shape)), dtype=np.float64)
    freq = np.full(kk.shape, np.nan)
    for c in np.unique(code):
        signal = signal_of(system, str(c))
        if signal is not None:
            sel = code == c
            freq[sel] = carrier_frequency_hz(signal, channel[sel])
    out.freq[ii, cc] = freq


def _span_text(a: float, b: float) -> str:
    return f"{np.datetime_as_string(gps_s2datetime(a), 'm')} to {np.datetime_as_string(gps_s2datetime(b), 'm')}"


def _systems_with_data(obs: xr.Dataset, nav: xr.Dataset, obs_path: str | Path, nav_name: str) -> list[str]:
    """Systems of :data:`SYSTEM_LETTERS` observed in ``obs`` and present in ``nav``."""
    in_obs = {str(v)[:1] for v in obs["sv"].values}
    in_nav = {str(v)[:1] for v in nav["sv"].values}
    systems = [sy for sy in SYSTEM_LETTERS if sy in in_obs and sy in in_nav]
    if not systems:
        raise RinexFormatError(
            f"{nav_name}: no system of {','.join(SYSTEM_LETTERS)} is both observed in {Path(obs_path).name} "
            f"(has {','.join(sorted(in_obs)) or 'none'}) and in the navigation files (have {','.join(sorted(in_nav)) or 'none'})"
        )
    return systems


def _check_coverage(arrays: _SatelliteArrays, prs: Pseudoranges, have_obs: NDArray[np.bool_], toe_span: tuple[float, float],
                    systems: list[str], obs_path: str | Path, nav_name: str, warnings: list[str]) -> None:
    """Raise when the ephemerides do not cover the observations; warn about satellites without one."""
    t = prs.time_gps_s
    toe_lo, toe_hi = toe_span
    if not np.isfinite(toe_lo):
        raise RinexFormatError(f"{nav_name}: no ephemeris records for {','.join(systems)}")
    if t.max() < toe_lo - _COMMON_SPAN_MARGIN_S or t.min() > toe_hi + _COMMON_SPAN_MARGIN_S:
        raise RinexFormatError(
            f"{nav_name}: no common time span with {Path(obs_path).name} "
            f"(observations {_span_text(t.min(), t.max())}, ephemerides {_span_text(toe_lo, toe_hi)} GPST)"
        )
    if not arrays.usable.any():
        raise RinexFormatError(f"{nav_name}: no usable ephemeris for any satellite observed in {Path(obs_path).name}")
    missing = sorted(set(prs.sv[have_obs.any(axis=0) & ~arrays.usable.any(axis=0)]))
    if missing:
        warnings.append(f"no usable ephemeris for {len(missing)} observed satellite(s): {' '.join(missing)}")


def _iono_free_usable(arrays: _SatelliteArrays, prs: Pseudoranges, systems: list[str],
                      priority2: dict[str, tuple[str, ...]], obs_path: str | Path, warnings: list[str]) -> NDArray[np.bool_]:
    """Usable observations with a second-frequency pseudorange; raises when there is none."""
    usable = arrays.usable
    dual = usable & np.isfinite(arrays.p_if)
    if not dual.any():
        second = ", ".join(c for c in codes_for(systems, priority2))
        raise RinexFormatError(
            f"{Path(obs_path).name}: no satellite has a second-frequency pseudorange for the iono-free combination "
            f"(codes {second}); use --iono klobuchar"
        )
    dropped = sorted(set(prs.sv[usable.any(axis=0) & ~dual.any(axis=0)]))
    if dropped:
        warnings.append(f"iono-free: {len(dropped)} satellite(s) without a usable second frequency not used: {' '.join(dropped)}")
    return dual


def snr_code(code: str) -> str:
    """The C/N0 observation of a pseudorange code: ``C1C`` -> ``S1C``, ``C1``/``P1`` -> ``S1``."""
    return "S" + code[1:]


def _snr(obs: xr.Dataset, prs: Pseudoranges) -> F64 | None:
    """``(T, n)`` C/N0 (dB-Hz) of each chosen code's signal; None when the file has no S observation."""
    have = [c for c in np.unique(prs.code) if c and snr_code(c) in obs]
    if not have:
        return None
    col = {sv: i for i, sv in enumerate(np.asarray(obs["sv"].values).astype(str))}
    idx = np.array([col[sv] for sv in prs.sv])
    out = np.full(prs.pr_m.shape, np.nan)
    for c in have:
        vals = np.asarray(obs[snr_code(c)].values, dtype=np.float64)[:, idx]
        use = (prs.code == c) & (vals > 0)
        out[use] = vals[use]
    return out


def _unused(prs: Pseudoranges, usable: NDArray[np.bool_], snr: F64 | None, config: ProcessingConfig) -> NDArray[np.int8]:
    """Why each observation is not usable (:data:`~gnss_cli.pipeline.results.UNUSED_REASONS` index;
    -1 not observed, 0 usable): no ephemeris, ``exclude``, ``snr_mask_dbhz`` (an observation without
    an S value passes the mask)."""
    code = np.zeros(prs.pr_m.shape, dtype=np.int8)
    code[~usable] = 1
    code[(code == 0) & np.isin(prs.sv, list(config.exclude))[None, :]] = 2
    if snr is not None and config.snr_mask_dbhz > 0:
        code[(code == 0) & (snr < config.snr_mask_dbhz)] = 3
    code[~np.isfinite(prs.pr_m)] = -1
    return code


def _selection(obs: xr.Dataset, prs: Pseudoranges, usable: NDArray[np.bool_],
               config: ProcessingConfig) -> tuple[NDArray[np.bool_], F64 | None, NDArray[np.int8]]:
    """Usable observations after ``exclude`` and ``snr_mask_dbhz``, the C/N0, the unused codes."""
    snr = _snr(obs, prs)
    unused = _unused(prs, usable, snr, config)
    return usable & (unused == 0), snr, unused


def _approx_position(obs: xr.Dataset) -> F64 | None:
    """The header's approximate position when it is near the Earth's surface, else None."""
    approx = np.asarray(obs.attrs.get("position", []) or [], dtype=np.float64).ravel()
    near = approx.size == 3 and EARTH_SURFACE_BAND_M[0] < np.linalg.norm(approx) < EARTH_SURFACE_BAND_M[1]
    return approx if near else None


def _klobuchar(nav, config: ProcessingConfig, nav_name: str, warnings: list[str]):  # type: ignore[no-untyped-def]
    """The navigation files' Klobuchar coefficients, else RTKLIB's defaults (with a warning)."""
    klob = klobuchar_coefficients(nav)
    if klob is None and config.iono == "klobuchar":
        klob = (KLOBUCHAR_DEFAULT_ALPHA.copy(), KLOBUCHAR_DEFAULT_BETA.copy())
        reason = nav.attrs.get("ionospheric_corr_problem") or f"{nav_name}: no Klobuchar coefficients in the header"
        warnings.append(f"{reason}; using the default coefficients (as RTKLIB)")
    return klob


def load_epochs(
    obs_path: str | Path,
    nav_paths: Sequence[str | Path],
    config: ProcessingConfig,
    timings: dict[str, float] | None = None,
) -> EpochData:
    """Read and validate the files, select pseudoranges, and compute satellite states.

    ``config.systems`` empty means every system of :data:`~gnss_cli.config.SYSTEM_LETTERS`
    that the observation file has and the navigation files have records of. With
    ``config.iono == "iono-free"`` ``pr_corrected_m`` is the ionosphere-free combination of
    the first and second frequency (:mod:`gnss_cli.gnss.signals`); satellites without a
    usable second frequency are not usable.

    Satellite states are evaluated once per observation, at ``t - P/c``, and moved to the
    transmit time ``t - P/c - dt_sv`` along the broadcast velocity (``|dt_sv| < 1 ms``: the
    neglected acceleration term is below 1e-6 m).

    ``timings``, when given, receives the wall time (s) of the stages ``read`` and ``orbits``.

    Raises
    ------
    InputError
        Unreadable, malformed or mismatched files (no common time span, no ephemeris, no
        system in both files, no dual-frequency pseudorange in iono-free mode).
    """
    clock = time.perf_counter()
    explicit = bool(config.systems)
    systems = list(config.systems) if explicit else list(SYSTEM_LETTERS)
    iono_free = config.iono == "iono-free"
    priority = {**DEFAULT_SIGNAL_PRIORITY, **{k: tuple(v) for k, v in config.signals.items()}}
    priority2 = {**DEFAULT_SECOND_SIGNAL_PRIORITY, **{k: tuple(v) for k, v in config.signals_second.items()}}
    codes = codes_for(systems, priority)
    codes += [x(c) for x in (snr_code, doppler_code) for c in codes_for(systems, priority) if x(c) not in codes]  # C/N0, Doppler
    if iono_free:
        codes += [c for c in codes_for(systems, priority2) if c not in codes]
    obs = read_obs(obs_path, systems=systems, codes=codes)
    nav = read_nav(list(nav_paths), systems=systems)
    nav_name = ",".join(Path(p).name for p in nav_paths)
    warnings: list[str] = list(nav.attrs.get("rejected_records", []))
    if not explicit:
        systems = _systems_with_data(obs, nav, obs_path, nav_name)
    if timings is not None:
        timings["read"] = time.perf_counter() - clock
        clock = time.perf_counter()

    prs = select_pseudoranges(obs, systems, priority)
    if prs.sv.size == 0:
        raise RinexFormatError(f"{obs_path}: no pseudoranges of {','.join(systems)} (codes {', '.join(codes_for(systems, priority))})")
    prs2 = align_pseudoranges(select_pseudoranges(obs, systems, priority2), prs.sv) if iono_free else None
    t = prs.time_gps_s
    sys_of = np.array([sv[0] for sv in prs.sv])
    doppler_hz = select_dopplers(obs, prs)
    arrays = _SatelliteArrays.empty(t.size, prs.sv.size, rates=doppler_hz is not None)
    have_obs = np.isfinite(prs.pr_m)
    toe_lo, toe_hi = np.inf, -np.inf
    for system in systems:
        cols = np.flatnonzero(sys_of == system)
        if cols.size == 0:
            continue
        records, toe = _system_records(nav, system)
        if records is None:
            name, what = ("GLONASS", "GLONASS") if system == "R" else (system, f"system {system}")
            warnings.append(f"{nav_name}: no {name} ephemeris; {what} not used")
            continue
        toe_lo, toe_hi = min(toe_lo, toe.min()), max(toe_hi, toe.max())
        _fill_system(arrays, records, system, prs, prs2, cols, have_obs, config.healthy_only)

    _check_coverage(arrays, prs, have_obs, (toe_lo, toe_hi), systems, obs_path, nav_name, warnings)
    usable, snr, unused = _selection(obs, prs, arrays.usable, config)
    if iono_free:
        usable = _iono_free_usable(replace(arrays, usable=usable), prs, systems, priority2, obs_path, warnings)
    used_systems = tuple(sy for sy in systems if usable[:, sys_of == sy].any())
    system_index = np.array([used_systems.index(x) if x in used_systems else 0 for x in sys_of], dtype=np.int64)
    if iono_free:
        pr_corr = np.where(usable, arrays.p_if + C_M_S * arrays.clk, np.nan)
    else:
        pr_corr = np.where(usable, prs.pr_m + C_M_S * (arrays.clk - arrays.tgd), np.nan)
    klob = _klobuchar(nav, config, nav_name, warnings)
    if timings is not None:
        timings["orbits"] = time.perf_counter() - clock
    return EpochData(
        time_gps_s=t,
        sv=prs.sv,
        pr_corrected_m=pr_corr,
        sat_ecef_m=arrays.sat,
        ura_m=arrays.ura,
        usable=usable,
        klobuchar=klob,
        approx_ecef_m=_approx_position(obs),
        marker_name=str(obs.attrs.get("marker_name", "") or ""),
        obs_path=str(obs_path),
        nav_paths=tuple(str(p) for p in nav_paths),
        warnings=tuple(warnings),
        systems=used_systems,
        system_index=system_index,
        iono_scale=arrays.iono_scale, snr_dbhz=snr, unused=unused,
        leap_seconds=nav_leap_seconds(nav_paths),
        **_rates(arrays, doppler_hz, usable),
    )


def _rates(arrays: _SatelliteArrays, doppler_hz: F64 | None, usable: NDArray[np.bool_]) -> dict[str, F64 | None]:
    """The Doppler fields of :class:`EpochData`: range rate ``-lambda D`` (m/s; NaN where there is no
    Doppler or the pseudorange is not usable), satellite velocity and clock drift; empty without Doppler."""
    if doppler_hz is None or arrays.freq is None:
        return {}
    rate = np.where(usable, -C_M_S / arrays.freq * doppler_hz, np.nan)
    return {"range_rate_m_s": rate, "sat_vel_ecef_m_s": arrays.vel, "sat_clock_drift_s_s": arrays.drift}
