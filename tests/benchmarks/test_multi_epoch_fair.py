"""How ``benchmarks/multi_epoch_fair.py`` groups its variants into runs: variants of different
methods share a run only when they agree on every setting they both give."""

from __future__ import annotations

import sys
from pathlib import Path

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
