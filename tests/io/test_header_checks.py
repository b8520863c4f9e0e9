"""Headers checked as RINEX defines them: a code that is not a RINEX code is refused with its
line, a system asked for (or present) that gives no pseudorange gets one warning naming the
system and why, every header error names its line, and messages carry no Python class names."""

from __future__ import annotations

import gzip
from pathlib import Path

import pytest

from gnss_cli.config import load_config
from gnss_cli.errors import RinexFormatError
from gnss_cli.io.compression import fault_text
from gnss_cli.io.rinex import read_obs, rinex_info
from gnss_cli.io.rinex2_obs import read_obs2
from gnss_cli.io.rinex3_obs import read_obs3
from gnss_cli.pipeline.epochs import load_epochs
from gnss_cli.pipeline.run import process

REPO = Path(__file__).resolve().parents[2]
SAMPLE = REPO / "sample_rinex" / "static"
OBS3 = (
    "     3.04           OBSERVATION DATA    M                   RINEX VERSION / TYPE\n"
    "G    2 C1C L1C                                              SYS / # / OBS TYPES\n"
    "E    1 C1C                                                  SYS / # / OBS TYPES\n"
    "                                                            END OF HEADER\n"
    "> 2020 06 25 00 00 30.0000000  0  2\n"
    "G05  20947300.931 8 110078836.38908\n"
    "E01  27616185.992 6\n"
)
OBS2_TYPES = "     2    C1    L1                                          # / TYPES OF OBSERV\n"
OBS2 = (
    "     2.11           OBSERVATION DATA    G (GPS)             RINEX VERSION / TYPE\n"
    + OBS2_TYPES
    + "                                                            END OF HEADER\n"
    " 20  6 25  0  0 30.0000000  0  1G05\n"
    "  20947300.931 8 110078836.389 8\n"
)


def _write(tmp_path: Path, name: str, text: str) -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def _sample_with(tmp_path: Path, name: str, edit) -> Path:  # noqa: ANN001 - str -> str
    """The repository's simulated sample observation file with its header edited."""
    text = (SAMPLE / "obs.rnx").read_text()
    head, sep, body = text.partition("END OF HEADER")
    return _write(tmp_path, name, edit(head) + sep + body)


@pytest.mark.parametrize("code", ["c1c", "ZZZ", "C1", "1CC", "CXC"])
def test_a_code_that_is_not_a_rinex3_code_is_refused_with_its_line(tmp_path: Path, code: str) -> None:
    bad = OBS3.replace("G    2 C1C L1C    ", f"G    2 {code:3s} L1C    ")
    with pytest.raises(RinexFormatError) as info:
        read_obs3(_write(tmp_path, "bad.rnx", bad))
    assert str(info.value).startswith(f"bad.rnx: header line 2: {code!r} is not a RINEX observation code")


def test_the_codes_of_the_format_tables_are_accepted(tmp_path: Path) -> None:
    """The grammar admits what real receivers write: codes of the format's tables for several
    systems and bands (C/L/D/S, band digit, attribute letter; X channel numbers), over a
    continuation line."""
    codes = "C1C L1C D1C S1C C2W L2W C5Q L5Q C7I L7I C6Z C2I C1X C8Q L8Q X1".split()
    lines = [f"G   {len(codes):2d} " + " ".join(codes[:13]), "      " + "".join(f" {c:3s}" for c in codes[13:])]
    types = "".join(f"{ln:60s}SYS / # / OBS TYPES\n" for ln in lines)
    header = OBS3.replace("G    2 C1C L1C                                              SYS / # / OBS TYPES\n", types)
    obs = read_obs3(_write(tmp_path, "ok.rnx", header.replace("G05  20947300.931 8 110078836.38908", "G05  20947300.931 8")))
    assert obs.attrs["obs_types"]["G"] == codes


def test_a_code_that_is_not_a_rinex2_code_is_refused_with_its_line(tmp_path: Path) -> None:
    bad = OBS2.replace(OBS2_TYPES, OBS2_TYPES.replace("C1    L1", "c1    L1"))
    with pytest.raises(RinexFormatError, match=r"^bad\.10o: line 2: 'c1' is not a RINEX 2 observation code"):
        read_obs2(_write(tmp_path, "bad.10o", bad))
    assert read_obs2(_write(tmp_path, "good.10o", OBS2))["C1"].size == 1


def test_header_count_errors_name_their_line(tmp_path: Path) -> None:
    wrong3 = OBS3.replace("E    1 C1C", "E    2 C1C")
    with pytest.raises(RinexFormatError, match=r"header line 3: system E announces 2 observation types but lists 1"):
        read_obs3(_write(tmp_path, "count.rnx", wrong3))
    wrong2 = OBS2.replace(OBS2_TYPES, OBS2_TYPES.replace("     2    C1", "     3    C1"))
    with pytest.raises(RinexFormatError, match=r"count\.10o: line 2: header declares 3 observation types but lists 2"):
        read_obs2(_write(tmp_path, "count.10o", wrong2))


def test_records_of_a_system_without_its_header_line_are_reported(tmp_path: Path) -> None:
    """Galileo's ``SYS / # / OBS TYPES`` line deleted: the reader names the system, the run warns
    once and solves with GPS (no silent drop)."""
    path = _sample_with(tmp_path, "noE.rnx", lambda h: "".join(ln for ln in h.splitlines(keepends=True) if not ln.startswith("E  ")))
    assert read_obs(path).attrs["unlisted_systems"] == "E"
    assert "unlisted_systems" not in read_obs(SAMPLE / "obs.rnx").attrs
    for config in (load_config(), load_config(overrides={"systems": ["G", "E"]})):
        warnings = process(path, [SAMPLE / "nav.rnx"], config).epochs.warnings
        said = [w for w in warnings if "system E (Galileo)" in w]
        assert said == ["noE.rnx: system E (Galileo) has observation records but no 'SYS / # / OBS TYPES' line "
                        "in the header; E not used"], warnings


def test_a_system_asked_for_without_observation_types_is_reported(tmp_path: Path) -> None:
    config = load_config(overrides={"systems": ["G", "C"]})
    for warnings in (process(SAMPLE / "obs.rnx", [SAMPLE / "nav.rnx"], config).epochs.warnings,
                     load_epochs(SAMPLE / "obs.rnx", [SAMPLE / "nav.rnx"], config).warnings):
        assert [w for w in warnings if "system C" in w] == [
            "obs.rnx: system C (BeiDou) is asked for (--systems) but the header lists no observation types for it; "
            "C not used"], warnings


def test_a_system_without_a_usable_pseudorange_code_is_reported(tmp_path: Path) -> None:
    path = _sample_with(tmp_path, "c5.rnx", lambda h: h.replace("G    3 C1C D1C S1C", "G    3 C5Q D1C S1C"))
    result = process(path, [SAMPLE / "nav.rnx"], load_config())
    said = [w for w in result.epochs.warnings if "system G" in w]
    assert len(said) == 1 and said[0].startswith("c5.rnx: system G (GPS) has no pseudorange code the run uses (C1C")
    assert said[0].endswith("among the header's types (C5Q D1C S1C); G not used")
    assert set(result.epochs.systems) == {"E"}


def test_clean_sample_has_no_system_warning() -> None:
    assert not [w for w in process(SAMPLE / "obs.rnx", [SAMPLE / "nav.rnx"], load_config()).epochs.warnings
                if "system " in w]


def test_read_faults_are_told_in_words(tmp_path: Path) -> None:
    """A truncated gzip file and an exception without text: no Python class name in the message."""
    whole = gzip.compress((SAMPLE / "obs.rnx").read_bytes())
    cut = tmp_path / "cut.rnx.gz"
    cut.write_bytes(whole[:200])
    with pytest.raises(RinexFormatError) as info:
        rinex_info(cut)
    assert "Error" not in str(info.value) and str(info.value).startswith(f"{cut}: cannot read file (")
    assert fault_text(EOFError()) == "the file ends inside its compressed data (truncated)"
    assert fault_text(OSError("CRC check failed")) == "CRC check failed"
