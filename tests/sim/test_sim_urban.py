"""The street canyon (``--environment urban``): open sky unchanged, masks, NLOS, C/N0, carrier
slips, the labels in faults.csv, the receiver profiles, and gnss-solve on the result."""

from __future__ import annotations

import hashlib
import re
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from sim_datasets import simulate

from gnss_cli.cli.exits import run_app
from gnss_cli.cli.simulate import app as simulate_app
from gnss_cli.constants import C_M_S
from gnss_cli.errors import ConfigError
from gnss_cli.gnss.frames import ecef2geodetic, geodetic2ecef
from gnss_cli.io.rinex import read_obs
from gnss_cli.sim.constellation import SYSTEMS
from gnss_cli.sim.error_sources import parse_error_list
from gnss_cli.sim.rinex_writer import ObsLayout
from gnss_cli.sim.scenario import (Scenario, ScenarioConfig, config_from_mapping, los_grid, run_scenario, with_receiver_profile,
                                   write_scenario)
from gnss_cli.sim.trajectory import drive_trajectory
from gnss_cli.sim.urban import RECEIVERS, street_heading_rad, street_mask_rad

# sha256 of the files written, for the settings of the test below, by the simulator before the
# street canyon existed: --environment open must keep writing these bytes. nav.rnx and
# truth_ranges.csv hold values of trigonometric functions to 13 significant digits, whose last
# digit depends on the machine's math library (numpy's SIMD paths, libm): for them the digest is
# of the text with every number rounded to 9 significant digits (:func:`_digest`).
OPEN_SHA256 = {
    "faults.csv": "2a360fd482102c4ccff2fad335e6bbf250f2c056561b5934431fb8b7688769e9",
    "nav.rnx": "5d61f8f2cb8d52d6586f0cae42afb093fb48671d3c63c6e0df29db310600e2a4",
    "obs.rnx": "707f78eb6293b756801d7b2ca88b93e4a3d0938380290dd70db7909ffd8b7c46",
    "truth.csv": "301f4e4248ad01c25fea1420662081d9a62b5548910e2d0aee8c418f6d2b0cd5",
    "truth_ranges.csv": "bea8510293ba365b6065175c7e509fafeb4d124b4f07611f40ed70dcd14e5600",
}
ROUNDED = ("nav.rnx", "truth_ranges.csv")
_NUMBER = re.compile(rb"[-+]?\d+\.\d+(?:[EeDd][-+]?\d+)?")


def _digest(name: str, data: bytes) -> str:
    """sha256 of ``data``; for the files of :data:`ROUNDED`, of the text with each decimal number
    rewritten to 9 significant digits (and -0 as 0), so that a last-digit difference of the math
    library does not count while any changed value does.

    >>> _digest("nav.rnx", b"1.000000000001E+00 -0.000E+00") == _digest("nav.rnx", b"1.000000000002E+00 0.000E+00")
    True
    >>> _digest("nav.rnx", b"1.00000001E+00") == _digest("nav.rnx", b"1.00000002E+00")
    False
    """
    if name in ROUNDED:
        data = _NUMBER.sub(lambda m: f"{float(m.group().replace(b'D', b'E').replace(b'd', b'e')) + 0.0:.8e}".encode(), data)
    return hashlib.sha256(data).hexdigest()


def test_open_environment_writes_the_bytes_of_before(tmp_path: Path) -> None:
    """Flight, G+E+C dual frequency, every error source, random outliers, truth ranges."""
    d = simulate(
        tmp_path, environment="open", trajectory="standard-flight", systems=("G", "E", "C"), duration_s=60.0, interval_s=2.0,
        errors="all", seed=9, layout=ObsLayout(dual_frequency=True), truth_ranges=True,
        error_settings={"outlier_rate": 0.1},
    )
    assert {p.name: _digest(p.name, p.read_bytes()) for p in d.iterdir()} == OPEN_SHA256


def _run(out: Path, errors: str, **changes: object) -> Scenario:
    """A run with ``changes`` over the defaults, the receiver profile applied as the CLI does."""
    cfg = with_receiver_profile(replace(ScenarioConfig(), **changes))  # type: ignore[arg-type]
    cfg = replace(cfg, errors=cfg.errors.with_sources(parse_error_list(errors)))
    scenario = run_scenario(cfg)
    write_scenario(scenario, out)
    return scenario


@dataclass(frozen=True)
class Pair:
    """A drive in the canyon and the same drive under open sky (same seed, systems, signals)."""

    urban_dir: Path
    open_dir: Path
    urban: Scenario
    open: Scenario


@pytest.fixture(scope="module")
def drive_pair(tmp_path_factory: pytest.TempPathFactory) -> Pair:
    """5 min at 1 Hz, dual profile, receiver clock only (no noise: the canyon's effects are exact)."""
    root = tmp_path_factory.mktemp("urban_drive")
    kw: dict[str, object] = {"trajectory": "drive", "duration_s": 300.0, "interval_s": 1.0, "seed": 4}
    urban = _run(root / "urban", "clock", environment="urban", **kw)
    cfg = urban.config
    opened = _run(root / "open", "clock", systems=cfg.systems, layout=cfg.layout, **kw)
    return Pair(root / "urban", root / "open", urban, opened)


def _labels(d: Path) -> pd.DataFrame:
    return pd.read_csv(d / "faults.csv")


def _obs_rows(d: Path) -> pd.DataFrame:
    """The observation file as rows (time, sv) with every code present."""
    ds = read_obs(d / "obs.rnx")
    df = ds.to_dataframe().reset_index()
    df["time"] = df["time"].dt.strftime("%Y-%m-%dT%H:%M:%S.000")
    codes = [c for c in ds.data_vars if c[0] == "C" and len(c) == 3]
    return df[df[codes].notna().any(axis=1)].set_index(["time", "sv"]).sort_index()


def test_the_canyon_keeps_the_drive_and_blocks_satellites(drive_pair: Pair) -> None:
    """Same truth; every tracked satellite is one the open sky also has; clearly fewer of them."""
    assert (drive_pair.urban_dir / "truth.csv").read_bytes() == (drive_pair.open_dir / "truth.csv").read_bytes()
    vis_u, vis_o = drive_pair.urban.observations.visible, drive_pair.open.observations.visible
    assert not (vis_u & ~vis_o).any()
    assert vis_u.sum(axis=1).mean() < 0.85 * vis_o.sum(axis=1).mean()
    assert vis_u.sum(axis=1).min() >= 4  # still solvable: the street is open along its axis


def test_labels_list_exactly_the_written_observations(drive_pair: Pair) -> None:
    labels = _labels(drive_pair.urban_dir)
    assert list(labels.columns) == ["time", "gps_week", "tow_s", "sv", "el_deg", "az_deg", "mask_deg", "los",
                                    "nlos_bias_m", "cn0_dbhz", "slip", "outlier_m"]
    rows = _obs_rows(drive_pair.urban_dir)
    assert set(zip(labels["time"], labels["sv"])) == set(rows.index)
    # direct when above the buildings, else NLOS
    assert ((labels["el_deg"] >= labels["mask_deg"] - 1e-3) == (labels["los"] == 1)).all()
    # the written C/N0 is the label's
    s1 = rows.loc[list(zip(labels["time"], labels["sv"]))]
    first = np.where(labels["sv"].str[0] == "C", s1["S2I"], s1["S1C"])
    assert np.abs(first - labels["cn0_dbhz"].to_numpy()).max() < 0.006


def test_the_labels_go_back_onto_the_epoch_grid(drive_pair: Pair) -> None:
    """``los_grid`` of faults.csv, on the scenario's own epochs and satellites (in reverse order, so
    that columns are matched by name): the canyon's ``los`` where a satellite was written, -1
    where it was not; an epoch the file does not hold is -1 throughout."""
    obs = drive_pair.urban.observations
    assert obs.urban is not None
    order = np.argsort(obs.sv)[::-1]
    t = np.append(obs.t_gps_s, obs.t_gps_s[-1] + 0.5)
    grid = los_grid(_labels(drive_pair.urban_dir), t, obs.sv[order])
    want = np.where(obs.visible, obs.urban.los.astype(np.int64), -1)[:, order]
    np.testing.assert_array_equal(grid[:-1], want)
    assert (grid[-1] == -1).all() and (want == 0).any() and (want == 1).any()


def test_nlos_bias_is_positive_and_is_what_the_pseudoranges_carry(drive_pair: Pair) -> None:
    """Canyon minus open sky, same seed and clock: the label's bias on NLOS, 0 on line of sight,
    on both signals (three F14.3 / %.3f roundings: < 2 mm)."""
    labels = _labels(drive_pair.urban_dir).set_index(["time", "sv"])
    u, o = _obs_rows(drive_pair.urban_dir), _obs_rows(drive_pair.open_dir)
    o = o.loc[u.index]
    nlos = labels.loc[u.index, "los"].to_numpy() == 0
    bias = labels.loc[u.index, "nlos_bias_m"].to_numpy()
    assert nlos.sum() > 300
    assert (bias[nlos] > 0.0).all() and (bias[~nlos] == 0.0).all()
    assert 1.0 < np.median(bias[nlos]) < 40.0 and bias[nlos].max() < 100.0
    n_checked = 0
    for s in sorted({sv[0] for sv in labels.index.get_level_values("sv")}):
        mine = u.index.get_level_values("sv").str[0] == s
        for code in SYSTEMS[s].codes:
            diff = (u.loc[mine, code] - o.loc[mine, code]).to_numpy()
            assert np.abs(diff - bias[mine]).max() < 2e-3, (s, code)
            n_checked += mine.sum()
    assert n_checked == 2 * len(u)


def _runs(flags: np.ndarray) -> np.ndarray:
    """Lengths of the runs of True along axis 0 of ``(T, n)``, all columns."""
    padded = np.vstack([np.zeros((1, flags.shape[1]), bool), flags, np.zeros((1, flags.shape[1]), bool)]).astype(int)
    edges = np.diff(padded, axis=0)
    starts, ends = np.nonzero(edges.T == 1), np.nonzero(edges.T == -1)
    return ends[1] - starts[1]


def test_nlos_persists_for_seconds(drive_pair: Pair) -> None:
    obs = drive_pair.urban.observations
    assert obs.urban is not None
    runs = _runs(obs.visible & ~obs.urban.los)
    assert runs.size > 20
    assert np.median(runs) >= 5 and runs.max() >= 20


def test_nlos_cn0_is_lower_than_line_of_sight_at_the_same_elevation(drive_pair: Pair) -> None:
    """Without noise the LOS C/N0 is the profile's model and NLOS is 8..16 dB (the [urban]
    range) below it."""
    labels = _labels(drive_pair.urban_dir)
    profile, urban = RECEIVERS[drive_pair.urban.config.receiver], drive_pair.urban.config.urban
    model = profile.cn0_zenith_dbhz - urban.cn0_elevation_drop_db * (1.0 - np.sin(np.deg2rad(labels["el_deg"])))
    drop = (model - labels["cn0_dbhz"]).to_numpy()
    los = labels["los"].to_numpy() == 1
    assert np.abs(drop[los]).max() < 0.01
    assert drop[~los].min() > 8.0 - 0.01 and drop[~los].max() < 16.0 + 0.01
    # and binned by elevation, as a solver would see it
    bins = np.floor(labels["el_deg"] / 10.0)
    means = labels.groupby([bins, labels["los"]])["cn0_dbhz"].mean().unstack()
    both = means.dropna()
    assert len(both) >= 2 and ((both[1] - both[0]) > 6.0).all()


def test_doppler_carries_the_nlos_delay_rate(drive_pair: Pair) -> None:
    """Canyon minus open-sky Doppler = -(d bias / dt) / lambda where the path stays one reflector
    (the central difference of the bias itself); 0 on line of sight."""
    u, o = drive_pair.urban.observations, drive_pair.open.observations
    assert u.urban is not None
    nlos = u.visible & ~u.urban.los
    lam = np.array([C_M_S / SYSTEMS[s[0]].freqs_hz[0] for s in u.sv])
    d_dop = (u.doppler_hz - o.doppler_hz)[..., 0]
    bias = u.urban.nlos_bias_m
    same_path = nlos[1:-1] & nlos[:-2] & nlos[2:] & ~u.urban.slip[1:-1] & ~u.urban.slip[2:]
    rate = (bias[2:] - bias[:-2]) / 2.0
    assert same_path.sum() > 200
    assert np.abs(d_dop[1:-1] + rate / lam)[same_path].max() < 1e-6
    assert np.abs(rate[same_path]).max() > 1e-3  # 5e-3 Hz and more: a missing rate term fails above
    los = u.visible & u.urban.los
    assert np.abs(d_dop[los]).max() < 1e-9


@pytest.fixture(scope="module")
def static_canyon(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A receiver standing in a street, 10 min at 1 Hz, single profile, no errors: its carrier
    phase follows the Doppler to well under 0.01 cycle except where lock is lost."""
    d = tmp_path_factory.mktemp("urban_static")
    _run(d, "none", environment="urban", receiver="single", duration_s=600.0, interval_s=1.0, seed=2)
    return d


def test_carrier_phase_slips_carry_the_loss_of_lock_indicator(static_canyon: Path) -> None:
    ds = read_obs(static_canyon / "obs.rnx", codes=["L1C", "L1Clli", "D1C"])
    labels = _labels(static_canyon)
    phase, lli, dop = ds["L1C"].values, ds["L1Clli"].values, ds["D1C"].values
    sv = list(ds["sv"].values)
    gps = labels[labels["sv"].str[0] == "G"]
    ti = np.searchsorted(pd.to_datetime(ds["time"].values), pd.to_datetime(gps["time"]))
    si = np.array([sv.index(s) for s in gps["sv"]])
    assert ((np.nan_to_num(lli[ti, si]) % 2 == 1) == (gps["slip"].to_numpy() == 1)).all()
    assert gps["slip"].sum() > 10
    # phase change over an epoch vs the trapezoid of the Doppler (satellite dynamics: < 1e-4 cycle;
    # F14.3 rounding 1e-3)
    residual = (phase[1:] - phase[:-1]) + 0.5 * (dop[1:] + dop[:-1])
    flagged = np.nan_to_num(lli[1:]) % 2 == 1
    both = np.isfinite(residual)
    assert np.abs(residual[both & ~flagged]).max() < 0.01
    assert (np.abs(residual[both & flagged]) > 0.5).all()


def test_urban_runs_are_reproducible_for_a_seed(tmp_path: Path) -> None:
    kw: dict[str, object] = {"environment": "urban", "trajectory": "drive", "duration_s": 60.0, "interval_s": 1.0}
    _run(tmp_path / "a", "all", seed=11, **kw)
    _run(tmp_path / "b", "all", seed=11, **kw)
    _run(tmp_path / "c", "all", seed=12, **kw)
    for name in ("obs.rnx", "nav.rnx", "truth.csv", "faults.csv"):
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes(), name
    assert (tmp_path / "a" / "faults.csv").read_bytes() != (tmp_path / "c" / "faults.csv").read_bytes()


def _obs_types(path: Path) -> dict[str, list[str]]:
    types = {}
    for line in path.read_text().splitlines():
        if line[60:].strip() == "SYS / # / OBS TYPES":
            types[line[0]] = line[7:60].split()
        if "END OF HEADER" in line:
            break
    return types


@pytest.mark.parametrize(
    ("args", "expected"),
    [
        (["--receiver", "single"], {"G": ["C1C", "L1C", "D1C", "S1C"], "C": ["C2I", "L2I", "D2I", "S2I"]}),
        (["--receiver", "dual", "--position", "35.7,139.7,40"],
         {s: [f"{k}{c[1:]}" for c in SYSTEMS[s].codes for k in "CLDS"] for s in "GECJ"}),
        (["--receiver", "dual", "--systems", "G"], {"G": ["C1C", "L1C", "D1C", "S1C", "C2W", "L2W", "D2W", "S2W"]}),
        (["--receiver", "dual", "--single-frequency"],
         {s: [f"{k}{SYSTEMS[s].codes[0][1:]}" for k in "CLDS"] for s in "GECJ"}),
    ],
)
def test_receiver_profiles_write_the_systems_and_signals_they_promise(
    args: list[str], expected: dict[str, list[str]], tmp_path: Path
) -> None:
    with pytest.raises(SystemExit) as exc:
        run_app(simulate_app, "gnss-simulate",
                ["--out-dir", str(tmp_path), "--environment", "urban", "--duration", "30", "--quiet", *args])
    assert exc.value.code == 0
    assert _obs_types(tmp_path / "obs.rnx") == expected
    written = set(pd.read_csv(tmp_path / "faults.csv")["sv"].str[0])
    assert written == set(expected)  # every promised system is tracked (QZSS over Japan)


def test_profile_applies_only_in_the_canyon_and_yields_to_explicit_settings() -> None:
    base = ScenarioConfig()
    assert config_from_mapping({"simulate": {"receiver": "single"}}, base).systems == base.systems
    city = config_from_mapping({"simulate": {"environment": "urban"}}, base)
    assert city.systems == RECEIVERS["dual"].systems and city.layout.dual_frequency
    mine = config_from_mapping({"simulate": {"environment": "urban", "systems": "E"}}, base)
    assert mine.systems == ("E",)
    # a later layer changing the receiver keeps the systems an earlier layer gave
    assert config_from_mapping({"simulate": {"receiver": "single"}}, mine).systems == ("E",)
    assert config_from_mapping({"simulate": {"receiver": "single"}}, city).systems == ("G", "C")
    with pytest.raises(ConfigError, match="--receiver"):
        config_from_mapping({"simulate": {"receiver": "triple"}}, base)
    with pytest.raises(ConfigError, match="street_widht_m"):
        config_from_mapping({"urban": {"street_widht_m": [10.0, 20.0]}}, base)
    with pytest.raises(ConfigError, match="nlos_share"):
        config_from_mapping({"urban": {"nlos_share": 1.5}}, base)


def test_street_mask_is_high_across_the_street_and_zero_along_it() -> None:
    """A 20 m wide street between 11.5 m walls (above the antenna): atan(11.5 / 10) across,
    0 along, and atan(11.5 |sin a| / 10) between (the wall is 10 / |sin a| away)."""
    az = np.deg2rad(np.array([0.0, 30.0, 90.0, 180.0, 270.0]))
    mask = street_mask_rad(az, 10.0, 11.5)
    assert mask[0] == 0.0 and abs(mask[3]) < 1e-15
    assert np.isclose(mask[2], np.arctan(1.15)) and np.isclose(mask[4], np.arctan(1.15))
    assert np.isclose(np.tan(mask[1]) * 10.0 / np.sin(np.deg2rad(30.0)), 11.5)
    assert street_mask_rad(np.pi / 2, 10.0, -1.0) == 0.0  # no building: no mask


def test_street_heading_follows_the_travel_and_holds_when_stopped() -> None:
    t = np.arange(6.0)
    v = np.array([[0, 0, 0], [3, 0, 0], [0, 0, 0], [0, 0, 0], [0, 4, 0], [0, 0, 0]], float)  # E, stop, N, stop
    heading, dist = street_heading_rad(v, t, 1.0)
    assert np.allclose(heading, [np.pi / 2, np.pi / 2, np.pi / 2, np.pi / 2, 0.0, 0.0])
    assert np.allclose(dist, [0.0, 1.5, 3.0, 3.0, 5.0, 7.0])  # trapezoid of the speeds
    assert np.allclose(street_heading_rad(np.zeros((3, 3)), t[:3], 1.0)[0], 1.0)


def test_drive_has_legs_stops_and_turns_on_the_ellipsoid() -> None:
    site = geodetic2ecef(np.deg2rad(55.5), np.deg2rad(8.5), 50.0)
    t = 1.0e9 + np.arange(0.0, 3600.0 + 0.01, 0.05)  # the integration grid (20 Hz)
    traj = drive_trajectory(t, site, np.random.default_rng(3))
    v = traj.vel_ecef_m_s
    # velocities are the derivatives of the positions: the trapezoid over one 0.05 s step
    assert np.abs(np.diff(traj.pos_ecef_m, axis=0) - 0.025 * (v[1:] + v[:-1])).max() < 1e-4
    _, _, h = ecef2geodetic(traj.pos_ecef_m)
    assert np.abs(h - 50.0).max() < 1e-4
    speed = np.linalg.norm(v, axis=1)
    moving = speed > 0.5
    assert 7.0 < speed[moving].mean() < 13.0 and speed.max() <= 13.0 + 1e-9
    stops = _runs((~moving)[:, None])
    assert (stops * 0.05 >= 5.0).sum() >= 3  # stops of 5 s or more
    heading = np.unwrap(np.arctan2(*np.einsum("tij,tj->ti", _enu(traj.pos_ecef_m), v)[moving, :2].T))
    turns = np.abs(np.diff(np.round(heading[::200] / (np.pi / 2))))
    assert turns.sum() >= 5
    # the seed fixes the drive
    assert np.array_equal(drive_trajectory(t, site, np.random.default_rng(3)).pos_ecef_m, traj.pos_ecef_m)
    other = drive_trajectory(t, site, np.random.default_rng(4))
    assert np.abs(other.pos_ecef_m - traj.pos_ecef_m).max() > 100.0


def _enu(pos_ecef_m: np.ndarray) -> np.ndarray:
    from gnss_cli.gnss.frames import ecef2enu_rotation

    lat, lon, _ = ecef2geodetic(pos_ecef_m)
    return ecef2enu_rotation(lat, lon)


@pytest.mark.parametrize("method", ["wls", "smoother"])
def test_gnss_solve_runs_on_the_canyon(method: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from gnss_cli.cli.solve import app as solve_app

    d = tmp_path / "sim"
    _run(d, "all", environment="urban", receiver="single", trajectory="drive", duration_s=120.0, seed=5)
    with pytest.raises(SystemExit) as exc:
        run_app(solve_app, "gnss-solve", [str(d / "obs.rnx"), str(d / "nav.rnx"), "--method", method,
                                          "--reference-csv", str(d / "truth.csv"), "--out-dir", str(tmp_path / "out")])
    assert exc.value.code == 0
    err = capsys.readouterr().err
    assert f"{method}: " in err and "3D RMS" in err
    errors = pd.read_csv(tmp_path / "out" / "errors.csv")
    assert len(errors) == 121 and (errors["status"] == "ok").any()  # a row per epoch, some accepted


def test_canyon_flags_show_the_packaged_defaults() -> None:
    import typer

    from gnss_cli.config import packaged_defaults

    command = typer.main.get_command(simulate_app)
    options = {opt: p for p in command.params for opt in getattr(p, "opts", [])}
    toml, built_in = packaged_defaults("simulate.toml"), ScenarioConfig()
    for flag, key in (("--environment", "environment"), ("--receiver", "receiver")):
        assert options[flag].default is None, flag  # type: ignore[attr-defined]
        assert options[flag].show_default == toml["simulate"][key] == getattr(built_in, key), flag  # type: ignore[attr-defined]
    assert set(toml["urban"]) == {f for f in built_in.urban.__dataclass_fields__}


@pytest.mark.parametrize(("args", "message"), [(["--environment", "city"], "--environment"),
                                               (["--environment", "urban", "--receiver", "triple"], "--receiver")])
def test_unknown_environment_or_receiver_is_a_configuration_error(
    args: list[str], message: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as exc:
        run_app(simulate_app, "gnss-simulate", ["--out-dir", str(tmp_path), "--duration", "10", *args])
    assert exc.value.code == 3
    assert message in capsys.readouterr().err
    assert not any(tmp_path.iterdir())
