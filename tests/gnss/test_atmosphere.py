"""Atmosphere models against values that follow from their definitions."""

from __future__ import annotations

import numpy as np

from gnss_cli.constants import C_M_S
from gnss_cli.gnss.atmosphere import klobuchar_delay_m, saastamoinen_delay_m


def test_klobuchar_night_floor_is_five_nanoseconds_times_obliquity():
    alpha = np.array([1e-8, 0.0, 0.0, 0.0])
    beta = np.array([90000.0, 0.0, 0.0, 0.0])
    # Local time 02:00 at longitude 0 (far from the 14:00 peak): only the 5 ns floor remains.
    d = klobuchar_delay_m(alpha, beta, 0.0, 0.0, 0.0, np.pi / 2, 2 * 3600.0)
    obliquity = 1.0 + 16.0 * (0.53 - 0.5) ** 3
    assert np.isclose(d, 5e-9 * obliquity * C_M_S, rtol=1e-12)


def test_klobuchar_peak_at_14h_local_time_adds_amplitude():
    alpha = np.array([2e-8, 0.0, 0.0, 0.0])
    beta = np.array([100000.0, 0.0, 0.0, 0.0])
    t_peak = 14 * 3600.0  # receiver at lon 0, zenith: pierce point lon 0 -> local time = GPS time of day
    d = klobuchar_delay_m(alpha, beta, 0.0, 0.0, 0.0, np.pi / 2, t_peak)
    obliquity = 1.0 + 16.0 * (0.53 - 0.5) ** 3
    assert np.isclose(d, (5e-9 + 2e-8) * obliquity * C_M_S, rtol=1e-9)
    assert klobuchar_delay_m(alpha, beta, 0.0, 0.0, 0.0, np.deg2rad(15.0), t_peak) > 2.0 * d


def test_saastamoinen_zenith_sea_level_and_mapping():
    zenith = saastamoinen_delay_m(np.deg2rad(45.0), 0.0, np.pi / 2)
    assert 2.3 < zenith < 2.6  # standard atmosphere: ~2.3 m dry + ~0.1-0.2 m wet
    el = np.deg2rad(30.0)
    assert np.isclose(saastamoinen_delay_m(np.deg2rad(45.0), 0.0, el), zenith / np.sin(el), rtol=1e-12)
    assert saastamoinen_delay_m(np.deg2rad(45.0), 2000.0, np.pi / 2) < zenith * 0.85
    assert saastamoinen_delay_m(0.0, 0.0, -0.1) == 0.0
