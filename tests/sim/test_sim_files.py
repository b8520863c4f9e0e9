"""Simulator outputs: readability, truth consistency, orbit error size, determinism, settings."""

from __future__ import annotations

import warnings
from importlib.resources import as_file, files
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from sim_datasets import simulate

from gnss_cli.cli.exits import run_app
from gnss_cli.cli.simulate import app
from gnss_cli.constants import C_M_S
from gnss_cli.gnss.ephemeris import KeplerEphemeris, select_ephemeris
from gnss_cli.gnss.frames import geodetic2ecef
from gnss_cli.gnss.orbits import broadcast_states
from gnss_cli.sim.constellation import SYSTEMS
from gnss_cli.sim.scenario import ScenarioConfig, load_config
from gnss_cli.sim.trajectory import flight_trajectory

ROOT = Path(__file__).resolve().parents[2]


def _georinex_load(path: Path):  # noqa: ANN202 - xarray Dataset
    georinex = pytest.importorskip("georinex")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FutureWarning)
        return georinex.load(path)


def test_georinex_reads_flight_obs_and_nav(tmp_path: Path) -> None:
    """The flight's files as georinex reads them (one minute: georinex takes ~0.1 s an epoch)."""
    from gnss_cli.sim.rinex_writer import ObsLayout

    flight = simulate(tmp_path / "flight", trajectory="flight", systems=("G", "E"), duration_s=60.0, interval_s=1.0,
                      errors="clock", layout=ObsLayout(dual_frequency=True))
    obs = _georinex_load(flight / "obs.rnx")
    nav = _georinex_load(flight / "nav.rnx")
    assert obs.sizes["time"] == 61
    assert {"C1C", "C2W", "C7Q", "D1C", "S1C"} <= set(obs.data_vars)
    # every satellite written has a pseudorange of GNSS size at every epoch it is listed
    c1 = obs["C1C"].values
    assert np.nanmin(c1) > 1.9e7 and np.nanmax(c1) < 3.0e7
    systems = {s[0] for s in nav["sv"].values}
    assert systems == {"G", "E"}
    for s in "GE":
        eph = KeplerEphemeris.from_dataset(nav, s)
        assert len(eph) > 0 and np.all(eph.sqrt_a_sqrt_m > 5000.0)


def test_georinex_reads_rinex2_obs(tmp_path: Path) -> None:
    data = simulate(tmp_path / "v2", systems=("G", "E"), duration_s=120.0, interval_s=30.0, errors="noise", rinex_version="2.11")
    obs = _georinex_load(data / "obs.rnx")
    assert obs.sizes["time"] == 5
    assert "C1" in obs.data_vars
    n_listed = sum(int(line[29:32]) for line in (data / "obs.rnx").read_text().splitlines()[14:] if line[:3] == " 24")
    assert int(np.isfinite(obs["C1"].values).sum()) == n_listed


def test_flight_velocity_is_derivative_of_position() -> None:
    """Simpson's rule over 1 s from the truth velocities reproduces the position change: its error
    (h^5/90 |v''''|) is far below 1 mm for aircraft dynamics, so 1 mm checks the truth's consistency."""
    start = geodetic2ecef(np.deg2rad(55.5), np.deg2rad(8.5), 50.0)
    t = 1.0e9 + np.arange(0.0, 600.0 + 0.25, 0.5)
    traj = flight_trajectory(t, start)
    v = traj.vel_ecef_m_s
    simpson = (v[:-2:2] + 4.0 * v[1:-1:2] + v[2::2]) / 6.0 * 1.0
    delta = traj.pos_ecef_m[2::2] - traj.pos_ecef_m[:-2:2]
    assert np.abs(simpson - delta).max() < 1e-3
    speed = np.linalg.norm(v, axis=1)
    assert speed.max() > 200.0 and np.linalg.norm(traj.pos_ecef_m[-1] - start) > 20_000.0


def test_flight_truth_csv_velocity_matches_positions(flight_exact: Path) -> None:
    """truth.csv at 1 Hz: trapezoid of the velocities vs position change, bounded by the
    trapezoid error h^3/12 |a'| with |a'| < 2 m/s^3 for these manoeuvres (plus 0.1 mm rounding)."""
    truth = pd.read_csv(flight_exact / "truth.csv")
    pos = truth[["x_m", "y_m", "z_m"]].to_numpy()
    vel = truth[["vx_m_s", "vy_m_s", "vz_m_s"]].to_numpy()
    trap = 0.5 * (vel[1:] + vel[:-1])
    assert np.abs(np.diff(pos, axis=0) - trap).max() < 2.0 / 12.0 + 1e-3


def test_orbit_error_has_the_asked_rms(tmp_path: Path) -> None:
    rms_asked = 2.0
    data = simulate(
        tmp_path / "orb",
        systems=("G", "E"),
        duration_s=3600.0,
        interval_s=60.0,
        errors="orbit",
        truth_ranges=True,
        error_settings={"orbit_rms_m": rms_asked},
    )
    nav = _georinex_load(data / "nav.rnx")
    sv_truth = pd.read_csv(data / "truth_ranges.csv")
    for system in "GE":
        eph = KeplerEphemeris.from_dataset(nav, system)
        rows = sv_truth[sv_truth["sv"].str.startswith(system)]
        diffs = []
        for sv, grp in rows.groupby("sv"):
            t_tx = grp["t_tx_gps_s"].to_numpy()
            idx = select_ephemeris(eph, np.array([sv]), t_tx)[:, 0]
            assert np.all(idx >= 0)
            st = broadcast_states(eph, idx, t_tx, gm_m3_s2=SYSTEMS[system].gm_m3_s2)
            diffs.append(st.pos_ecef_m - grp[["x_sv_m", "y_sv_m", "z_sv_m"]].to_numpy())
        d = np.concatenate(diffs)
        rms = np.sqrt(np.mean(np.sum(d**2, axis=1)))
        assert abs(rms / rms_asked - 1.0) < 0.10, (system, rms)


def test_no_orbit_error_means_nav_is_truth(static_exact_gps_gal: Path) -> None:
    nav = _georinex_load(static_exact_gps_gal / "nav.rnx")
    sv_truth = pd.read_csv(static_exact_gps_gal / "truth_ranges.csv")
    eph = KeplerEphemeris.from_dataset(nav, "G")
    rows = sv_truth[sv_truth["sv"].str.startswith("G")]
    idx = np.array([select_ephemeris(eph, np.array([s]), np.array([t]))[0, 0] for s, t in zip(rows["sv"], rows["t_tx_gps_s"])])
    st = broadcast_states(eph, idx, rows["t_tx_gps_s"].to_numpy())
    assert np.abs(st.pos_ecef_m - rows[["x_sv_m", "y_sv_m", "z_sv_m"]].to_numpy()).max() < 1e-3
    assert np.abs(C_M_S * st.clock_s - rows["clock_sv_m"].to_numpy()).max() < 1e-3


def test_doppler_is_minus_range_rate(tmp_path: Path) -> None:
    """Noise-free 1 Hz data: -lambda D equals the central difference of the pseudorange
    (its error h^2/6 |P'''| is < 1e-4 m/s; the 1 mm obs rounding gives < 1e-3 m/s)."""
    data = simulate(
        tmp_path / "dop", systems=("G",), duration_s=20.0, interval_s=1.0, errors="clock",
        error_settings={"clock_random_walk_m_sqrt_s": 0.0},  # bias + drift: differentiable
    )
    obs = _georinex_load(data / "obs.rnx")
    lam = C_M_S / SYSTEMS["G"].freqs_hz[0]
    p = obs["C1C"].values
    d = obs["D1C"].values
    fd = (p[2:] - p[:-2]) / 2.0
    ok = np.isfinite(fd) & np.isfinite(d[1:-1])
    assert ok.sum() > 50
    assert np.abs(fd[ok] + lam * d[1:-1][ok]).max() < 2e-3


def test_light_time_ranges_are_consistent(static_exact_gps_gal: Path) -> None:
    """The range is the distance from the satellite rotated by omega_e tau (tau = range / c) to
    the antenna at the true reception time: the light-time equation holds. (t_tx itself, a float
    of GPS seconds, resolves only 2.4e-7 s, so c (t_rx - t_tx) cannot be checked to 1 mm.)"""
    truth = pd.read_csv(static_exact_gps_gal / "truth.csv")
    rows = pd.read_csv(static_exact_gps_gal / "truth_ranges.csv").merge(truth[["time", "x_m", "y_m", "z_m", "clock_m", "gps_week", "tow_s"]], on="time")
    tau = rows["range_m"].to_numpy() / C_M_S
    ang = 7.2921151467e-5 * tau
    x, y, z = (rows[c].to_numpy() for c in ("x_sv_m", "y_sv_m", "z_sv_m"))
    sat = np.stack([np.cos(ang) * x + np.sin(ang) * y, -np.sin(ang) * x + np.cos(ang) * y, z], axis=1)
    rng = np.linalg.norm(sat - rows[["x_m", "y_m", "z_m"]].to_numpy(), axis=1)
    assert np.abs(rng - rows["range_m"].to_numpy()).max() < 1e-3
    assert rows["el_deg"].min() >= 5.0


def test_same_seed_same_bytes_different_seed_different_noise(tmp_path: Path) -> None:
    kw = dict(systems=("G", "E"), duration_s=120.0, interval_s=10.0, errors="all")
    a = simulate(tmp_path / "a", seed=11, **kw)
    b = simulate(tmp_path / "b", seed=11, **kw)
    c = simulate(tmp_path / "c", seed=12, **kw)
    for name in ("obs.rnx", "nav.rnx", "truth.csv"):
        assert (a / name).read_bytes() == (b / name).read_bytes(), name
    obs_a, obs_c = _georinex_load(a / "obs.rnx"), _georinex_load(c / "obs.rnx")
    diff = obs_a["C1C"].values - obs_c["C1C"].values
    diff = diff[np.isfinite(diff)]
    assert diff.size > 100 and np.std(diff) > 0.5  # metre-level noise, clock and orbit draws differ
    assert (a / "nav.rnx").read_bytes() != (c / "nav.rnx").read_bytes()  # orbit errors drawn anew


def test_errors_none_is_exact_and_noise_is_white(tmp_path: Path) -> None:
    """Pseudorange minus its exact value: zero for --errors none; for white constant noise the
    sample std over ~1,000 values is within 10 % of sigma (5 standard errors)."""
    exact = simulate(tmp_path / "x", systems=("G",), duration_s=600.0, interval_s=10.0, errors="none", seed=3)
    noisy = simulate(
        tmp_path / "n", systems=("G",), duration_s=600.0, interval_s=10.0, errors="noise", seed=3,
        error_settings={"noise_sigma_m": 2.0, "noise_elevation_dependent": False},
    )
    e = _georinex_load(exact / "obs.rnx")["C1C"].values
    n = _georinex_load(noisy / "obs.rnx")["C1C"].values
    d = (n - e)[np.isfinite(n - e)]
    assert d.size > 500
    assert abs(np.std(d) / 2.0 - 1.0) < 0.1 and abs(np.mean(d)) < 5 * 2.0 / np.sqrt(d.size)


def test_configs_toml_equals_built_in_defaults() -> None:
    """The packaged simulate.toml (package data, what gnss-simulate --help points to)."""
    with as_file(files("gnss_cli") / "configs" / "simulate.toml") as path:
        assert load_config(path) == ScenarioConfig()


def test_config_rejects_unknown_keys(tmp_path: Path) -> None:
    from gnss_cli.errors import ConfigError

    bad = tmp_path / "bad.toml"
    bad.write_text("[errors]\nnoise_sigmaa_m = 1.0\n")
    with pytest.raises(ConfigError, match="noise_sigmaa_m"):
        load_config(bad)


@pytest.mark.parametrize(
    ("args", "code", "message"),
    [
        (["--errors", "noise,bogus"], 3, "unknown source"),
        (["--systems", "G,X"], 3, "--systems"),
        (["--start", "yesterday"], 3, "--start"),
        (["--rinex-version", "2", "--systems", "C"], 3, "BeiDou"),
        (["--interval", "0"], 3, "interval must be > 0"),
        (["--trajectory", "csv:/nonexistent/traj.csv"], 4, "not found"),
    ],
)
def test_cli_errors_have_exit_codes(
    args: list[str], code: int, message: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as exc:
        run_app(app, "gnss-simulate", ["--out-dir", str(tmp_path), "--duration", "60", *args])
    assert exc.value.code == code
    err = capsys.readouterr().err
    assert err.startswith("gnss-simulate: error:") and message in err


def test_cli_writes_files_and_csv_trajectory(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A csv: trajectory (the truth of a flight run fed back) reproduces that run's truth."""
    first = tmp_path / "first"
    with pytest.raises(SystemExit) as exc:
        run_app(app, "gnss-simulate", ["--out-dir", str(first), "--trajectory", "standard-flight", "--duration", "60", "--errors", "none"])
    assert exc.value.code == 0
    assert {p.name for p in first.iterdir()} == {"obs.rnx", "nav.rnx", "truth.csv"}
    assert "wrote" in capsys.readouterr().err
    second = tmp_path / "second"
    with pytest.raises(SystemExit) as exc:
        run_app(
            app,
            "gnss-simulate",
            ["--out-dir", str(second), "--trajectory", f"csv:{first / 'truth.csv'}", "--duration", "60", "--errors", "none", "--quiet"],
        )
    assert exc.value.code == 0
    t1, t2 = pd.read_csv(first / "truth.csv"), pd.read_csv(second / "truth.csv")
    assert np.abs(t1[["x_m", "y_m", "z_m"]].to_numpy() - t2[["x_m", "y_m", "z_m"]].to_numpy()).max() < 1e-3
    # truth.csv holds 0.1 mm, the obs 1 mm: the re-simulated pseudoranges agree to a rounding step
    p1 = _georinex_load(first / "obs.rnx")["C1C"].values
    p2 = _georinex_load(second / "obs.rnx")["C1C"].values
    assert np.array_equal(np.isfinite(p1), np.isfinite(p2))
    assert np.nanmax(np.abs(p1 - p2)) <= 1.5e-3


ORBIT_RADIUS_M = 3.0e7
"""Larger than any GNSS orbit radius: an angle error of x rad moves a satellite by < x * 3e7 m."""
FIT_S = 4 * 3600.0
"""Longer than any ephemeris fit interval: a clock-drift error of x s/s is < x * 4 h at its end."""
POSITION_TOL_M = 1e-6
TIME_TOL_S = 1e-12
NAV_TOL = {
    # clock terms: 1e-12 s of clock over the fit interval
    "SVclockBias": TIME_TOL_S, "SVclockDrift": TIME_TOL_S / FIT_S, "SVclockDriftRate": TIME_TOL_S / FIT_S**2,
    "TGD": TIME_TOL_S, "BGDe5a": TIME_TOL_S, "BGDe5b": TIME_TOL_S,
    # orbit terms: 1e-6 m of satellite position over the fit interval
    "Crs": POSITION_TOL_M, "Crc": POSITION_TOL_M,
    "M0": POSITION_TOL_M / ORBIT_RADIUS_M, "omega": POSITION_TOL_M / ORBIT_RADIUS_M,
    "Omega0": POSITION_TOL_M / ORBIT_RADIUS_M, "Io": POSITION_TOL_M / ORBIT_RADIUS_M,
    "Cuc": POSITION_TOL_M / ORBIT_RADIUS_M, "Cus": POSITION_TOL_M / ORBIT_RADIUS_M,
    "Cic": POSITION_TOL_M / ORBIT_RADIUS_M, "Cis": POSITION_TOL_M / ORBIT_RADIUS_M,
    "Eccentricity": POSITION_TOL_M / ORBIT_RADIUS_M,
    "DeltaN": POSITION_TOL_M / ORBIT_RADIUS_M / FIT_S, "OmegaDot": POSITION_TOL_M / ORBIT_RADIUS_M / FIT_S,
    "IDOT": POSITION_TOL_M / ORBIT_RADIUS_M / FIT_S,
    "sqrtA": POSITION_TOL_M / (2.0 * np.sqrt(ORBIT_RADIUS_M)),  # da = 2 sqrt(A) d(sqrtA)
    "Toe": TIME_TOL_S, "TransTime": TIME_TOL_S,
}
"""Per nav field, the change that moves a satellite by 1e-6 m or its clock by 1e-12 s; other
fields (week, IODE, health, accuracy, flags) are integers or codes and must be equal. RINEX
writes 12 significant digits, so no field is held to less than 2e-12 of its size."""
OBS_TOL = {"C": POSITION_TOL_M, "L": POSITION_TOL_M / 0.19, "D": POSITION_TOL_M / 0.19, "S": 1e-6}
"""Per observation type: pseudorange m, phase cycles and Doppler Hz (L1 wavelength 0.19 m), dB-Hz."""
TRUTH_TOL = {"tow_s": TIME_TOL_S, "clock_drift_m_s": POSITION_TOL_M}
"""truth.csv columns not in metres (positions, velocities per s, clock in m: 1e-6; angles below)."""


def _sample_differences(new_dir: Path, old_dir: Path) -> list[str]:
    """Values of the regenerated files that differ from the committed ones by more than the
    physics-sized tolerances (empty list: the same data set)."""
    from gnss_cli.io.rinex3_nav import read_nav3
    from gnss_cli.io.rinex3_obs import read_obs3

    problems: list[str] = []

    def compare(name: str, a: np.ndarray, b: np.ndarray, tol: float) -> None:
        a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
        if a.shape != b.shape or not np.array_equal(np.isnan(a), np.isnan(b)):
            problems.append(f"{name}: shape or missing values differ")
            return
        ok = ~np.isnan(a)
        allowed = np.maximum(tol, 2e-12 * np.maximum(np.abs(a[ok]), np.abs(b[ok])))
        excess = np.abs(a[ok] - b[ok]) - allowed
        if excess.size and excess.max() > 0:
            k = int(np.argmax(excess))
            problems.append(f"{name}: differs by {abs(a[ok][k] - b[ok][k]):.3g} (tolerance {allowed[k]:.3g})")

    obs_new, obs_old = read_obs3(new_dir / "obs.rnx"), read_obs3(old_dir / "obs.rnx")
    if not (np.array_equal(obs_new["time"].values, obs_old["time"].values)
            and np.array_equal(obs_new["sv"].values, obs_old["sv"].values)
            and set(obs_new.data_vars) == set(obs_old.data_vars)):
        return ["obs.rnx: epochs, satellites or observation codes differ"]
    for code in obs_new.data_vars:
        compare(f"obs.rnx {code}", obs_new[code].values, obs_old[code].values, OBS_TOL[str(code)[0]])

    nav_new, nav_old = read_nav3(new_dir / "nav.rnx"), read_nav3(old_dir / "nav.rnx")
    if not (np.array_equal(nav_new["time"].values, nav_old["time"].values)
            and np.array_equal(nav_new["sv"].values, nav_old["sv"].values)
            and set(nav_new.data_vars) == set(nav_old.data_vars)):
        return ["nav.rnx: records (toc, satellites or fields) differ"]
    for field in nav_new.data_vars:
        compare(f"nav.rnx {field}", nav_new[field].values, nav_old[field].values, NAV_TOL.get(str(field), 0.0))
    for key in ("ionospheric_corr_GPS",):
        compare(f"nav.rnx {key}", np.asarray(nav_new.attrs.get(key, [])), np.asarray(nav_old.attrs.get(key, [])), 0.0)

    truth_new, truth_old = pd.read_csv(new_dir / "truth.csv"), pd.read_csv(old_dir / "truth.csv")
    if list(truth_new.columns) != list(truth_old.columns) or list(truth_new["time"]) != list(truth_old["time"]):
        return problems + ["truth.csv: columns or epochs differ"]
    for col in truth_new.columns.drop("time"):
        tol = TRUTH_TOL.get(col, POSITION_TOL_M / ORBIT_RADIUS_M * 180 / np.pi if col.endswith("_deg") else POSITION_TOL_M)
        compare(f"truth.csv {col}", truth_new[col].to_numpy(), truth_old[col].to_numpy(), tol)
    return problems


def test_committed_samples_are_reproduced_by_their_command(tmp_path: Path) -> None:
    """sample_rinex/ is what make_samples.sh writes (same seed, same data): every value of the
    regenerated obs.rnx, nav.rnx and truth.csv equals the committed one within what moves a
    position or range by 1e-6 m or a time or clock by 1e-12 s (not byte for byte: the last of
    a nav number's 12 digits may differ between library versions)."""
    script = (ROOT / "sample_rinex" / "make_samples.sh").read_text()
    assert "--out-dir sample_rinex/static" in script
    commands = [
        ["--trajectory", "static", "--start", "2024-03-01T00:00:00", "--duration", "3600", "--interval", "30",
         "--systems", "G,E", "--seed", "7", "--errors", "all", "--quiet"],
    ]
    for name, args in zip(("static",), commands):
        flat = " ".join(script.replace("\\\n", " ").split())
        assert " ".join(args[:-1]) in flat, name
        with pytest.raises(SystemExit) as exc:
            run_app(app, "gnss-simulate", [*args, "--out-dir", str(tmp_path / name)])
        assert exc.value.code == 0
        assert _sample_differences(tmp_path / name, ROOT / "sample_rinex" / name) == [], name
    total = sum(p.stat().st_size for p in (ROOT / "sample_rinex").rglob("*") if p.is_file())
    assert total < 300_000


def test_sample_comparison_sees_a_1_mm_change(tmp_path: Path) -> None:
    """The comparison above is not blind: one pseudorange off by 1 mm is reported."""
    committed = ROOT / "sample_rinex" / "static"
    assert _sample_differences(committed, committed) == []
    for name in ("obs.rnx", "nav.rnx", "truth.csv"):
        (tmp_path / name).write_bytes((committed / name).read_bytes())
    obs = (tmp_path / "obs.rnx").read_text().splitlines(keepends=True)
    end = next(i for i, line in enumerate(obs) if "END OF HEADER" in line)
    row = next(i for i in range(end + 1, len(obs)) if obs[i][:1] in "GE")
    value = float(obs[row][3:17])
    obs[row] = obs[row][:3] + f"{value + 0.001:14.3f}" + obs[row][17:]
    (tmp_path / "obs.rnx").write_text("".join(obs))
    problems = _sample_differences(tmp_path, committed)
    assert len(problems) == 1 and problems[0].startswith("obs.rnx C1C"), problems


def test_semicircle_is_annihilated_by_its_lag3_kernel() -> None:
    """ENU of the constant-speed half circle satisfy (z-1)(z^2 - 2 cos(w dt) z + 1) w = 0."""
    from gnss_cli.gnss.frames import ecef2enu
    from gnss_cli.sim.trajectory import semicircle_trajectory

    centre = geodetic2ecef(np.deg2rad(55.5), np.deg2rad(8.5), 50.0)
    t = 1.0e9 + np.arange(0.0, 601.0, 1.0)
    traj = semicircle_trajectory(t, centre, speed_m_s=50.0)
    enu = ecef2enu(traj.pos_ecef_m, centre)
    c = np.cos(np.pi / 600.0)
    # (z-1)(z^2 - 2c z + 1) = z^3 - (2c+1) z^2 + (2c+1) z - 1
    res = enu[3:] - (2 * c + 1) * enu[2:-1] + (2 * c + 1) * enu[1:-2] - enu[:-3]
    assert np.abs(res).max() < 1e-6 * np.abs(enu).max()
    assert np.allclose(np.linalg.norm(traj.vel_ecef_m_s, axis=1), 50.0, rtol=1e-12)


def test_rinex2_tenth_second_epochs_read_exactly(tmp_path: Path) -> None:
    """0.1 s epochs written as RINEX 2 (F11.7 seconds) come back to the nanosecond."""
    from gnss_cli.io.rinex2_obs import read_obs2

    data = simulate(tmp_path / "v2", systems=("G",), duration_s=3.0, interval_s=0.1, errors="none", rinex_version="2.11")
    obs = read_obs2(data / "obs.rnx")
    steps = np.diff(obs.time.values).astype(np.int64)
    assert obs.sizes["time"] >= 30 and np.all(steps == 100_000_000)
    ref = _georinex_load(data / "obs.rnx")
    lag = (obs.time.values - ref.time.values.astype("datetime64[ns]")).astype(np.int64)
    assert np.all((lag >= 0) & (lag <= 1_000_000))  # georinex: whole milliseconds, truncated
