"""Receiver trajectories: static, a simulated flight (drawn from the seed, or the standard one), a drive
through streets, a constant-speed semicircle, or a CSV file.

A :class:`Trajectory` holds ECEF positions and velocities at the epochs (GPS seconds).
The flight is integrated in geodetic coordinates from a smooth speed / heading / climb-rate
profile on a fine grid (trapezoidal rule, 100 Hz; manoeuvres drawn from the seed, or the fixed
profile of the standard flight), so its velocities are the derivatives of
its positions to well under a millimetre per second (the drive likewise, from a speed / heading
profile drawn from the seed); the semicircle is a closed-form arc in
the local tangent plane of its centre, so its ENU coordinates satisfy the lag-3 kernel
``(z - 1)(z^2 - 2 cos(w dt) z + 1)`` exactly.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from gnss_cli.constants import WGS84_A_M, WGS84_E2
from gnss_cli.errors import InputError, InputFileNotFoundError, UsageError
from gnss_cli.gnss.frames import ecef2enu_rotation, ecef2geodetic, geodetic2ecef
from gnss_cli.gnss.time import datetime2gps_s

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class Trajectory:
    """Receiver antenna positions and velocities.

    Attributes
    ----------
    t_gps_s : ``(T,)`` epochs, s since the GPS epoch.
    pos_ecef_m : ``(T, 3)`` ECEF position, m.
    vel_ecef_m_s : ``(T, 3)`` ECEF velocity, m/s.
    """

    t_gps_s: F64
    pos_ecef_m: F64
    vel_ecef_m_s: F64


def static_trajectory(t_gps_s: F64, pos_ecef_m: F64) -> Trajectory:
    """A receiver at rest at ``pos_ecef_m`` ``(3,)`` for epochs ``t_gps_s`` ``(T,)``."""
    t = np.asarray(t_gps_s, dtype=np.float64)
    pos = np.broadcast_to(np.asarray(pos_ecef_m, dtype=np.float64), (t.size, 3)).copy()
    return Trajectory(t, pos, np.zeros_like(pos))


def _smoothstep(x: F64) -> F64:
    """0 for x <= 0, 1 for x >= 1, C1-continuous cubic in between."""
    y = np.clip(x, 0.0, 1.0)
    return y * y * (3.0 - 2.0 * y)


def _ramp(t_s: F64, start_s: float, duration_s: float, delta: float) -> F64:
    return delta * _smoothstep((t_s - start_s) / duration_s)


def standard_flight_profile(t_rel_s: F64) -> tuple[F64, F64, F64]:
    """Ground speed (m/s), heading (rad from north) and climb rate (m/s) of the standard flight
    (``--trajectory standard-flight``: the same path for every seed).

    Notes
    -----
    A take-off roll accelerating to 80 m/s in 40 s, a climb at 10 m/s with acceleration to
    150 m/s, a 90 deg right turn, acceleration to 220 m/s at cruise height, a 180 deg left
    turn and a descent: over a 10-min run it covers ~100 km; longer runs cruise on.
    Speed and heading change through smooth (C1) ramps, so velocity is continuous and
    acceleration bounded (~2 m/s^2 along track, ~0.5 g in the turns).
    """
    t = np.asarray(t_rel_s, dtype=np.float64)
    speed = 5.0 + _ramp(t, 0.0, 40.0, 75.0) + _ramp(t, 60.0, 60.0, 70.0) + _ramp(t, 240.0, 60.0, 70.0)
    heading = np.deg2rad(60.0) + _ramp(t, 150.0, 45.0, np.pi / 2.0) - _ramp(t, 360.0, 90.0, np.pi)
    climb = _ramp(t, 40.0, 10.0, 10.0) - _ramp(t, 220.0, 20.0, 10.0) - _ramp(t, 480.0, 20.0, 8.0) + _ramp(
        t, 560.0, 20.0, 8.0
    )
    return speed, heading, climb


@dataclass(frozen=True)
class FlightLimits:
    """Physical bounds of the seed-drawn flight (:func:`flight_profile`); every draw respects them.

    Attributes
    ----------
    max_speed_m_s : ground speed, m/s (airborne speeds are drawn in ``min_air_speed_m_s`` ..).
    min_air_speed_m_s : lowest speed once airborne, m/s.
    max_along_m_s2 : along-track acceleration (take-off roll and speed changes), m/s^2.
    max_lateral_m_s2 : centripetal acceleration in a turn (0.5 g), m/s^2.
    max_climb_m_s : climb or sink rate, m/s.
    max_vertical_m_s2 : vertical acceleration (changes of the climb rate), m/s^2.
    min_height_agl_m, max_height_agl_m : heights above the take-off point between which the
        level-offs are drawn, m.
    """

    max_speed_m_s: float = 230.0
    min_air_speed_m_s: float = 70.0
    max_along_m_s2: float = 2.5
    max_lateral_m_s2: float = 4.9
    max_climb_m_s: float = 12.0
    max_vertical_m_s2: float = 1.5
    min_height_agl_m: float = 300.0
    max_height_agl_m: float = 4000.0


FLIGHT_LIMITS = FlightLimits()


def flight_profile(
    t_rel_s: F64, rng: np.random.Generator, *, limits: FlightLimits = FLIGHT_LIMITS
) -> tuple[F64, F64, F64]:
    """Ground speed (m/s), heading (rad from north) and climb rate (m/s) of a manoeuvring flight
    drawn from ``rng``.

    Parameters
    ----------
    t_rel_s
        Times since the start ``(N,)``, s, increasing from 0.
    rng
        Random generator: the heading, take-off, every manoeuvre and its time are drawn from it.
    limits
        The physical bounds every draw respects.

    Notes
    -----
    From rest on the ground the aircraft rolls (1.5..2.5 m/s^2 peak) to a rotation speed of
    70..90 m/s, climbs at 5..12 m/s to a first level of 600..2500 m above the take-off point,
    and then, after straight legs of 10..60 s, manoeuvres: with probabilities 0.4 / 0.3 / 0.3 a
    turn of 30..180 deg left or right (turn rate up to 3 deg/s, centripetal acceleration under
    ``max_lateral_m_s2``), a speed change to 90..230 m/s, or a climb or descent at 4..12 m/s to a
    new level. Each change is a C1 ramp (:func:`_smoothstep`) of speed, heading or climb rate:
    velocity and acceleration are continuous (jerk is not), the peak of a ramp of ``delta``
    over ``D`` seconds being ``1.5 delta / D``; its duration is chosen so that peak stays in the bounds.
    """
    lim = limits
    t = np.asarray(t_rel_s, dtype=np.float64)
    span = float(t[-1]) if t.size else 0.0
    speed = np.zeros_like(t)
    heading = np.full_like(t, rng.uniform(0.0, 2.0 * np.pi))
    climb = np.zeros_like(t)
    state = {"cursor": 0.0, "v": 0.0, "h": 0.0}

    def change_speed(v_new: float, accel_m_s2: float) -> None:
        duration = max(1.5 * abs(v_new - state["v"]) / accel_m_s2, 1.0)
        speed[:] += _ramp(t, state["cursor"], duration, v_new - state["v"])
        state["cursor"] += duration
        state["v"] = v_new

    def change_level(dh_m: float, rate_m_s: float) -> None:
        # ramp the climb rate to +-rate, hold, ramp back to 0: each ramp climbs rate * D / 2
        ramp_s = max(1.5 * rate_m_s / lim.max_vertical_m_s2, 1.0)
        rate = float(np.sign(dh_m)) * rate_m_s
        hold_s = max(abs(dh_m) / rate_m_s - ramp_s, 0.0)
        c0 = state["cursor"]
        climb[:] += _ramp(t, c0, ramp_s, rate) - _ramp(t, c0 + ramp_s + hold_s, ramp_s, rate)
        state["cursor"] = c0 + 2.0 * ramp_s + hold_s
        state["h"] += rate * (ramp_s + hold_s)

    # take-off roll on the ground, then the first climb
    change_speed(rng.uniform(70.0, 90.0), rng.uniform(1.5, lim.max_along_m_s2))
    change_level(rng.uniform(600.0, 2500.0), rng.uniform(5.0, lim.max_climb_m_s))
    while state["cursor"] <= span:
        state["cursor"] += rng.uniform(10.0, 60.0)
        kind = rng.choice(3, p=[0.4, 0.3, 0.3])
        if kind == 0:
            turn = rng.choice([-1.0, 1.0]) * np.deg2rad(rng.uniform(30.0, 180.0))
            # peak turn rate 1.5 |turn| / D <= min(3 deg/s, a_lat / v)
            max_rate = min(np.deg2rad(3.0), lim.max_lateral_m_s2 / max(state["v"], 1.0)) * rng.uniform(0.5, 1.0)
            duration = 1.5 * abs(turn) / max_rate
            heading[:] += _ramp(t, state["cursor"], duration, turn)
            state["cursor"] += duration
        elif kind == 1:
            change_speed(rng.uniform(lim.min_air_speed_m_s + 20.0, lim.max_speed_m_s),
                         rng.uniform(0.5, lim.max_along_m_s2))
        else:
            target = rng.uniform(lim.min_height_agl_m, lim.max_height_agl_m)
            if abs(target - state["h"]) > 50.0:
                change_level(target - state["h"], rng.uniform(4.0, lim.max_climb_m_s))
    return speed, np.mod(heading, 2.0 * np.pi), climb


def flight_trajectory(
    t_gps_s: F64, start_ecef_m: F64, rng: np.random.Generator | None = None, *, substeps_per_s: int = 100
) -> Trajectory:
    """A simulated flight starting at ``start_ecef_m``: drawn from ``rng`` (:func:`flight_profile`),
    or the standard flight (:func:`standard_flight_profile`) when ``rng`` is None.

    Parameters
    ----------
    t_gps_s
        Epochs ``(T,)``, uniformly spaced, s since the GPS epoch.
    start_ecef_m
        Take-off point ``(3,)``, ECEF m.
    rng
        Random generator of the manoeuvres; None: the standard flight.
    substeps_per_s
        Integration rate of the geodetic equations, Hz.

    Notes
    -----
    ``dlat/dt = v_N / (M + h)``, ``dlon/dt = v_E / ((N + h) cos lat)``, ``dh/dt = v_U`` with the
    WGS-84 radii of curvature ``M``, ``N``, integrated with the trapezoidal rule; the ECEF velocity
    is the ENU velocity rotated at the current position.
    """
    t = np.asarray(t_gps_s, dtype=np.float64)
    if t.ndim != 1 or t.size < 1:
        raise UsageError(f"t_gps_s must be a non-empty 1-D array, got shape {t.shape}")
    if rng is None:
        return _integrate_profile(t, start_ecef_m, standard_flight_profile, substeps_per_s)
    # the profile is drawn once on the integration grid, so the draws do not depend on the epochs
    return _integrate_profile(t, start_ecef_m, lambda tr: flight_profile(tr, rng), substeps_per_s)


def _integrate_profile(
    t: F64, start_ecef_m: F64, profile: Callable[[F64], tuple[F64, F64, F64]], substeps_per_s: int
) -> Trajectory:
    """Integrate a speed / heading / climb-rate profile of the time since ``t[0]`` on the ellipsoid
    (the equations of :func:`flight_trajectory`) and sample it at the epochs ``t``."""
    span = float(t[-1] - t[0])
    n_fine = max(int(np.ceil(span * substeps_per_s)), 1)
    t_fine = np.linspace(0.0, span, n_fine + 1)
    speed, heading, climb = profile(t_fine)
    v_e, v_n = speed * np.sin(heading), speed * np.cos(heading)
    lat0, lon0, h0 = (float(v) for v in ecef2geodetic(np.asarray(start_ecef_m, dtype=np.float64)))
    h = h0 + _cumtrapz(climb, t_fine)
    # lat and lon depend on the position through M and N: fixed-point passes of the
    # cumulative trapezoid converge at once (the radii change by ~1e-5 over 100 km)
    lat = np.full_like(t_fine, lat0)
    for _ in range(3):
        m_r, n_r = _radii(lat)
        lat = lat0 + _cumtrapz(v_n / (m_r + h), t_fine)
    m_r, n_r = _radii(lat)
    lon = lon0 + _cumtrapz(v_e / ((n_r + h) * np.cos(lat)), t_fine)
    step = span / n_fine
    pick = np.clip(np.round((t - t[0]) / step).astype(np.intp), 0, n_fine)
    pos = geodetic2ecef(lat[pick], lon[pick], h[pick])
    enu_vel = np.stack([v_e[pick], v_n[pick], climb[pick]], axis=-1)
    rot = ecef2enu_rotation(lat[pick], lon[pick])  # (T, 3, 3), v_enu = R v_ecef
    vel = np.einsum("tji,tj->ti", rot, enu_vel)
    return Trajectory(t, pos, vel)


def drive_profile(
    t_rel_s: F64, rng: np.random.Generator, *, speed_m_s: float = 10.0, turn_speed_m_s: float = 5.0,
    acceleration_m_s2: float = 1.5,
) -> tuple[F64, F64, F64]:
    """Speed (m/s), heading (rad from north) and climb rate (0, m/s) of a random drive through streets.

    Parameters
    ----------
    t_rel_s
        Times since the start ``(N,)``, s, increasing from 0.
    rng
        Random generator: the legs, stops and turns are drawn from it.
    speed_m_s
        Mean cruising speed; each leg's speed is drawn uniformly within +-30 % of it.
    turn_speed_m_s
        Speed through a turn (slowed down to before it).
    acceleration_m_s2
        Magnitude of every speed change.

    Notes
    -----
    From rest the vehicle accelerates to the leg's speed, cruises for 15..60 s and then, with
    probabilities 0.45 / 0.25 / 0.30, turns 90 deg left or right (slowing to ``turn_speed_m_s``,
    6 s through the turn), stops for 5..30 s, or goes on at a new speed. Speed and heading change
    through the C1 ramps of :func:`flight_profile`, so velocity and acceleration are continuous.
    """
    t = np.asarray(t_rel_s, dtype=np.float64)
    span = float(t[-1]) if t.size else 0.0
    speed = np.zeros_like(t)
    heading = np.full_like(t, rng.uniform(0.0, 2.0 * np.pi))
    cursor, v_now = 0.0, 0.0

    def change_speed(v_new: float) -> None:
        nonlocal cursor, v_now, speed
        duration = max(abs(v_new - v_now) / acceleration_m_s2, 1.0)
        speed += _ramp(t, cursor, duration, v_new - v_now)
        cursor, v_now = cursor + duration, v_new

    while cursor <= span:
        change_speed(speed_m_s * rng.uniform(0.7, 1.3))
        cursor += rng.uniform(15.0, 60.0)
        kind = rng.choice(3, p=[0.45, 0.25, 0.30])
        if kind == 0:
            change_speed(turn_speed_m_s)
            heading += _ramp(t, cursor, 6.0, rng.choice([-1.0, 1.0]) * np.pi / 2.0)
            cursor += 6.0
        elif kind == 1:
            change_speed(0.0)
            cursor += rng.uniform(5.0, 30.0)
    return np.maximum(speed, 0.0), np.mod(heading, 2.0 * np.pi), np.zeros_like(t)


def drive_trajectory(t_gps_s: F64, start_ecef_m: F64, rng: np.random.Generator, *, speed_m_s: float = 10.0,
                     substeps_per_s: int = 20) -> Trajectory:
    """A drive through a street grid (:func:`drive_profile`) on the ellipsoid, starting at rest at
    ``start_ecef_m`` ``(3,)``; epochs ``t_gps_s`` ``(T,)`` uniformly spaced, s.

    The legs are drawn from ``rng``; the integration is that of :func:`flight_trajectory`
    at ``substeps_per_s`` (a turn at 5 m/s moves 0.25 m per 20 Hz step).
    """
    t = np.asarray(t_gps_s, dtype=np.float64)
    if t.ndim != 1 or t.size < 1:
        raise UsageError(f"t_gps_s must be a non-empty 1-D array, got shape {t.shape}")
    return _integrate_profile(t, start_ecef_m, lambda tr: drive_profile(tr, rng, speed_m_s=speed_m_s), substeps_per_s)


def _cumtrapz(f: F64, x: F64) -> F64:
    """Cumulative trapezoidal integral of samples ``f`` over ``x``, starting at 0."""
    return np.concatenate([[0.0], np.cumsum(0.5 * (f[1:] + f[:-1]) * np.diff(x))])


def _radii(lat_rad: F64) -> tuple[F64, F64]:
    """Meridian (M) and prime-vertical (N) radii of curvature of WGS-84, m."""
    s2 = np.sin(lat_rad) ** 2
    w = np.sqrt(1.0 - WGS84_E2 * s2)
    return WGS84_A_M * (1.0 - WGS84_E2) / w**3, WGS84_A_M / w


def semicircle_trajectory(t_gps_s: F64, centre_ecef_m: F64, *, speed_m_s: float = 50.0) -> Trajectory:
    """Half a circle at constant speed, in the tangent plane of ``centre_ecef_m``, over the run.

    The angular rate is ``pi / (t[-1] - t[0])`` and the radius ``speed / rate``; the arc starts
    due south of the centre and moves counter-clockwise (east first).
    """
    t = np.asarray(t_gps_s, dtype=np.float64)
    span = float(t[-1] - t[0])
    if span <= 0.0:
        raise UsageError("a semicircle needs a positive duration")
    rate = np.pi / span
    radius = speed_m_s / rate
    ang = -np.pi / 2.0 + rate * (t - t[0])
    enu = np.stack([radius * np.cos(ang), radius * np.sin(ang), np.zeros_like(t)], axis=-1)
    enu_vel = np.stack([-radius * rate * np.sin(ang), radius * rate * np.cos(ang), np.zeros_like(t)], axis=-1)
    centre = np.asarray(centre_ecef_m, dtype=np.float64)
    lat, lon, _ = ecef2geodetic(centre)
    rot = ecef2enu_rotation(lat, lon)
    return Trajectory(t, enu @ rot + centre, enu_vel @ rot)


def csv_trajectory(path: Path, t_gps_s: F64) -> Trajectory:
    """Positions from a CSV file, interpolated (cubic Hermite from the finite-difference velocity)
    to the epochs.

    The file has a ``time`` column (ISO 8601, GPS time) or ``t_gps_s``, and either ``x_m, y_m, z_m``
    (ECEF) or ``lat_deg, lon_deg, height_m``. Velocity columns ``vx_m_s, vy_m_s, vz_m_s`` are
    used when present, else central differences of the positions.

    Raises
    ------
    InputFileNotFoundError, InputError
        Missing file, missing columns, or epochs outside the file's time span.
    """
    p = Path(path)
    if not p.is_file():
        raise InputFileNotFoundError(f"trajectory file not found: {p}")
    try:
        df = pd.read_csv(p)
    except (OSError, ValueError) as exc:
        raise InputError(f"{p}: not a readable CSV file ({exc})") from exc
    if "t_gps_s" in df:
        tf = df["t_gps_s"].to_numpy(dtype=np.float64)
    elif "time" in df:
        tf = datetime2gps_s(pd.to_datetime(df["time"]).to_numpy(dtype="datetime64[ns]"))
    else:
        raise InputError(f"{p}: needs a 'time' or 't_gps_s' column, found {list(df.columns)}")
    if {"x_m", "y_m", "z_m"} <= set(df.columns):
        pos = df[["x_m", "y_m", "z_m"]].to_numpy(dtype=np.float64)
    elif {"lat_deg", "lon_deg", "height_m"} <= set(df.columns):
        pos = geodetic2ecef(np.deg2rad(df["lat_deg"].to_numpy(float)), np.deg2rad(df["lon_deg"].to_numpy(float)), df["height_m"].to_numpy(float))
    else:
        raise InputError(f"{p}: needs x_m,y_m,z_m or lat_deg,lon_deg,height_m columns, found {list(df.columns)}")
    if tf.size < 2 or np.any(np.diff(tf) <= 0) or not np.all(np.isfinite(pos)):
        raise InputError(f"{p}: needs at least two rows with strictly increasing times and finite positions")
    if {"vx_m_s", "vy_m_s", "vz_m_s"} <= set(df.columns):
        vel = df[["vx_m_s", "vy_m_s", "vz_m_s"]].to_numpy(dtype=np.float64)
    else:
        vel = np.gradient(pos, tf, axis=0)
    t = np.asarray(t_gps_s, dtype=np.float64)
    if t[0] < tf[0] - 1e-6 or t[-1] > tf[-1] + 1e-6:
        raise InputError(f"{p}: the file covers {tf[0]:.3f}..{tf[-1]:.3f} GPS s, the run needs {t[0]:.3f}..{t[-1]:.3f}")
    from scipy.interpolate import CubicHermiteSpline

    spline = CubicHermiteSpline(tf, pos, vel, axis=0)
    return Trajectory(t, spline(t), spline.derivative()(t))
