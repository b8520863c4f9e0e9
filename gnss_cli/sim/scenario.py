"""A simulation run: settings, the computation, and the files it writes.

``run_scenario(config)`` builds the trajectory, the constellations' truth records, the
observables and the (possibly perturbed) navigation records; ``write_scenario`` writes
``obs.rnx``, ``nav.rnx``, ``truth.csv`` and optionally ``truth_ranges.csv`` and ``faults.csv`` (the
random outliers, or in the street canyon the labels of every satellite and epoch). One
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
    drive_trajectory,
    flight_trajectory,
    semicircle_trajectory,
    static_trajectory,
)
from gnss_cli.sim.urban import RECEIVERS, UrbanConfig, validate_urban

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
    trajectory : ``static``, ``flight``, ``standard-flight``, ``drive``, ``semicircle`` or ``csv:FILE``.
    start : ISO 8601 start (GPS time); ``flight`` and ``drive`` start later, at a time drawn from
        the seed (:func:`start_offset_s`).
    start_window_s : ``flight`` and ``drive`` start within this many seconds after ``start``
        (whole intervals drawn uniformly from the seed); 0 starts them at ``start``.
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
    environment : ``open`` (open sky) or ``urban`` (a street canyon, :mod:`gnss_cli.sim.urban`).
    receiver : receiver profile in the canyon, ``single`` or ``dual`` (:data:`~gnss_cli.sim.urban.RECEIVERS`).
    urban : the canyon's settings.
    given : the keys among ``systems`` and ``dual_frequency`` set explicitly (by a TOML file or a
        flag): with ``environment = "urban"`` the receiver profile sets the others
        (:func:`with_receiver_profile`, which :func:`config_from_mapping` applies; a config
        built with ``dataclasses.replace`` runs as it is). Not compared.
    """

    trajectory: str = "static"
    start: str = "2024-03-01T00:00:00"
    start_window_s: float = 86400.0
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
    environment: str = "open"
    receiver: str = "dual"
    urban: UrbanConfig = field(default_factory=UrbanConfig)
    given: frozenset[str] = field(default=frozenset(), compare=False)


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
    """Apply a parsed TOML mapping to ``base`` (see :func:`load_config`); in the street canyon the
    receiver profile fills in what the mapping and ``base`` left unset (:func:`with_receiver_profile`)."""
    unknown_tables = set(data) - {"simulate", "errors", "ionosphere", "urban"}
    if unknown_tables:
        raise ConfigError(f"{source}: unknown table(s) {sorted(unknown_tables)}")
    sim = dict(data.get("simulate", {}))
    err = dict(data.get("errors", {}))
    ion = dict(data.get("ionosphere", {}))
    city = dict(data.get("urban", {}))
    cfg = replace(base, given=base.given | (set(sim) & {"systems", "dual_frequency"}))
    errors = cfg.errors
    try:
        if "errors" in sim:
            errors = errors.with_sources(parse_error_list(str(sim.pop("errors"))))
        layout_keys = {f.name for f in fields(ObsLayout)}
        layout = replace(cfg.layout, **{k: bool(sim.pop(k)) for k in list(sim) if k in layout_keys})
        if "systems" in sim:
            sim["systems"] = parse_systems(str(sim["systems"]))
        scen_keys = {f.name for f in fields(ScenarioConfig)} - {"errors", "layout", "klobuchar_alpha", "klobuchar_beta", "urban", "given"}
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
        bad = set(city) - {f.name for f in fields(UrbanConfig)}
        if bad:
            raise ConfigError(f"{source}: unknown [urban] key(s) {sorted(bad)}")
        city = {k: tuple(float(x) for x in v) if isinstance(v, list) else v for k, v in city.items()}
        urban = validate_urban(replace(cfg.urban, **city))
        cfg = replace(cfg, errors=validate(errors), layout=layout, urban=urban, **sim)
        if ion:
            bad = set(ion) - {"alpha", "beta"}
            if bad or any(len(ion.get(k, [0] * 4)) != 4 for k in ("alpha", "beta")):
                raise ConfigError(f"{source}: [ionosphere] takes alpha and beta, four numbers each")
            cfg = replace(
                cfg,
                klobuchar_alpha=tuple(float(v) for v in ion.get("alpha", cfg.klobuchar_alpha)),
                klobuchar_beta=tuple(float(v) for v in ion.get("beta", cfg.klobuchar_beta)),
            )
        cfg = with_receiver_profile(cfg)
    except (TypeError, UsageError) as exc:
        raise ConfigError(f"{source}: {exc}") from exc
    return cfg


def with_receiver_profile(config: ScenarioConfig) -> ScenarioConfig:
    """In the street canyon, the receiver profile's systems and frequencies where ``config.given``
    does not name them (unchanged in open sky).

    Raises
    ------
    UsageError
        For an unknown environment or receiver.
    """
    if config.environment not in ("open", "urban"):
        raise UsageError(f"--environment: expected open or urban, got {config.environment!r}")
    if config.receiver not in RECEIVERS:
        raise UsageError(f"--receiver: expected one of {sorted(RECEIVERS)}, got {config.receiver!r}")
    if config.environment == "open":
        return config
    profile = RECEIVERS[config.receiver]
    systems = config.systems if "systems" in config.given else profile.systems
    dual = config.layout.dual_frequency if "dual_frequency" in config.given else profile.dual_frequency
    return replace(config, systems=systems, layout=replace(config.layout, dual_frequency=dual))


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


SEEDED_TRAJECTORIES = ("flight", "drive")
"""Trajectory kinds whose path and start time are drawn from the seed."""


def trajectory_streams(seed: int) -> list[np.random.Generator]:
    """The children of the run's generator: the path's manoeuvres (or the drive's legs), the street
    canyon, the start time. Drawn from their own streams, runs that differ only in their error
    sources share them; spawning leaves the parent's stream (the errors) as it was."""
    return np.random.default_rng(seed).spawn(3)


def start_offset_s(config: ScenarioConfig) -> float:
    """Seconds after ``config.start`` at which the run begins: for :data:`SEEDED_TRAJECTORIES` a whole
    number of intervals drawn uniformly in ``[0, start_window_s)`` from the seed's start-time stream
    (so two seeds see other satellite geometry), else 0."""
    if config.trajectory not in SEEDED_TRAJECTORIES or not config.start_window_s > 0.0 or not config.interval_s > 0.0:
        return 0.0
    n = max(int(np.floor(config.start_window_s / config.interval_s)), 1)
    return config.interval_s * float(trajectory_streams(config.seed)[2].integers(0, n))


def epochs_gps_s(config: ScenarioConfig) -> F64:
    """Epoch labels of the run, GPS seconds ``(T,)``, from ``start`` plus :func:`start_offset_s`.

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
    if not config.start_window_s >= 0.0:
        raise UsageError(f"start_window_s must be >= 0, got {config.start_window_s}")
    n = int(np.floor(config.duration_s / config.interval_s + 1e-9)) + 1
    return t0 + start_offset_s(config) + config.interval_s * np.arange(n)


def build_trajectory(config: ScenarioConfig, t_gps_s: F64, rng: np.random.Generator | None = None) -> Trajectory:
    """The receiver trajectory named by ``config.trajectory`` (``rng`` draws the flight's manoeuvres
    or the drive's legs; default: the seed's trajectory stream, :func:`trajectory_streams`).

    Raises
    ------
    UsageError
        For an unknown trajectory kind.
    """
    site = geodetic2ecef(np.deg2rad(config.latitude_deg), np.deg2rad(config.longitude_deg), config.height_m)
    kind = config.trajectory
    if kind == "static":
        return static_trajectory(t_gps_s, site)
    own = rng if rng is not None or kind not in SEEDED_TRAJECTORIES else trajectory_streams(config.seed)[0]
    if kind == "flight":
        return flight_trajectory(t_gps_s, site, own)
    if kind == "standard-flight":
        return flight_trajectory(t_gps_s, site)
    if kind == "drive":
        return drive_trajectory(t_gps_s, site, own, speed_m_s=config.urban.drive_speed_m_s)
    if kind == "semicircle":
        return semicircle_trajectory(t_gps_s, site, speed_m_s=config.semicircle_speed_m_s)
    if kind.startswith("csv:"):
        return csv_trajectory(Path(kind[4:]), t_gps_s)
    raise UsageError(f"--trajectory: expected static, flight, standard-flight, drive, semicircle or csv:FILE, got {kind!r}")


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
    if config.rinex_version == "2.11" and config.layout.phase:
        raise UsageError("--phase: carrier phases are written in RINEX 3 only: use --rinex-version 3")
    with_receiver_profile(config)
    rng = np.random.default_rng(config.seed)
    # the path, the canyon and the start time draw from their own streams (the children of
    # :func:`trajectory_streams`), so runs that differ only in their error sources share them;
    # open sky on a fixed path spawns none (its outlier stream is the parent's first child)
    seeded = config.environment == "urban" or config.trajectory in SEEDED_TRAJECTORIES
    own = rng.spawn(3) if seeded else None
    t = epochs_gps_s(config)
    trajectory = build_trajectory(config, t, own[0] if own else None)
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
        canyon=(config.urban, RECEIVERS[config.receiver], own[1]) if own and config.environment == "urban" else None,
        phase_pll_bandwidth_hz=config.urban.pll_bandwidth_hz if config.layout.phase else None,
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
    if obs.urban is not None:
        written.append(out / "faults.csv")
        _write_csv(urban_labels_table(scenario), written[-1], {"tow_s": "%.3f", "nlos_bias_m": "%.3f", "outlier_m": "%.3f",
                                                                "cn0_dbhz": "%.2f", "el_deg": "%.3f", "az_deg": "%.3f", "mask_deg": "%.3f"})
    elif obs.outlier_bias_m is not None:
        written.append(out / "faults.csv")
        _write_csv(faults_table(scenario), written[-1], {"bias_m": "%.3f"})
    return written


def urban_labels_table(scenario: Scenario) -> pd.DataFrame:
    """The street canyon's labels: one row per satellite and epoch written to ``obs.rnx``.

    Columns: ``time, gps_week, tow_s`` (as truth.csv), ``sv``, ``el_deg, az_deg``, the buildings'
    ``mask_deg`` in that direction, ``los`` (1 direct, 0 NLOS), ``nlos_bias_m`` (extra path on code
    and carrier, m), ``cn0_dbhz`` (first signal, as written), ``slip`` (1: carrier continuity lost
    since the previous epoch, the LLI is set) and ``outlier_m`` (random outlier, m; 0 without).
    """
    obs = scenario.observations
    labels = obs.urban
    if labels is None:
        raise UsageError("urban_labels_table: the scenario has no street canyon (environment open)")
    order = np.argsort(obs.sv, kind="stable")  # the order of obs.rnx
    ti, si = np.nonzero(obs.visible[:, order])
    si = order[si]
    week, tow = gps_s2week_tow(obs.t_gps_s)
    outlier = obs.outlier_bias_m if obs.outlier_bias_m is not None else np.zeros(obs.visible.shape)
    return pd.DataFrame(
        {
            "time": _iso(obs.t_gps_s)[ti],
            "gps_week": week[ti],
            "tow_s": tow[ti],
            "sv": obs.sv[si],
            "el_deg": np.rad2deg(obs.el_rad[ti, si]),
            "az_deg": np.rad2deg(obs.az_rad[ti, si]),
            "mask_deg": np.rad2deg(labels.mask_el_rad[ti, si]),
            "los": labels.los[ti, si].astype(np.int64),
            "nlos_bias_m": labels.nlos_bias_m[ti, si],
            "cn0_dbhz": labels.cn0_dbhz[ti, si],
            "slip": labels.slip[ti, si].astype(np.int64),
            "outlier_m": outlier[ti, si],
        }
    )


def los_grid(labels: pd.DataFrame, time_gps_s: F64, sv: NDArray[np.str_]) -> NDArray[np.int64]:
    """The ``los`` column of a ``faults.csv`` (:func:`urban_labels_table`) on an epoch grid:
    ``(T, n)`` 1 direct, 0 NLOS, -1 no row, for the epochs ``time_gps_s`` (GPS s; matched by their
    time of week to the millisecond) and the satellites ``sv``."""
    rows = labels.assign(tow_s=labels["tow_s"].round(3), sv=labels["sv"].astype(str))
    grid = rows.pivot_table(index="tow_s", columns="sv", values="los", aggfunc="first")
    tow = np.round(gps_s2week_tow(np.asarray(time_gps_s, dtype=float))[1], 3)
    return grid.reindex(index=tow, columns=np.asarray(sv).astype(str)).fillna(-1).to_numpy(dtype=np.int64)


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
