"""Satellite positions and clocks from broadcast Keplerian ephemerides (IS-GPS-200, 20.3.3.4.3).

Vectorized over any batch shape: ``idx`` picks an ephemeris record for every element of
``t_gps_s``. Positions are ECEF at the given (transmit) time, in the frame of that time:
the Earth-rotation (Sagnac) correction during signal flight is applied by the caller
(:mod:`gnss_cli.gnss.range_model`), which knows the receiver position.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from gnss_cli.constants import F_REL_S_SQRT_M, GM_GPS_M3_S2, OMEGA_E_RAD_S, SECONDS_PER_WEEK
from gnss_cli.errors import UsageError
from gnss_cli.gnss.ephemeris import KeplerEphemeris

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class SatelliteStates:
    """Satellite states for a batch of (record, time) pairs.

    Attributes
    ----------
    pos_ecef_m : ``(..., 3)`` ECEF position at the given time, m.
    vel_ecef_m_s : ``(..., 3)`` ECEF velocity, m/s (rotating frame).
    clock_s : ``(...,)`` satellite clock offset incl. the relativistic term, excl. TGD, s.
    tgd_s : ``(...,)`` broadcast L1 group delay, s.
    relativistic_s : ``(...,)`` the relativistic term ``F e sqrt(A) sin E`` included in ``clock_s``, s.
    valid : ``(...,)`` True where a record was given (``idx >= 0``).
    """

    pos_ecef_m: F64
    vel_ecef_m_s: F64
    clock_s: F64
    tgd_s: F64
    relativistic_s: F64
    valid: NDArray[np.bool_]


def solve_kepler(
    mean_anomaly_rad: F64, e: F64, *, tol_rad: float = 1e-14, max_iter: int = 30
) -> F64:
    """Eccentric anomaly E from M = E - e sin E, by Newton's method to ``tol_rad``.

    Raises
    ------
    UsageError
        When ``max_iter`` iterations do not reach the tolerance (e >= 1 or non-finite input).
    """
    m = np.asarray(mean_anomaly_rad, dtype=np.float64)
    ecc = np.asarray(e, dtype=np.float64)
    ea = m.copy()
    active = np.ones(ea.shape, dtype=bool)
    for _ in range(max_iter):
        step = (ea - ecc * np.sin(ea) - m) / (1.0 - ecc * np.cos(ea))
        # each anomaly stops at its own convergence: the same input gives the same bits in any
        # batch (a long file's parts batch other observations than the whole file)
        ea = np.where(active, ea - step, ea)
        active &= ~(np.abs(step) <= tol_rad)
        if not active.any():
            return ea
    raise UsageError(f"Kepler's equation did not converge in {max_iter} iterations (max |step| {np.nanmax(np.abs(step)):.3g} rad)")


def broadcast_states(
    eph: KeplerEphemeris,
    idx: NDArray[np.intp],
    t_gps_s: F64,
    *,
    gm_m3_s2: float = GM_GPS_M3_S2,
    omega_e_rad_s: float = OMEGA_E_RAD_S,
    clock_only: bool = False,
) -> SatelliteStates:
    """Positions, velocities and clocks of satellites at times ``t_gps_s`` (GPS seconds).

    Parameters
    ----------
    eph
        Ephemeris table.
    idx
        Record index per element, any shape; -1 marks "no record" (result NaN, ``valid`` False).
    t_gps_s
        Times (same shape as ``idx``), s since the GPS epoch: the signal transmit times.
    gm_m3_s2, omega_e_rad_s
        The system's constants (GPS defaults).
    clock_only
        Clocks only (positions and velocities NaN): the clock drift needs no second orbit.

    Notes
    -----
    IS-GPS-200 Table 20-IV: ``tk = t - toe``; ``n = sqrt(GM/A^3) + dn``; Kepler's equation
    solved iteratively; second-harmonic corrections; ``Omega = Omega0 + (OmegaDot - wE) tk
    - wE toe_sow``. Clock: ``af0 + af1 (t - toc) + af2 (t - toc)^2 + F e sqrt(A) sin E``.
    """
    idx = np.asarray(idx)
    t = np.broadcast_to(np.asarray(t_gps_s, dtype=np.float64), idx.shape)
    valid = idx >= 0
    k = np.where(valid, idx, 0)
    if len(eph) == 0:
        nan = np.full(idx.shape, np.nan)
        return SatelliteStates(
            np.full((*idx.shape, 3), np.nan), np.full((*idx.shape, 3), np.nan), nan, nan.copy(), nan.copy(), valid & False
        )

    def g(a: F64) -> F64:
        return a[k]

    toe = g(eph.toe_gps_s)
    a = g(eph.sqrt_a_sqrt_m) ** 2
    ecc = g(eph.e)
    tk = np.where(valid, t - toe, 0.0)
    n0 = np.sqrt(gm_m3_s2 / a**3)
    n = n0 + g(eph.delta_n_rad_s)
    mk = g(eph.m0_rad) + n * tk
    ek = solve_kepler(mk, ecc)
    sin_e = np.sin(ek)
    if clock_only:
        clock, rel = _clock_s(eph, k, t, ecc, sin_e)
        nan3 = np.full((*idx.shape, 3), np.nan)
        return SatelliteStates(nan3, nan3.copy(), np.where(valid, clock, np.nan), np.where(valid, g(eph.tgd_s), np.nan),
                               np.where(valid, rel, np.nan), valid)
    cos_e = np.cos(ek)
    denom = 1.0 - ecc * cos_e
    nu = np.arctan2(np.sqrt(1.0 - ecc**2) * sin_e, cos_e - ecc)
    phi = nu + g(eph.omega_rad)
    s2, c2 = np.sin(2.0 * phi), np.cos(2.0 * phi)
    du = g(eph.cus_rad) * s2 + g(eph.cuc_rad) * c2
    dr = g(eph.crs_m) * s2 + g(eph.crc_m) * c2
    di = g(eph.cis_rad) * s2 + g(eph.cic_rad) * c2
    u = phi + du
    r = a * denom + dr
    inc = g(eph.i0_rad) + di + g(eph.idot_rad_s) * tk
    xp, yp = r * np.cos(u), r * np.sin(u)
    toe_sow = np.mod(toe, SECONDS_PER_WEEK)
    omega_dot = g(eph.omega_dot_rad_s)
    node = g(eph.omega0_rad) + (omega_dot - omega_e_rad_s) * tk - omega_e_rad_s * toe_sow
    cn, sn, ci, si = np.cos(node), np.sin(node), np.cos(inc), np.sin(inc)
    x = xp * cn - yp * ci * sn
    y = xp * sn + yp * ci * cn
    z = yp * si

    # Velocity (derivatives of the above; used for Doppler and interpolation checks).
    ek_dot = n / denom
    nu_dot = ek_dot * np.sqrt(1.0 - ecc**2) / denom
    u_dot = nu_dot * (1.0 + 2.0 * (g(eph.cus_rad) * c2 - g(eph.cuc_rad) * s2))
    r_dot = a * ecc * sin_e * ek_dot + 2.0 * nu_dot * (g(eph.crs_m) * c2 - g(eph.crc_m) * s2)
    i_dot = g(eph.idot_rad_s) + 2.0 * nu_dot * (g(eph.cis_rad) * c2 - g(eph.cic_rad) * s2)
    node_dot = omega_dot - omega_e_rad_s
    xp_dot = r_dot * np.cos(u) - r * u_dot * np.sin(u)
    yp_dot = r_dot * np.sin(u) + r * u_dot * np.cos(u)
    vx = xp_dot * cn - yp_dot * ci * sn + yp * si * sn * i_dot - y * node_dot
    vy = xp_dot * sn + yp_dot * ci * cn - yp * si * cn * i_dot + x * node_dot
    vz = yp_dot * si + yp * ci * i_dot

    clock, rel = _clock_s(eph, k, t, ecc, sin_e)
    pos = np.stack([x, y, z], axis=-1)
    vel = np.stack([vx, vy, vz], axis=-1)
    nan_mask = ~valid
    pos[nan_mask] = np.nan
    vel[nan_mask] = np.nan
    clock = np.where(valid, clock, np.nan)
    tgd = np.where(valid, g(eph.tgd_s), np.nan)
    rel = np.where(valid, rel, np.nan)
    return SatelliteStates(pos, vel, clock, tgd, rel, valid)


def _clock_s(eph: KeplerEphemeris, k: NDArray[np.intp], t: F64, ecc: F64, sin_e: F64) -> tuple[F64, F64]:
    """Clock ``af0 + af1 (t - toc) + af2 (t - toc)^2 + rel`` and the relativistic term ``rel = F e sqrt(A) sin E`` (s)."""
    dtc = t - eph.toc_gps_s[k]
    clock = eph.af0_s[k] + eph.af1_s_s[k] * dtc + eph.af2_s_s2[k] * dtc**2
    rel = F_REL_S_SQRT_M * ecc * eph.sqrt_a_sqrt_m[k] * sin_e
    return clock + rel, rel
