"""Trajectories drawn from the seed: ``flight`` and ``drive`` change path and start time with
``seed``; ``standard-flight`` and ``semicircle`` are the same for every seed."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from gnss_cli.gnss.frames import ecef2enu_rotation, ecef2geodetic
from gnss_cli.sim.scenario import ScenarioConfig, build_trajectory, epochs_gps_s, run_scenario
from gnss_cli.sim.trajectory import FLIGHT_LIMITS, Trajectory

START_GPS_S = float(epochs_gps_s(ScenarioConfig())[0])


def _run(kind: str, seed: int, duration_s: float = 600.0, interval_s: float = 1.0, **changes: object) -> Trajectory:
    cfg = replace(ScenarioConfig(), trajectory=kind, seed=seed, duration_s=duration_s, interval_s=interval_s,
                  **changes)  # type: ignore[arg-type]
    return build_trajectory(cfg, epochs_gps_s(cfg))


def _enu_velocity(traj: Trajectory) -> tuple[np.ndarray, np.ndarray]:
    """ENU velocity ``(T, 3)`` and height ``(T,)`` along the path."""
    lat, lon, h = ecef2geodetic(traj.pos_ecef_m)
    return np.einsum("tij,tj->ti", ecef2enu_rotation(lat, lon), traj.vel_ecef_m_s), h


@pytest.mark.parametrize("kind", ["flight", "drive"])
def test_two_seeds_give_other_paths_and_start_times(kind: str) -> None:
    a, b = _run(kind, 1), _run(kind, 2)
    assert a.t_gps_s[0] != b.t_gps_s[0]
    # other manoeuvres: compare the shapes, relative to each start point
    rel_a, rel_b = a.pos_ecef_m - a.pos_ecef_m[0], b.pos_ecef_m - b.pos_ecef_m[0]
    assert np.abs(rel_a - rel_b).max() > (1000.0 if kind == "flight" else 100.0)


@pytest.mark.parametrize("kind", ["flight", "drive"])
def test_one_seed_is_reproducible(kind: str) -> None:
    a, b = _run(kind, 5), _run(kind, 5)
    assert np.array_equal(a.t_gps_s, b.t_gps_s) and np.array_equal(a.pos_ecef_m, b.pos_ecef_m)
    assert np.array_equal(a.vel_ecef_m_s, b.vel_ecef_m_s)


def test_the_run_uses_the_trajectory_of_its_seed() -> None:
    """run_scenario draws the same path and epochs as build_trajectory, whatever the error sources."""
    cfg = replace(ScenarioConfig(), trajectory="flight", seed=3, duration_s=30.0, interval_s=1.0)
    scen = run_scenario(cfg)
    path = build_trajectory(cfg, epochs_gps_s(cfg))
    assert np.array_equal(scen.trajectory.pos_ecef_m, path.pos_ecef_m)
    quiet = run_scenario(replace(cfg, errors=cfg.errors.with_sources(frozenset())))
    assert np.array_equal(quiet.trajectory.pos_ecef_m, path.pos_ecef_m)


@pytest.mark.parametrize("kind", ["flight", "drive"])
def test_start_times_lie_in_the_window_on_the_interval_grid(kind: str) -> None:
    starts = np.array([_run(kind, seed, duration_s=10.0, interval_s=2.0).t_gps_s[0] for seed in range(20)])
    offsets = starts - START_GPS_S
    assert (offsets >= 0.0).all() and (offsets < 86400.0).all()
    assert np.allclose(offsets / 2.0, np.round(offsets / 2.0))
    assert np.unique(starts).size >= 18  # 20 draws out of 43200 slots
    assert offsets.max() - offsets.min() > 3600.0  # hours apart: other satellite geometry
    # start_window_s = 0 starts at --start
    assert _run(kind, 7, duration_s=10.0, start_window_s=0.0).t_gps_s[0] == START_GPS_S


@pytest.mark.parametrize("kind", ["standard-flight", "semicircle", "static"])
def test_fixed_paths_do_not_depend_on_the_seed(kind: str) -> None:
    a, b = _run(kind, 1, duration_s=300.0), _run(kind, 2, duration_s=300.0)
    assert a.t_gps_s[0] == b.t_gps_s[0] == START_GPS_S
    assert np.array_equal(a.pos_ecef_m, b.pos_ecef_m)


@pytest.mark.parametrize("seed", range(1, 13))
def test_flight_manoeuvres_within_the_stated_bounds(seed: int) -> None:
    """Take-off from rest on the ground, then climbs, turns, speed changes and descents; speed,
    climb rate and acceleration inside :data:`FLIGHT_LIMITS`; acceleration continuous."""
    lim, dt = FLIGHT_LIMITS, 0.05
    traj = _run("flight", seed, duration_s=900.0, interval_s=dt)
    v, h = _enu_velocity(traj)
    h0 = h[0]
    speed = np.linalg.norm(v[:, :2], axis=1)
    assert speed[0] < 1e-9 and speed.max() <= lim.max_speed_m_s + 1e-6
    assert np.abs(v[:, 2]).max() <= lim.max_climb_m_s + 1e-6
    assert np.abs(h[: int(10.0 / dt)] - h0).max() < 1e-3  # the roll stays on the runway
    assert h.min() >= h0 - 1e-3 and h.max() - h0 <= lim.max_height_agl_m + 1.0
    assert h.max() - h0 > 500.0  # it climbed
    # acceleration from the velocity (exact on the profile) by differences over dt
    acc = np.diff(v, axis=0) / dt
    along = np.einsum("ti,ti->t", acc[:, :2], v[1:, :2]) / np.maximum(speed[1:], 1e-9)
    lateral = np.sqrt(np.maximum(np.sum(acc[:, :2] ** 2, axis=1) - along**2, 0.0))
    assert np.abs(along).max() <= lim.max_along_m_s2 + 0.05
    assert lateral.max() <= lim.max_lateral_m_s2 + 0.05
    assert np.abs(acc[:, 2]).max() <= lim.max_vertical_m_s2 + 0.05
    assert _acceleration_is_continuous("flight", seed, 0.02)
    # it manoeuvres: turns and speed changes after take-off
    heading = np.unwrap(np.arctan2(v[:, 0], v[:, 1])[speed > 30.0])
    assert np.ptp(heading) > np.deg2rad(25.0) or np.ptp(speed[speed > 30.0]) > 20.0


@pytest.mark.parametrize("seed", range(1, 7))
def test_drive_stays_on_the_ground_within_bounds(seed: int) -> None:
    dt = 0.05
    traj = _run("drive", seed, duration_s=600.0, interval_s=dt)
    v, h = _enu_velocity(traj)
    assert np.abs(h - h[0]).max() < 0.01  # height constant within a centimetre
    assert np.abs(v[:, 2]).max() < 1e-6
    speed = np.linalg.norm(v[:, :2], axis=1)
    assert speed[0] < 1e-9 and speed.max() <= 13.0 + 1e-6  # drive_speed_m_s 10 +- 30 %
    acc = np.diff(v, axis=0) / dt
    # 1.5 m/s^2 speed changes peak at 2.25, a 90 deg turn at 5 m/s in 6 s at ~2 m/s^2
    assert np.linalg.norm(acc, axis=1).max() < 3.5
    assert _acceleration_is_continuous("drive", seed, 0.1)


def _acceleration_is_continuous(kind: str, seed: int, dt: float) -> bool:
    """The largest change of the acceleration between neighbouring samples halves when the spacing
    halves (bounded jerk); a step in the acceleration would stay the same size. ``dt`` a multiple of
    two integration steps (the epochs pick the integration grid's samples)."""
    steps = []
    for h in (dt, dt / 2.0):
        v, _ = _enu_velocity(_run(kind, seed, duration_s=600.0, interval_s=h))
        steps.append(np.abs(np.diff(np.diff(v, axis=0) / h, axis=0)).max())
    return bool(steps[1] < 0.65 * steps[0])
