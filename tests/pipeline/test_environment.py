"""The environment (``[processing] environment``, :mod:`gnss_cli.pipeline.environment`): the WLS
variance factor against its definition written out, the judgement of simulated open-sky and
street-canyon drives, a judged run equal to the run given that environment (whole, in parts, in
several processes), and what the outputs say of it."""

from __future__ import annotations

import csv
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from gnss_cli.config import load_config
from gnss_cli.errors import ConfigError
from gnss_cli.pipeline import load_epochs, process, solve_method
from gnss_cli.pipeline.environment import (HEAD_EPOCHS, describe, head_variance_factor, judged,
                                           variance_factor, with_environment)

ROOT = Path(__file__).resolve().parents[2]


def _simulate(out: Path, *args: str) -> Path:
    from gnss_cli.cli.exits import run_app
    from gnss_cli.cli.simulate import app

    with pytest.raises(SystemExit) as done:
        run_app(app, "gnss-simulate", ["--trajectory", "drive", "--interval", "1", "--out-dir", str(out), "-q", *args])
    assert done.value.code == 0
    return out


@pytest.fixture(scope="module")
def canyon(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return _simulate(tmp_path_factory.mktemp("env") / "canyon", "--duration", "90", "--environment", "urban",
                     "--receiver", "single", "--seed", "211")


@pytest.fixture(scope="module")
def open_sky(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return _simulate(tmp_path_factory.mktemp("env") / "open", "--duration", "90", "--systems", "G,E,C", "--seed", "211")


def _files(d: Path) -> tuple[Path, list[Path]]:
    return d / "obs.rnx", [d / "nav.rnx"]


def test_the_variance_factor_is_the_median_chi_square_per_degree_of_freedom(canyon: Path) -> None:
    """Against the definition written out epoch by epoch: ``sum (r / sigma)^2`` over the satellites
    the fix used, over ``n - 3 - clocks`` (one clock per system letter; the single profile has no
    QZSS), median over the epochs with a degree of freedom -- of the plain fix the judgement uses
    and of an FDE fix, whose statistic is then its test's."""
    letters = None
    for integrity in ("off", "fde"):
        cfg = load_config(None, {"methods": "wls", "environment": "open", "integrity": integrity})
        data = load_epochs(*_files(canyon), cfg)
        sol = solve_method(data, "wls", cfg)
        letters = np.array([s[0] for s in data.sv.astype(str)])
        ratios = []
        for t in range(data.time_gps_s.size):
            used = np.isfinite(sol.residuals_m[t]) & ~sol.excluded[t]
            dof = used.sum() - 3 - len(set(letters[used]))
            if dof >= 1:
                stat = float(np.sum((sol.residuals_m[t, used] / sol.sigma_m[t, used]) ** 2))
                if integrity == "fde" and np.isfinite(sol.test_stat[t]):
                    assert stat == pytest.approx(sol.test_stat[t], rel=1e-6)  # the test's statistic
                ratios.append(stat / dof)
        assert len(ratios) > 60
        assert variance_factor(sol, data) == pytest.approx(float(np.median(ratios)), rel=1e-6)
        if integrity == "off":
            assert head_variance_factor(cfg, data) == pytest.approx(float(np.median(ratios)), rel=1e-6)


def test_a_canyon_is_judged_urban_and_open_sky_open(canyon: Path, open_sky: Path) -> None:
    cfg = load_config(None, {"methods": "wls"})
    assert cfg.environment == "auto"
    factors = {}
    for name, d in (("canyon", canyon), ("open", open_sky)):
        data = load_epochs(*_files(d), cfg)
        factors[name] = head_variance_factor(cfg, data)
        got = judged(cfg, data)
        assert got.environment == ("urban" if name == "canyon" else "open")
        assert describe(got) == (f"{got.environment} (auto: variance factor {factors[name]:.2f} "
                                 f"{'>' if name == 'canyon' else '<='} {cfg.urban_variance_factor:g})")
    assert factors["canyon"] > 2 * cfg.urban_variance_factor > 4 * factors["open"]


def test_the_urban_settings_are_those_of_configs_urban_toml() -> None:
    """``configs/urban.toml`` names the environment; its ``[urban]`` table is applied over the
    packaged settings and nothing else changes. A table of one's own is taken as given (a key set
    in it, not the packaged value)."""
    base = load_config(None, {})
    urban = judged(load_config(ROOT / "configs" / "urban.toml", {}), None)
    assert urban.environment == "urban" and describe(urban) == "urban"
    assert (urban.max_simultaneous_faults, urban.prior_fault_satellite) == (3, 1e-2)
    assert (urban.nlos.detector, urban.nlos.min_direct_dof) == ("arcs", 1)
    undone = replace(urban, environment="auto", max_simultaneous_faults=base.max_simultaneous_faults,
                     prior_fault_satellite=base.prior_fault_satellite, nlos=base.nlos)
    assert undone == base
    assert with_environment(base, "open") == replace(base, environment="open")
    mine = judged(load_config(None, {"environment": "urban", "urban.nlos_min_direct_dof": 0,
                                     "urban.max_simultaneous_faults": 2}), None)
    assert (mine.nlos.min_direct_dof, mine.max_simultaneous_faults, mine.nlos.detector) == (0, 2, "arcs")


def test_a_given_environment_and_integrity_off_are_not_judged(canyon: Path) -> None:
    data = load_epochs(*_files(canyon), load_config(None, {"methods": "wls"}))
    assert describe(judged(load_config(None, {"environment": "open"}), data)) == "open"
    off = judged(load_config(None, {"integrity": "off"}), data)
    assert off.environment == "open" and describe(off) == "open (auto: integrity off)"
    assert describe(judged(load_config(None, {}), None)) == "open (auto: no epoch to judge)"


@pytest.mark.parametrize(("key", "value", "match"), [("environment", "city", "environment: expected one of auto, open, urban"),
                                                     ("urban_variance_factor", 0.0, "urban_variance_factor: expected"),
                                                     ("urban.nlos_detector", "cn0", "urban.nlos_detector"),
                                                     ("urban.max_simultaneous_faults", 4, "urban.max_simultaneous_faults"),
                                                     ("urban.nlos_min_direct_dof", -1, "urban.nlos_min_direct_dof"),
                                                     ("urban.prior_fault_satellite", 1.0, "urban.prior_fault_satellite")])
def test_bad_settings_are_refused_by_name(key: str, value: object, match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        load_config(None, {key: value})


NUMPY_2 = int(np.__version__.split(".")[0]) >= 2


def _same(a, b) -> None:  # noqa: ANN001 - two RunResults
    """The same rows: positions and levels to the bit with numpy 2; with numpy 1.x, whose vectorized
    sums change their last bits with the arrays' memory alignment from run to run, positions to 1e-9
    relative and levels to 1e-6: a canyon fix's levels of ten kilometres come from near-singular
    geometry, which magnifies those last bits (measured once: 7e-9 relative, 3e-7 m)."""
    close = np.testing.assert_array_equal if NUMPY_2 else (
        lambda x, y: np.testing.assert_allclose(x, y, rtol=1e-9, atol=1e-9))
    close_levels = np.testing.assert_array_equal if NUMPY_2 else (
        lambda x, y: np.testing.assert_allclose(x, y, rtol=1e-6, atol=1e-9))
    for m in a.solutions:
        close(a.solutions[m].x_ecef_m, b.solutions[m].x_ecef_m)
        np.testing.assert_array_equal(a.solutions[m].status, b.solutions[m].status)
        close_levels(a.solutions[m].hpl_m, b.solutions[m].hpl_m)


def test_a_judged_run_is_the_run_given_its_environment(canyon: Path, open_sky: Path) -> None:
    """auto on the canyon gives urban's rows bit for bit, and on open sky open's; the two differ on
    the canyon (the judgement changes what runs)."""
    over = {"methods": "wls,smoother"}
    auto = process(*_files(canyon), load_config(None, over))
    _same(auto, process(*_files(canyon), load_config(None, {**over, "environment": "urban"})))
    opened = process(*_files(canyon), load_config(None, {**over, "environment": "open"}))
    assert not np.array_equal(auto.solutions["wls"].status, opened.solutions["wls"].status)
    assert "min direct dof 1" in auto.settings["wls"].integrity and "nlos" not in opened.settings["wls"].integrity
    assert auto.environment.startswith("urban (auto: variance factor ") and opened.environment == "open"
    _same(process(*_files(open_sky), load_config(None, over)),
          process(*_files(open_sky), load_config(None, {**over, "environment": "open"})))


def test_a_file_in_parts_is_judged_on_the_same_epochs(canyon: Path) -> None:
    """Read in parts of 20 epochs, the file is judged on its first epochs joined from the parts, as
    the whole file is: the same environment and the same factor."""
    from gnss_cli.pipeline.run import Run

    runs = {}
    for name, over in (("whole", {}), ("parts", {"chunk_epochs": 20, "stream_above_epochs": 20})):
        run = Run(*_files(canyon), load_config(None, {"methods": "wls", **over}))
        n_parts = sum(1 for _ in run.parts())
        runs[name] = (describe(run.config), n_parts)
    assert runs["parts"][0] == runs["whole"][0] and runs["whole"][0].startswith("urban (auto")
    assert runs["whole"][1] == 1 and runs["parts"][1] > 1
    assert HEAD_EPOCHS > 90  # the whole 90 s file judges it, however it is read


def test_a_canyon_day_file_in_several_processes_is_solved_as_in_one(tmp_path: Path) -> None:
    """A file long enough to be cut in one part per process (single-epoch methods, 1,100 epochs),
    judged urban: the NLOS detector needs the whole file, so the parts are joined again and the
    rows are those of one process."""
    from gnss_cli.parallel import can_fork

    if not can_fork():
        pytest.skip("no fork on this platform: nothing to join")
    d = _simulate(tmp_path / "long", "--duration", "1100", "--environment", "urban", "--receiver", "single",
                  "--seed", "212")
    one = process(*_files(d), load_config(None, {"methods": "wls", "processes": 1}))
    two = process(*_files(d), load_config(None, {"methods": "wls", "processes": 2}))
    _same(one, two)
    assert "min direct dof 1" in two.settings["wls"].integrity


def test_the_outputs_say_which_environment_ran(canyon: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from gnss_cli.cli.exits import run_app
    from gnss_cli.cli.solve import app

    obs, navs = _files(canyon)
    with pytest.raises(SystemExit) as done:
        run_app(app, "gnss-solve", [str(obs), *map(str, navs), "--out-dir", str(tmp_path / "out")])
    assert done.value.code == 0
    err = capsys.readouterr().err
    assert "gnss-solve: environment urban (auto: variance factor " in err
    with open(tmp_path / "out" / "summary.csv", newline="") as f:
        settings = next(csv.DictReader(f))["settings"]
    assert "environment=urban (auto: variance factor " in settings and "faults at once 3" in settings
    with pytest.raises(SystemExit) as done:
        run_app(app, "gnss-solve", [str(obs), *map(str, navs), "--environment", "city", "-o", str(tmp_path / "p.csv")])
    assert done.value.code == 3
    assert "environment: expected one of auto, open, urban" in capsys.readouterr().err
    assert not (tmp_path / "p.csv").exists()


def test_the_python_api_says_which_environment_ran() -> None:
    import gnss_cli

    sample = ROOT / "sample_rinex" / "static"
    ds = gnss_cli.solve(sample / "obs.rnx", sample / "nav.rnx")
    assert ds.attrs["environment"].startswith("open (auto: variance factor ")
    assert gnss_cli.solve(sample / "obs.rnx", sample / "nav.rnx", environment="urban").attrs["environment"] == "urban"
