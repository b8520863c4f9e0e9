"""How ``benchmarks/multi_epoch_fair.py`` groups its variants into runs (variants of different
methods share a run only when they agree on every setting they both give), chooses a setting on
its training runs and deals the runs among processes."""

from __future__ import annotations

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
