"""Atmospheric delay models for single-frequency pseudoranges.

- Klobuchar ionosphere (IS-GPS-200, 20.3.3.5.2.5) from the eight broadcast coefficients.
- Saastamoinen troposphere with a standard atmosphere, as in RTKLIB's ``tropmodel``
  (pressure and temperature from the height, relative humidity 0.7, ``1/cos(z)`` mapping),
  so gnss-solve and RTKLIB agree on the same data.

All functions are vectorized: arguments broadcast against each other.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gnss_cli.constants import C_M_S

F64 = NDArray[np.float64]

KLOBUCHAR_DEFAULT_ALPHA = np.array([0.1118e-07, -0.7451e-08, -0.5961e-07, 0.1192e-06])
"""Klobuchar alpha used when no navigation file carries coefficients (RTKLIB's ``ion_default``)."""
KLOBUCHAR_DEFAULT_BETA = np.array([0.1167e06, -0.2294e06, -0.1311e06, 0.1049e07])
"""Klobuchar beta used when no navigation file carries coefficients (RTKLIB's ``ion_default``)."""


def klobuchar_delay_m(
    alpha: ArrayLike,
    beta: ArrayLike,
    lat_rad: ArrayLike,
    lon_rad: ArrayLike,
    az_rad: ArrayLike,
    el_rad: ArrayLike,
    t_gps_s: ArrayLike,
) -> F64:
    """L1 ionospheric group delay (m) of the Klobuchar model.

    Parameters
    ----------
    alpha, beta
        Broadcast coefficients ``(4,)`` each (s, s/semicircle^n and s, s/semicircle^n).
    lat_rad, lon_rad
        Receiver geodetic latitude and longitude, rad.
    az_rad, el_rad
        Satellite azimuth and elevation, rad.
    t_gps_s
        Time, s since the GPS epoch (only the time of day matters).

    Returns
    -------
    ndarray
        Delay in metres on L1 (scale by ``(f_L1/f)^2`` for other frequencies).

    Notes
    -----
    Angles of the ICD are in semicircles; the obliquity factor is ``1 + 16 (0.53 - E)^3``.
    """
    a = np.asarray(alpha, dtype=np.float64)
    b = np.asarray(beta, dtype=np.float64)
    el = np.asarray(el_rad, dtype=np.float64) / np.pi
    az = np.asarray(az_rad, dtype=np.float64)
    phi_u = np.asarray(lat_rad, dtype=np.float64) / np.pi
    lam_u = np.asarray(lon_rad, dtype=np.float64) / np.pi
    psi = 0.0137 / (el + 0.11) - 0.022
    phi_i = np.clip(phi_u + psi * np.cos(az), -0.416, 0.416)
    lam_i = lam_u + psi * np.sin(az) / np.cos(phi_i * np.pi)
    phi_m = phi_i + 0.064 * np.cos((lam_i - 1.617) * np.pi)
    t = np.mod(4.32e4 * lam_i + np.asarray(t_gps_s, dtype=np.float64), 86400.0)
    f = 1.0 + 16.0 * (0.53 - el) ** 3
    amp = a[0] + phi_m * (a[1] + phi_m * (a[2] + phi_m * a[3]))
    per = b[0] + phi_m * (b[1] + phi_m * (b[2] + phi_m * b[3]))
    amp = np.maximum(amp, 0.0)
    per = np.maximum(per, 72000.0)
    x = 2.0 * np.pi * (t - 50400.0) / per
    day = np.abs(x) < 1.57
    x4 = np.zeros_like(x)
    x4[day] = x[day] ** 4  # (pow is the slowest step: night-time values are not needed)
    delay_s = np.where(
        day,
        f * (5e-9 + amp * (1.0 - x**2 / 2.0 + x4 / 24.0)),
        f * 5e-9,
    )
    return C_M_S * delay_s


def saastamoinen_delay_m(
    lat_rad: ArrayLike,
    h_m: ArrayLike,
    el_rad: ArrayLike,
    humidity: float = 0.7,
) -> F64:
    """Slant tropospheric delay (m): Saastamoinen with a standard atmosphere.

    Parameters
    ----------
    lat_rad
        Geodetic latitude, rad.
    h_m
        Ellipsoidal height, m (below 0 treated as 0; outside -100 m .. 10 km: no delay).
    el_rad
        Elevation, rad (no delay at or below the horizon).
    humidity
        Relative humidity, 0..1.

    Notes
    -----
    ``p = 1013.25 (1 - 2.2557e-5 h)^5.2568`` hPa, ``T = 15 - 6.5e-3 h + 273.16`` K,
    ``e = 6.108 RH exp((17.15 T - 4684) / (T - 38.45))`` hPa; hydrostatic
    ``0.0022768 p / (1 - 0.00266 cos 2 lat - 0.00028 h/km) / cos z`` and wet
    ``0.002277 (1255/T + 0.05) e / cos z``, z the zenith angle.
    """
    lat = np.asarray(lat_rad, dtype=np.float64)
    h = np.asarray(h_m, dtype=np.float64)
    el = np.asarray(el_rad, dtype=np.float64)
    hgt = np.clip(h, 0.0, 1e4)
    pres = 1013.25 * (1.0 - 2.2557e-5 * hgt) ** 5.2568
    temp = 15.0 - 6.5e-3 * hgt + 273.16
    e = 6.108 * humidity * np.exp((17.15 * temp - 4684.0) / (temp - 38.45))
    cos_z = np.sin(np.maximum(el, 1e-3))
    trph = 0.0022768 * pres / (1.0 - 0.00266 * np.cos(2.0 * lat) - 0.00028 * hgt / 1e3) / cos_z
    trpw = 0.002277 * (1255.0 / temp + 0.05) * e / cos_z
    ok = (h >= -100.0) & (h <= 1e4) & (el > 0.0)
    return np.where(ok, trph + trpw, 0.0)
