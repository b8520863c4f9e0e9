"""Range-rate geometry and the Doppler selection."""

from __future__ import annotations

import numpy as np
import xarray as xr

from gnss_cli.gnss.doppler import range_rate_system
from gnss_cli.gnss.range_model import sagnac_range
from gnss_cli.gnss.observables import select_dopplers, select_pseudoranges


def test_range_rate_rows_are_the_time_derivative_of_the_sagnac_range():
    """For satellites and a receiver moving in straight lines, the model range rate
    ``d/dt r(t) + d - c dt_sv_dot`` (numerical derivative of the range of the geometry module)
    satisfies ``H [v; d] = y`` to 1e-5 m/s; the Earth-rotation rate term is ~4e-3 m/s."""
    rng = np.random.default_rng(5)
    n = 8
    sat = rng.normal(size=(n, 3))
    sat *= 2.6e7 / np.linalg.norm(sat, axis=1, keepdims=True)
    sat_v = rng.normal(scale=2000.0, size=(n, 3))
    x = np.array([3.58e6, 5.35e5, 5.23e6])
    v = np.array([60.0, -35.0, 4.0])
    drift_m_s, sat_drift = 12.5, rng.normal(scale=1e-9, size=n)
    h = 1e-3

    def r(t: float) -> np.ndarray:
        return sagnac_range((sat + sat_v * t)[None], (x + v * t)[None])[0][0]

    rate = (r(h) - r(-h)) / (2 * h) + drift_m_s - 299_792_458.0 * sat_drift
    H, y = range_rate_system(sat[None], sat_v[None], sat_drift[None], rate[None], x[None])
    assert np.abs(H[0] @ np.r_[v, drift_m_s] - y[0]).max() < 1e-5
    H0, y0 = range_rate_system(sat[None], sat_v[None], sat_drift[None], rate[None], x[None])
    plain = np.einsum("nk,nk->n", (sat - x) / np.linalg.norm(sat - x, axis=1, keepdims=True), sat_v - v)
    assert np.abs(plain + drift_m_s - 299_792_458.0 * sat_drift - rate).max() > 1e-4  # the rotation term matters


def test_doppler_follows_the_pseudorange_signal():
    t = np.array(["2024-03-01T00:00:00", "2024-03-01T00:00:01"], dtype="datetime64[ns]")
    nan = np.nan
    ds = xr.Dataset(
        {"C1C": (("time", "sv"), [[2.1e7, 2.2e7], [nan, 2.2e7]]),
         "C1W": (("time", "sv"), [[2.1e7, 2.2e7], [2.1e7, 2.2e7]]),
         "D1C": (("time", "sv"), [[-100.0, 0.0], [-101.0, 50.0]]),
         "D1W": (("time", "sv"), [[-7.0, -8.0], [-9.0, -10.0]])},
        coords={"time": t, "sv": ["G01", "G02"]},
    )
    prs = select_pseudoranges(ds, ["G"])
    dop = select_dopplers(ds, prs)
    # G01: C1C then C1W (epoch 1) -> D1C then D1W; G02: C1C -> D1C, whose 0 is a missing value
    np.testing.assert_array_equal(dop, [[-100.0, nan], [-9.0, 50.0]])
