"""The dataset of the Python API selects methods with ``sel(method=...)``; its keyword errors
name the keyword and the nearest valid one."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import gnss_cli
from gnss_cli.errors import ConfigError, KeywordError

SAMPLE = Path(__file__).resolve().parents[2] / "sample_rinex" / "static"


@pytest.fixture(scope="module")
def ds():  # type: ignore[no-untyped-def]
    return gnss_cli.solve(SAMPLE / "obs.rnx", SAMPLE / "nav.rnx", methods="ls,wls")


def test_sel_method_selects_that_method_only(ds) -> None:  # type: ignore[no-untyped-def]
    assert ds.sizes["method"] == 2
    wls = ds.sel(method="wls")
    assert "method" not in wls.dims and wls["method"].item() == "wls"
    np.testing.assert_array_equal(wls["x_m"].values, ds["x_m"].values[:, 1])
    np.testing.assert_array_equal(ds["x_m"].sel(method="ls").values, ds["x_m"].values[:, 0])
    assert not np.array_equal(ds.sel(method="ls")["x_m"].values, wls["x_m"].values, equal_nan=True)
    assert list(ds.sel(method=["wls"])["method"].values) == ["wls"]
    # the dict form and the derived datasets keep working
    np.testing.assert_array_equal(ds.sel({"method": "wls"})["x_m"].values, wls["x_m"].values)
    np.testing.assert_array_equal(ds.isel(time=slice(0, 5)).sel(method="wls")["x_m"].values, wls["x_m"].values[:5])
    frame = ds.sel(method="wls").to_dataframe()
    assert len(frame) == ds.sizes["time"]


def test_sel_keeps_xarrays_lookup_rule(ds) -> None:  # type: ignore[no-untyped-def]
    t = ds["time"].values[3] + np.timedelta64(2, "s")
    near = ds.sel(time=t, method="nearest")
    assert near["time"].values == ds["time"].values[3] and near.sizes["method"] == 2


def test_sel_with_a_mistyped_method_names_the_nearest(ds) -> None:  # type: ignore[no-untyped-def]
    with pytest.raises(KeyError, match=r"did you mean 'wls'"):
        ds.sel(method="wsl")


@pytest.mark.parametrize("options, message", [
    ({"method": "wls"}, r"unknown keyword 'method'; did you mean 'methods'\?"),
    ({"elevation_mask": 10}, r"unknown keyword 'elevation_mask'; did you mean 'elevation_mask_deg'\?"),
    ({"refrence": "1,2,3"}, r"unknown keyword 'refrence'; did you mean 'reference'\?"),
    ({"stls": {"lagg": 3}}, r"stls=: unknown key 'lagg'; did you mean 'lag'\?"),
])
def test_unknown_keyword_names_it_and_the_nearest_valid_one(options, message) -> None:  # type: ignore[no-untyped-def]
    with pytest.raises(KeywordError, match=message) as info:
        gnss_cli.solve(SAMPLE / "obs.rnx", SAMPLE / "nav.rnx", **options)
    assert isinstance(info.value, TypeError) and isinstance(info.value, ConfigError)
    assert str(info.value).startswith("gnss_cli.solve: ")


def test_geodetic_reference_string_equals_the_ecef_array(ds) -> None:  # type: ignore[no-untyped-def]
    import pymap3d

    ecef = np.array(pymap3d.geodetic2ecef(55.5, 8.5, 50.0))
    a = gnss_cli.solve(SAMPLE / "obs.rnx", SAMPLE / "nav.rnx", methods="wls", reference="geodetic:55.5,8.5,50")
    b = gnss_cli.solve(SAMPLE / "obs.rnx", SAMPLE / "nav.rnx", methods="wls", reference=ecef)
    assert np.isfinite(a["err_3d_m"].values).all()
    np.testing.assert_allclose(a["err_3d_m"].values, b["err_3d_m"].values, rtol=0, atol=1e-6)
