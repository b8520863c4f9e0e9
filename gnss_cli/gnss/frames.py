"""Reference frames: ECEF (WGS-84), geodetic latitude/longitude/height, local ENU.

Geodetic conversions delegate to :mod:`pymap3d` (vectorized, WGS-84); this module adds
the rotation matrices that DOP and the behavioral layer need, and azimuth/elevation of
line-of-sight vectors, all vectorized over leading batch dimensions.
"""

from __future__ import annotations

import numpy as np
import pymap3d
from numpy.typing import ArrayLike, NDArray

from gnss_cli.constants import WGS84_A_M, WGS84_F

_ELLIPSOID = pymap3d.Ellipsoid(WGS84_A_M, WGS84_A_M * (1.0 - WGS84_F), "wgs84")


def ecef2geodetic(xyz_m: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """ECEF position(s) ``(..., 3)`` in metres -> latitude rad, longitude rad, ellipsoidal height m."""
    xyz = np.asarray(xyz_m, dtype=np.float64)
    lat, lon, h = pymap3d.ecef2geodetic(xyz[..., 0], xyz[..., 1], xyz[..., 2], ell=_ELLIPSOID, deg=False)
    shape = xyz.shape[:-1]  # pymap3d returns a scalar latitude for a single point given as (1, 3)
    return tuple(np.reshape(np.asarray(v, dtype=np.float64), shape) for v in (lat, lon, h))  # type: ignore[return-value]


def geodetic2ecef(lat_rad: ArrayLike, lon_rad: ArrayLike, h_m: ArrayLike) -> NDArray[np.float64]:
    """Latitude rad, longitude rad, ellipsoidal height m -> ECEF ``(..., 3)`` in metres."""
    x, y, z = pymap3d.geodetic2ecef(lat_rad, lon_rad, h_m, ell=_ELLIPSOID, deg=False)
    return np.stack(np.broadcast_arrays(x, y, z), axis=-1).astype(np.float64)


def ecef2enu_rotation(lat_rad: ArrayLike, lon_rad: ArrayLike) -> NDArray[np.float64]:
    """Rotation matrices ``(..., 3, 3)`` taking ECEF vectors to local East-North-Up.

    ``v_enu = R @ v_ecef``; rows are the unit vectors east, north, up in ECEF.
    """
    lat = np.asarray(lat_rad, dtype=np.float64)
    lon = np.asarray(lon_rad, dtype=np.float64)
    sl, cl = np.sin(lat), np.cos(lat)
    so, co = np.sin(lon), np.cos(lon)
    zero = np.zeros_like(lat)
    east = np.stack([-so, co, zero], axis=-1)
    north = np.stack([-sl * co, -sl * so, cl], axis=-1)
    up = np.stack([cl * co, cl * so, sl], axis=-1)
    return np.stack([east, north, up], axis=-2)


def ecef2enu(xyz_m: ArrayLike, origin_ecef_m: ArrayLike) -> NDArray[np.float64]:
    """ECEF points ``(..., 3)`` -> ENU coordinates (m) relative to one origin ``(3,)``."""
    origin = np.asarray(origin_ecef_m, dtype=np.float64)
    lat, lon, _ = ecef2geodetic(origin)
    rot = ecef2enu_rotation(lat, lon)
    return (np.asarray(xyz_m, dtype=np.float64) - origin) @ rot.T


def enu2ecef(enu_m: ArrayLike, origin_ecef_m: ArrayLike) -> NDArray[np.float64]:
    """ENU coordinates ``(..., 3)`` relative to an origin ``(3,)`` -> ECEF points (m)."""
    origin = np.asarray(origin_ecef_m, dtype=np.float64)
    lat, lon, _ = ecef2geodetic(origin)
    rot = ecef2enu_rotation(lat, lon)
    return np.asarray(enu_m, dtype=np.float64) @ rot + origin


def azimuth_elevation(los_enu: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Azimuth (rad, clockwise from north, [0, 2pi)) and elevation (rad) of ENU vectors ``(..., 3)``."""
    v = np.asarray(los_enu, dtype=np.float64)
    horiz = np.hypot(v[..., 0], v[..., 1])
    az = np.mod(np.arctan2(v[..., 0], v[..., 1]), 2.0 * np.pi)
    el = np.arctan2(v[..., 2], horiz)
    return az, el


def satellite_azimuth_elevation_deg(sat_ecef_m: ArrayLike, rx_ecef_m: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Azimuth (deg, clockwise from north, [0, 360)) and elevation (deg) ``(T, n)`` of satellites
    ``(T, n, 3)`` (ECEF m) seen from receivers ``(T, 3)`` (ECEF m); NaN where a receiver
    position is not finite."""
    sat = np.asarray(sat_ecef_m, dtype=np.float64)
    rx = np.asarray(rx_ecef_m, dtype=np.float64)
    ok = np.isfinite(rx).all(axis=-1)
    rx_safe = np.where(ok[:, None], rx, np.array([WGS84_A_M, 0.0, 0.0]))
    lat, lon, _ = ecef2geodetic(rx_safe)
    los = np.einsum("tij,tnj->tni", ecef2enu_rotation(lat, lon), sat - rx_safe[:, None, :])
    az, el = azimuth_elevation(los)
    return np.where(ok[:, None], np.degrees(az), np.nan), np.where(ok[:, None], np.degrees(el), np.nan)
