"""Protection levels over faults of several satellites at once (``max_simultaneous_faults``,
docs/integrity.md): the pair subsets equal independent least-squares solves without the two
satellites, the unmonitored probability is the binomial tail, the default (single faults) is
unchanged, and two simultaneous biases the single-fault levels fail to bound are bounded or
detected with pairs monitored."""

from __future__ import annotations

import itertools
import math
from dataclasses import replace

import numpy as np
import pytest

from gnss_cli.config import load_config
from gnss_cli.errors import ConfigError
from gnss_cli.gnss.frames import ecef2enu_rotation, ecef2geodetic
from gnss_cli.gnss.range_model import ISB_CONSTRAINT_VAR_M2
from gnss_cli.pipeline.epochs import load_epochs
from gnss_cli.pipeline.integrity import (_monitored_order, _multi_hypotheses, separate_subsets,
                                         separation_levels, unmonitored_probability)
from gnss_cli.pipeline.snapshot import solve_method
from gnss_cli.sim.scenario import ScenarioConfig, config_from_mapping, run_scenario, write_scenario

FIXED_W = 1.0 / ISB_CONSTRAINT_VAR_M2


def _explicit(A, q, we, keep, fixed):
    """Weighted least squares of the rows ``keep`` (a fixed unknown's column dropped: its value is 0)."""
    free = np.flatnonzero(fixed == 0)
    s = np.sqrt(we * keep)
    x = np.zeros(A.shape[1])
    x[free] = np.linalg.lstsq(s[:, None] * A[:, free], s * q, rcond=None)[0]
    return x


def test_pair_subsets_equal_independent_solves_without_the_two():
    """Two systems, the second of two satellites only: every pair of the ten rows, as
    :func:`_multi_hypotheses` forms it (the second system's clock fixed when both its satellites
    are out), solves like weighted least squares without those two rows."""
    rng = np.random.default_rng(3)
    t, n, m = 3, 10, 5
    N = n + 2  # two clock constraint rows (weight 0 here: the systems are present)
    A = np.zeros((t, N, m))
    A[:, :n, :3] = rng.normal(size=(t, n, 3))
    A[:, :8, 3], A[:, 8:n, 4] = 1.0, 1.0
    A[:, n, 3], A[:, n + 1, 4] = 1.0, 1.0
    q = rng.normal(size=(t, N)) * 3.0
    var = rng.uniform(0.5, 4.0, size=(t, N))
    mask = np.zeros((t, N), dtype=bool)
    mask[:, :n] = True
    we = np.where(mask, 1.0 / var, 0.0)
    sat = mask[:, :n]
    pairs = np.array(list(itertools.combinations(range(n), 2)))
    used = np.broadcast_to(np.arange(n), (t, n))
    cfg = replace(load_config(), max_simultaneous_faults=2, prior_fault_satellite=1e-2)
    removed, fixed, candidate, prior = _multi_hypotheses(A, sat, used[:, pairs], N, cfg)
    assert candidate.all() and np.allclose(prior, 1e-4)
    both = np.flatnonzero((pairs == [8, 9]).all(axis=1))
    assert (fixed[:, both, 4] == 1).all() and fixed.sum() == t  # only the pair that empties system 2
    sep = separate_subsets(A, q, we, var, removed, fixed, FIXED_W)
    for e in range(t):
        x0 = _explicit(A[e], q[e], we[e], np.ones(N), np.zeros(m))
        for h, (i, j) in enumerate(pairs):
            keep = np.ones(N)
            keep[[i, j]] = 0
            xk = _explicit(A[e], q[e], we[e], keep, fixed[e, h])
            if sep.solvable[e, h]:
                np.testing.assert_allclose(sep.delta[e, h, :3], (xk - x0)[:3], rtol=1e-7, atol=1e-8)
    assert sep.solvable.all()


@pytest.mark.parametrize("p", [1e-3, 1e-2, 3e-2])
def test_unmonitored_probability_is_the_binomial_tail(p):
    for n in (0, 1, 2, 5, 12, 40):
        for order in (1, 2, 3):
            direct = sum(math.comb(n, j) * p**j * (1 - p) ** (n - j) for j in range(order + 1, n + 1))
            got = float(unmonitored_probability(np.array([n]), p, order)[0])
            assert got == pytest.approx(direct, rel=1e-9, abs=1e-300)
    # one fault at most: the probability the single-fault levels have always taken from the risk
    n = np.arange(4, 40)
    np.testing.assert_allclose(unmonitored_probability(n, p, 1), 1 - (1 - p) ** n - n * p * (1 - p) ** (n - 1),
                               rtol=1e-9)


def test_monitored_order_follows_the_prior():
    """Pairs (triples) only while more faults than singles (pairs) are likelier than a tenth of
    the risk; none when the levels would be infinite anyway."""
    n = np.array([6, 10, 15, 32, 40])
    cfg = replace(load_config(), max_simultaneous_faults=3)
    np.testing.assert_array_equal(_monitored_order(n, replace(cfg, prior_fault_satellite=1e-3)), [1, 1, 2, 2, 2])
    np.testing.assert_array_equal(_monitored_order(n, replace(cfg, prior_fault_satellite=1e-2)), [2, 3, 3, 3, 3])
    np.testing.assert_array_equal(_monitored_order(n, replace(cfg, prior_fault_satellite=3e-2)), [3, 3, 3, 1, 1])
    with pytest.raises(ConfigError):
        load_config(None, {"max_simultaneous_faults": 4})


@pytest.fixture(scope="module")
def static(tmp_path_factory):
    """A static GPS receiver, 300 epochs at 1 s (white noise only), and its truth."""
    cfg_sim = config_from_mapping({"simulate": {"trajectory": "static", "duration_s": 300.0, "seed": 11,
                                                "systems": "G", "errors": "noise"}}, ScenarioConfig())
    scen = run_scenario(cfg_sim)
    folder = tmp_path_factory.mktemp("multifault")
    write_scenario(scen, folder)
    cfg = load_config(None, {"iono": "none", "tropo": "none"})
    data = load_epochs(folder / "obs.rnx", [folder / "nav.rnx"], cfg)
    truth = scen.observations.rx_pos_ecef_m[np.searchsorted(scen.observations.t_gps_s, data.time_gps_s)]
    return cfg, data, truth


def _misleading(sol, truth):
    lat, lon, _ = ecef2geodetic(truth)
    enu = np.einsum("tij,tj->ti", ecef2enu_rotation(lat, lon), sol.x_ecef_m - truth)
    ok = sol.status == "ok"
    return ok & ((np.hypot(enu[:, 0], enu[:, 1]) > sol.hpl_m) | (np.abs(enu[:, 2]) > sol.vpl_m))


def test_default_is_the_single_fault_levels(static):
    """max_simultaneous_faults = 1 (and 2 at a prior that needs no pairs): the same levels and fixes."""
    cfg, data, _ = static
    cfg = replace(cfg, max_simultaneous_faults=1, prior_fault_satellite=1e-3)
    one = solve_method(data, "wls", cfg)
    two = solve_method(data, "wls", replace(cfg, max_simultaneous_faults=2))  # p = 1e-3, <= 12 satellites
    np.testing.assert_array_equal(one.x_ecef_m, two.x_ecef_m)
    np.testing.assert_array_equal(one.hpl_m, two.hpl_m)
    np.testing.assert_array_equal(one.status, two.status)


def test_two_simultaneous_biases_are_bounded_or_detected_with_pairs(static):
    """The same ramp (0 to 40 m over 300 s) on two satellites seen throughout: of all such pairs,
    the one the single-fault levels (prior 1e-3, the former defaults) bound worst leaves misleading
    ``ok`` epochs (measured: 33); with pairs monitored (prior 1e-2) none: each epoch is bounded or
    detected."""
    cfg, data, truth = static
    cfg = replace(cfg, max_simultaneous_faults=1, prior_fault_satellite=1e-3)
    T = data.time_gps_s.size
    full = np.flatnonzero(data.usable.sum(axis=0) == T)
    ramp = np.linspace(0.0, 40.0, T)

    def biased(a, b):
        pr = data.pr_corrected_m.copy()
        pr[:, [a, b]] += ramp[:, None]
        return replace(data, pr_corrected_m=pr)

    worst = max(itertools.combinations(full, 2),
                key=lambda ab: _misleading(solve_method(biased(*ab), "wls", cfg), truth).sum())
    single = solve_method(biased(*worst), "wls", cfg)
    assert _misleading(single, truth).sum() >= 10
    pairs = solve_method(biased(*worst), "wls", replace(cfg, max_simultaneous_faults=2, prior_fault_satellite=1e-2))
    assert _misleading(pairs, truth).sum() == 0
    assert (pairs.status == "ok").sum() >= 0.8 * T  # bounded, not made unavailable
    assert np.isfinite(pairs.hpl_m[pairs.status == "ok"]).all()


def test_separation_levels_with_pairs_cover_the_single_levels(static):
    """Pairs add hypotheses: at the same prior the levels can only grow (and the budget shrink)."""
    cfg, data, _ = static
    cfg = replace(cfg, max_simultaneous_faults=1)
    sol = solve_method(data, "wls", replace(cfg, integrity="off"))
    from gnss_cli.gnss.range_model import linearize
    rows = np.arange(0, 300, 10)
    lin = linearize(data, rows, sol.x_ecef_m[rows], sol.clocks_m[rows], cfg)
    args = (lin.A, lin.q, lin.mask, np.where(lin.mask, lin.var_m2, 1.0), np.where(lin.mask, 1.0 / lin.var_m2, 0.0),
            lin.rot, lin.sat_rows)
    p1 = replace(cfg, prior_fault_satellite=1e-2, integrity_risk=2e-2)  # single faults: a finite budget
    h1, v1, _ = separation_levels(*args, p1)
    h2, v2, _ = separation_levels(*args, replace(p1, max_simultaneous_faults=2))
    assert np.isfinite(h1).all() and (h2 >= h1 - 1e-9).all() and (v2 >= v1 - 1e-9).all() and (h2 > h1).any()
