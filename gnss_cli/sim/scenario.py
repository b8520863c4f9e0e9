"""A simulation run: settings, the computation, and the files it writes.

``run_scenario(config)`` builds the trajectory, the constellations' truth records, the
observables and the (possibly perturbed) navigation records; ``write_scenario`` writes
``obs.rnx``, ``nav.rnx``, ``truth.csv`` and optionally ``truth_ranges.csv``. One
``numpy.random.Generator`` seeded with ``config.seed`` drives every random draw, in a fixed
order, so the same settings give the same bytes.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from gnss_cli.constants import SECONDS_PER_WEEK
from gnss_cli.errors import ConfigError, InputFileNotFoundError, UsageError
from gnss_cli.gnss.ephemeris import KeplerEphemeris
from gnss_cli.gnss.frames import ecef2geodetic, geodetic2ecef
from gnss_cli.gnss.time import datetime2gps_s, gps_s2datetime, gps_s2week_tow
from gnss_cli.sim.constellation import SYSTEMS, broadcast_records, issue_times_gps_s, nominal_constellation
from gnss_cli.sim.error_sources import ErrorConfig, parse_error_list, perturb_ephemeris, validate
from gnss_cli.sim.observables import Observations, simulate_observations
from gnss_cli.sim.rinex_writer import ObsLayout, write_nav_rinex3, write_obs_rinex2, write_obs_rinex3
from gnss_cli.sim.trajectory import (
    Trajectory,
    csv_trajectory,
    flight_trajectory,
    semicircle_trajectory,
    static_trajectory,
)

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

F64 = NDArray[np.float64]

KLOBUCHAR_ALPHA = (1.1176e-08, 7.4506e-09, -5.9605e-08, -5.9605e-08)
KLOBUCHAR_BETA = (9.0112e04, 4.9152e04, -1.3107e05, -3.2768e05)


@dataclass(frozen=True)
class ScenarioConfig:
    """Settings of one run (defaults = ``gnss_cli/configs/simulate.toml``).

    Attributes
    ----------
    trajectory : ``static``, ``flight``, ``semicircle`` or ``csv:FILE``.
    start : ISO 8601 start (GPS time).
    duration_s, interval_s : run length and epoch spacing, s.
    systems : system letters (``G``, ``E``, ``C``, ``J``).
    seed : seed of the run's random generator.
    errors : error sources and sizes.
    elevation_mask_deg : satellites below are not written.
    latitude_deg, longitude_deg, height_m : static site / take-off point / semicircle centre.
    semicircle_speed_m_s : speed on the semicircle.
    rinex_version : ``3.04``, ``3.05`` or ``2.11`` for the observation file.
    layout : observation types written.
    truth_ranges : also write ``truth_ranges.csv``.
    klobuchar_alpha, klobuchar_beta : broadcast ionosphere coefficients.
    constellation_seed : seed of the (fixed) constellation design.
    """

    trajectory: str = "static"
    start: str = "2024-03-01T00:00:00"
    duration_s: float = 3600.0
    interval_s: float = 1.0
    systems: tuple[str, ...] = ("G",)
    seed: int = 7
    errors: ErrorConfig = field(default_factory=lambda: ErrorConfig(enabled=parse_error_list("all")))
    elevation_mask_deg: float = 5.0
    latitude_deg: float = 55.5
    longitude_deg: float = 8.5
    height_m: float = 50.0
    semicircle_speed_m_s: float = 50.0
    rinex_version: str = "3.04"
    layout: ObsLayout = field(default_factory=ObsLayout)
    truth_ranges: bool = False
    klobuchar_alpha: tuple[float, ...] = KLOBUCHAR_ALPHA
    klobuchar_beta: tuple[float, ...] = KLOBUCHAR_BETA
    constellation_seed: int = 2024


@dataclass(frozen=True)
class Scenario:
    """A computed run: the settings, trajectory, truth and broadcast records, observables."""

    config: ScenarioConfig
    trajectory: Trajectory
    truth: dict[str, KeplerEphemeris]
    nav: dict[str, KeplerEphemeris]
    tgd2_s: dict[str, F64]
    observations: Observations


def load_config(path: Path, base: ScenarioConfig | None = None) -> ScenarioConfig:
    """Settings from a TOML file (``[simulate]``, ``[errors]``, ``[ionosphere]`` tables) over ``base``.

    Raises
    ------
    InputFileNotFoundError
        When the file is missing.
    ConfigError
        For invalid TOML, unknown keys or wrong types.
    """
    p = Path(path)
    if not p.is_file():
        raise InputFileNotFoundError(f"configuration file not found: {p}")
    try:
        data = tomllib.loads(p.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{p}: not valid TOML ({exc})") from exc
    return config_from_mapping(data, base or ScenarioConfig(), source=str(p))


def config_from_mapping(data: dict[str, Any], base: ScenarioConfig, *, source: str = "configuration") -> ScenarioConfig:
    """Apply a parsed TOML mapping to ``base`` (see :func:`load_config`)."""
    unknown_tables = set(data) - {"simulate", "errors", "ionosphere"}
    if unknown_tables:
        raise ConfigError(f"{source}: unknown table(s) {sorted(unknown_tables)}")
    sim = dict(data.get("simulate", {}))
    err = dict(data.get("errors", {}))
    ion = dict(data.get("ionosphere", {}))
    cfg = base
    errors = cfg.errors
    try:
        if "errors" in sim:
            errors = errors.with_sources(parse_error_list(str(sim.pop("errors"))))
        layout_keys = {f.name for f in fields(ObsLayout)}
        layout = replace(cfg.layout, **{k: bool(sim.pop(k)) for k in list(sim) if k in layout_keys})
        if "systems" in sim:
            sim["systems"] = parse_systems(str(sim["systems"]))
        scen_keys = {f.name for f in fields(ScenarioConfig)} - {"errors", "layout", "klobuchar_alpha", "klobuchar_beta"}
        bad = set(sim) - scen_keys
        if bad:
            raise ConfigError(f"{source}: unknown [simulate] key(s) {sorted(bad)}")
        err_keys = {f.name for f in fields(ErrorConfig)} - {"enabled"}
        bad = set(err) - err_keys
        if bad:
            raise ConfigError(f"{source}: unknown [errors] key(s) {sorted(bad)}")
        for key in ("outlier_sats", "orbit_ric_weights", "outlier_range_m"):
            if key in err:
                err[key] = tuple(err[key])
        errors = replace(errors, **err)
        cfg = replace(cfg, errors=validate(errors), layout=layout, **sim)
        if ion:
            bad = set(ion) - {"alpha", "beta"}
            if bad or any(len(ion.get(k, [0] * 4)) != 4 for k in ("alpha", "beta")):
                raise ConfigError(f"{source}: [ionosphere] takes alpha and beta, four numbers each")
            cfg = replace(
                cfg,
                klobuchar_alpha=tuple(float(v) for v in ion.get("alpha", cfg.klobuchar_alpha)),
                klobuchar_beta=tuple(float(v) for v in ion.get("beta", cfg.klobuchar_beta)),
            )
    except (TypeError, UsageError) as exc:
        raise ConfigError(f"{source}: {exc}") from exc
    return cfg


def parse_systems(text: str) -> tuple[str, ...]:
    """``'G,E'`` -> ``('G', 'E')``.

    Raises
    ------
    UsageError
        For an empty list or a system that cannot be simulated.
    """
    letters = tuple(dict.fromkeys(w.strip().upper() for w in text.split(",") if w.strip()))
    bad = [s for s in letters if s not in SYSTEMS]
    if not letters or bad:
        raise UsageError(f"--systems: expected a comma list of {sorted(SYSTEMS)}, got {text!r}")
    return letters


def epochs_gps_s(config: ScenarioConfig) -> F64:
    """Epoch labels of the run, GPS seconds ``(T,)``.

    Raises
    ------
    UsageError
        For a bad start time, a non-positive interval or a negative duration.
    """
    try:
        t0 = float(datetime2gps_s(np.datetime64(config.start, "ns")))
    except ValueError as exc:
        raise UsageError(f"--start: not an ISO 8601 time: {config.start!r}") from exc
    if not config.interval_s > 0.0 or not config.duration_s >= 0.0:
        raise UsageError(f"interval must be > 0 and duration >= 0, got {config.interval_s} and {config.duration_s}")
    n = int(np.floor(config.duration_s / config.interval_s + 1e-9)) + 1
    return t0 + config.interval_s * np.arange(n)


def build_trajectory(config: ScenarioConfig, t_gps_s: F64) -> Trajectory:
    """The receiver trajectory named by ``config.trajectory``.

    Raises
    ------
    UsageError
        For an unknown trajectory kind.
    """
    site = geodetic2ecef(np.deg2rad(config.latitude_deg), np.deg2rad(config.longitude_deg), config.height_m)
    kind = config.trajectory
    if kind == "static":
        return static_trajectory(t_gps_s, site)
    if kind == "flight":
        return flight_trajectory(t_gps_s, site)
    if kind == "semicircle":
        return semicircle_trajectory(t_gps_s, site, speed_m_s=config.semicircle_speed_m_s)
    if kind.startswith("csv:"):
        return csv_trajectory(Path(kind[4:]), t_gps_s)
    raise UsageError(f"--trajectory: expected static, flight, semicircle or csv:FILE, got {kind!r}")


def run_scenario(config: ScenarioConfig) -> Scenario:
    """Compute a run (no files written).

    Raises
    ------
    UsageError, ConfigError, InputError
        For invalid settings or an unreadable trajectory file.
    """
    validate(config.errors)
    if config.rinex_version not in ("3.04", "3.05", "2.11"):
        raise UsageError(f"--rinex-version: expected 3 (3.04), 3.05 or 2 (2.11), got {config.rinex_version!r}")
    if config.rinex_version == "2.11" and ("C" in config.systems or "J" in config.systems):
        raise UsageError("RINEX 2.11 does not define BeiDou or QZSS observations: use --rinex-version 3")
    rng = np.random.default_rng(config.seed)
    t = epochs_gps_s(config)
    trajectory = build_trajectory(config, t)
    week_start = float(np.floor(t[0] / SECONDS_PER_WEEK) * SECONDS_PER_WEEK)
    truth: dict[str, KeplerEphemeris] = {}
    tgd2: dict[str, F64] = {}
    for system in config.systems:
        constellation = nominal_constellation(system, week_start, seed=config.constellation_seed)
        toes = issue_times_gps_s(system, float(t[0]), float(t[-1]))
        truth[system] = broadcast_records(constellation, toes)
        tgd2[system] = np.tile(constellation.tgd2_s, toes.size)
    obs = simulate_observations(
        trajectory,
        truth,
        tgd2,
        config.errors,
        rng,
        klobuchar_alpha=np.asarray(config.klobuchar_alpha),
        klobuchar_beta=np.asarray(config.klobuchar_beta),
        elevation_mask_deg=config.elevation_mask_deg,
    )
    nav = dict(truth)
    if config.errors.on("orbit"):
        for system in config.systems:
            spec = SYSTEMS[system]
            nav[system] = perturb_ephemeris(
                truth[system],
                config.errors.orbit_rms_m,
                rng,
                gm_m3_s2=spec.gm_m3_s2,
                omega_e_rad_s=spec.omega_e_rad_s,
                ric_weights=config.errors.orbit_ric_weights,
            )
    return Scenario(config, trajectory, truth, nav, tgd2, obs)


def truth_table(scenario: Scenario) -> pd.DataFrame:
    """The receiver truth: one row per epoch (label time), position at the true reception time."""
    obs = scenario.observations
    week, tow = gps_s2week_tow(obs.t_gps_s)
    lat, lon, h = ecef2geodetic(obs.rx_pos_ecef_m)
    return pd.DataFrame(
        {
            "time": _iso(obs.t_gps_s),
            "gps_week": week,
            "tow_s": tow,
            "x_m": obs.rx_pos_ecef_m[:, 0],
            "y_m": obs.rx_pos_ecef_m[:, 1],
            "z_m": obs.rx_pos_ecef_m[:, 2],
            "vx_m_s": obs.rx_vel_ecef_m_s[:, 0],
            "vy_m_s": obs.rx_vel_ecef_m_s[:, 1],
            "vz_m_s": obs.rx_vel_ecef_m_s[:, 2],
            "lat_deg": np.rad2deg(lat),
            "lon_deg": np.rad2deg(lon),
            "height_m": h,
            "clock_m": obs.rx_clock_m,
            "clock_drift_m_s": obs.rx_clock_drift_m_s,
        }
    )


def truth_ranges_table(scenario: Scenario) -> pd.DataFrame:
    """Per visible satellite and epoch: true transmit time, satellite position and clock, range,
    elevation, azimuth and the atmospheric delays put into the first pseudorange."""
    obs = scenario.observations
    ti, si = np.nonzero(obs.visible)
    return pd.DataFrame(
        {
            "time": _iso(obs.t_gps_s)[ti],
            "sv": obs.sv[si],
            "t_tx_gps_s": obs.t_tx_gps_s[ti, si],
            "x_sv_m": obs.sv_pos_ecef_m[ti, si, 0],
            "y_sv_m": obs.sv_pos_ecef_m[ti, si, 1],
            "z_sv_m": obs.sv_pos_ecef_m[ti, si, 2],
            "clock_sv_m": obs.sv_clock_m[ti, si],
            "range_m": obs.range_m[ti, si],
            "el_deg": np.rad2deg(obs.el_rad[ti, si]),
            "az_deg": np.rad2deg(obs.az_rad[ti, si]),
            "iono_m": obs.iono_m[ti, si],
            "tropo_m": obs.tropo_m[ti, si],
        }
    )


def _iso(t_gps_s: F64) -> NDArray[np.str_]:
    return np.datetime_as_string(gps_s2datetime(t_gps_s), unit="ms")


def write_scenario(scenario: Scenario, out_dir: Path) -> list[Path]:
    """Write ``obs.rnx``, ``nav.rnx``, ``truth.csv`` (and ``truth_ranges.csv``) into ``out_dir``.

    Returns
    -------
    list of Path
        The files written.
    """
    cfg = scenario.config
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    obs = scenario.observations
    approx = scenario.trajectory.pos_ecef_m[0]
    written = [out / "obs.rnx", out / "nav.rnx", out / "truth.csv"]
    if cfg.rinex_version == "2.11":
        write_obs_rinex2(written[0], obs, approx, cfg.interval_s, layout=cfg.layout)
    else:
        write_obs_rinex3(written[0], obs, approx, cfg.interval_s, layout=cfg.layout, version=cfg.rinex_version)
    write_nav_rinex3(
        written[1],
        scenario.nav,
        scenario.tgd2_s,
        np.asarray(cfg.klobuchar_alpha),
        np.asarray(cfg.klobuchar_beta),
        float(obs.t_gps_s[0]),
    )
    formats = {"tow_s": "%.3f"}
    _write_csv(truth_table(scenario), written[2], formats)
    if cfg.truth_ranges:
        written.append(out / "truth_ranges.csv")
        _write_csv(truth_ranges_table(scenario), written[-1], {"t_tx_gps_s": "%.9f", "el_deg": "%.4f", "az_deg": "%.4f"})
    if obs.outlier_bias_m is not None:
        written.append(out / "faults.csv")
        _write_csv(faults_table(scenario), written[-1], {"bias_m": "%.3f"})
    return written


def faults_table(scenario: Scenario) -> pd.DataFrame:
    """The random outliers (``outlier_rate > 0``): one row per faulty epoch, its satellite and bias (m)."""
    obs = scenario.observations
    bias = obs.outlier_bias_m if obs.outlier_bias_m is not None else np.zeros(obs.visible.shape)
    ti, si = np.nonzero(bias)
    return pd.DataFrame({"time": _iso(obs.t_gps_s)[ti], "satellite": obs.sv[si], "bias_m": bias[ti, si]})


def _write_csv(df: pd.DataFrame, path: Path, formats: dict[str, str]) -> None:
    """CSV with fixed float formats: 4 decimals (0.1 mm, 0.1 mm/s) unless given; degrees 9."""
    out = df.copy()
    for col in out.columns:
        if out[col].dtype.kind == "f":
            fmt = formats.get(col, "%.9f" if col in ("lat_deg", "lon_deg") else "%.4f")
            out[col] = [fmt % v for v in out[col].to_numpy()]
    out.to_csv(path, index=False, lineterminator="\n")
