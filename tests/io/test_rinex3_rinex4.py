"""RINEX 4.00 files (which georinex rejects): values checked by hand against the file text,
plus structural invariants, and the merging of several navigation files."""

from __future__ import annotations

import gzip
from pathlib import Path

import numpy as np
import pytest
import xarray

from gnss_cli.io.compression import open_text
from gnss_cli.io.rinex3_nav import FIELD_NAMES, read_nav3
from gnss_cli.io.rinex3_obs import read_obs3

RINEX_DIR = Path(__file__).resolve().parents[2] / ".." / "shared" / "rinex"
KMS3_OBS = RINEX_DIR / "kms3-2022159-rinex4" / "KMS300DNK_R_20221591000_01H_30S_MO.crx"
KMS3_NAV = RINEX_DIR / "kms3-2022159-rinex4" / "KMS300DNK_R_20221591000_01H_MN.rnx.gz"
ESBC_NAV = RINEX_DIR / "esbc-2020177" / "ESBC00DNK_R_20201770000_01D_MN.rnx.gz"


def _need(path: Path) -> Path:
    if not path.is_file():
        pytest.skip(f"shared RINEX data not found: {path} (expected ../shared/rinex next to the repo)")
    return path


@pytest.fixture(scope="module")
def kms3_obs() -> xarray.Dataset:
    return read_obs3(_need(KMS3_OBS))


@pytest.fixture(scope="module")
def kms3_nav() -> xarray.Dataset:
    return read_nav3(_need(KMS3_NAV))


# ---------------------------------------------------------------- RINEX 4 observations


def test_kms3_obs_structure(kms3_obs: xarray.Dataset) -> None:
    obs = kms3_obs
    assert obs.attrs["version"] == 4.0
    assert obs.sizes["time"] == 19  # the README's epoch count (the header says 120)
    step_s = np.diff(obs.time.values) / np.timedelta64(1, "s")
    assert (step_s == 30.0).all()
    assert obs.time.values[0] == np.datetime64("2022-06-08T10:00:00", "ns")
    assert obs.time.dtype == np.dtype("datetime64[ns]")
    assert obs.sv.dtype == np.dtype("<U3")
    assert list(obs.sv.values) == sorted(obs.sv.values)
    assert {s[0] for s in obs.sv.values} == {"C", "E", "G", "J", "R", "S"}
    counts = {"C": 12, "E": 10, "G": 11, "J": 8, "R": 10, "S": 4}  # SYS / # / OBS TYPES
    assert {k: len(v) for k, v in obs.attrs["obs_types"].items()} == counts
    all_codes = {c for v in obs.attrs["obs_types"].values() for c in v}
    assert set(obs.data_vars) == all_codes
    # every pseudorange is a plausible range to a GNSS satellite (m); SBAS S48 is not:
    # the file itself holds 8948470.655 m for it ('S48   8948470.655 5 ...')
    not_sbas = [s for s in obs.sv.values if not s.startswith("S")]
    for code in (c for c in obs.data_vars if str(c).startswith("C")):
        values = obs[code].sel(sv=not_sbas).values
        values = values[np.isfinite(values)]
        assert ((values > 1.8e7) & (values < 4.6e7)).all(), code
    assert obs["C1C"].sel(sv="S48").values[0] == 8948470.655
    assert obs.attrs["position"] == [3516213.438, 781859.8595, 5246037.966]


def test_kms3_obs_hand_checked_first_epoch(kms3_obs: xarray.Dataset) -> None:
    # from the decompressed text, epoch '> 2022 06 08 10 00 00.0000000  0 49'
    first = kms3_obs.isel(time=0)
    assert first["C1C"].sel(sv="E01").item() == 28062283.645
    assert first["C5Q"].sel(sv="E01").item() == 28062288.828
    assert np.isnan(first["L6C"].sel(sv="E01").item())  # blank field
    assert first["L7Q"].sel(sv="E01").item() == 112995133.283
    assert first["L8Q"].sel(sv="E01").item() == 111558748.927
    assert first["C2I"].sel(sv="C05").item() == 39975899.571
    assert np.isnan(first["C1P"].sel(sv="C05").item())
    assert first["C1C"].sel(sv="G09").item() == 25865519.844
    assert first["C2L"].sel(sv="G09").item() == 25865524.740
    assert np.isnan(first["C2W"].sel(sv="G09").item())
    assert np.isnan(first["L1C"].sel(sv="G09").item())
    assert first["C1C"].sel(sv="R04").item() == 22684733.618
    assert first["L2P"].sel(sv="R04").item() == 94481189.042
    assert first["C1C"].sel(sv="S26").item() == 40096735.255
    assert first["L1C"].sel(sv="J04").item() == 233392158.143
    # 49 satellites announced in the epoch line, 49 with at least one value
    n_with_data = sum(np.isfinite(first[c].values) for c in first.data_vars)
    assert int(np.count_nonzero(n_with_data)) == 49


def test_kms3_obs_filters(kms3_obs: xarray.Dataset) -> None:
    sub = read_obs3(KMS3_OBS, systems=["G", "E"], codes=["C1"])
    assert set(sub.data_vars) == {"C1C", "C1L", "C1W"}
    assert {s[0] for s in sub.sv.values} == {"G", "E"}
    ref = kms3_obs[list(sub.data_vars)].sel(sv=sub.sv.values)
    for code in sub.data_vars:
        np.testing.assert_array_equal(sub[code].values, ref[code].values)
    pr = read_obs3(KMS3_OBS, pseudorange_only=True)
    assert set(pr.data_vars) == {c for c in kms3_obs.data_vars if str(c).startswith("C")}


# ---------------------------------------------------------------- RINEX 4 navigation


def test_kms3_nav_gps_lnav_record_by_hand(kms3_nav: xarray.Dataset) -> None:
    # '> EPH G02 LNAV' / 'G02 2022 06 08 10 00 00-6.528543308377E-04 ...'
    g02 = kms3_nav.sel(sv="G02", time=np.datetime64("2022-06-08T10:00:00"))
    expected = {
        "SVclockBias": -6.528543308377e-04, "SVclockDrift": 3.410605131648e-13, "IODE": 96.0,
        "Crs": 3.384375e01, "DeltaN": 4.106242470052e-09, "M0": -2.157708626665,
        "Eccentricity": 2.041313482914e-02, "sqrtA": 5.153679471970e03, "Toe": 2.952e05,
        "Omega0": 2.277502707678, "Io": 9.659928182326e-01, "omega": -1.414485730254,
        "OmegaDot": -7.679605600684e-09, "IDOT": 5.857386840816e-11, "GPSWeek": 2213.0,
        "SVacc": 2.8, "health": 0.0, "TGD": -1.769512891769e-08, "IODC": 96.0,
        "TransTime": 2.88018e05, "FitIntvl": 4.0,
    }  # fmt: skip
    for name, value in expected.items():
        assert g02[name].item() == value, name
    assert np.isnan(g02["spare0"].item())


def test_kms3_nav_glonass_fdma_in_metres(kms3_nav: xarray.Dataset) -> None:
    # '> EPH R03 FDMA' / 'R03 2022 06 08 09 45 00 ...'; positions in the file in km
    r03 = kms3_nav.sel(sv="R03", time=np.datetime64("2022-06-08T09:45:00"))
    assert r03["SVclockBias"].item() == 5.807634443045e-05
    assert r03["MessageFrameTime"].item() == 2.934e05
    assert r03["X"].item() == -1.158823828125e04 * 1000.0
    assert r03["dX"].item() == -5.671300888062e-01 * 1000.0
    assert r03["Y"].item() == -1.108993261719e04 * 1000.0
    assert r03["FreqNum"].item() == 5.0
    assert r03["Z"].item() == 1.986426855469e04 * 1000.0
    assert r03["dZ2"].item() == -2.793967723846e-09 * 1000.0


def test_kms3_nav_beidou_blank_spare_is_nan_alone(kms3_nav: xarray.Dataset) -> None:
    # '> EPH C08 D1', 6th line: IDOT, blank spare, BDT week 857
    c08 = kms3_nav.sel(sv="C08", time=np.datetime64("2022-06-08T09:00:00"))
    assert c08["IDOT"].item() == 6.482412875659e-10
    assert np.isnan(c08["spare0"].item())
    assert c08["BDTWeek"].item() == 857.0
    assert c08["TGD1"].item() == 1.07e-08
    assert c08["TGD2"].item() == -6.0e-10


def test_kms3_nav_record_inventory(kms3_nav: xarray.Dataset) -> None:
    text = open_text(KMS3_NAV)
    eph = [ln.split() for ln in text.splitlines() if ln.startswith("> EPH")]
    readable = [(sv, typ) for _, _, sv, typ in eph if typ in {"LNAV", "INAV", "FNAV", "D1", "D2", "FDMA", "SBAS"}]
    assert len(readable) == len(eph)  # this file holds only types the reader handles
    n_records = int(np.isfinite(kms3_nav["SVclockBias"].values).sum())
    assert n_records == len(readable) == 31 + 55 + 53 + 33 + 3 + 24 + 158
    assert kms3_nav.attrs["svtype"] == ["G", "R", "E", "S", "C", "J"]
    assert set(kms3_nav.data_vars) == set().union(*(FIELD_NAMES[s] for s in "GRESCJ"))
    # Galileo I/NAV and F/NAV at one toc: the second record in file order goes to E.._1
    suffixed = [s for s in kms3_nav.sv.values if "_" in s]
    assert suffixed and all(s.startswith("E") and s.endswith("_1") for s in suffixed)


def test_kms3_nav_ion_records_to_attributes(kms3_nav: xarray.Dataset) -> None:
    # '> ION G29 LNAV', '> ION E01 IFNV', '> ION C08 D1D2'
    np.testing.assert_array_equal(
        kms3_nav.attrs["ionospheric_corr_GPS"],
        [1.024454832077e-08, 2.235174179077e-08, -5.960464477539e-08, -1.192092895508e-07,
         9.6256e04, 1.31072e05, -6.5536e04, -5.89824e05],
    )  # fmt: skip
    np.testing.assert_array_equal(kms3_nav.attrs["ionospheric_corr_GAL"], [78.5, 5.390625e-01, 2.713012695312e-02])
    assert kms3_nav.attrs["ionospheric_corr_BDS"][0] == 2.142041921616e-08
    assert kms3_nav.attrs["ionospheric_corr_BDS"][7] == -6.5536e04


# ---------------------------------------------------------------- several navigation files


def test_same_file_twice_keeps_each_record_once(kms3_nav: xarray.Dataset) -> None:
    twice = read_nav3([KMS3_NAV, KMS3_NAV])
    xarray.testing.assert_identical(twice.drop_attrs(), kms3_nav.drop_attrs())


def test_per_system_files_merge_to_the_mixed_file(kms3_nav: xarray.Dataset, tmp_path: Path) -> None:
    """Split the mixed file into one file per system (as archives ship them) and merge."""
    lines = open_text(KMS3_NAV).splitlines(keepends=True)
    end = next(i for i, ln in enumerate(lines) if "END OF HEADER" in ln) + 1
    header, body = lines[:end], lines[end:]
    per_system: dict[str, list[str]] = {}
    current = ""
    for ln in body:
        if ln.startswith(">"):
            current = ln[6]
        per_system.setdefault(current, []).append(ln)
    paths = []
    for sys_char, sys_lines in sorted(per_system.items()):
        path = tmp_path / f"nav_{sys_char}.rnx.gz"
        path.write_bytes(gzip.compress("".join(header + sys_lines).encode("ascii")))
        paths.append(path)
    assert len(paths) == 6
    merged = read_nav3(paths)
    xarray.testing.assert_identical(merged.drop_attrs(), kms3_nav.drop_attrs())
    assert merged.attrs["filename"].count("nav_") == 6


def test_rinex3_and_rinex4_files_merge(kms3_nav: xarray.Dataset) -> None:
    esbc = read_nav3(_need(ESBC_NAV), systems=["G"])
    both = read_nav3([ESBC_NAV, KMS3_NAV], systems=["G"])
    gps_kms3 = kms3_nav.sel(sv=[s for s in kms3_nav.sv.values if s.startswith("G")])
    assert set(both.sv.values) == set(esbc.sv.values) | set(gps_kms3.sv.values)
    assert both.sizes["time"] == len(set(esbc.time.values) | set(gps_kms3.dropna("time", how="all").time.values))
    g02 = both["sqrtA"].sel(sv="G02")
    assert g02.sel(time=np.datetime64("2022-06-08T10:00:00")).item() == 5.153679471970e03
    np.testing.assert_array_equal(
        g02.sel(time=esbc.time.values).values, esbc["sqrtA"].sel(sv="G02").values
    )
    # attributes come from the first file that has them
    np.testing.assert_array_equal(both.attrs["ionospheric_corr_GPS"], esbc.attrs["ionospheric_corr_GPS"])
    assert set(both.attrs["svtype"]) == {"G"}
