"""Files -> epochs: read and validate the RINEX files, select pseudoranges, satellite states.

:func:`load_epochs` produces the :class:`~gnss_cli.pipeline.results.EpochData` every
estimator works on. The satellite states at transmit time and the clock- and group-delay-
corrected pseudoranges come from the pseudorange model (:mod:`gnss_cli.gnss.range_model`). Observations are padded to a common satellite axis; rows of unusable
satellites are masked, so every epoch is one slice of stacked ``(T, n, ...)`` arrays.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import xarray as xr
from numpy.typing import NDArray

from gnss_cli.config import SYSTEM_LETTERS, ProcessingConfig
from gnss_cli.constants import C_M_S
from gnss_cli.errors import RinexFormatError
from gnss_cli.gnss.atmosphere import KLOBUCHAR_DEFAULT_ALPHA, KLOBUCHAR_DEFAULT_BETA
from gnss_cli.gnss.broadcast import MAX_EPHEMERIS_SIGMA_M, GlonassRecords, KeplerRecords, system_records
from gnss_cli.gnss.carrier import phase_slips
from gnss_cli.gnss.observables import (
    DEFAULT_SECOND_SIGNAL_PRIORITY,
    DEFAULT_SIGNAL_PRIORITY,
    Pseudoranges,
    align_pseudoranges,
    codes_for,
    doppler_code,
    phase_code,
    select_dopplers,
    select_phases,
    select_pseudoranges,
)
from gnss_cli.gnss.range_model import (
    EARTH_SURFACE_BAND_M,
    SatelliteArrays,
    corrected_pseudoranges,
    satellites_at_transmit_time,
)
from gnss_cli.gnss.signals import iono_free_combination_m
from gnss_cli.gnss.time import gps_s2datetime
from gnss_cli.io.fixed_width import lli_name
from gnss_cli.io.navigation import navigation_files
from gnss_cli.io.rinex import klobuchar_coefficients, read_obs
from gnss_cli.io.rinex3_header import SYSTEM_NAMES
from gnss_cli.pipeline.results import EpochData

__all__ = ["load_epochs", "signal_setup", "build_epochs", "file_warnings", "system_warnings", "used_systems", "finish_epochs",
           "EpochSetup", "Coverage", "clock_systems", "SHARED_CLOCKS"]

F64 = NDArray[np.float64]
_COMMON_SPAN_MARGIN_S = 4 * 3600.0  # observations this far outside the ephemerides' toe span share no time


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


def _unused(prs: Pseudoranges, usable: NDArray[np.bool_], snr: F64 | None, config: ProcessingConfig,
            ura_m: F64) -> NDArray[np.int8]:
    """Why each observation is not usable (:data:`~gnss_cli.pipeline.results.UNUSED_REASONS` index;
    -1 not observed, 0 usable): no ephemeris, an ephemeris sigma ``ura_m`` (m) above
    :data:`~gnss_cli.gnss.broadcast.MAX_EPHEMERIS_SIGMA_M`, ``exclude``, ``snr_mask_dbhz`` (an
    observation without an S value passes the mask)."""
    code = np.zeros(prs.pr_m.shape, dtype=np.int8)
    code[~usable] = 1
    code[(code == 0) & (ura_m > MAX_EPHEMERIS_SIGMA_M)] = 4
    code[(code == 0) & np.isin(prs.sv, list(config.exclude))[None, :]] = 2
    if snr is not None and config.snr_mask_dbhz > 0:
        code[(code == 0) & (snr < config.snr_mask_dbhz)] = 3
    code[~np.isfinite(prs.pr_m)] = -1
    return code


def _selection(obs: xr.Dataset, prs: Pseudoranges, usable: NDArray[np.bool_], config: ProcessingConfig,
               ura_m: F64) -> tuple[NDArray[np.bool_], F64 | None, NDArray[np.int8]]:
    """Usable observations after the ephemeris sigma limit, ``exclude`` and ``snr_mask_dbhz``, the
    C/N0, the unused codes."""
    snr = _snr(obs, prs)
    unused = _unused(prs, usable, snr, config, ura_m)
    return usable & (unused == 0), snr, unused


def _approx_position(obs: xr.Dataset) -> F64 | None:
    """The header's approximate position when it is near the Earth's surface, else None."""
    approx = np.asarray(obs.attrs.get("position", []) or [], dtype=np.float64).ravel()
    near = approx.size == 3 and EARTH_SURFACE_BAND_M[0] < np.linalg.norm(approx) < EARTH_SURFACE_BAND_M[1]
    return approx if near else None


def klobuchar_for(nav: xr.Dataset, config: ProcessingConfig, nav_name: str, warnings: list[str]) -> tuple[F64, F64] | None:
    """The navigation files' Klobuchar coefficients, else RTKLIB's defaults (with a warning)."""
    klob = klobuchar_coefficients(nav)
    if klob is None and config.iono == "klobuchar":
        klob = (KLOBUCHAR_DEFAULT_ALPHA.copy(), KLOBUCHAR_DEFAULT_BETA.copy())
        reason = nav.attrs.get("ionospheric_corr_problem") or f"{nav_name}: no Klobuchar coefficients in the header"
        warnings.append(f"{reason}; using the default coefficients (as RTKLIB)")
    return klob


@dataclass
class EpochSetup:
    """What every part of a run shares: the signal choice and the navigation data
    (:func:`signal_setup`, then :meth:`read_navigation`)."""

    obs_path: str
    nav_paths: tuple[str, ...]
    config: ProcessingConfig
    explicit: bool
    systems: list[str]
    priority: dict[str, tuple[str, ...]]
    priority2: dict[str, tuple[str, ...]]
    codes: list[str]
    nav: xr.Dataset | None = None
    nav_name: str = ""
    klobuchar: tuple[F64, F64] | None = None
    klobuchar_warnings: tuple[str, ...] = ()
    leap_seconds: float | None = None
    _records: dict[str, tuple[GlonassRecords | KeplerRecords | None, F64]] = field(default_factory=dict)

    @property
    def iono_free(self) -> bool:
        return self.config.iono == "iono-free"

    def read_navigation(self) -> None:
        """Read the navigation files (records, Klobuchar coefficients, leap seconds; in a process
        that :func:`~gnss_cli.io.navigation.keep_navigation` was called in, the last files
        read are taken again unread while they are unchanged, with their per-system records)."""
        self.nav, self.leap_seconds, self._records = navigation_files(self.nav_paths, self.systems)
        self.nav_name = ",".join(Path(p).name for p in self.nav_paths)
        warnings: list[str] = []
        self.klobuchar = klobuchar_for(self.nav, self.config, self.nav_name, warnings)
        self.klobuchar_warnings = tuple(warnings)

    def records(self, system: str) -> tuple[GlonassRecords | KeplerRecords | None, F64]:
        if system not in self._records:
            assert self.nav is not None
            self._records[system] = system_records(self.nav, system)
        return self._records[system]


def signal_setup(obs_path: str | Path, nav_paths: Sequence[str | Path], config: ProcessingConfig) -> EpochSetup:
    """The systems and the observation codes to read (pseudoranges, C/N0, Doppler, second frequency)."""
    explicit = bool(config.systems)
    systems = list(config.systems) if explicit else list(SYSTEM_LETTERS)
    priority = {**DEFAULT_SIGNAL_PRIORITY, **{k: tuple(v) for k, v in config.signals.items()}}
    priority2 = {**DEFAULT_SECOND_SIGNAL_PRIORITY, **{k: tuple(v) for k, v in config.signals_second.items()}}
    codes = codes_for(systems, priority)
    codes += [x(c) for x in (snr_code, doppler_code) for c in codes_for(systems, priority) if x(c) not in codes]  # C/N0, Doppler
    iono_free = config.iono == "iono-free"
    if config.uses("phase") and config.multi_epoch_methods:  # phase_rows of smoother, kf and stls --lag L
        phases = [phase_code(c) for c in codes_for(systems, priority)]
        phases += [phase_code(c) for c in codes_for(systems, priority2)] if iono_free else []  # iono-free phase
        codes += [c for c in phases + [lli_name(c) for c in phases] if c not in codes]
    if iono_free:
        codes += [c for c in codes_for(systems, priority2) if c not in codes]
    return EpochSetup(str(obs_path), tuple(str(p) for p in nav_paths), config, explicit, systems, priority, priority2, codes)


@dataclass
class Coverage:
    """Per satellite of a part of the file: observed, with a usable ephemeris, usable after the
    selection, usable in the end (iono-free: with a second frequency); the time span; and whether
    the part gave the multi-epoch methods range rates (Doppler) and carrier phase. Parts of one
    file on one satellite axis combine with :meth:`merge`."""

    have_obs: NDArray[np.bool_]
    eph_usable: NDArray[np.bool_]
    selected: NDArray[np.bool_]
    usable: NDArray[np.bool_]
    t_min_s: float
    t_max_s: float
    has_doppler: bool = False
    has_phase: bool = False

    def merge(self, other: Coverage) -> Coverage:
        return Coverage(self.have_obs | other.have_obs, self.eph_usable | other.eph_usable,
                        self.selected | other.selected, self.usable | other.usable,
                        min(self.t_min_s, other.t_min_s), max(self.t_max_s, other.t_max_s),
                        self.has_doppler or other.has_doppler, self.has_phase or other.has_phase)


def build_epochs(obs: xr.Dataset, prs: Pseudoranges, setup: EpochSetup, systems: Sequence[str]) -> tuple[EpochData, Coverage]:
    """The :class:`EpochData` of ``obs`` on the satellite axis of ``prs`` (without systems and
    warnings: :func:`finish_epochs`), and its :class:`Coverage`."""
    config = setup.config
    prs2 = align_pseudoranges(select_pseudoranges(obs, systems, setup.priority2), prs.sv) if setup.iono_free else None
    t = prs.time_gps_s
    doppler_hz = select_dopplers(obs, prs)
    arrays = satellites_at_transmit_time(prs, prs2, lambda system: setup.records(system)[0], systems,
                                         config.healthy_only, rates=doppler_hz is not None)
    have_obs = np.isfinite(prs.pr_m)
    selected, snr, unused = _selection(obs, prs, arrays.usable, config, arrays.ura)
    usable = selected & np.isfinite(arrays.p_if) if setup.iono_free else selected
    pr_corr = corrected_pseudoranges(prs.pr_m, arrays, usable, setup.iono_free)
    data = EpochData(
        time_gps_s=t, sv=prs.sv, pr_corrected_m=pr_corr, sat_ecef_m=arrays.sat, ura_m=arrays.ura, usable=usable,
        klobuchar=setup.klobuchar, approx_ecef_m=_approx_position(obs),
        marker_name=str(obs.attrs.get("marker_name", "") or ""), obs_path=setup.obs_path, nav_paths=setup.nav_paths,
        iono_scale=arrays.iono_scale, snr_dbhz=snr, unused=unused, leap_seconds=setup.leap_seconds,
        **_rates(arrays, doppler_hz, usable),
        **_phases(obs, prs, prs2, arrays, doppler_hz, pr_corr, usable, t, config),
    )
    cov = Coverage(have_obs.any(axis=0), arrays.usable.any(axis=0), selected.any(axis=0), usable.any(axis=0),
                   float(t.min()), float(t.max()), data.range_rate_m_s is not None, data.phase_m is not None)
    return data, cov


def file_warnings(setup: EpochSetup, sv: NDArray[np.str_], systems: Sequence[str], cov: Coverage) -> list[str]:
    """The run's warnings for the whole file's :class:`Coverage`; raises when the ephemerides
    do not cover the observations or (iono-free) no satellite has a second frequency."""
    assert setup.nav is not None
    warnings: list[str] = list(setup.nav.attrs.get("rejected_records", []))
    nav_name, obs_name = setup.nav_name, Path(setup.obs_path).name
    sys_of = np.array([s[0] for s in sv])
    toe_lo, toe_hi = np.inf, -np.inf
    for system in systems:
        if not (sys_of == system).any():
            continue
        records, toe = setup.records(system)
        if records is None:
            name, what = ("GLONASS", "GLONASS") if system == "R" else (system, f"system {system}")
            warnings.append(f"{nav_name}: no {name} ephemeris; {what} not used")
            continue
        toe_lo, toe_hi = min(toe_lo, toe.min()), max(toe_hi, toe.max())
    if not np.isfinite(toe_lo):
        raise RinexFormatError(f"{nav_name}: no ephemeris records for {','.join(systems)}")
    if cov.t_max_s < toe_lo - _COMMON_SPAN_MARGIN_S or cov.t_min_s > toe_hi + _COMMON_SPAN_MARGIN_S:
        raise RinexFormatError(
            f"{nav_name}: no common time span with {obs_name} "
            f"(observations {_span_text(cov.t_min_s, cov.t_max_s)}, ephemerides {_span_text(toe_lo, toe_hi)} GPST)"
        )
    if not cov.eph_usable.any():
        raise RinexFormatError(f"{nav_name}: no usable ephemeris for any satellite observed in {obs_name}")
    missing = sorted(set(sv[cov.have_obs & ~cov.eph_usable]))
    if missing:
        warnings.append(f"no usable ephemeris for {len(missing)} observed satellite(s): {' '.join(missing)}")
    if setup.iono_free:
        if not cov.usable.any():
            second = ", ".join(c for c in codes_for(systems, setup.priority2))
            raise RinexFormatError(
                f"{obs_name}: no satellite has a second-frequency pseudorange for the iono-free combination "
                f"(codes {second}); use --iono klobuchar"
            )
        dropped = sorted(set(sv[cov.selected & ~cov.usable]))
        if dropped:
            warnings.append(f"iono-free: {len(dropped)} satellite(s) without a usable second frequency not used: {' '.join(dropped)}")
    return warnings + list(setup.klobuchar_warnings)


def system_warnings(setup: EpochSetup, obs_types: dict[str, list[str]] | None, unlisted: str,
                    observed: set[str], with_pseudorange: set[str]) -> list[str]:
    """One warning per system asked for (``--systems``), or present in the file when every system
    is, that gives no pseudorange: the reason in words (records without a ``SYS / # / OBS TYPES``
    line, no observation types in the header, no pseudorange code among the header's types, no
    records, or no values).

    Parameters
    ----------
    obs_types : the header's observation types per system (RINEX 3/4); None for RINEX 2.
    unlisted : letters of the systems with records but no observation types in the header.
    observed, with_pseudorange : satellites in the file, and those with a pseudorange of the codes used.
    """
    name = Path(setup.obs_path).name
    listed = set(obs_types or {})
    sys_observed = {sv[0] for sv in observed}
    sys_with_pr = {sv[0] for sv in with_pseudorange}
    present = listed | set(unlisted) | sys_observed
    candidates = setup.systems if setup.explicit else [s for s in SYSTEM_LETTERS if s in present]
    out = []
    for system in candidates:
        if system in sys_with_pr:
            continue
        codes = codes_for([system], setup.priority)
        if system in unlisted:
            reason = "has observation records but no 'SYS / # / OBS TYPES' line in the header"
        elif obs_types is not None and system not in listed:
            reason = "is asked for (--systems) but the header lists no observation types for it"
        elif obs_types is not None and not any(t.startswith(tuple(codes)) for t in obs_types[system]):
            reason = (f"has no pseudorange code the run uses ({', '.join(codes)}) among the header's types "
                      f"({' '.join(obs_types[system])})")
        elif system not in sys_observed:
            reason = "is asked for (--systems) but the file has no records of it"
        else:
            reason = f"has no values of the pseudorange codes the run uses ({', '.join(codes)})"
        out.append(f"{name}: system {system} ({SYSTEM_NAMES[system]}) {reason}; {system} not used")
    return out


def used_systems(sv: NDArray[np.str_], systems: Sequence[str], cov: Coverage) -> tuple[str, ...]:
    """The systems with a usable observation, in clock-column order."""
    sys_of = np.array([s[0] for s in sv])
    return tuple(sy for sy in systems if cov.usable[sys_of == sy].any())


SHARED_CLOCKS = {"J": "G"}
"""Systems whose satellites use another system's receiver clock by default: QZSS time is steered
to GPS time and QZSS L1 C/A is designed to be interoperable with GPS L1 C/A (IS-QZSS-PNT), so
QZSS shares the GPS clock column (as RTKLIB's ``pntpos.c``). Galileo, BeiDou and GLONASS keep
clocks of their own (their system time offsets and receiver signal delays differ from GPS's)."""


def clock_systems(used: Sequence[str], qzss_own_clock: bool = False) -> tuple[str, ...]:
    """The clock columns of the systems ``used``: each system, except QZSS when GPS is used too and
    ``qzss_own_clock`` is false (then QZSS satellites are in GPS's column). QZSS without GPS keeps
    its clock (the reference clock when it is alone).

    >>> clock_systems(("G", "E", "J")), clock_systems(("G", "J"), qzss_own_clock=True), clock_systems(("J",))
    (('G', 'E'), ('G', 'J'), ('J',))
    """
    shared = {} if qzss_own_clock else SHARED_CLOCKS
    return tuple(s for s in used if shared.get(s) not in used)


def finish_epochs(data: EpochData, used: tuple[str, ...], warnings: Sequence[str] = (),
                  qzss_own_clock: bool = False) -> EpochData:
    """``data`` with its clock columns (:func:`clock_systems` of the systems ``used``), every
    satellite's clock-column index, and the warnings."""
    clocks = clock_systems(used, qzss_own_clock)
    column = {s: clocks.index(s) if s in clocks else clocks.index(SHARED_CLOCKS[s]) for s in used}
    index = np.array([column.get(s[0], 0) for s in data.sv], dtype=np.int64)
    return replace(data, systems=clocks, system_index=index, warnings=tuple(warnings))


def load_epochs(
    obs_path: str | Path,
    nav_paths: Sequence[str | Path],
    config: ProcessingConfig,
    timings: dict[str, float] | None = None,
    given: list[xr.Dataset] | None = None,
) -> EpochData:
    """Read and validate the files, select pseudoranges, and compute satellite states.

    ``config.systems`` empty means every system of :data:`~gnss_cli.config.SYSTEM_LETTERS`
    that the observation file has and the navigation files have records of. With
    ``config.iono == "iono-free"`` ``pr_corrected_m`` is the ionosphere-free combination of
    the first and second frequency (:mod:`gnss_cli.gnss.signals`); satellites without a
    usable second frequency are not usable.

    Satellite states are those of the transmit time ``t - P/c - dt_sv``
    (:func:`~gnss_cli.gnss.range_model.satellites_at_transmit_time`).

    ``timings``, when given, receives the wall time (s) of the stages ``read`` and ``orbits``.
    ``given``: the observation file already read (``read_obs(obs_path, systems, codes)`` with
    :func:`signal_setup`'s systems and codes) as a one-element list, emptied here so that the
    dataset is freed once used; else the file is read here.

    Raises
    ------
    InputError
        Unreadable, malformed or mismatched files (no common time span, no ephemeris, no
        system in both files, no dual-frequency pseudorange in iono-free mode).
    """
    clock = time.perf_counter()
    setup = signal_setup(obs_path, nav_paths, config)
    obs = read_obs(obs_path, systems=setup.systems, codes=setup.codes) if not given else given.pop()
    setup.read_navigation()
    assert setup.nav is not None
    systems = setup.systems if setup.explicit else _systems_with_data(obs, setup.nav, obs_path, setup.nav_name)
    if timings is not None:
        timings["read"] = time.perf_counter() - clock
        clock = time.perf_counter()
    prs = select_pseudoranges(obs, systems, setup.priority)
    if prs.sv.size == 0:
        raise RinexFormatError(f"{obs_path}: no pseudoranges of {','.join(systems)} (codes {', '.join(codes_for(systems, setup.priority))})")
    data, cov = build_epochs(obs, prs, setup, systems)
    warnings = system_warnings(setup, obs.attrs.get("obs_types"), obs.attrs.get("unlisted_systems", ""),
                               set(np.asarray(obs["sv"].values).astype(str).tolist()), set(prs.sv.tolist()))
    warnings += file_warnings(setup, prs.sv, systems, cov)
    if timings is not None:
        timings["orbits"] = time.perf_counter() - clock
    return finish_epochs(data, used_systems(prs.sv, systems, cov), warnings, config.qzss_own_clock)


def _rates(arrays: SatelliteArrays, doppler_hz: F64 | None, usable: NDArray[np.bool_]) -> dict[str, F64 | None]:
    """The Doppler fields of :class:`EpochData`: range rate ``-lambda D`` (m/s; NaN where there is no
    Doppler or the pseudorange is not usable), satellite velocity and clock drift; empty without Doppler."""
    if doppler_hz is None:
        return {}
    rate = np.where(usable, -C_M_S / arrays.freq * doppler_hz, np.nan)
    return {"range_rate_m_s": rate, "sat_vel_ecef_m_s": arrays.vel, "sat_clock_drift_s_s": arrays.drift}


def _phases(obs: xr.Dataset, prs: Pseudoranges, prs2: Pseudoranges | None, arrays: SatelliteArrays,
            doppler_hz: F64 | None, pr_corr: F64, usable: NDArray[np.bool_], t: F64, config: ProcessingConfig
            ) -> dict[str, F64 | NDArray[np.bool_]]:
    """The carrier-phase fields of :class:`EpochData` (``lambda phi + c dt_sv``, m, and where it may
    have slipped, :func:`~gnss_cli.gnss.carrier.phase_slips`: against the range rates, or without
    Doppler against ``pr_corr``, the corrected pseudoranges); empty without phase, or without
    ``phase`` in the measurements.

    Iono-free (``prs2``, the second signals' pseudoranges): the ionosphere-free combination of the
    two signals' phases, as the pseudoranges are combined (the ionosphere's change would otherwise
    stay in every difference, the carrier's sign opposite to the code's); a loss of lock on either
    signal breaks it. NaN where the second signal has no phase."""
    if not config.uses("phase"):
        return {}
    selected = select_phases(obs, prs)
    if selected is None:
        return {}
    cycles, lli = selected
    lam = C_M_S / arrays.freq
    carrier_m = lam * cycles
    if prs2 is not None:
        second = select_phases(obs, prs2)
        if second is None or arrays.freq2 is None:
            return {}
        carrier_m = iono_free_combination_m(carrier_m, C_M_S / arrays.freq2 * second[0], arrays.freq, arrays.freq2)
        lli = (lli.astype(np.int64) | second[1].astype(np.int64)).astype(np.float64)
    phase = np.where(usable, carrier_m + C_M_S * arrays.clk, np.nan)
    rate = np.where(usable, -lam * doppler_hz, np.nan) if doppler_hz is not None else np.full(phase.shape, np.nan)
    slip = phase_slips(t, phase, rate, lli, config.phase_slip_m, pr_corr)
    return {"phase_m": phase, "phase_slip": slip}
