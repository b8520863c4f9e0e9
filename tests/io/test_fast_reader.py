"""The fast RINEX 3 readers give the same datasets as georinex on every shared file it reads.

georinex 1.16 is the independent reference. Its loads are slow (seconds to minutes), so
each is done once per module and filtered where the file is large (the 24 h ESBC file:
GPS C1C over the whole day, every system and code over the first 30 minutes).
"""

from __future__ import annotations

import warnings
from datetime import datetime
from pathlib import Path

import numpy as np
import pytest
import xarray

from gnss_cli.io.rinex3_nav import read_nav3
from gnss_cli.io.rinex3_obs import read_obs3

georinex = pytest.importorskip("georinex")

RINEX_DIR = Path(__file__).resolve().parents[2] / ".." / "shared" / "rinex"
P433_OBS = RINEX_DIR / "p433-2019" / "P43300USA_R_20190012056_17M_15S_MO.crx"
ESBC_OBS = RINEX_DIR / "esbc-2020177" / "ESBC00DNK_R_20201770000_01D_30S_MO.crx.gz"
ESBC_NAV = RINEX_DIR / "esbc-2020177" / "ESBC00DNK_R_20201770000_01D_MN.rnx.gz"


def _need(path: Path) -> Path:
    if not path.is_file():
        pytest.skip(f"shared RINEX data not found: {path} (expected ../shared/rinex next to the repo)")
    return path


def _georinex_load(path: Path, **kwargs: object) -> xarray.Dataset:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return georinex.load(path, **kwargs)


def _assert_same_obs(ours: xarray.Dataset, ref: xarray.Dataset) -> None:
    """Identical coordinates, variable names and values (NaN-aware, bit for bit)."""
    np.testing.assert_array_equal(ours.sv.values, ref.sv.values.astype("<U3"))
    np.testing.assert_array_equal(ours.time.values, ref.time.values.astype("datetime64[ns]"))
    assert set(ours.data_vars) == set(ref.data_vars)
    for code in ref.data_vars:
        a, b = ours[code].values, ref[code].values
        same = (a == b) | (np.isnan(a) & np.isnan(b))
        assert same.all(), f"{code}: {np.count_nonzero(~same)} values differ"


# ---------------------------------------------------------------- observation files


@pytest.fixture(scope="module")
def p433_pair() -> tuple[xarray.Dataset, xarray.Dataset]:
    path = _need(P433_OBS)
    return read_obs3(path), _georinex_load(path)


def test_p433_all_systems_all_codes_identical(p433_pair: tuple[xarray.Dataset, xarray.Dataset]) -> None:
    ours, ref = p433_pair
    assert ours.sizes["time"] == 70  # the README's epoch count
    _assert_same_obs(ours, ref)
    assert ours.attrs["version"] == ref.attrs["version"] == 3.03
    assert ours.attrs["interval"] == ref.attrs["interval"] == 15.0
    assert ours.attrs["time_system"] == ref.attrs["time_system"] == "GPS"
    assert ours.attrs["position"] == ref.attrs["position"]


def test_p433_filters_match_georinex_use_and_meas(p433_pair: tuple[xarray.Dataset, xarray.Dataset]) -> None:
    path = _need(P433_OBS)
    ref = _georinex_load(path, use={"E", "R"}, meas=["C1", "L5"])
    ours = read_obs3(path, systems=["E", "R"], codes=["C1", "L5"])
    _assert_same_obs(ours, ref)
    assert set(ours.data_vars) == {"C1C", "L5Q"}
    assert {s[0] for s in ours.sv.values} == {"E", "R"}


@pytest.fixture(scope="module")
def esbc_gps_c1c() -> xarray.Dataset:
    return _georinex_load(_need(ESBC_OBS), use={"G"}, meas=["C1C"])


@pytest.fixture(scope="module")
def esbc_fast_all() -> xarray.Dataset:
    return read_obs3(_need(ESBC_OBS))


def test_esbc_whole_day_gps_c1c_identical(esbc_gps_c1c: xarray.Dataset) -> None:
    ours = read_obs3(ESBC_OBS, systems=["G"], codes=["C1C"])
    assert ours.sizes["time"] == 2880
    _assert_same_obs(ours, esbc_gps_c1c)


def test_esbc_every_system_and_code_first_half_hour(esbc_fast_all: xarray.Dataset) -> None:
    window = (datetime(2020, 6, 25, 0, 0), datetime(2020, 6, 25, 0, 30))
    ref = _georinex_load(ESBC_OBS, tlim=window)
    ours = esbc_fast_all.sel(time=slice(np.datetime64(window[0]), np.datetime64(window[1])))
    assert set(ours.sv.values) >= set(ref.sv.values)
    absent = sorted(set(ours.sv.values) - set(ref.sv.values))
    for code in ours.data_vars:  # satellites seen later in the day: no data in the window
        assert np.isnan(ours[code].sel(sv=absent).values).all()
    _assert_same_obs(ours.sel(sv=ref.sv.values.astype("<U3")), ref)
    assert {s[0] for s in ref.sv.values} == {"C", "E", "G", "R", "S"}  # no QZSS in view yet


def test_esbc_pseudorange_only_is_the_c_codes_of_the_full_read(esbc_fast_all: xarray.Dataset) -> None:
    pr = read_obs3(ESBC_OBS, pseudorange_only=True)
    assert set(pr.data_vars) == {c for c in esbc_fast_all.data_vars if str(c).startswith("C")}
    _assert_same_obs(pr, esbc_fast_all[list(pr.data_vars)])


def test_esbc_hand_checked_first_epoch(esbc_fast_all: xarray.Dataset) -> None:
    # values copied from the decompressed file text, epoch 2020 06 25 00 00 00
    first = esbc_fast_all.isel(time=0)
    assert first.time.values == np.datetime64("2020-06-25T00:00:00", "ns")
    assert first["C2I"].sel(sv="C05").item() == 40715949.461
    assert np.isnan(first["C6I"].sel(sv="C05").item())  # blank field
    assert first["C7I"].sel(sv="C05").item() == 40715946.882
    assert first["D2I"].sel(sv="C07").item() == -484.694
    assert first["C1C"].sel(sv="G05").item() == 20947300.931
    assert first["S2W"].sel(sv="G05").item() == 55.0
    assert first["C1C"].sel(sv="E01").item() == 27616185.992
    assert first["C1C"].sel(sv="G02").item() == 25847357.745
    assert np.isnan(first["L1C"].sel(sv="G02").item())  # G02 has C1C, D1C and S1C only
    assert first.attrs["obs_types"]["G"][:5] == ["C1C", "C1W", "C2L", "C2W", "C5Q"]
    assert first.attrs["position"] == [3582105.2910, 532589.7313, 5232754.8054]
    assert first.attrs["marker_name"] == "ESBC00DNK"
    assert first.attrs["rxmodel"] == "SEPT POLARX5"
    assert first.attrs["interval"] == 30.0


# ---------------------------------------------------------------- navigation files


@pytest.fixture(scope="module")
def esbc_nav_pair() -> tuple[xarray.Dataset, xarray.Dataset]:
    path = _need(ESBC_NAV)
    return read_nav3(path), _georinex_load(path)


def test_esbc_nav_same_layout_as_georinex(esbc_nav_pair: tuple[xarray.Dataset, xarray.Dataset]) -> None:
    ours, ref = esbc_nav_pair
    np.testing.assert_array_equal(ours.sv.values, ref.sv.values)  # includes 'E01_1' (F/NAV + I/NAV)
    np.testing.assert_array_equal(ours.time.values, ref.time.values)
    assert set(ours.data_vars) == set(ref.data_vars)
    assert ours.attrs["svtype"] == ref.attrs["svtype"]
    np.testing.assert_array_equal(ours.attrs["ionospheric_corr_GPS"], ref.attrs["ionospheric_corr_GPS"])
    np.testing.assert_array_equal(ours.attrs["ionospheric_corr_GAL"], ref.attrs["ionospheric_corr_GAL"])


def test_esbc_nav_values_identical_where_georinex_decodes(
    esbc_nav_pair: tuple[xarray.Dataset, xarray.Dataset],
) -> None:
    ours, ref = esbc_nav_pair
    n_checked = 0
    for name in ref.data_vars:
        a, b = ours[name].values, ref[name].values
        finite = np.isfinite(b)
        np.testing.assert_array_equal(a[finite], b[finite], err_msg=str(name))
        n_checked += int(finite.sum())
    assert n_checked > 40_000  # GPS, GLONASS, QZSS and SBAS records: 47,488 values


def test_esbc_nav_records_georinex_drops_are_only_blank_spare_records(
    esbc_nav_pair: tuple[xarray.Dataset, xarray.Dataset],
) -> None:
    """georinex turns a whole record into NaN when one field is blank (Galileo / BeiDou
    spare fields here); the fast reader keeps the other fields. Check which records those
    are and their values against the file text."""
    ours, ref = esbc_nav_pair
    ref_has = np.isfinite(ref["SVclockBias"].values)
    ours_has = np.isfinite(ours["SVclockBias"].values)
    assert not (ref_has & ~ours_has).any()
    extra_sv = {str(ours.sv.values[j])[0] for j in np.nonzero(ours_has & ~ref_has)[1]}
    assert extra_sv == {"C", "E"}
    assert int((ours_has & ~ref_has).sum()) == 357 + 1602  # every C and E record of the file
    # E01 at 2020-06-24 23:30:00, first record in the file (lines 3064-3071)
    e01 = ours.sel(sv="E01", time=np.datetime64("2020-06-24T23:30:00"))
    assert e01["SVclockBias"].item() == -8.846927667037e-04
    assert e01["IODnav"].item() == 61.0
    assert e01["sqrtA"].item() == 5.440602037430e03
    assert e01["DataSrc"].item() == 258.0
    assert e01["GALWeek"].item() == 2111.0
    assert np.isnan(e01["spare0"].item())
    assert e01["TransTime"].item() == 3.445400000000e05
    # C05 at 2020-06-24 22:00:00 (lines 208-215)
    c05 = ours.sel(sv="C05", time=np.datetime64("2020-06-24T22:00:00"))
    assert c05["SVclockBias"].item() == -5.154609680176e-04
    assert c05["AODE"].item() == 1.0
    assert c05["BDTWeek"].item() == 755.0
    assert c05["TGD1"].item() == 1.0e-10
    assert c05["TGD2"].item() == -9.3e-09
    assert c05["AODC"].item() == 0.0
