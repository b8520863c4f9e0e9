"""Reference inputs: ``--reference`` ECEF or geodetic, the reference CSV layouts, each checked
against pymap3d's conversion (an independent implementation of WGS-84)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pymap3d
import pytest

from gnss_cli.errors import ConfigError
from gnss_cli.io.reference import MATCH_TOLERANCE_S, coverage_warning, parse_reference, read_reference_csv, reference_from_csv

LLH = [(55.5, 8.5, 50.0), (22.299915404, 114.177707462, 4.89), (-33.9, -70.6, 3200.0), (89.9, -179.0, -20.0)]


@pytest.mark.parametrize("lat, lon, h", LLH)
def test_geodetic_reference_equals_pymap3d_ecef(lat: float, lon: float, h: float) -> None:
    expected = np.array(pymap3d.geodetic2ecef(lat, lon, h))
    np.testing.assert_allclose(parse_reference(f"geodetic:{lat},{lon},{h}"), expected, rtol=0, atol=1e-6)
    np.testing.assert_allclose(parse_reference(f"GEODETIC: {lat}, {lon}, {h}"), expected, rtol=0, atol=1e-6)
    text = ",".join(f"{v:.6f}" for v in expected)
    np.testing.assert_allclose(parse_reference(text), parse_reference(f"ecef:{text}"), rtol=0, atol=0)


def test_geodetic_values_without_the_prefix_are_refused_with_a_hint() -> None:
    with pytest.raises(ConfigError, match=r"write geodetic:LAT,LON,H"):
        parse_reference("22.3,114.2,4.9")
    with pytest.raises(ConfigError, match=r"\|LAT\| <= 90"):
        parse_reference("geodetic:114.2,22.3,4.9")
    with pytest.raises(ConfigError, match=r"expected geodetic:LAT,LON,H"):
        parse_reference("geodetic:1,2")
    with pytest.raises(ConfigError, match=r"expected X,Y,Z \(ECEF, m\) or geodetic"):
        parse_reference("enu:1,2,3")


def _truth(n: int = 5) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    tow = 270149.0 + np.arange(n)
    lat, lon, h = 22.299915404 + 1e-5 * np.arange(n), 114.177707462 - 2e-5 * np.arange(n), 4.89 + np.arange(n)
    return tow, np.column_stack([lat, lon, h]), np.column_stack(pymap3d.geodetic2ecef(lat, lon, h))


def test_csv_layouts_give_the_same_ecef_rows(tmp_path) -> None:  # type: ignore[no-untyped-def]
    tow, llh, xyz = _truth()
    week = 2108
    iso = (np.datetime64("1980-01-06T00:00:00", "ns") + (week * 604800 + tow).astype(np.int64).astype("timedelta64[s]"))
    files = {
        "time_ecef.csv": pd.DataFrame({"time": np.datetime_as_string(iso, unit="ms"), "x_m": xyz[:, 0], "y_m": xyz[:, 1], "z_m": xyz[:, 2]}),
        "week_llh.csv": pd.DataFrame({"gps_week": week, "tow_s": tow, "lat_deg": llh[:, 0], "lon_deg": llh[:, 1], "height_m": llh[:, 2]}),
        "time_latitude.csv": pd.DataFrame({"time": np.datetime_as_string(iso, unit="ms"), "latitude": llh[:, 0],
                                           "longitude": llh[:, 1], "height": llh[:, 2]}),
    }
    t_gps = week * 604800.0 + tow
    for name, df in files.items():
        df.to_csv(tmp_path / name, index=False)
        t, rows, tow_only = read_reference_csv(tmp_path / name)
        assert not tow_only, name
        np.testing.assert_allclose(t, t_gps, rtol=0, atol=1e-6, err_msg=name)
        np.testing.assert_allclose(rows, xyz, rtol=0, atol=1e-6, err_msg=name)
    headerless = tmp_path / "truth.csv"  # the UrbanNav layout: week,tow,lat,lon,height, no header
    headerless.write_text("".join(f"{week},{t:.0f},{a:.9f},{b:.9f},{c:.9f}\n" for t, (a, b, c) in zip(tow, llh)))
    t, rows, tow_only = read_reference_csv(headerless)
    assert not tow_only
    np.testing.assert_allclose(t, t_gps, rtol=0, atol=1e-6)
    np.testing.assert_allclose(rows, xyz, rtol=0, atol=1e-6)


def test_headerless_file_whose_week_column_is_no_week_is_matched_by_seconds_of_week(tmp_path) -> None:  # type: ignore[no-untyped-def]
    tow, llh, xyz = _truth()
    f = tmp_path / "groundTruth.csv"  # as the shared UrbanNav file: the seconds of week twice
    f.write_text("".join(f"{t:.0f},{t:.0f},{a:.9f},{b:.9f},{c:.9f}\n" for t, (a, b, c) in zip(tow, llh)))
    t, _, tow_only = read_reference_csv(f)
    assert tow_only
    np.testing.assert_array_equal(t, tow)
    epochs = 2108 * 604800.0 + np.concatenate([[tow[0] - 1.0], tow + 0.004])  # tagged 4 ms late, one before the truth
    ref = reference_from_csv(f, epochs)
    assert np.isnan(ref[0]).all()
    np.testing.assert_allclose(ref[1:], xyz, rtol=0, atol=1e-6)
    assert MATCH_TOLERANCE_S < 0.5  # never the neighbouring second


@pytest.mark.parametrize("text, message", [
    ("a,b\n1,2\n", "no time"),
    ("time,x_m\n2024-01-01,1\n", "no position columns"),
    ("time,x_m,y_m,z_m\nnot-a-time,1,2,3\n", "bad time or position"),
])
def test_bad_csv_is_one_config_error(tmp_path, text: str, message: str) -> None:  # type: ignore[no-untyped-def]
    f = tmp_path / "ref.csv"
    f.write_text(text)
    with pytest.raises(ConfigError, match=message):
        read_reference_csv(f)


def test_coverage_warning_thresholds() -> None:
    assert coverage_warning(0, 0, "r.csv") is None
    assert "matches none of the 10 solved epochs" in str(coverage_warning(0, 10, "r.csv"))
    assert "matches 4 of the 10 solved epochs" in str(coverage_warning(4, 10, "r.csv"))
    assert coverage_warning(5, 10, "r.csv") is None
