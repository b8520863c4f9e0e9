"""A RINEX 3 navigation file cut inside a record, or inside its last value, is refused with
the line (the fuzz cases where a cut tst2 nav file lost satellites silently)."""

from __future__ import annotations

from pathlib import Path

import pytest

from gnss_cli.cli.exits import run_app
from gnss_cli.cli.solve import app
from gnss_cli.errors import RinexFormatError
from gnss_cli.io.rinex import read_nav

TST = "tst2-2020155-urban-static"


def _cut(src: Path, dst: Path, n_bytes: int) -> Path:
    dst.write_bytes(src.read_bytes().rstrip()[:n_bytes])
    return dst


@pytest.mark.parametrize(("back", "match"), [(300, r"record of G has 4 lines \(expected 8\): the file ends inside it"),
                                             (100, r"record of G has 6 lines"),
                                             (7, r"the file ends inside a value \('2.663400000' has no exponent\)")])
def test_a_cut_file_is_refused_with_its_line(rinex_dir: Path, tmp_path: Path, back: int, match: str) -> None:
    src = rinex_dir / TST / "hksc155d.20n"
    cut = _cut(src, tmp_path / "cut.20n", len(src.read_bytes().rstrip()) - back)
    with pytest.raises(RinexFormatError, match=rf"^cut\.20n:\d+: {match}"):
        read_nav(cut)
    assert read_nav(src).sizes["sv"] == 32


def test_a_record_missing_a_line_in_the_middle_is_refused(rinex_dir: Path, tmp_path: Path) -> None:
    lines = (rinex_dir / TST / "hksc155d.20n").read_text().splitlines()
    start = next(i for i, x in enumerate(lines) if "END OF HEADER" in x) + 1
    bad = tmp_path / "gap.20n"
    bad.write_text("\n".join(lines[: start + 3] + lines[start + 4:]) + "\n")
    with pytest.raises(RinexFormatError, match=rf"gap\.20n:{start + 1}: record of G has 7 lines .*a line is missing or extra"):
        read_nav(bad)


def test_the_command_line_blames_the_navigation_file(rinex_dir: Path, tmp_path: Path,
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    src = rinex_dir / TST / "hksc155d.20n"
    cut = _cut(src, tmp_path / "hksc155d.20n", len(src.read_bytes()) // 2 + 37)
    with pytest.raises(SystemExit) as exc:
        run_app(app, "gnss-solve", [str(rinex_dir / TST / "2020_06_03_TST_03.obs.gz"), str(cut), "-o", str(tmp_path / "o.csv")])
    err = capsys.readouterr().err
    assert exc.value.code == 4 and "hksc155d.20n:" in err and "the file ends inside it" in err
    assert len(err.strip().splitlines()) == 1 and not (tmp_path / "o.csv").exists()
