"""Malformed input gives a typed error naming the file and the problem; every packaging
opens to the same text."""

from __future__ import annotations

import bz2
import gzip
import zipfile
from pathlib import Path

import numpy as np
import pytest

from gnss_cli.errors import InputFileNotFoundError, RinexFormatError, UsageError
from gnss_cli.io.compression import open_bytes, open_text
from gnss_cli.io.rinex3_nav import read_nav3
from gnss_cli.io.fixed_width import parse_f14_3, parse_uint_columns
from gnss_cli.io.rinex3_obs import read_obs3

RINEX_DIR = Path(__file__).resolve().parents[2] / ".." / "shared" / "rinex"
MALFORMED = RINEX_DIR / "malformed"
P433_OBS = RINEX_DIR / "p433-2019" / "P43300USA_R_20190012056_17M_15S_MO.crx"
KMS3_NAV = RINEX_DIR / "kms3-2022159-rinex4" / "KMS300DNK_R_20221591000_01H_MN.rnx.gz"

OBS3_HEADER = (
    "     3.04           OBSERVATION DATA    M                   RINEX VERSION / TYPE\n"
    "G    2 C1C L1C                                              SYS / # / OBS TYPES\n"
    "E    1 C1C                                                  SYS / # / OBS TYPES\n"
    "                                                            END OF HEADER\n"
)
GOOD_EPOCH = (
    "> 2020 06 25 00 00 30.0000000  0  2\n"
    "G05  20947300.931 8 110078836.38908\n"
    "E01  27616185.992 6\n"
)


def _need(path: Path) -> Path:
    if not path.exists():
        pytest.skip(f"shared RINEX data not found: {path} (expected ../shared/rinex next to the repo)")
    return path


def _write(tmp_path: Path, name: str, text: str) -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


# ---------------------------------------------------------------- shared malformed files


@pytest.mark.parametrize(
    ("name", "message"),
    [
        ("blank3.10o", "blank3.10o: no observation records"),
        ("junk_time_obs3.10o", "junk_time_obs3.10o: bad epoch line 10: '> 23 29'"),
        ("blank.10o", "blank.10o: RINEX version 2.11 is not read by the RINEX 3/4 reader"),
        ("blank.10n", "blank.10n: not a RINEX observation file (RINEX TYPE 'N')"),
        ("badtime.10o", "badtime.10o: RINEX version 2.11"),
        ("wrong_obs2_count.10o", "wrong_obs2_count.10o: RINEX version 2.11"),
    ],
)
def test_shared_malformed_obs_files(name: str, message: str) -> None:
    with pytest.raises(RinexFormatError) as info:
        read_obs3(_need(MALFORMED / name))
    assert message in str(info.value)
    assert info.value.exit_code == 4


@pytest.mark.parametrize("name", ["blank.10n", "blank3.10o", "junk_time_obs3.10o"])
def test_shared_malformed_nav_files(name: str) -> None:
    with pytest.raises(RinexFormatError, match=name):
        read_nav3(_need(MALFORMED / name))


def test_missing_file() -> None:
    with pytest.raises(InputFileNotFoundError, match="no_such.rnx: file not found"):
        read_obs3("no_such.rnx")
    with pytest.raises(InputFileNotFoundError, match="no_such.rnx"):
        read_nav3(["no_such.rnx"])
    with pytest.raises(FileNotFoundError):  # also the builtin
        open_text("no_such.rnx")


# ---------------------------------------------------------------- hand-made broken files


def test_good_tiny_file_reads(tmp_path: Path) -> None:
    obs = read_obs3(_write(tmp_path, "ok.rnx", OBS3_HEADER + GOOD_EPOCH))
    assert list(obs.sv.values) == ["E01", "G05"]
    assert obs["C1C"].values.tolist() == [[27616185.992, 20947300.931]]
    assert obs["L1C"].sel(sv="G05").item() == 110078836.389
    assert np.isnan(obs["L1C"].sel(sv="E01").item())


def test_event_epochs_are_skipped(tmp_path: Path) -> None:
    body = (
        GOOD_EPOCH
        + ">                              4  2\n"
        + "SITE MOVED                                                  COMMENT\n"
        + "G05  NOT AN OBSERVATION                                     COMMENT\n"
        + "> 2020 06 25 00 01 00.0000000  1  1\n"  # flag 1 (power failure): data follow
        + "G05  20947330.000 8\n"
    )
    obs = read_obs3(_write(tmp_path, "events.rnx", OBS3_HEADER + body))
    np.testing.assert_array_equal(
        obs.time.values, np.array(["2020-06-25T00:00:30", "2020-06-25T00:01:00"], dtype="datetime64[ns]")
    )
    assert obs["C1C"].sel(sv="G05").values.tolist() == [20947300.931, 20947330.0]
    assert obs.attrs["interval"] == 30.0  # no INTERVAL record: median spacing


@pytest.mark.parametrize(
    ("body", "message"),
    [
        ("> 2020 06 25 00 00 30.0000000  0  3\nG05  20947300.931 8\nE01  27616185.992 6\n",
         "bad epoch line 5: it announces 3 records but 2 lines follow"),
        ("> 2020 13 25 00 00 30.0000000  0  1\nG05  20947300.931 8\n", "bad epoch line 5"),
        ("> 2020 06 25 00 00 3x.0000000  0  1\nG05  20947300.931 8\n", "bad epoch line 5"),
        ("> 2020 06 25 00 00 30.0000000  0  1\nX05  20947300.931 8\n", "bad satellite id 'X05' on line 6"),
        ("> 2020 06 25 00 00 30.0000000  0  1\nG05  2094730x.931 8\n", "bad C1C value '  2094730x.931' on line 6"),
        ("garbage\n" + GOOD_EPOCH, "unexpected text on line 5 before the first epoch line"),
        ("> 2020 06 25 00 00 30.0000000  0  2\nG05  20947300.931 8\nE01  27616185.992 6  27616185.992 6\n",
         "line 7: more observations than the 1 of the header's 'SYS / # / OBS TYPES' for system E"),
    ],
)  # fmt: skip
def test_bad_obs_bodies(tmp_path: Path, body: str, message: str) -> None:
    with pytest.raises(RinexFormatError) as info:
        read_obs3(_write(tmp_path, "bad.rnx", OBS3_HEADER + body))
    assert str(info.value).startswith("bad.rnx: ")
    assert message in str(info.value)


def test_bad_headers(tmp_path: Path) -> None:
    with pytest.raises(RinexFormatError, match="empty.rnx: empty file"):
        read_obs3(_write(tmp_path, "empty.rnx", "\n\n"))
    with pytest.raises(RinexFormatError, match="no 'END OF HEADER'"):
        read_obs3(_write(tmp_path, "cut.rnx", OBS3_HEADER.splitlines(keepends=True)[0]))
    with pytest.raises(RinexFormatError, match="not a RINEX file"):
        read_obs3(_write(tmp_path, "text.rnx", "hello\n" + OBS3_HEADER))
    wrong_count = OBS3_HEADER.replace("G    2 C1C L1C", "G    3 C1C L1C")
    with pytest.raises(RinexFormatError, match="system G announces 3 observation types but lists 2"):
        read_obs3(_write(tmp_path, "count.rnx", wrong_count + GOOD_EPOCH))
    with pytest.raises(RinexFormatError, match=r"none of the systems \['C'\]"):
        read_obs3(_write(tmp_path, "sys.rnx", OBS3_HEADER + GOOD_EPOCH), systems=["C"])


def test_bad_nav_number(tmp_path: Path) -> None:
    text = open_text(_need(KMS3_NAV))
    broken = text.replace("2.041313482914E-02", "2.04131348291xE-02", 1)
    path = tmp_path / "broken_nav.rnx"
    path.write_text(broken)
    with pytest.raises(RinexFormatError, match=r"broken_nav.rnx: bad number '2.04131348291xE-02' on line 8"):
        read_nav3(path)


def test_bad_arguments() -> None:
    with pytest.raises(UsageError, match="systems"):
        read_obs3("x.rnx", systems=["GPS"])
    with pytest.raises(UsageError, match="codes"):
        read_obs3("x.rnx", codes=["C1C!"])
    with pytest.raises(UsageError, match="path_or_paths"):
        read_nav3([])
    with pytest.raises(UsageError, match="systems"):
        read_nav3("x.rnx", systems=["Q"])


def test_corrupt_compression(tmp_path: Path) -> None:
    good = gzip.compress((OBS3_HEADER + GOOD_EPOCH).encode())
    path = tmp_path / "cut.rnx.gz"
    path.write_bytes(good[: len(good) // 2])
    with pytest.raises(RinexFormatError, match="cut.rnx.gz: corrupt or truncated compressed file"):
        read_obs3(path)
    crx = tmp_path / "bad.crx"
    crx.write_text(
        "1.0                 COMPACT RINEX FORMAT                    CRINEX VERS   / TYPE\n"
        "garbage\n"
    )
    with pytest.raises(RinexFormatError, match="bad.crx: corrupt Compact RINEX"):
        open_text(crx)


# ---------------------------------------------------------------- packagings


def test_every_packaging_gives_the_same_text(tmp_path: Path) -> None:
    import hatanaka

    crx_bytes = _need(P433_OBS).read_bytes()
    plain = hatanaka.crx2rnx(crx_bytes)  # the reference decompression
    assert open_bytes(P433_OBS) == plain
    assert plain.startswith(b"     3.03")
    packed = {
        "a.rnx": plain,
        "a.rnx.gz": gzip.compress(plain),
        "a.rnx.bz2": bz2.compress(plain),
        "a.crx.gz": gzip.compress(crx_bytes),
        "misnamed.txt": gzip.compress(plain),  # content decides, not the name
    }
    for name, data in packed.items():
        (tmp_path / name).write_bytes(data)
        assert open_bytes(tmp_path / name) == plain, name
    with zipfile.ZipFile(tmp_path / "a.zip", "w") as archive:
        archive.writestr("P433.crx", crx_bytes)
    assert open_bytes(tmp_path / "a.zip") == plain
    ncompress = pytest.importorskip("ncompress")
    (tmp_path / "a.crx.Z").write_bytes(ncompress.compress(crx_bytes))
    assert open_bytes(tmp_path / "a.crx.Z") == plain
    assert open_text(tmp_path / "a.crx.Z") == plain.decode("ascii")


# ---------------------------------------------------------------- field decoders


def test_f14_3_decoder_equals_python_float() -> None:
    rng = np.random.default_rng(7)
    ints = rng.integers(-999_999_999_999, 9_999_999_999_999, size=2000)
    fields = [f"{v / 1000:14.3f}".encode() for v in ints] + [b" " * 14, b"      1.5E+00 "]
    chars = np.frombuffer(b"".join(fields), dtype=np.uint8).reshape(-1, 14)
    values, odd = parse_f14_3(chars)
    expected = np.array([float(f) for f in fields[:-2]])
    np.testing.assert_array_equal(values[:-2], expected)  # bit for bit
    assert not odd[:-2].any()
    assert np.isnan(values[-2]) and not odd[-2]  # blank: missing
    assert odd[-1]  # not F14.3: left to the general decoder


def test_uint_decoder() -> None:
    chars = np.frombuffer(b" 43  22  7 7 x 1  0 0   ", dtype=np.uint8).reshape(-1, 3)
    values, ok = parse_uint_columns(chars)
    assert ok.tolist() == [True, True, True, False, False, True, False, False]
    assert values[ok].tolist() == [43, 2, 2, 1]


# ---------------------------------------------------------------- whole-file checks of the epochs


def _epoch3(sec: str, flag: int = 0) -> str:
    return f"> 2020 06 25 00 00 {sec}  {flag}  1\nG05  20947300.931 8\n"


@pytest.mark.parametrize(
    ("body", "message"),
    [
        (_epoch3("30.0000000") + _epoch3("30.0000000"),
         "line 7: epoch 2020-06-25T00:00:30 is not later than the epoch 2020-06-25T00:00:30 on line 5"),
        (_epoch3("30.0000000") + _epoch3("59.0000000") + _epoch3("30.0000000"),
         "line 9: epoch 2020-06-25T00:00:30 is not later than the epoch 2020-06-25T00:00:59 on line 7"),
        ((_epoch3("30.0000000") + _epoch3("45.5000000")) * 3,
         "line 9: epoch 2020-06-25T00:00:30 is not later than the epoch 2020-06-25T00:00:45.5 on line 7"),
    ],
    ids=["duplicate", "restamped", "body-three-times"],
)
def test_an_epoch_not_later_than_the_one_before_is_rejected(tmp_path: Path, body: str, message: str) -> None:
    with pytest.raises(RinexFormatError) as info:
        read_obs3(_write(tmp_path, "rep.rnx", OBS3_HEADER + body))
    assert str(info.value) == f"rep.rnx: {message} (repeated or out-of-order epoch)"


def test_event_records_may_repeat_a_time(tmp_path: Path) -> None:
    body = _epoch3("30.0000000") + _epoch3("30.0000000", flag=6) + _epoch3("59.0000000")
    obs = read_obs3(_write(tmp_path, "slips.rnx", OBS3_HEADER + body))
    assert obs.sizes["time"] == 2


def test_a_file_cut_inside_its_last_value_is_rejected(tmp_path: Path) -> None:
    text = OBS3_HEADER + GOOD_EPOCH
    cut = text.rindex("27616185.992") + len("2761618")
    with pytest.raises(RinexFormatError, match=r"cut\.rnx: line 7: the file ends inside observation 1 of the line"):
        read_obs3(_write(tmp_path, "cut.rnx", text[:cut]))
    with gzip.open(tmp_path / "cut.rnx.gz", "wt") as f:
        f.write(text[:cut])
    with pytest.raises(RinexFormatError, match=r"cut\.rnx\.gz: line 7: the file ends inside observation 1"):
        read_obs3(tmp_path / "cut.rnx.gz")
    for end in (text.rstrip("\n"), text.rstrip("\n")[:-2]):  # no line end, after the strength digit or the value
        whole = read_obs3(_write(tmp_path, "whole.rnx", end))
        assert whole["C1C"].sel(sv="E01").item() == 27616185.992


def test_compact_rinex_that_crx2rnx_only_warns_about_is_rejected(tmp_path: Path) -> None:
    lines = _need(RINEX_DIR / "kms3-2022159-rinex4" / "KMS300DNK_R_20221591000_01H_30S_MO.crx").read_bytes().split(b"\n")
    crx = tmp_path / "dup.crx"
    crx.write_bytes(b"\n".join(lines[:1089] + lines[1088:]))  # one differential line twice
    with pytest.raises(RinexFormatError, match=r"^dup\.crx: corrupt Compact RINEX \(Hatanaka\) file \(crx2rnx: "):
        open_bytes(crx)


def test_blanks_after_the_last_field_are_not_extra_observations(tmp_path: Path) -> None:
    body = GOOD_EPOCH.replace("E01  27616185.992 6\n", "E01  27616185.992 6" + " " * 40 + "\n")
    obs = read_obs3(_write(tmp_path, "padded.rnx", OBS3_HEADER + body))
    assert obs["C1C"].sel(sv="E01").item() == 27616185.992
