"""How ``benchmarks/multi_epoch_fair.py`` groups its variants into runs (variants of different
methods share a run only when they agree on every setting they both give), chooses a setting on
its training runs and deals the runs among processes."""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
import multi_epoch_fair as fair  # noqa: E402


def test_variants_sharing_a_key_with_other_values_take_separate_runs() -> None:
    """The smoother's cv and the kf's cv both read ``kalman.accel_psd_m2_s3``: with different
    chosen values they must not share a run, where one value would silently overwrite the other."""
    chosen = {"kf cv": 1.0, "kf ca": 0.1, "smoother quadrature": 1, "smoother cv": 0.1, "smoother ca": 0.01,
              "stls": (0, 1e-3)}
    variants = fair.variants_for(chosen, ("kf cv", "kf ca", "smoother quadrature", "smoother cv", "smoother ca",
                                          "stls", "kf cv free clocks", "kf ca free clocks"))
    rounds = fair.plan_rounds(variants)
    assert sorted(n for r in rounds for n in r) == sorted(variants)
    for r in rounds:
        methods = [n.split()[0] for n in r]
        assert len(methods) == len(set(methods))  # one variant of a method per run
        merged: dict[str, object] = {}
        for settings in r.values():
            for key, value in settings.items():
                assert merged.setdefault(key, value) == value, (key, r)
    cv = {n: v["kalman.accel_psd_m2_s3"] for n, v in variants.items() if "kalman.accel_psd_m2_s3" in v}
    assert cv["kf cv"] == 1.0 and cv["smoother cv"] == 0.1  # each keeps its own chosen PSD


def test_a_conflicting_key_splits_a_run_and_agreement_shares_one() -> None:
    apart = fair.plan_rounds({"kf cv": {"kalman.model": "cv", "kalman.accel_psd_m2_s3": 1.0},
                              "smoother cv": {"smoother.motion": "cv", "kalman.accel_psd_m2_s3": 0.1}})
    assert [list(r) for r in apart] == [["kf cv"], ["smoother cv"]]
    shared = fair.plan_rounds({"kf cv": {"kalman.model": "cv", "kalman.accel_psd_m2_s3": 1.0},
                               "smoother cv": {"smoother.motion": "cv", "kalman.accel_psd_m2_s3": 1.0},
                               "stls": {"stls.lag": 3}})
    assert [list(r) for r in shared] == [["kf cv", "smoother cv", "stls"]]


def test_choose_keeps_the_most_constrained_candidate_the_training_cannot_tell_from_the_best() -> None:
    """The one-standard-error rule: a first candidate whose paired differences to the best scatter
    around zero is kept; one that is worse on every run by more than the differences' spread is not."""
    rng = np.random.default_rng(7)
    base = rng.uniform(1.0, 2.0, 12)
    tied = base + rng.normal(0.0, 0.05, 12)
    tied += 0.5 * float(np.std(tied - base, ddof=1) / np.sqrt(12)) - float(np.mean(tied - base))  # half an SE worse
    assert np.mean(tied) > np.mean(base)  # the best by its mean is the second candidate
    assert fair.choose((0.01, 0.1), {"0.01": list(tied), "0.1": list(base)}) == 0.01
    worse = base + 0.05 + rng.normal(0.0, 0.005, 12)  # about 30 standard errors worse
    assert fair.choose((0.01, 0.1), {"0.01": list(worse), "0.1": list(base)}) == 0.1
    # a third, best candidate after a tie: the rule walks the list in order, the tie with it decides
    assert fair.choose((0.01, 0.1, 1.0), {"0.01": list(worse), "0.1": list(tied), "1.0": list(base)}) == 0.1
    # pairs are labelled as in the scores, and one run has no spread: the best
    assert fair.choose(((0, 1e-12), (10, 1e-3)), {"0/1e-12": [1.1], "10/0.001": [1.0]}) == (10, 1e-3)


def test_in_parallel_returns_what_the_runs_return_in_their_order() -> None:
    items = list(range(7))
    got = fair.in_parallel(lambda x: (x * x, os.getpid()), items)
    assert [v for v, _ in got] == [x * x for x in items]
    if fair.can_fork() and fair.cores() > 1:
        assert os.getpid() not in {pid for _, pid in got}  # solved in the children


def test_in_parallel_raises_what_a_run_raised() -> None:
    def run(x: int) -> int:
        if x == 0:
            raise ValueError("run 0 failed")
        return x

    with pytest.raises(ValueError, match="run 0 failed"):
        fair.in_parallel(run, [0, 1, 2, 3])


def test_a_candidate_without_a_solved_epoch_is_never_chosen() -> None:
    """``mse_per_run`` marks a run the variant did not solve as ``inf`` (not NaN, which every
    comparison of ``choose`` would pass over silently), so even listed first it is not kept."""
    solved = {"enu_m": np.ones((5, 3))}
    unsolved = {"enu_m": np.full((5, 3), np.nan)}
    runs = [{"a": unsolved, "b": solved}, {"a": solved, "b": solved}, {"a": solved, "b": solved}]
    mse = {"a": fair.mse_per_run(runs, "a"), "b": fair.mse_per_run(runs, "b")}
    assert mse["a"] == [np.inf, 3.0, 3.0] and mse["b"] == [3.0, 3.0, 3.0]
    assert fair.choose(("a", "b"), mse) == "b"


def _runs(errors: dict[str, list[np.ndarray]]) -> list[dict[str, dict[str, object]]]:
    names = list(errors)
    return [{n: {"enu_m": errors[n][k], "tow_s": np.arange(errors[n][k].shape[0], dtype=float), "ran": {}}
             for n in names} for k in range(len(errors[names[0]]))]


def test_the_units_of_the_interval_add_up_to_the_reported_rms() -> None:
    """Per run (several runs) or per epoch (one), the squared errors kept for the interval give back
    the pooled RMS of the table over the same compared epochs, an epoch another method missed excluded."""
    rng = np.random.default_rng(3)
    a = [rng.normal(0, 1, (40, 3)) for _ in range(3)]
    b = [rng.normal(0, 2, (40, 3)) for _ in range(3)]
    b[1][5] = np.nan  # not compared, for either method
    rows = fair.evaluate(_runs({"wls": a, "stls": a, "kf cv": b}))
    for n in ("stls", "kf cv"):
        units = rows[n]["sq_units_m2"]
        assert len(units["3d"]) == 3 and rows[n]["compared"] == 119
        assert np.isclose(np.sqrt(sum(units["3d"]) / 119), rows[n]["rms_3d_m"], rtol=1e-12)
        assert np.isclose(np.sqrt(sum(units["h"]) / 119), rows[n]["rms_h_m"], rtol=1e-12)
    one = fair.evaluate(_runs({"wls": a[:1], "stls": a[:1], "kf cv": b[:1]}))
    assert len(one["stls"]["sq_units_m2"]["h"]) == 40
    assert np.isclose(np.sqrt(np.mean(one["stls"]["sq_units_m2"]["h"])), one["stls"]["rms_h_m"], rtol=1e-12)


def test_ratio_interval_is_exact_where_there_is_no_spread() -> None:
    b = np.random.default_rng(5).uniform(0.5, 2.0, 30)
    lo, hi = fair.ratio_interval(4.0 * b, b)  # every unit twice the RMS: every resample gives 2
    assert np.isclose(lo, 2.0) and np.isclose(hi, 2.0)
    a = b * np.random.default_rng(6).uniform(0.5, 1.5, 30)
    lo, hi = fair.ratio_interval(a, b, block=30)  # one block holds the whole series: the point ratio
    assert np.isclose(lo, np.sqrt(a.sum() / b.sum())) and np.isclose(hi, lo)
    assert np.isnan(fair.ratio_interval([1.0], [1.0])[0])


def test_ratio_interval_covers_the_true_ratio_about_95_percent_of_the_time() -> None:
    """Independent units with a known ratio of RMS (1.2): over 300 draws of 20 units the interval
    holds it about 95 % of the time (a binomial 95 % range, with the bootstrap's small-sample
    under-coverage allowed for)."""
    rng = np.random.default_rng(11)
    hits = 0
    for k in range(300):
        b = rng.chisquare(3, 20)
        a = 1.44 * rng.chisquare(3, 20)
        lo, hi = fair.ratio_interval(a, b, n_boot=1000, seed=k)
        hits += lo <= 1.2 <= hi
    assert 0.85 <= hits / 300 <= 0.99


def test_blocks_widen_the_interval_of_a_correlated_series() -> None:
    """Errors correlated over many epochs (an AR(1) with coefficient 0.95, as a smoothed solution's):
    single epochs resampled as if independent understate the spread; blocks of 20 do not."""
    rng = np.random.default_rng(2)
    x = np.zeros(400)
    for t in range(1, 400):
        x[t] = 0.95 * x[t - 1] + rng.normal()
    a = np.exp(x / 3)  # squared errors, positive and correlated
    b = np.ones(400)
    lo1, hi1 = fair.ratio_interval(a, b, block=1)
    lo20, hi20 = fair.ratio_interval(a, b, block=20)
    assert hi20 - lo20 > 2 * (hi1 - lo1)


def test_the_json_keeps_the_run_units_that_give_back_the_interval() -> None:
    """``drop_epoch_units`` rounds the per-run squared errors to six digits (the interval from them
    moves by far less than its printed two decimals) and drops the per-epoch ones of a single trajectory."""
    rng = np.random.default_rng(4)
    a, b = list(rng.uniform(0.5, 3.0, 10) / 3), list(rng.uniform(0.5, 3.0, 10) / 7)
    cases = {"flight": {"pr": {"stls": {"sq_units_m2": {"3d": a}}, "kf ca": {"sq_units_m2": {"3d": b}}}},
             "yamatogawa": {"pr": {"stls": {"sq_units_m2": {"h": a}}, "vertical_bias_removed_m": 0.1}}}
    before = fair.ratio_interval(a, b)
    fair.drop_epoch_units(cases)
    kept = cases["flight"]["pr"]
    assert all(v == float(f"{v:.6g}") for v in kept["stls"]["sq_units_m2"]["3d"])
    assert kept["stls"]["sq_units_m2"]["3d"] != a  # rounded: the drawn values have more digits
    assert np.allclose(before, fair.ratio_interval(kept["stls"]["sq_units_m2"]["3d"], kept["kf ca"]["sq_units_m2"]["3d"]),
                       rtol=1e-5)
    assert "sq_units_m2" not in cases["yamatogawa"]["pr"]["stls"]


def test_default_candidate_is_nearest_the_best_in_its_worst_set() -> None:
    """One default for every measurement set: the candidate whose training RMS over its set's best
    is lowest in its worst set, not the best of any one set."""
    rms = {"pr": {"0/1e-06": 1.08, "0/1e-12": 1.18, "15/1e-12": 1.5},
           "pr+doppler": {"0/1e-06": 0.411, "0/1e-12": 0.410, "15/1e-12": 0.414},
           "pr+doppler+phase": {"0/1e-06": 0.155, "0/1e-12": 0.177, "15/1e-12": 0.150}}
    chosen = {k: {"rms_3d_m": {"stls": v}} for k, v in rms.items()}
    best, scores = fair.default_candidate(chosen)
    assert best == (0, 1e-6)  # best with the pseudoranges alone, but in no other set
    assert scores == pytest.approx({"0/1e-06": 0.155 / 0.150, "0/1e-12": 0.177 / 0.150, "15/1e-12": 1.5 / 1.08})
    # a candidate the training did not score in some set is not chosen
    del rms["pr"]["0/1e-06"]
    best, scores = fair.default_candidate({k: {"rms_3d_m": {"stls": v}} for k, v in rms.items()})
    assert best == (0, 1e-12) and set(scores) == {"0/1e-12", "15/1e-12"}


def test_the_packaged_stls_defaults_are_the_committed_training_runs_choice() -> None:
    """``[stls] window`` and ``behavior_pfa`` are what :func:`default_candidate` takes from the
    training scores of the committed benchmark result: a default changed without a run that
    chose it, or a run that chose otherwise, fails here."""
    result = Path(fair.OUT)
    if not result.is_file():
        pytest.skip(f"no {result}")
    chosen = json.loads(result.read_text(encoding="utf-8"))["settings_chosen"]
    assert tuple(fair.default_candidate(chosen)[0]) == fair.packaged_default()
