"""The settings a fixed-motion method reports name the process noise it ran with."""

from __future__ import annotations

import pytest

from gnss_cli.config import load_config
from gnss_cli.pipeline.methods import method_settings


@pytest.mark.parametrize("motion, key, value, words", [
    ("cv", "kalman.accel_psd_m2_s3", 0.1, "motion cv (acceleration PSD 0.1 m^2/s^3)"),
    ("ca", "kalman.jerk_psd_m2_s5", 0.01, "motion ca (jerk PSD 0.01 m^2/s^5)"),
])
def test_smoother_and_kf_report_the_psd_of_their_motion(motion: str, key: str, value: float, words: str) -> None:
    """Two runs that differ only in the process noise must not report the same model: the
    equal-information benchmark chooses the PSD per method and reads back what ran."""
    cfg = load_config(None, {"methods": "wls,smoother,kf", "smoother.motion": motion, "kalman.model": motion, key: value})
    ran = method_settings(cfg, True, False)
    assert ran["smoother"].model == words and ran["kf"].model == words
    other = method_settings(load_config(None, {"methods": "wls,smoother", "smoother.motion": motion, key: 10 * value}),
                            True, False)
    assert other["smoother"].model != words


def test_the_quadrature_motion_has_no_process_noise_to_report() -> None:
    cfg = load_config(None, {"methods": "wls,smoother", "smoother.motion": "quadrature", "kalman.accel_psd_m2_s3": 0.1})
    assert method_settings(cfg, True, False)["smoother"].model == "motion quadrature"


@pytest.mark.parametrize("overrides, window", [
    ({}, "whole segments"),
    ({"stls.window": 15}, "15 epochs"),
    ({"stls.behavior_pfa": 0.0}, "whole segments, untested"),
    ({"stls.kernel": "full", "stls.window": 30}, "30 epochs, untested"),
])
def test_stls_window_says_whether_a_behavior_test_chose_the_spans(overrides: dict, window: str) -> None:
    """``window`` says ``untested`` exactly where no behavior test runs: ``behavior_pfa = 0`` and the
    full kernel, which smooths the fixes without one (``pipeline.behavioral.smooth``)."""
    cfg = load_config(None, {"methods": "wls,stls", "stls.lag": 3, **overrides})
    assert method_settings(cfg, True, False)["stls"].window == window
