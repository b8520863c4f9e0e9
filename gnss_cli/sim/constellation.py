"""Nominal GPS, Galileo, BeiDou-MEO and QZSS constellations as exactly representable broadcast records.

Every simulated satellite flies ONE orbit: a Keplerian ellipse with the secular drifts of
the broadcast model (``delta_n``, ``OmegaDot``, ``IDOT``) and constant second-harmonic
corrections, fixed by its elements at the start of the GPS week of the simulation. It is
issued as broadcast records every ``issue_interval_s`` (2 h, toc = toe) in which only the
reference-time terms (``toe``, ``m0``, ``omega0``, ``i0`` and the clock polynomial) change,
so consecutive issues describe the same orbit and the same clock. Each element is rounded
to the 13 significant digits of the RINEX ``D19.12`` field *before* use, so
:func:`gnss_cli.gnss.orbits.broadcast_states` applied to the truth table IS the truth, and
a reader of the written navigation file recovers it to ~1e-5 m.

Times in a :class:`~gnss_cli.gnss.ephemeris.KeplerEphemeris` are GPS seconds. BeiDou
records are written in BDT (GPST - 14 s, weeks counted from 2006-01-01); the node longitude
``omega0`` of the table refers to the GPS week start and the written one to the BDT week
start (they differ by ``14 s * omega_e``): :func:`file_omega0_rad` converts. QZSS records
are GPS LNAV records (IS-QZSS-PNT) in GPS time: QZSS time is steered to GPS time, and the
simulator gives both the same receiver clock.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from gnss_cli.constants import (
    FREQ_B1I_HZ,
    FREQ_E5B_HZ,
    FREQ_L1_HZ,
    FREQ_L2_HZ,
    GM_GAL_M3_S2,
    GM_GPS_M3_S2,
    OMEGA_E_BDS_RAD_S,
    OMEGA_E_RAD_S,
    SECONDS_PER_WEEK,
)
from gnss_cli.errors import UsageError
from gnss_cli.gnss.ephemeris import KeplerEphemeris
from gnss_cli.gnss.orbits import solve_kepler

F64 = NDArray[np.float64]

BDT_WEEK0_GPS_S = 1356 * SECONDS_PER_WEEK + 14.0
"""Start of BDT week 0 (2006-01-01 00:00:00 BDT) in GPS seconds."""

FREQ_B2I_HZ = 1_207.14e6
"""BeiDou B2I carrier frequency, Hz."""


@dataclass(frozen=True)
class SystemSpec:
    """Constants and signals of one simulated constellation.

    Attributes
    ----------
    char : RINEX system letter.
    gm_m3_s2, omega_e_rad_s : the system's broadcast-orbit constants.
    week0_gps_s : start of the system's week 0 in GPS seconds (0 for GPS and Galileo).
    codes : RINEX 3 codes of the first and second pseudorange (``C1C``, ``C2W`` ...).
    freqs_hz : carrier frequencies of the two signals, Hz.
    rinex2_codes : the RINEX 2.11 observation types of the two signals.
    """

    char: str
    gm_m3_s2: float
    omega_e_rad_s: float
    week0_gps_s: float
    codes: tuple[str, str]
    freqs_hz: tuple[float, float]
    rinex2_codes: tuple[str, str]


SYSTEMS: dict[str, SystemSpec] = {
    "G": SystemSpec("G", GM_GPS_M3_S2, OMEGA_E_RAD_S, 0.0, ("C1C", "C2W"), (FREQ_L1_HZ, FREQ_L2_HZ), ("C1", "P2")),
    "E": SystemSpec("E", GM_GAL_M3_S2, OMEGA_E_RAD_S, 0.0, ("C1C", "C7Q"), (FREQ_L1_HZ, FREQ_E5B_HZ), ("C1", "C7")),
    "C": SystemSpec(
        "C", GM_GAL_M3_S2, OMEGA_E_BDS_RAD_S, BDT_WEEK0_GPS_S, ("C2I", "C7I"), (FREQ_B1I_HZ, FREQ_B2I_HZ), ("C2", "C7")
    ),
    "J": SystemSpec("J", GM_GPS_M3_S2, OMEGA_E_RAD_S, 0.0, ("C1C", "C2L"), (FREQ_L1_HZ, FREQ_L2_HZ), ("C1", "C2")),
}
"""Simulated systems. Galileo's second signal is E5b (the I/NAV clock pair), BeiDou's B2I,
QZSS's L2C (QZSS has no L2 P(Y))."""

QZSS_QZO_PRNS = (1, 2, 3)
"""RINEX PRNs of the simulated quasi-zenith (inclined geosynchronous) satellites (QZS-1, -2, -4)."""
QZSS_GEO_PRN = 7
"""RINEX PRN of the simulated geostationary QZSS satellite (QZS-3, PRN 199)."""
QZSS_APOGEE_LON_DEG = 139.0
"""East longitude of the QZO ground track's northern apogee (the figure eight over Japan), deg."""
QZSS_GEO_LON_DEG = 127.0
"""East longitude of the QZSS GEO, deg."""


@dataclass(frozen=True)
class Constellation:
    """One orbit and one clock per satellite, at the reference epoch ``t_ref_gps_s``.

    Arrays have shape ``(n,)``. ``raan_rad`` is the node's inertial longitude measured from
    the Greenwich meridian at ``t_ref_gps_s`` (a GPS week start), ``m_ref_rad`` the mean anomaly
    at that epoch; clocks are ``af0 + af1 (t - t_ref)`` (s).
    """

    system: str
    sv: NDArray[np.str_]
    t_ref_gps_s: float
    sqrt_a_sqrt_m: F64
    e: F64
    i_ref_rad: F64
    raan_rad: F64
    omega_rad: F64
    m_ref_rad: F64
    delta_n_rad_s: F64
    idot_rad_s: F64
    omega_dot_rad_s: F64
    cuc_rad: F64
    cus_rad: F64
    crc_m: F64
    crs_m: F64
    cic_rad: F64
    cis_rad: F64
    af0_s: F64
    af1_s_s: F64
    tgd_s: F64
    tgd2_s: F64


def _walker(n_planes: int, per_plane: int, phasing: int) -> tuple[F64, F64]:
    """Node longitudes and mean anomalies (rad) of a Walker ``t/p/f`` pattern, plane-major order."""
    total = n_planes * per_plane
    plane = np.repeat(np.arange(n_planes), per_plane)
    slot = np.tile(np.arange(per_plane), n_planes)
    raan = 2.0 * np.pi * plane / n_planes
    anomaly = 2.0 * np.pi * slot / per_plane + 2.0 * np.pi * phasing * plane / total
    return raan, anomaly


def nominal_constellation(system: str, t_ref_gps_s: float, *, seed: int = 2024) -> Constellation:
    """A realistic nominal constellation of one system.

    Parameters
    ----------
    system
        ``'G'`` (31 satellites: 6 planes at 55 deg, a = 26,560 km, a Walker 30/6/2 pattern plus
        G31 in plane A), ``'E'`` (Walker 24/3/1 at 56 deg,
        a = 29,600 km), ``'C'`` (BeiDou-3 MEO, Walker 24/3/1 at 55 deg, a = 27,906 km) or ``'J'``
        (QZSS: J01-J03 on one figure-eight ground track over Japan, J07 geostationary; see
        :func:`_qzss_constellation`).
    t_ref_gps_s
        Reference epoch, s since the GPS epoch; it should be a GPS week start.
    seed
        Seed of the generator that spreads eccentricities, harmonics and clock terms: the
        constellation is a fixed design, independent of the scenario's noise seed.

    Returns
    -------
    Constellation

    Raises
    ------
    UsageError
        For an unknown system letter.

    Notes
    -----
    Eccentricities 0.001-0.02, ``delta_n`` ~ 4e-9 rad/s, ``OmegaDot`` ~ -8e-9 rad/s,
    harmonic corrections of the broadcast magnitudes (``crc`` ~ 200 m), clock offsets up to
    0.5 ms, drifts up to 5e-12 s/s, group delays up to 15 ns, quantized to the broadcast
    resolutions (2^-31 s, 2^-43 s/s, 2^-31 s; BeiDou TGD 0.1 ns).
    """
    if system not in SYSTEMS:
        raise UsageError(f"unknown system {system!r}: expected one of {sorted(SYSTEMS)}")
    rng = np.random.default_rng([seed, ord(system)])
    if system == "J":
        return _qzss_constellation(t_ref_gps_s, rng)
    if system == "G":
        raan, anom = _walker(6, 5, 2)
        raan = np.append(raan, raan[0])
        anom = np.append(anom, anom[0] + np.pi / 5.0)
        prn = np.arange(1, raan.size + 1)
        a_m, inc_deg = 26_559_700.0, 55.0
    elif system == "E":
        raan, anom = _walker(3, 8, 1)
        prn = np.arange(1, 25)
        a_m, inc_deg = 29_600_318.0, 56.0
    else:
        raan, anom = _walker(3, 8, 1)
        prn = np.r_[19:31, 32:38, 41:47]
        a_m, inc_deg = 27_906_100.0, 55.0
    n = raan.size
    sv = np.array([f"{system}{p:02d}" for p in prn])

    def u(lo: float, hi: float) -> F64:
        return rng.uniform(lo, hi, n)

    def quant(x: F64, step: float) -> F64:
        return np.round(x / step) * step

    e = u(0.001, 0.02)
    omega = u(-np.pi, np.pi)
    # place the satellite's argument of latitude at the Walker slot
    m_ref = np.mod(anom - omega + np.pi, 2.0 * np.pi) - np.pi
    tgd2 = quant(u(-15e-9, 15e-9), 1e-10)
    tgd = quant(u(-15e-9, 15e-9), 2.0**-31 if system == "G" else 1e-10)
    return Constellation(
        system=system,
        sv=sv,
        t_ref_gps_s=float(t_ref_gps_s),
        sqrt_a_sqrt_m=np.sqrt(a_m + u(-2000.0, 2000.0)),
        e=e,
        i_ref_rad=np.deg2rad(inc_deg + u(-1.5, 1.5)),
        raan_rad=raan + u(-0.02, 0.02),
        omega_rad=omega,
        m_ref_rad=m_ref,
        delta_n_rad_s=u(3.5e-9, 5.5e-9),
        idot_rad_s=u(-3e-10, 3e-10),
        omega_dot_rad_s=u(-8.5e-9, -7.5e-9),
        cuc_rad=u(-5e-6, 5e-6),
        cus_rad=u(-1e-5, 1e-5),
        crc_m=u(150.0, 300.0),
        crs_m=u(-100.0, 100.0),
        cic_rad=u(-2e-7, 2e-7),
        cis_rad=u(-2e-7, 2e-7),
        af0_s=quant(u(-5e-4, 5e-4), 2.0**-31),
        af1_s_s=quant(u(-5e-12, 5e-12), 2.0**-43),
        tgd_s=tgd,
        tgd2_s=tgd2,
    )


def _qzss_constellation(t_ref_gps_s: float, rng: np.random.Generator) -> Constellation:
    """QZSS: three quasi-zenith satellites and one GEO.

    The QZO satellites (J01-J03) fly inclined geosynchronous orbits (``a = (GM / omega_e^2)^(1/3)``
    = 42,164 km, e = 0.075, i = 41 deg, argument of perigee 270 deg: the apogee in the north)
    in planes 120 deg apart whose mean anomalies lag by 120 deg, so all three follow one
    figure-eight ground track, 8 h apart, its apogee at :data:`QZSS_APOGEE_LON_DEG` east and
    41 deg north: one of them is always high over Japan. J01 is at apogee at ``t_ref_gps_s``.
    J07 is geostationary at :data:`QZSS_GEO_LON_DEG` east (i = 0.05 deg, e = 2e-4). Clock
    terms and group delays are spread as GPS's, harmonic corrections are small.
    """
    n_qzo = len(QZSS_QZO_PRNS)
    n = n_qzo + 1
    sv = np.array([f"J{p:02d}" for p in (*QZSS_QZO_PRNS, QZSS_GEO_PRN)])
    a_m = (GM_GPS_M3_S2 / OMEGA_E_RAD_S**2) ** (1.0 / 3.0)
    k = np.arange(n_qzo)
    lag = 2.0 * np.pi * k / n_qzo
    # apogee (argument of latitude 90 deg) over the node + 90 deg: the node 90 deg west of it
    raan_qzo = np.deg2rad(QZSS_APOGEE_LON_DEG - 90.0) + lag
    omega = np.r_[np.full(n_qzo, np.deg2rad(-90.0)), 0.0]  # 270 deg, as the records hold it
    m_ref = np.r_[np.mod(np.pi - lag + np.pi, 2.0 * np.pi) - np.pi, 0.0]  # J01 at apogee (M = pi)
    raan = np.r_[raan_qzo, np.deg2rad(QZSS_GEO_LON_DEG)]

    def u(lo: float, hi: float) -> F64:
        return rng.uniform(lo, hi, n)

    def quant(x: F64, step: float) -> F64:
        return np.round(x / step) * step

    return Constellation(
        system="J",
        sv=sv,
        t_ref_gps_s=float(t_ref_gps_s),
        sqrt_a_sqrt_m=np.sqrt(np.full(n, a_m)),
        e=np.r_[np.full(n_qzo, 0.075), 2e-4],
        i_ref_rad=np.deg2rad(np.r_[np.full(n_qzo, 41.0), 0.05]),
        raan_rad=raan,
        omega_rad=omega,
        m_ref_rad=m_ref,
        delta_n_rad_s=u(-1e-10, 1e-10),
        idot_rad_s=u(-1e-11, 1e-11),
        omega_dot_rad_s=u(-3e-9, -2e-9),
        cuc_rad=u(-2e-6, 2e-6),
        cus_rad=u(-2e-6, 2e-6),
        crc_m=u(-200.0, 200.0),
        crs_m=u(-200.0, 200.0),
        cic_rad=u(-2e-7, 2e-7),
        cis_rad=u(-2e-7, 2e-7),
        af0_s=quant(u(-5e-4, 5e-4), 2.0**-31),
        af1_s_s=quant(u(-5e-12, 5e-12), 2.0**-43),
        tgd_s=quant(u(-15e-9, 15e-9), 2.0**-31),
        tgd2_s=quant(u(-15e-9, 15e-9), 1e-10),
    )


def rinex_round(x: F64) -> F64:
    """Values rounded to what a RINEX ``D19.12`` field holds (13 significant digits)."""
    arr = np.asarray(x, dtype=np.float64)
    return np.array([float(f"{v:.12E}") for v in arr.ravel()], dtype=np.float64).reshape(arr.shape)


def system_week_start_gps_s(system: str, t_gps_s: F64) -> F64:
    """Start (GPS seconds) of the system's week containing each instant."""
    w0 = SYSTEMS[system].week0_gps_s
    t = np.asarray(t_gps_s, dtype=np.float64)
    return w0 + np.floor((t - w0) / SECONDS_PER_WEEK) * SECONDS_PER_WEEK


def file_omega0_rad(system: str, omega0_rad: F64, toe_gps_s: F64) -> F64:
    """Node longitude as written in the file (system week origin) from the table's (GPS week origin)."""
    spec = SYSTEMS[system]
    gps_week_start = np.floor(np.asarray(toe_gps_s) / SECONDS_PER_WEEK) * SECONDS_PER_WEEK
    shift = system_week_start_gps_s(system, toe_gps_s) - gps_week_start
    return _wrap(np.asarray(omega0_rad) - spec.omega_e_rad_s * shift)


def _wrap(angle_rad: F64) -> F64:
    return np.mod(np.asarray(angle_rad) + np.pi, 2.0 * np.pi) - np.pi


def issue_times_gps_s(system: str, t_start_gps_s: float, t_end_gps_s: float, issue_interval_s: float = 7200.0) -> F64:
    """Reference times (toe = toc) of the issues covering ``[t_start, t_end]``: the interval grid in
    the system's own time scale, from the last grid point at or before the start to the first at or
    after the end, so the nearest issue is never more than half an interval away."""
    w0 = SYSTEMS[system].week0_gps_s
    first = w0 + np.floor((t_start_gps_s - w0) / issue_interval_s) * issue_interval_s
    last = w0 + np.ceil((t_end_gps_s - w0) / issue_interval_s) * issue_interval_s
    return np.arange(first, last + 0.5 * issue_interval_s, issue_interval_s)


def broadcast_records(constellation: Constellation, toe_gps_s: F64) -> KeplerEphemeris:
    """Truth records of every satellite at every issue time (record-major by issue, then satellite).

    Parameters
    ----------
    constellation
        The orbits and clocks.
    toe_gps_s
        Issue reference times, shape ``(k,)``, GPS seconds.

    Returns
    -------
    KeplerEphemeris
        ``k * n`` records, elements already rounded to the RINEX representation.

    Notes
    -----
    With ``dt = toe - t_ref``: ``m0 = M_ref + (sqrt(GM/A^3) + delta_n) dt``;
    ``i0 = i_ref + IDOT dt``; ``omega0 = RAAN + OmegaDot dt - omega_e (W(toe) - t_ref)``,
    ``W(toe)`` the GPS week start of toe (the broadcast node formula subtracts
    ``omega_e toe_sow``); ``af0 = af0_ref + af1 dt``.
    """
    c = constellation
    spec = SYSTEMS[c.system]
    toe = np.asarray(toe_gps_s, dtype=np.float64)
    k, n = toe.size, c.sv.size
    t = np.repeat(toe, n)
    dt = t - c.t_ref_gps_s

    def rep(x: F64) -> F64:
        return np.tile(np.asarray(x, dtype=np.float64), k)

    sqrt_a = rinex_round(rep(c.sqrt_a_sqrt_m))
    delta_n = rinex_round(rep(c.delta_n_rad_s))
    mean_motion = np.sqrt(spec.gm_m3_s2 / sqrt_a**6) + delta_n
    week_start = np.floor(t / SECONDS_PER_WEEK) * SECONDS_PER_WEEK
    m0 = _wrap(rep(c.m_ref_rad) + mean_motion * dt)
    omega0 = _wrap(rep(c.raan_rad) + rep(c.omega_dot_rad_s) * dt - spec.omega_e_rad_s * (week_start - c.t_ref_gps_s))
    # round what is written (file node longitude for BeiDou), then map back
    omega0 = omega0 + (rinex_round(file_omega0_rad(c.system, omega0, t)) - file_omega0_rad(c.system, omega0, t))
    i0 = rep(c.i_ref_rad) + rep(c.idot_rad_s) * dt
    af0 = rep(c.af0_s) + rep(c.af1_s_s) * dt
    iode = np.repeat(np.mod(np.round((toe - toe[0]) / 7200.0), 256.0), n)
    zeros = np.zeros(k * n)
    return KeplerEphemeris(
        sv=np.tile(c.sv, k),
        toc_gps_s=t,
        toe_gps_s=t,
        af0_s=rinex_round(af0),
        af1_s_s=rinex_round(rep(c.af1_s_s)),
        af2_s_s2=zeros.copy(),
        sqrt_a_sqrt_m=sqrt_a,
        e=rinex_round(rep(c.e)),
        i0_rad=rinex_round(i0),
        omega0_rad=omega0,
        omega_rad=rinex_round(rep(c.omega_rad)),
        m0_rad=rinex_round(m0),
        delta_n_rad_s=delta_n,
        idot_rad_s=rinex_round(rep(c.idot_rad_s)),
        omega_dot_rad_s=rinex_round(rep(c.omega_dot_rad_s)),
        cuc_rad=rinex_round(rep(c.cuc_rad)),
        cus_rad=rinex_round(rep(c.cus_rad)),
        crc_m=rinex_round(rep(c.crc_m)),
        crs_m=rinex_round(rep(c.crs_m)),
        cic_rad=rinex_round(rep(c.cic_rad)),
        cis_rad=rinex_round(rep(c.cis_rad)),
        tgd_s=rinex_round(rep(c.tgd_s)),
        health=zeros.copy(),
        fit_interval_h=np.full(k * n, 4.0),
        iode=iode,
    )


def argument_of_latitude_rad(eph: KeplerEphemeris) -> F64:
    """Argument of latitude ``u = nu + omega`` (rad) of every record at its toe (harmonics ignored)."""
    ea = solve_kepler(eph.m0_rad, eph.e)
    nu = np.arctan2(np.sqrt(1.0 - eph.e**2) * np.sin(ea), np.cos(ea) - eph.e)
    return nu + eph.omega_rad
