"""Signal frequencies, broadcast group delays and the ionosphere-free combination.

The group delays are checked from first principles: satellites with arbitrary hardware
delays per signal, broadcast clocks and TGD/BGD values built from those delays by the
interface-document definitions; the iono-free pseudorange plus the broadcast clock must
then be the geometric range, with any ionospheric delay.
"""

from __future__ import annotations

import numpy as np
import pytest

from gnss_cli.constants import C_M_S
from gnss_cli.gnss.signals import (
    carrier_frequency_hz,
    group_delay_s,
    iono_free_combination_m,
    iono_free_pseudorange_m,
    signal_of,
)

RHO_M = 2.2e7
RNG = np.random.default_rng(11)


def _measure(signal_delays_s: dict[str, float], freqs_hz: dict[str, float], dts_s: float, iono_l1_m: float) -> dict[str, float]:
    """Pseudoranges of each signal: rho - c dts + c delta_s + I_L1 (f_L1 / f_s)^2."""
    f_l1 = 1575.42e6
    return {s: RHO_M - C_M_S * dts_s + C_M_S * d + iono_l1_m * (f_l1 / freqs_hz[s]) ** 2 for s, d in signal_delays_s.items()}


def _if_delay(d1: float, d2: float, f1: float, f2: float) -> float:
    g = (f1 / f2) ** 2
    return (g * d1 - d2) / (g - 1.0)


@pytest.mark.parametrize(
    ("system", "code", "signal"),
    [("G", "C1C", "L1"), ("G", "C2W", "L2"), ("G", "P2", "L2"), ("G", "C5Q", "L5"), ("E", "C7Q", "E5b"),
     ("E", "C5X", "E5a"), ("C", "C2I", "B1I"), ("C", "C1I", "B1I"), ("C", "C1P", "B1C"), ("C", "C7I", "B2I"),
     ("C", "C7D", "B2b"), ("C", "C6I", "B3I"), ("R", "C2P", "G2"), ("J", "C2L", "L2"), ("G", "L1C", None)],
)
def test_signal_of_rinex_codes(system, code, signal):
    assert signal_of(system, code) == signal


def test_glonass_channel_frequencies_keep_the_9_7_ratio():
    k = np.arange(-7, 7)
    f1, f2 = carrier_frequency_hz("G1", k), carrier_frequency_hz("G2", k)
    assert np.allclose(f1 / f2, 9.0 / 7.0, rtol=0, atol=1e-15)
    assert f1[7] == 1602.0e6 and f2[0] == 1246.0e6 - 7 * 0.4375e6


@pytest.mark.parametrize("iono_m", [0.0, 3.0, 25.0])
def test_gps_l1_l2_iono_free_with_tgd_refers_to_the_broadcast_clock(iono_m):
    f = {"L1": 1575.42e6, "L2": 1227.60e6}
    d = {"L1": RNG.normal(0, 5e-9), "L2": RNG.normal(0, 5e-9)}
    dts = 1e-4
    gamma = (f["L1"] / f["L2"]) ** 2
    clock_brd = dts - _if_delay(d["L1"], d["L2"], f["L1"], f["L2"])  # clock refers to the L1/L2 pair
    tgd = (d["L1"] - d["L2"]) / (1.0 - gamma)  # IS-GPS-200 20.3.3.3.3.2
    p = _measure(d, f, dts, iono_m)
    pif = iono_free_pseudorange_m("G", np.array(["C1W"]), np.array([p["L1"]]), np.array(["C2W"]), np.array([p["L2"]]),
                                  tgd_s=np.array([tgd]))
    assert pif[0] + C_M_S * clock_brd == pytest.approx(RHO_M, abs=1e-6)
    # single frequency: L1 minus TGD plus the clock leaves rho + I
    assert p["L1"] - C_M_S * group_delay_s("G", "L1", tgd) + C_M_S * clock_brd - iono_m == pytest.approx(RHO_M, abs=1e-6)
    # the TGDs cancel in the L1/L2 pair: the plain combination is the same number
    plain = iono_free_combination_m(p["L1"], p["L2"], f["L1"], f["L2"])
    assert pif[0] == pytest.approx(float(plain), abs=1e-6)


@pytest.mark.parametrize("fnav", [False, True])
@pytest.mark.parametrize("second", ["C7Q", "C5Q"])
def test_galileo_e1_e5a_e5b_with_inav_and_fnav_clocks(fnav, second):
    f = {"E1": 1575.42e6, "E5a": 1176.45e6, "E5b": 1207.14e6}
    d = {s: RNG.normal(0, 5e-9) for s in f}
    dts, iono = -3e-4, 12.0
    bgd = {x: (d["E1"] - d[x]) / (1.0 - (f["E1"] / f[x]) ** 2) for x in ("E5a", "E5b")}  # OS SIS ICD 5.1.5
    own, other = ("E5a", "E5b") if fnav else ("E5b", "E5a")
    clock_brd = dts - _if_delay(d["E1"], d[own], f["E1"], f[own])
    p = _measure(d, f, dts, iono)
    s2 = signal_of("E", second)
    pif = iono_free_pseudorange_m(
        "E", np.array(["C1C"]), np.array([p["E1"]]), np.array([second]), np.array([p[s2]]),
        tgd_s=np.array([bgd[own]]), tgd2_s=np.array([bgd[other]]), fnav=np.array([fnav]),
    )
    assert pif[0] + C_M_S * clock_brd == pytest.approx(RHO_M, abs=1e-6)
    # every signal alone: P - c d_s + c clock = rho + I_s
    for s in f:
        ds = group_delay_s("E", s, bgd[own], bgd[other], fnav)
        iono_s = iono * (f["E1"] / f[s]) ** 2
        assert p[s] - C_M_S * float(ds) + C_M_S * clock_brd - iono_s == pytest.approx(RHO_M, abs=1e-6)


@pytest.mark.parametrize("second", ["C7I", "C6I"])
def test_beidou_clock_refers_to_b3i(second):
    f = {"B1I": 1561.098e6, "B2I": 1207.14e6, "B3I": 1268.52e6}
    d = {s: RNG.normal(0, 5e-9) for s in f}
    dts, iono = 2e-4, 8.0
    clock_brd = dts - d["B3I"]
    tgd1, tgd2 = d["B1I"] - d["B3I"], d["B2I"] - d["B3I"]  # BDS-SIS-ICD-B1I 5.2.4.10
    p = _measure(d, f, dts, iono)
    pif = iono_free_pseudorange_m("C", np.array(["C2I"]), np.array([p["B1I"]]), np.array([second]),
                                  np.array([p[signal_of("C", second)]]), tgd_s=np.array([tgd1]), tgd2_s=np.array([tgd2]))
    assert pif[0] + C_M_S * clock_brd == pytest.approx(RHO_M, abs=1e-6)


def test_glonass_iono_free_per_channel():
    k = np.array([-7.0, 0.0, 6.0])
    f1, f2 = carrier_frequency_hz("G1", k), carrier_frequency_hz("G2", k)
    iono = np.array([4.0, 9.0, 20.0])  # on L1
    p1 = RHO_M + iono * (1575.42e6 / f1) ** 2
    p2 = RHO_M + iono * (1575.42e6 / f2) ** 2
    pif = iono_free_pseudorange_m("R", np.full(3, "C1C"), p1, np.full(3, "C2P"), p2, tgd_s=np.zeros(3), glonass_channel=k)
    assert np.allclose(pif, RHO_M, rtol=0, atol=1e-6)


def test_unsupported_or_missing_pairs_give_nan():
    p = np.array([2e7, 2e7, 2e7, np.nan])
    out = iono_free_pseudorange_m(
        "G", np.array(["C1C", "C1C", "C1C", "C1C"]), p, np.array(["C5Q", "C1W", "C2W", "C2W"]), p,
        tgd_s=np.zeros(4),
    )
    assert np.isnan(out[0])  # L5 needs the CNAV ISCs
    assert np.isnan(out[1])  # same frequency
    assert np.isfinite(out[2])
    assert np.isnan(out[3])  # missing first frequency
