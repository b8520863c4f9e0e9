"""Time spans of RINEX files (the navigation matching of gnss-batch) and station names."""

from __future__ import annotations

import gzip
from pathlib import Path

import numpy as np
import pytest

from gnss_cli.errors import InputFileNotFoundError, RinexFormatError
from gnss_cli.io.catalog import covering_navs, nav_toc_span, obs_time_span
from gnss_cli.io.reference import timestamps_gps_s

SAMPLE = Path(__file__).resolve().parents[2] / "sample_rinex" / "static"


def _gps_s(iso: str) -> float:
    return float(timestamps_gps_s(np.datetime64(iso, "ns")))


def test_sample_spans_from_the_header_and_from_the_epoch_lines(tmp_path: Path) -> None:
    first, last = _gps_s("2024-03-01T00:00:00"), _gps_s("2024-03-01T01:00:00")
    assert obs_time_span(SAMPLE / "obs.rnx") == (first, last)
    # without TIME OF LAST OBS (optional in RINEX), and with a wrong header last time left out,
    # the epoch lines decide; the same through gzip
    lines = (SAMPLE / "obs.rnx").read_text().splitlines(keepends=True)
    body = [ln for ln in lines if "TIME OF LAST OBS" not in ln]
    epochs = [i for i, ln in enumerate(body) if ln.startswith(">")]
    cut = "".join(body[:epochs[-10]])  # the last 10 epochs dropped: 00:55:00 is the last one left
    (tmp_path / "obs.rnx").write_text(cut)
    (tmp_path / "obs.rnx.gz").write_bytes(gzip.compress(cut.encode()))
    for p in (tmp_path / "obs.rnx", tmp_path / "obs.rnx.gz"):
        assert obs_time_span(p) == (first, _gps_s("2024-03-01T00:55:00"))
    assert nav_toc_span(SAMPLE / "nav.rnx") == (first, _gps_s("2024-03-01T02:00:00"))


def test_rinex2_span_from_its_epoch_lines(rinex_dir: Path) -> None:
    """0759's header has no TIME OF LAST OBS: 120 epochs, 30 s apart, the last one read."""
    first, last = obs_time_span(rinex_dir / "rtklib-0759" / "07590920.05o")
    assert first == _gps_s("2005-04-02T00:00:00")
    assert last == pytest.approx(first + 119 * 30.0, abs=0.01)
    a, b = nav_toc_span(rinex_dir / "rtklib-0759" / "07590920.05n")
    assert covering_navs((first, last), [(a, b)]) == [0]


@pytest.mark.parametrize("name", ["esbc-2020177/ESBC00DNK_R_20201770000_01D_MN.rnx.gz",
                                  "kms3-2022159-rinex4/KMS300DNK_R_20221591000_01H_MN.rnx.gz",
                                  "rtklib-0759/07590920.05n"])
def test_nav_span_is_that_of_the_whole_reading(rinex_dir: Path, name: str) -> None:
    """RINEX 3/4 spans come from the record start lines alone (ESBC: 3, KMS3: 4): the same as the
    dataset's times."""
    from gnss_cli.io.rinex import read_nav

    path = rinex_dir / name
    t = timestamps_gps_s(read_nav(path)["time"].values)
    assert nav_toc_span(path) == (float(t.min()), float(t.max()))


def test_unreadable_files_are_input_errors(tmp_path: Path) -> None:
    with pytest.raises(InputFileNotFoundError, match="nothere.rnx: no such file"):
        obs_time_span(tmp_path / "nothere.rnx")
    (tmp_path / "empty.rnx").write_text("     3.04           OBSERVATION DATA    M                   RINEX VERSION / TYPE\n"
                                        "                                                            END OF HEADER\n")
    with pytest.raises(RinexFormatError, match="no epoch line"):
        obs_time_span(tmp_path / "empty.rnx")


def test_margin_only_when_nothing_overlaps() -> None:
    hour = 3600.0
    navs = [(0.0, 2 * hour), (4 * hour, 6 * hour)]
    assert covering_navs((1 * hour, 5 * hour), navs) == [0, 1]
    assert covering_navs((2.5 * hour, 3 * hour), navs) == [0, 1]  # in the gap: both within 2 h
    assert covering_navs((2.5 * hour, 3 * hour), navs, margin_s=0.6 * hour) == [0]
    assert covering_navs((9 * hour, 10 * hour), navs) == []
