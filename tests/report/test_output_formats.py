"""Every output format read back by an independent reader: RTKLIB's pos2kml for ``.pos``,
json / xml.etree for GeoJSON and KML, pyarrow for Parquet, a hand parser for NMEA; the
UTC time stamps; the E/N/U uncertainty columns against a recomputation and the scatter of a
simulation."""

from __future__ import annotations

import io
import json
import shutil
import subprocess
import xml.etree.ElementTree as ET
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from gnss_cli.config import load_config
from gnss_cli.formats import geojson_text, kml_text, nmea_checksum, nmea_text, parquet_bytes, pos_text
from gnss_cli.pipeline import process
from gnss_cli.report import positions_table, summary_table

KML_NS = {"k": "http://www.opengis.net/kml/2.2"}
DATASETS = {
    "rtklib-0759": ("07590920.05o", "07590920.05n", 13.0),
    "yamatogawa-2010006-kinematic": ("yamatogawa_rover.obs", "brdc0060.10n", 15.0),
}


def _ecef(lat_deg, lon_deg, h_m):  # type: ignore[no-untyped-def]
    """WGS-84 geodetic -> ECEF, written out here so that the check does not use the code under test."""
    a, e2 = 6378137.0, 6.69437999014e-3
    lat, lon = np.deg2rad(np.asarray(lat_deg, float)), np.deg2rad(np.asarray(lon_deg, float))
    n = a / np.sqrt(1 - e2 * np.sin(lat) ** 2)
    h = np.asarray(h_m, float)
    return np.stack([(n + h) * np.cos(lat) * np.cos(lon), (n + h) * np.cos(lat) * np.sin(lon), (n * (1 - e2) + h) * np.sin(lat)], -1)


@pytest.fixture(scope="module", params=sorted(DATASETS))
def run(request, rinex_dir):  # type: ignore[no-untyped-def]
    obs, nav, leap = DATASETS[request.param]
    folder = rinex_dir / request.param
    result = process(folder / obs, [folder / nav], load_config(overrides={"methods": "ls,wls"}))
    return request.param, result, leap


def _solved(table: pd.DataFrame, method: str) -> pd.DataFrame:
    t = table[(table["method"] == method) & table["status"].isin(["ok", "fallback_wls"])]
    return t.reset_index(drop=True)


def test_utc_time_is_gpst_minus_the_header_leap_seconds(run) -> None:  # type: ignore[no-untyped-def]
    _, result, leap = run
    assert result.epochs.leap_seconds == leap
    gpst, utc = positions_table(result, None, "gpst"), positions_table(result, None, "utc")
    dt = (pd.to_datetime(gpst["time"]) - pd.to_datetime(utc["time"])).dt.total_seconds()
    assert (dt == leap).all()
    assert (gpst["tow_s"] == utc["tow_s"]).all() and (gpst["gps_week"] == utc["gps_week"]).all()
    cols = [c for c in gpst.columns if c != "time"]
    pd.testing.assert_frame_equal(gpst[cols], utc[cols])


@pytest.mark.parametrize("time_system", ["gpst", "utc"])
def test_every_format_reads_back_to_the_same_positions(run, time_system: str) -> None:  # type: ignore[no-untyped-def]
    _, result, _ = run
    table = positions_table(result, None, time_system)
    wls = _solved(table, "wls")
    xyz = wls[["x_m", "y_m", "z_m"]].to_numpy()
    times = pd.to_datetime(wls["time"])

    # pos: ECEF columns and yyyy/mm/dd hh:mm:ss.sss in the chosen time scale
    text = pos_text(table[table["method"] == "wls"], time_system)
    assert ("%  UTC " if time_system == "utc" else "%  GPST ") in text
    rows = [line.split() for line in text.splitlines() if line and not line.startswith("%")]
    assert len(rows) == len(wls)
    assert np.abs(np.array([[float(v) for v in r[2:5]] for r in rows]) - xyz).max() < 1e-3
    assert [pd.Timestamp(f"{r[0].replace('/', '-')} {r[1]}") for r in rows] == list(times)
    assert {r[5] for r in rows} == {"5"}

    # geojson: RFC 7946 FeatureCollection, [lon, lat, h]
    doc = json.loads(geojson_text(table, time_system))
    assert doc["type"] == "FeatureCollection"
    lines = [f for f in doc["features"] if f["geometry"] and f["geometry"]["type"] == "LineString"]
    assert [f["properties"]["method"] for f in lines] == ["ls", "wls"]
    line = np.array(lines[1]["geometry"]["coordinates"])
    assert np.abs(_ecef(line[:, 1], line[:, 0], line[:, 2]) - xyz).max() < 1e-3
    points = [f for f in doc["features"] if f["geometry"] and f["geometry"]["type"] == "Point" and f["properties"]["method"] == "wls"]
    assert [pd.Timestamp(p["properties"]["time"]) for p in points] == list(times)
    assert all(p["properties"]["status"] in ("ok", "fallback_wls") and p["properties"]["gdop"] > 0 for p in points)

    # kml: one Placemark LineString per method, lon,lat,h
    root = ET.fromstring(kml_text(table))
    marks = root.findall(".//k:Placemark", KML_NS)
    assert [m.find("k:name", KML_NS).text for m in marks] == ["ls", "wls"]
    coords = np.array([[float(v) for v in c.split(",")] for c in marks[1].find(".//k:coordinates", KML_NS).text.split()])
    assert np.abs(_ecef(coords[:, 1], coords[:, 0], coords[:, 2]) - xyz).max() < 1e-3

    # nmea: checksums, ddmm.mmmm, time of day and date
    sentences = nmea_text(table[table["method"] == "wls"]).splitlines()
    gga = []
    for s in sentences:
        body, _, check = s[1:].partition("*")
        x = 0
        for ch in body:
            x ^= ord(ch)
        assert check == f"{x:02X}"
        f = body.split(",")
        if f[0].endswith("GGA") and f[6] != "0":
            lat = (int(f[2][:2]) + float(f[2][2:]) / 60) * (1 if f[3] == "N" else -1)
            lon = (int(f[4][:3]) + float(f[4][3:]) / 60) * (1 if f[5] == "E" else -1)
            gga.append((f[1], lat, lon, float(f[9])))
    assert len(gga) == len(wls)
    assert np.abs(_ecef([g[1] for g in gga], [g[2] for g in gga], [g[3] for g in gga]) - xyz).max() < 1e-3
    assert [g[0] for g in gga] == [t.strftime("%H%M%S.") + f"{t.microsecond // 10000:02d}" for t in times]

    # parquet: typed columns
    import pyarrow as pa
    import pyarrow.parquet as pq

    blob = parquet_bytes(table, time_system)
    schema = pq.read_schema(io.BytesIO(blob))
    want_tz = "UTC" if time_system == "utc" else None
    assert schema.field("time").type == pa.timestamp("ns", tz=want_tz)
    assert pa.types.is_dictionary(schema.field("method").type)
    assert schema.field("x_m").type == pa.float64() and schema.field("sde_m").type == pa.float64()
    assert schema.field("status").type in (pa.string(), pa.large_string())
    back = pd.read_parquet(io.BytesIO(blob))
    back_wls = back[(back["method"] == "wls") & back["status"].isin(["ok", "fallback_wls"])]
    assert np.abs(back_wls[["x_m", "y_m", "z_m"]].to_numpy() - xyz).max() < 1e-3
    expected_t = times.dt.tz_localize("UTC") if time_system == "utc" else times
    assert list(back_wls["time"]) == list(expected_t)


def test_rtklib_pos2kml_reads_our_pos_file(run, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    exe = shutil.which("pos2kml")
    if exe is None:
        pytest.skip("pos2kml (Debian package rtklib) not on PATH")
    name, result, _ = run
    table = positions_table(result)
    wls = _solved(table, "wls")
    path = tmp_path / f"{name}.pos"
    path.write_text(pos_text(table[table["method"] == "wls"]), newline="")
    subprocess.run([exe, "-a", "-o", str(tmp_path / "out.kml"), str(path)], check=True, capture_output=True)
    root = ET.parse(tmp_path / "out.kml").getroot()
    points = [c.text.strip() for c in root.iter() if c.tag.endswith("Point") for c in c if c.tag.endswith("coordinates")]
    lonlath = np.array([[float(v) for v in p.split(",")] for p in points])
    assert len(lonlath) == len(wls)
    xyz = wls[["x_m", "y_m", "z_m"]].to_numpy()
    # pos2kml prints 9 decimals of a degree (0.1 mm) and the height to 1 mm
    assert np.abs(_ecef(lonlath[:, 1], lonlath[:, 0], lonlath[:, 2]) - xyz).max() < 1e-3


def test_uncertainty_columns_are_the_rotated_covariance(run) -> None:  # type: ignore[no-untyped-def]
    _, result, _ = run
    table = positions_table(result)
    s = result.solutions["wls"]
    wls = table[table["method"] == "wls"].reset_index(drop=True)
    for t in (0, len(wls) // 2, len(wls) - 1):
        lat, lon = np.deg2rad(wls.loc[t, "lat_deg"]), np.deg2rad(wls.loc[t, "lon_deg"])
        r = np.array([[-np.sin(lon), np.cos(lon), 0.0],
                      [-np.sin(lat) * np.cos(lon), -np.sin(lat) * np.sin(lon), np.cos(lat)],
                      [np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)]])
        c = r @ s.cov_m2[t, :3, :3] @ r.T
        got = wls.loc[t, ["sde_m", "sdn_m", "sdu_m", "sden_m2", "sdnu_m2", "sdue_m2"]].to_numpy(dtype=float)
        want = [np.sqrt(c[0, 0]), np.sqrt(c[1, 1]), np.sqrt(c[2, 2]), c[0, 1], c[1, 2], c[2, 0]]
        np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-12)


def test_summary_has_mean_position_and_scatter(run) -> None:  # type: ignore[no-untyped-def]
    _, result, _ = run
    summary = summary_table(result).set_index("method")
    s = result.solutions["wls"]
    x = s.x_ecef_m[np.isfinite(s.x_ecef_m).all(axis=1)]
    np.testing.assert_allclose(summary.loc["wls", ["mean_x_m", "mean_y_m", "mean_z_m"]].to_numpy(dtype=float), x.mean(axis=0))
    back = _ecef(summary.loc["wls", "mean_lat_deg"], summary.loc["wls", "mean_lon_deg"], summary.loc["wls", "mean_height_m"])
    assert np.abs(back - x.mean(axis=0)).max() < 1e-4
    scatter = summary.loc["wls", ["scatter_e_m", "scatter_n_m", "scatter_u_m"]].to_numpy(dtype=float)
    assert np.all(scatter > 0) and abs(np.linalg.norm(scatter) - np.sqrt(((x - x.mean(axis=0)) ** 2).sum(axis=1).mean())) < 1e-6


def test_sd_of_wls_matches_the_scatter_of_a_simulation(tmp_path: Path) -> None:
    """White 1 m noise, equal weights of 1 m: the predicted E/N/U sigmas are the actual scatter
    (within a factor of 2; measured ratios are near 1)."""
    from gnss_cli.sim.error_sources import parse_error_list
    from gnss_cli.sim.scenario import ScenarioConfig, run_scenario, write_scenario

    base = ScenarioConfig()
    cfg = replace(base, duration_s=600.0, interval_s=1.0, seed=11,
                  errors=replace(base.errors.with_sources(parse_error_list("noise")), noise_sigma_m=1.0,
                                 noise_elevation_dependent=False))
    write_scenario(run_scenario(cfg), tmp_path)
    proc_cfg = load_config(overrides={"methods": "wls", "iono": "none", "tropo": "none"})
    proc_cfg = replace(proc_cfg, weights=replace(proc_cfg.weights, model="equal", a_m=1.0))
    result = process(tmp_path / "obs.rnx", [tmp_path / "nav.rnx"], proc_cfg)
    truth = pd.read_csv(tmp_path / "truth.csv")
    from gnss_cli.io.reference import reference_from_csv

    ref = reference_from_csv(tmp_path / "truth.csv", result.epochs.time_gps_s)
    table = positions_table(result, ref)
    assert len(truth) >= len(table) > 500
    for err, sd in (("e_err_m", "sde_m"), ("n_err_m", "sdn_m"), ("u_err_m", "sdu_m")):
        ratio = table[err].std() / np.sqrt((table[sd] ** 2).mean())
        assert 0.5 < ratio < 2.0, (err, ratio)


def test_nmea_checksum_is_the_xor_between_dollar_and_star() -> None:
    # the checksum of this classic GGA example sentence is 47
    assert nmea_checksum("GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,") == "47"


def test_smoothed_stls_rows_use_the_multi_epoch_covariance(rinex_dir) -> None:  # type: ignore[no-untyped-def]
    """With --lag the stls sd columns come from the window's multi-epoch covariance: more
    constraints than one epoch, so never larger than the WLS fix's."""
    folder = rinex_dir / "rtklib-0759"
    cfg = load_config(overrides={"methods": "wls,stls", "stls.lag": 3})
    result = process(folder / "07590920.05o", [folder / "07590920.05n"], cfg)
    table = positions_table(result)
    wls = table[table["method"] == "wls"].reset_index(drop=True)
    stls = table[table["method"] == "stls"].reset_index(drop=True)
    ok = stls["status"] == "ok"
    assert ok.sum() > 100
    for col in ("sde_m", "sdn_m", "sdu_m"):
        assert (stls.loc[ok, col] <= wls.loc[ok, col] * (1 + 1e-9)).all(), col
    cov = result.solutions["stls"].cov_m2[ok.to_numpy(), 2, 2]
    assert np.all(cov <= result.solutions["wls"].cov_m2[ok.to_numpy(), 2, 2] * (1 + 1e-9))


def test_southern_and_western_coordinates_and_failed_epochs() -> None:
    """A hand-made table: S/W hemispheres in NMEA, a failed epoch as GGA quality 0 / RMC V,
    omitted from pos, null geometry in GeoJSON."""
    lat, lon, h = np.array([-33.8568, -33.8569, np.nan]), np.array([-70.6483, -70.6482, np.nan]), np.array([520.1234, 520.5, np.nan])
    xyz = _ecef(lat, lon, h)
    table = pd.DataFrame({"time": ["2024-03-01T12:00:00.000", "2024-03-01T12:00:01.000", "2024-03-01T12:00:02.000"],
                          "gps_week": 2303, "tow_s": [475200.0, 475201.0, 475202.0], "method": "wls",
                          "x_m": xyz[:, 0], "y_m": xyz[:, 1], "z_m": xyz[:, 2], "lat_deg": lat, "lon_deg": lon, "height_m": h,
                          "n_sat": [8, 8, 3], "hdop": [0.9, 0.9, np.nan], "status": ["ok", "ok", "too_few_satellites"]})
    for c in ("sde_m", "sdn_m", "sdu_m"):
        table[c] = [1.0, 1.0, np.nan]
    for c in ("sden_m2", "sdnu_m2", "sdue_m2"):
        table[c] = [0.0, 0.0, np.nan]
    sentences = nmea_text(table).splitlines()
    assert len(sentences) == 6
    f = sentences[0].split(",")
    assert f[3] == "S" and f[5] == "W" and f[2].startswith("3351.") and f[4].startswith("07038.")
    assert abs(int(f[2][:2]) + float(f[2][2:]) / 60 - 33.8568) < 1e-9 and abs(int(f[4][:3]) + float(f[4][3:]) / 60 - 70.6483) < 1e-9
    assert sentences[4].split(",")[6] == "0" and sentences[5].split(",")[2] == "V"
    rows = [line for line in pos_text(table).splitlines() if not line.startswith("%")]
    # sd E = N = U = 1 m, no correlation: the ECEF covariance is I as well
    assert len(rows) == 2 and [abs(float(v)) for v in rows[0].split()[7:13]] == [1.0, 1.0, 1.0, 0.0, 0.0, 0.0]
    doc = json.loads(geojson_text(table))
    assert [f["geometry"] is None for f in doc["features"]] == [False, False, False, True]
