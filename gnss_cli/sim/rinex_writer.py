"""RINEX writers: 3.04 observations, 2.11 observations and 3.04 navigation (GPS LNAV,
Galileo I/NAV, BeiDou D1).

Values use the fixed-width formats of the RINEX descriptions (``F14.3`` observations,
``D19.12`` ephemeris fields written with ``E``, ``F9.2`` versions, 60-column header bodies
with the label in columns 61-80). Headers carry no wall-clock time: the PGM / RUN BY / DATE
line holds the simulated start time, so the same inputs give the same bytes.
"""

from __future__ import annotations

import datetime as dt
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from gnss_cli.constants import BDT_MINUS_GPST_S, SECONDS_PER_WEEK
from gnss_cli.errors import UsageError
from gnss_cli.gnss.ephemeris import KeplerEphemeris
from gnss_cli.gnss.time import gps_s2datetime
from gnss_cli.sim.constellation import SYSTEMS, file_omega0_rad, system_week_start_gps_s
from gnss_cli.sim.observables import Observations

F64 = NDArray[np.float64]

PROGRAM = "gnss-simulate"
AGENCY = "gnss-solve"
SYSTEM_NAMES = {"G": "G: GPS", "E": "E: GALILEO", "C": "C: BEIDOU", "J": "J: QZSS", "M": "M: MIXED"}


@dataclass(frozen=True)
class ObsLayout:
    """What goes into an observation file.

    Attributes
    ----------
    dual_frequency : write the second pseudorange (C2W / C7Q / C7I).
    doppler : write Doppler (D1C, D2I ...).
    snr : write signal strength (S1C ...).
    phase : carrier phases (L1C ...) in open sky (continuous, :mod:`gnss_cli.sim.observables`);
        the street canyon always writes them. RINEX 3 only.
    """

    dual_frequency: bool = False
    doppler: bool = True
    snr: bool = True
    phase: bool = False


def _calendar(t_gps_s: float) -> dt.datetime:
    """GPS seconds -> naive datetime (microseconds; RINEX epochs are written to 0.1 us)."""
    return gps_s2datetime(np.round(t_gps_s, 6)).astype("datetime64[us]").astype(dt.datetime)  # type: ignore[no-any-return]


def _hline(body: str, label: str) -> str:
    if len(body) > 60:
        raise UsageError(f"RINEX header body longer than 60 columns for {label!r}: {body!r}")
    return f"{body:<60s}{label:<20s}".rstrip() + "\n"


def _pgm_line(start_gps_s: float) -> str:
    t = _calendar(start_gps_s)
    return _hline(f"{PROGRAM:<20s}{AGENCY:<20s}{t:%Y%m%d %H%M%S} GPS", "PGM / RUN BY / DATE")


def _d19(x: float) -> str:
    """One RINEX D19.12 field (written with E)."""
    return f"{x: .12E}"


def write_nav_rinex3(
    path: Path,
    tables: dict[str, KeplerEphemeris],
    tgd2_s: dict[str, F64],
    klobuchar_alpha: F64,
    klobuchar_beta: F64,
    start_gps_s: float,
    *,
    version: str = "3.04",
) -> None:
    """Write a RINEX 3 navigation file with the records of the given systems.

    Parameters
    ----------
    path
        Output file.
    tables
        System letter -> records (GPS-time tables as in :mod:`gnss_cli.sim.constellation`).
    tgd2_s
        System letter -> second group delay per record (BeiDou TGD2; others unused), s.
    klobuchar_alpha, klobuchar_beta
        Coefficients for the ``GPSA`` / ``GPSB`` header lines.
    start_gps_s
        Simulated start (for the PGM / RUN BY / DATE line).
    version
        ``'3.04'`` or ``'3.05'``.

    Notes
    -----
    Records: GPS LNAV (8 lines, IODC = IODE, fit interval 4 h); QZSS in the same LNAV format
    (L2 codes 2 = L2C, L2 P data flag 1, fit interval flag 0); Galileo I/NAV (data sources
    517: E1-B + E5b-I, clock for E5b/E1; BGD E5a/E1 = BGD E5b/E1); BeiDou D1 (times in BDT,
    ``omega0`` from the BDT week start). Transmission time: one hour before toe (not before the
    week start).
    """
    systems = [s for s in "GECJ" if s in tables]
    sys_char = systems[0] if len(systems) == 1 else "M"
    lines = [
        _hline(f"{float(version):9.2f}{'':11s}{'N: GNSS NAV DATA':20s}{SYSTEM_NAMES[sys_char]:20s}", "RINEX VERSION / TYPE"),
        _pgm_line(start_gps_s),
        _hline("GPSA " + "".join(f"{v:12.4E}" for v in klobuchar_alpha), "IONOSPHERIC CORR"),
        _hline("GPSB " + "".join(f"{v:12.4E}" for v in klobuchar_beta), "IONOSPHERIC CORR"),
        _hline("", "END OF HEADER"),
    ]
    for system in systems:
        eph = tables[system]
        order = np.lexsort((eph.toe_gps_s, eph.sv))
        omega0_file = file_omega0_rad(system, eph.omega0_rad, eph.toe_gps_s)
        week_start = system_week_start_gps_s(system, eph.toe_gps_s)
        week = np.round((week_start - SYSTEMS[system].week0_gps_s) / SECONDS_PER_WEEK)
        toe_sow = eph.toe_gps_s - week_start
        ttr = np.maximum(toe_sow - 3600.0, 0.0)
        tgd2 = np.asarray(tgd2_s.get(system, np.zeros(len(eph))))
        for i in order:
            toc_sys = eph.toc_gps_s[i] + (BDT_MINUS_GPST_S if system == "C" else 0.0)
            t = _calendar(toc_sys)
            head = f"{eph.sv[i]:3s} {t:%Y %m %d %H %M %S}"
            rows = [
                [eph.af0_s[i], eph.af1_s_s[i], eph.af2_s_s2[i]],
                [eph.iode[i], eph.crs_m[i], eph.delta_n_rad_s[i], eph.m0_rad[i]],
                [eph.cuc_rad[i], eph.e[i], eph.cus_rad[i], eph.sqrt_a_sqrt_m[i]],
                [toe_sow[i], eph.cic_rad[i], omega0_file[i], eph.cis_rad[i]],
                [eph.i0_rad[i], eph.crc_m[i], eph.omega_rad[i], eph.omega_dot_rad_s[i]],
            ]
            if system == "G":
                rows += [
                    [eph.idot_rad_s[i], 1.0, week[i], 0.0],
                    [2.0, eph.health[i], eph.tgd_s[i], eph.iode[i]],
                    [ttr[i], eph.fit_interval_h[i]],
                ]
            elif system == "J":  # L2C on L2, L2 P data flag 1; fit interval flag 0 (2 h, readers take 4 h)
                rows += [
                    [eph.idot_rad_s[i], 2.0, week[i], 1.0],
                    [2.0, eph.health[i], eph.tgd_s[i], eph.iode[i]],
                    [ttr[i], 0.0],
                ]
            elif system == "E":
                rows += [
                    [eph.idot_rad_s[i], 517.0, week[i], 0.0],
                    [3.12, eph.health[i], eph.tgd_s[i], eph.tgd_s[i]],
                    [ttr[i]],
                ]
            else:
                rows += [
                    [eph.idot_rad_s[i], 0.0, week[i], 0.0],
                    [2.0, eph.health[i], eph.tgd_s[i], tgd2[i]],
                    [ttr[i], eph.iode[i]],
                ]
            lines.append(head + "".join(_d19(v) for v in rows[0]) + "\n")
            lines.extend("    " + "".join(_d19(v) for v in row) + "\n" for row in rows[1:])
    Path(path).write_text("".join(lines), encoding="ascii")


def obs_codes(system: str, layout: ObsLayout, *, phase: bool = False) -> list[str]:
    """RINEX 3 observation codes written for a system, in file order (``phase``: with the carrier
    phase of each signal after its pseudorange)."""
    c1, c2 = SYSTEMS[system].codes
    codes = [c1]
    if phase:
        codes.append("L" + c1[1:])
    if layout.doppler:
        codes.append("D" + c1[1:])
    if layout.snr:
        codes.append("S" + c1[1:])
    if layout.dual_frequency:
        codes.append(c2)
        if phase:
            codes.append("L" + c2[1:])
        if layout.doppler:
            codes.append("D" + c2[1:])
        if layout.snr:
            codes.append("S" + c2[1:])
    return codes


def _obs_values(obs: Observations, code_kind: str, signal: int) -> F64:
    if code_kind == "C":
        return obs.pseudorange_m[..., signal]
    if code_kind == "D":
        return obs.doppler_hz[..., signal]
    if code_kind == "L" and obs.phase_cycles is not None:
        return obs.phase_cycles[..., signal]
    return obs.snr_dbhz[..., signal]


def _ssi(snr_dbhz: F64) -> NDArray[np.int64]:
    """RINEX signal-strength indicator 1..9 from C/N0 (dB-Hz / 6)."""
    return np.clip(np.floor(snr_dbhz / 6.0), 1, 9).astype(np.int64)


def _field(value: float, ssi: int | None, lli: bool = False) -> str:
    """F14.3, the loss-of-lock indicator (``1``: lost lock, cycle slip possible; blank) and the SSI."""
    text = f"{value:14.3f}"
    if len(text) > 14:
        raise UsageError(f"observation value {value} does not fit the RINEX F14.3 field")
    return text + ("1" if lli else " ") + (str(ssi) if ssi is not None else " ")


def _header_common(
    start_gps_s: float, end_gps_s: float, interval_s: float, approx_ecef_m: F64, marker: str
) -> tuple[list[str], list[str]]:
    first, last = _calendar(start_gps_s), _calendar(end_gps_s)

    def tline(t: dt.datetime, label: str) -> str:
        sec = t.second + t.microsecond * 1e-6
        return _hline(f"{t.year:6d}{t.month:6d}{t.day:6d}{t.hour:6d}{t.minute:6d}{sec:13.7f}     GPS", label)

    before = [
        _pgm_line(start_gps_s),
        _hline(marker, "MARKER NAME"),
        _hline(f"{'simulation':20s}{AGENCY:40s}", "OBSERVER / AGENCY"),
        _hline(f"{'0':20s}{PROGRAM:20s}{'0.1.0':20s}", "REC # / TYPE / VERS"),
        _hline(f"{'0':20s}{'SIMULATED       NONE':20s}", "ANT # / TYPE"),
        _hline("".join(f"{v:14.4f}" for v in approx_ecef_m), "APPROX POSITION XYZ"),
        _hline("".join(f"{0.0:14.4f}" for _ in range(3)), "ANTENNA: DELTA H/E/N"),
    ]
    after = [
        _hline(f"{interval_s:10.3f}", "INTERVAL"),
        tline(first, "TIME OF FIRST OBS"),
        tline(last, "TIME OF LAST OBS"),
    ]
    return before, after


def write_obs_rinex3(
    path: Path,
    obs: Observations,
    approx_ecef_m: F64,
    interval_s: float,
    *,
    layout: ObsLayout = ObsLayout(),
    version: str = "3.04",
    marker: str = "SIM",
) -> None:
    """Write the visible observations as a RINEX 3.04 (or 3.05) observation file.

    Parameters
    ----------
    path
        Output file.
    obs
        Simulated observables (``visible`` selects what is written; epochs without any visible
        satellite are written with 0 satellites). Carrier phases (``L1C`` ...) are written when
        ``obs.phase_cycles`` is set, their loss-of-lock indicators from ``obs.urban.slip``.
    approx_ecef_m
        APPROX POSITION XYZ ``(3,)``, m.
    interval_s
        INTERVAL header value, s.
    layout
        Which observations to write.
    version
        ``'3.04'`` or ``'3.05'``.
    marker
        MARKER NAME.
    """
    systems = [s for s in "GECJ" if np.any(np.char.startswith(obs.sv, s))]
    sys_char = systems[0] if len(systems) == 1 else "M"
    before, after = _header_common(obs.t_gps_s[0], obs.t_gps_s[-1], interval_s, approx_ecef_m, marker)
    lines = [
        _hline(f"{float(version):9.2f}{'':11s}{'OBSERVATION DATA':20s}{sys_char:20s}", "RINEX VERSION / TYPE"),
        *before[:2],
        _hline("NON_PHYSICAL", "MARKER TYPE"),
        *before[2:],
    ]
    codes_by_sys = {s: obs_codes(s, layout, phase=obs.phase_cycles is not None) for s in systems}
    for s in systems:
        codes = codes_by_sys[s]
        for k in range(0, len(codes), 13):
            chunk = "".join(f" {c}" for c in codes[k : k + 13])
            lines.append(_hline((f"{s}  {len(codes):3d}" if k == 0 else " " * 6) + chunk, "SYS / # / OBS TYPES"))
    if layout.snr:
        lines.append(_hline("DBHZ", "SIGNAL STRENGTH UNIT"))
    lines += after
    lines.append(_hline("", "END OF HEADER"))
    sys_of = np.array([s[0] for s in obs.sv])
    columns = {
        s: [(c[0], 0 if c[1:] == SYSTEMS[s].codes[0][1:] else 1) for c in codes_by_sys[s]] for s in systems
    }
    values = {
        s: np.stack([_obs_values(obs, kind, sig) for kind, sig in columns[s]], axis=-1) for s in systems
    }  # each (T, n, k)
    ssi = _ssi(obs.snr_dbhz)
    slip = obs.urban.slip if obs.urban is not None else np.zeros(obs.visible.shape, dtype=bool)
    order = np.argsort(obs.sv, kind="stable")
    for ti, t in enumerate(obs.t_gps_s):
        vis = [j for j in order if obs.visible[ti, j]]
        cal = _calendar(t)
        sec = cal.second + cal.microsecond * 1e-6
        lines.append(f"> {cal:%Y %m %d %H %M}{sec:11.7f}  0{len(vis):3d}\n")
        for j in vis:
            s = sys_of[j]
            fields = [
                _field(values[s][ti, j, k], int(ssi[ti, j, sig]) if kind == "C" else None, kind == "L" and bool(slip[ti, j]))
                for k, (kind, sig) in enumerate(columns[s])
            ]
            lines.append((obs.sv[j] + "".join(fields)).rstrip() + "\n")
    Path(path).write_text("".join(lines), encoding="ascii")


def write_obs_rinex2(
    path: Path,
    obs: Observations,
    approx_ecef_m: F64,
    interval_s: float,
    *,
    layout: ObsLayout = ObsLayout(),
    marker: str = "SIM",
) -> None:
    """Write the visible observations as a RINEX 2.11 observation file.

    GPS: ``C1`` (and ``P2``), Galileo: ``C1`` (and ``C7``); ``D1``/``S1`` when asked. One list of
    types serves all systems; an observation a system lacks is blank.

    Raises
    ------
    UsageError
        For BeiDou and QZSS, which RINEX 2.11 does not define.
    """
    systems = [s for s in "GECJ" if np.any(np.char.startswith(obs.sv, s))]
    if "C" in systems or "J" in systems:
        raise UsageError("RINEX 2.11 does not define BeiDou or QZSS observations: use --rinex-version 3")
    types: list[tuple[str, dict[str, tuple[str, int]]]] = [("C1", {s: ("C", 0) for s in systems})]
    if layout.dual_frequency:
        for s in systems:
            code = SYSTEMS[s].rinex2_codes[1]
            existing = [t for t in types if t[0] == code]
            if existing:
                existing[0][1][s] = ("C", 1)
            else:
                types.append((code, {s: ("C", 1)}))
    if layout.doppler:
        types.append(("D1", {s: ("D", 0) for s in systems}))
    if layout.snr:
        types.append(("S1", {s: ("S", 0) for s in systems}))
    sys_char = {"G": "G (GPS)", "E": "E (GALILEO)"}.get(systems[0], "") if len(systems) == 1 else "M (MIXED)"
    before, after = _header_common(obs.t_gps_s[0], obs.t_gps_s[-1], interval_s, approx_ecef_m, marker)
    lines = [
        _hline(f"{2.11:9.2f}{'':11s}{'OBSERVATION DATA':20s}{sys_char:20s}", "RINEX VERSION / TYPE"),
        *before,
        _hline(f"{1:6d}{1:6d}", "WAVELENGTH FACT L1/2"),
    ]
    names = [t[0] for t in types]
    for k in range(0, len(names), 9):
        body = (f"{len(names):6d}" if k == 0 else " " * 6) + "".join(f"    {n}" for n in names[k : k + 9])
        lines.append(_hline(body, "# / TYPES OF OBSERV"))
    lines += after
    lines.append(_hline("", "END OF HEADER"))
    ssi = _ssi(obs.snr_dbhz)
    order = np.argsort(obs.sv, kind="stable")
    for ti, t in enumerate(obs.t_gps_s):
        vis = [j for j in order if obs.visible[ti, j]]
        cal = _calendar(t)
        sec = cal.second + cal.microsecond * 1e-6
        head = f" {cal.year % 100:02d} {cal.month:2d} {cal.day:2d} {cal.hour:2d} {cal.minute:2d}{sec:11.7f}  0{len(vis):3d}"
        ids = [obs.sv[j] for j in vis]
        lines.append(head + "".join(ids[:12]) + "\n")
        for k in range(12, len(ids), 12):
            lines.append(" " * 32 + "".join(ids[k : k + 12]) + "\n")
        for j in vis:
            s = obs.sv[j][0]
            fields = []
            for _, per_sys in types:
                if s not in per_sys:
                    fields.append(" " * 16)
                    continue
                kind, sig = per_sys[s]
                value = float(_obs_values(obs, kind, sig)[ti, j])
                fields.append(_field(value, int(ssi[ti, j, sig]) if kind == "C" else None))
            for k in range(0, len(fields), 5):
                lines.append("".join(fields[k : k + 5]).rstrip() + "\n")
    Path(path).write_text("".join(lines), encoding="ascii")

