"""Broadcast Keplerian orbits and clocks of Galileo, BeiDou and QZSS (and GPS, for dispatch).

The Keplerian systems share :class:`~gnss_cli.gnss.ephemeris.KeplerEphemeris` and the
IS-GPS-200 evaluation of :func:`~gnss_cli.gnss.orbits.broadcast_states`; they differ in

* constants: GPS/QZSS ``GM = 3.986005e14``, ``wE = 7.2921151467e-5``; Galileo
  ``GM = 3.986004418e14`` (Galileo OS SIS ICD 5.1.1); BeiDou CGCS2000 ``GM = 3.986004418e14``,
  ``wE = 7.292115e-5`` (BDS-SIS-ICD-B1I 5.2.4);
* time scale: GST is aligned with GPST; BDT = GPST - 14 s. Inside the tables every time is
  GPS seconds (:mod:`gnss_cli.gnss.time`); BeiDou is evaluated in BDT internally because
  ``Omega0`` refers to the start of the BDT week;
* group delay for single-frequency users: GPS/QZSS TGD (L1 C/A), Galileo BGD(E1,E5b) (E1),
  BeiDou TGD1 (B1I);
* BeiDou GEO satellites (C01-C05, C59-C63): the node is not rotated with the Earth; the
  position in the inertial-like frame is rotated by -5 deg about x, then by ``wE tk``
  about z (BDS-SIS-ICD-B1I Table 5-11);
* record selection: GPS/QZSS nearest toe within half the fit interval
  (:func:`~gnss_cli.gnss.ephemeris.select_ephemeris`), the later toe at a tie; BeiDou
  nearest toe within 4 h on either side (as RTKLIB); Galileo records are fitted forward
  from toe, so the latest record with ``toe <= t`` and ``t - toe`` at most 3 h
  (:data:`GAL_MAX_AGE_S`, :func:`select_forward_ephemeris`);
* health: the selected record's health decides, an older healthy record never replaces
  an unhealthy one (RTKLIB); QZSS health is masked with :data:`QZSS_L1_HEALTH_MASK`.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import xarray as xr
from numpy.typing import NDArray

from gnss_cli.constants import (
    BDT_MINUS_GPST_S,
    GM_GAL_M3_S2,
    GM_GPS_M3_S2,
    OMEGA_E_BDS_RAD_S,
    OMEGA_E_RAD_S,
    SECONDS_PER_WEEK,
)
from gnss_cli.errors import RinexFormatError, UsageError
from gnss_cli.gnss.ephemeris import KeplerEphemeris, records_by_satellite, select_ephemeris, select_nearest_record
from gnss_cli.gnss.orbits import SatelliteStates, broadcast_states

F64 = NDArray[np.float64]

KEPLER_SYSTEMS = ("G", "E", "C", "J")
"""RINEX system letters whose broadcast orbits are Keplerian (handled here)."""

BDS_GEO_PRNS = frozenset((1, 2, 3, 4, 5, 59, 60, 61, 62, 63))
"""BeiDou PRNs of geostationary satellites (RTKLIB convention, BDS-3 GEO from 59)."""

GAL_DATASRC_INAV = 0b101  # bit 0 I/NAV E1-B, bit 2 I/NAV E5b-I
GAL_DATASRC_FNAV = 0b010  # bit 1 F/NAV E5a-I

GAL_MAX_AGE_S = 3.0 * 3600.0
"""Longest time after toe a Galileo record is used by default, s.

The records are valid for 4 h, but they are refreshed every 10 min: a record older than
3 h means a data gap, and on esbc-2020177 ages of 3-4 h reach 7 m against precise orbits
(max 1.34 m up to 3 h)."""

BDS_MAX_AGE_S = 4.0 * 3600.0
"""Longest ``|t - toe|`` a BeiDou record is used, s (records are hourly; RTKLIB allows 6 h)."""

_SIN_M5 = np.sin(np.deg2rad(-5.0))
_COS_M5 = np.cos(np.deg2rad(-5.0))

_CONSTANTS = {
    "G": (GM_GPS_M3_S2, OMEGA_E_RAD_S),
    "J": (GM_GPS_M3_S2, OMEGA_E_RAD_S),
    "E": (GM_GAL_M3_S2, OMEGA_E_RAD_S),
    "C": (GM_GAL_M3_S2, OMEGA_E_BDS_RAD_S),
}


def system_constants(system: str) -> tuple[float, float]:
    """``(GM m^3/s^2, omega_E rad/s)`` of a Keplerian system (``'G' 'E' 'C' 'J'``).

    Raises
    ------
    UsageError
        For a system letter that is not Keplerian.
    """
    if system not in _CONSTANTS:
        raise UsageError(f"system must be one of {KEPLER_SYSTEMS}, got {system!r}")
    return _CONSTANTS[system]


def is_bds_geo(sv: NDArray[np.str_]) -> NDArray[np.bool_]:
    """True for BeiDou GEO satellite ids (``'C01'``-``'C05'``, ``'C59'``-``'C63'``)."""
    s = np.asarray(sv).astype(str)
    out = np.zeros(s.shape, dtype=bool)
    for i, name in np.ndenumerate(s):
        out[i] = name[:1] == "C" and name[1:3].isdigit() and int(name[1:3]) in BDS_GEO_PRNS
    return out


def ephemeris_for_system(nav: xr.Dataset, system: str) -> KeplerEphemeris:
    """Keplerian records of one system from a georinex-layout navigation dataset.

    Parameters
    ----------
    nav
        Dataset with dims ``(time, sv)`` as :func:`gnss_cli.io.rinex.read_nav` returns;
        ``time`` is the toc in the system's own time scale, as written in RINEX.
    system
        ``'G'`` (GPS), ``'J'`` (QZSS), ``'E'`` (Galileo) or ``'C'`` (BeiDou).

    Returns
    -------
    KeplerEphemeris
        Times in GPS seconds. Galileo: I/NAV records only when any satellite has I/NAV
        (``DataSrc`` bit 0 or 2), else F/NAV; ``tgd_s`` = BGD(E1,E5b) for I/NAV,
        BGD(E1,E5a) for F/NAV, ``tgd2_s`` the other BGD, ``fnav`` True for F/NAV; the
        georinex suffix (``'E01_1'``) is dropped from ids.
        BeiDou: toc/toe converted from BDT to GPST (+14 s), ``tgd_s`` = TGD1 (B1I),
        ``tgd2_s`` = TGD2 (B2I), ``health`` = SatH1.

    Raises
    ------
    UsageError
        For an unknown system letter.
    RinexFormatError
        When a required variable is missing.
    """
    system_constants(system)
    if system in ("G", "J"):
        return KeplerEphemeris.from_dataset(nav, system)
    svs = np.asarray(nav["sv"].values).astype(str)
    keep = np.char.startswith(svs, system)
    if not keep.any():
        return KeplerEphemeris.empty()
    sub = nav.isel(sv=np.flatnonzero(keep))
    if system == "E":
        need = ["DataSrc", "BGDe5a", "BGDe5b", "health"]
    else:
        need = ["TGD1", "SatH1"]
    missing = [n for n in need if n not in sub]
    if missing:
        raise RinexFormatError(f"{nav.attrs.get('filename', 'navigation data')}: missing ephemeris fields {missing}")
    extra = sub.copy()
    if system == "E":
        src = np.nan_to_num(sub["DataSrc"].values, nan=0.0).astype(np.int64)
        inav = (src & GAL_DATASRC_INAV) != 0
        fnav = (src & GAL_DATASRC_FNAV) != 0
        use_inav = bool(inav.any())
        chosen = inav if use_inav else fnav
        tgd = np.where(inav, sub["BGDe5b"].values, sub["BGDe5a"].values)
        extra["TGD"] = (("time", "sv"), np.where(chosen, tgd, np.nan))
        extra["TGD2"] = (("time", "sv"), np.where(inav, sub["BGDe5a"].values, sub["BGDe5b"].values))
        extra["FNAV"] = (("time", "sv"), np.where(inav, 0.0, 1.0))
        extra["sqrtA"] = (("time", "sv"), np.where(chosen, sub["sqrtA"].values, np.nan))
        if "SISA" in sub:
            extra["SVacc"] = sub["SISA"]  # signal-in-space accuracy, m: KeplerEphemeris.ura_m
        # Health bits 0-8 (E1-B / E5b / E5a DVS and HS); 0 = healthy.
        extra["health"] = sub["health"]
        if "IODnav" in sub:
            extra["IODE"] = sub["IODnav"]
        eph = KeplerEphemeris.from_dataset(extra, system)
        return replace(eph, sv=np.array([s[:3] for s in eph.sv.astype(str)], dtype="<U3"))
    # BeiDou
    extra["TGD"] = sub["TGD1"]
    extra["health"] = sub["SatH1"]
    if "AODE" in sub:
        extra["IODE"] = sub["AODE"]
    eph = KeplerEphemeris.from_dataset(extra, system)
    # from_dataset took toc and the week from the BDT-labelled epoch: shift to GPST.
    shift = -BDT_MINUS_GPST_S
    eph = replace(eph, toc_gps_s=eph.toc_gps_s + shift, toe_gps_s=eph.toe_gps_s + shift,
                  sv=np.array([s[:3] for s in eph.sv.astype(str)], dtype="<U3"))
    return eph


def select_forward_ephemeris(
    eph: KeplerEphemeris,
    sv: NDArray[np.str_],
    t_gps_s: F64,
    *,
    max_age_s: float = GAL_MAX_AGE_S,
    healthy_only: bool = True,
) -> NDArray[np.intp]:
    """Index of the latest record with ``toe <= t <= toe + max_age_s`` (-1: none).

    Parameters
    ----------
    eph
        Ephemeris table.
    sv
        Satellite ids, shape ``(n,)``.
    t_gps_s
        Epochs, shape ``(T,)``, s since the GPS epoch.
    max_age_s
        Longest use after toe, s (default 4 h).
    healthy_only
        Skip records with non-zero health.

    Returns
    -------
    ndarray of intp, shape ``(T, n)``

    Notes
    -----
    Galileo and BeiDou broadcast records are fitted over the interval that starts at
    their toe; using a record before its toe gives errors of tens of metres.
    """
    t = np.asarray(t_gps_s, dtype=np.float64)
    out = np.full((t.shape[0], len(sv)), -1, dtype=np.intp)
    for j, rows in records_by_satellite(eph.sv, eph.health, sv, healthy_only=False):
        # latest toe; among equal toe the latest toc (last transmitted)
        order = np.lexsort((eph.toc_gps_s[rows], eph.toe_gps_s[rows]))
        rows = rows[order]
        toe = eph.toe_gps_s[rows]
        pos = np.searchsorted(toe, t + 1e-6, side="right") - 1
        ok = pos >= 0
        pos_c = np.where(ok, pos, 0)
        ok &= t - toe[pos_c] <= max_age_s + 1e-6
        if healthy_only:  # the record in force is unhealthy: no older record replaces it
            ok &= eph.health[rows[pos_c]] == 0
        out[:, j] = np.where(ok, rows[pos_c], -1)
    return out


QZSS_L1_HEALTH_MASK = 0xFE
"""Bits of the QZSS health word that concern L1 C/A positioning (RTKLIB's mask: bit 0,
the L1C health flag of IS-QZSS, is ignored)."""


def select_system_ephemeris(
    eph: KeplerEphemeris, sv: NDArray[np.str_], t_gps_s: F64, system: str, *, healthy_only: bool = True
) -> NDArray[np.intp]:
    """Record per epoch and satellite with the system's rule (see the module notes).

    Returns
    -------
    ndarray of intp, shape ``(T, n)``; -1 where no record is usable.
    """
    system_constants(system)
    if system == "E":
        return select_forward_ephemeris(eph, sv, t_gps_s, max_age_s=GAL_MAX_AGE_S, healthy_only=healthy_only)
    if system == "C":  # nearest toe on either side, as RTKLIB
        return select_nearest_record(eph.sv, eph.toe_gps_s, eph.health, BDS_MAX_AGE_S, sv, t_gps_s,
                                     healthy_only=healthy_only)
    if system == "J":
        health = np.nan_to_num(eph.health, nan=1.0).astype(np.int64) & QZSS_L1_HEALTH_MASK
        eph = replace(eph, health=health.astype(np.float64))
    return select_ephemeris(eph, sv, t_gps_s, healthy_only=healthy_only)


def system_states(
    eph: KeplerEphemeris,
    idx: NDArray[np.intp],
    t_gps_s: F64,
    system: str,
    clock_only: bool = False,
) -> SatelliteStates:
    """Positions, velocities and clocks of one Keplerian system at GPS times ``t_gps_s``.

    Parameters
    ----------
    eph
        Records of ``system`` (:func:`ephemeris_for_system`), times in GPS seconds.
    idx
        Record index per element, any shape; -1 = no record (NaN, ``valid`` False).
    t_gps_s
        Times (shape of ``idx``), s since the GPS epoch (GPST).
    system
        ``'G' 'J' 'E' 'C'``.
    clock_only
        Clocks only; positions and velocities NaN (:func:`~gnss_cli.gnss.orbits.broadcast_states`).

    Returns
    -------
    SatelliteStates
        ECEF (WGS-84 / GTRF / CGCS2000, equal at this level) position m, velocity m/s,
        clock s (incl. relativistic term, excl. group delay), ``tgd_s`` the
        single-frequency group delay of the system (see the module notes).

    Notes
    -----
    BeiDou GEO (BDS-SIS-ICD-B1I 5.2.4.12): ``Omega = Omega0 + OmegaDot tk - wE toe``;
    ``r_GK`` from the orbital plane as usual; ``r = Rz(wE tk) Rx(-5 deg) r_GK``.

    Raises
    ------
    UsageError
        For an unknown system letter or a shape mismatch.
    """
    gm, we = system_constants(system)
    idx = np.asarray(idx)
    t = np.asarray(t_gps_s, dtype=np.float64)
    try:
        t = np.broadcast_to(t, idx.shape)
    except ValueError:
        raise UsageError(f"t_gps_s shape {np.shape(t_gps_s)} does not broadcast to idx shape {idx.shape}") from None
    if system != "C":
        return broadcast_states(eph, idx, t, gm_m3_s2=gm, omega_e_rad_s=we, clock_only=clock_only)
    # BeiDou: evaluate in BDT (Omega0 refers to the BDT week).
    d = BDT_MINUS_GPST_S
    eph_bdt = replace(eph, toc_gps_s=eph.toc_gps_s + d, toe_gps_s=eph.toe_gps_s + d)
    t_bdt = t + d
    geo_rec = is_bds_geo(eph.sv) if len(eph) else np.zeros(0, dtype=bool)
    valid = idx >= 0
    geo = valid & (geo_rec[np.where(valid, idx, 0)] if len(eph) else False)
    meo = broadcast_states(eph_bdt, np.where(geo, -1, idx), t_bdt, gm_m3_s2=gm, omega_e_rad_s=we, clock_only=clock_only)
    if not geo.any():
        return meo
    # GEO: node not rotating with the Earth -> evaluate with omega_E = 0 and the
    # -wE toe_sow term folded into Omega0, then rotate.
    toe_sow = np.mod(eph_bdt.toe_gps_s, SECONDS_PER_WEEK)
    eph_geo = replace(eph_bdt, omega0_rad=eph_bdt.omega0_rad - we * toe_sow)
    gk = broadcast_states(eph_geo, np.where(geo, idx, -1), t_bdt, gm_m3_s2=gm, omega_e_rad_s=0.0, clock_only=clock_only)
    k = np.where(geo, idx, 0)
    tk = t_bdt - eph_bdt.toe_gps_s[k]
    so, co = np.sin(we * tk), np.cos(we * tk)
    xg, yg, zg = gk.pos_ecef_m[..., 0], gk.pos_ecef_m[..., 1], gk.pos_ecef_m[..., 2]
    vxg, vyg, vzg = gk.vel_ecef_m_s[..., 0], gk.vel_ecef_m_s[..., 1], gk.vel_ecef_m_s[..., 2]
    # Rx(-5 deg): y' = y cos + z sin(5) ... with phi = -5 deg: y' = c y + s z, z' = -s y + c z
    y1 = _COS_M5 * yg + _SIN_M5 * zg
    z1 = -_SIN_M5 * yg + _COS_M5 * zg
    vy1 = _COS_M5 * vyg + _SIN_M5 * vzg
    vz1 = -_SIN_M5 * vyg + _COS_M5 * vzg
    x = co * xg + so * y1
    y = -so * xg + co * y1
    vx = co * vxg + so * vy1 + we * (-so * xg + co * y1)
    vy = -so * vxg + co * vy1 + we * (-co * xg - so * y1)
    pos = np.where(geo[..., None], np.stack([x, y, z1], axis=-1), meo.pos_ecef_m)
    vel = np.where(geo[..., None], np.stack([vx, vy, vz1], axis=-1), meo.vel_ecef_m_s)
    return SatelliteStates(
        pos,
        vel,
        np.where(geo, gk.clock_s, meo.clock_s),
        np.where(geo, gk.tgd_s, meo.tgd_s),
        np.where(geo, gk.relativistic_s, meo.relativistic_s),
        valid,
    )
