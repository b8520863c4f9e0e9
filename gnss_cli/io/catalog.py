"""What a RINEX file covers, for sorting many files: time spans, navigation coverage, station names.

``gnss-batch`` matches navigation files to observation files by time: an observation
file spans its first to its last epoch (:func:`obs_time_span`: the header's ``TIME OF
FIRST OBS`` / ``TIME OF LAST OBS``, else the epoch lines themselves), a navigation file
the times of clock (toc) of its records (:func:`nav_toc_span`), and
:func:`covering_navs` picks the navigation files whose span overlaps the observation
span. Times are seconds since the GPS epoch (1980-01-06 00:00:00), read as GPS time
whatever the file's time system (the few seconds between GPS, Galileo, BeiDou time and
UTC do not matter when the spans are hours).
"""

from __future__ import annotations

import bz2
import gzip
import re
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from gnss_cli.errors import InputFileNotFoundError, RinexFormatError
from gnss_cli.io.compression import open_bytes
from gnss_cli.io.reference import timestamps_gps_s

__all__ = ["obs_time_span", "nav_toc_span", "covering_navs", "station_id", "NAV_MARGIN_S"]

NAV_MARGIN_S = 7200.0
"""Seconds a navigation file's toc span is extended on each side when no file overlaps an
observation span (a broadcast record serves up to about 2 h around its toc)."""

# RINEX 3/4 epoch line "> 2020 06 25 23 59 30.0000000  0 31"; RINEX 2 " 05  4  2  0 59 30.0000000  0  8G..."
_EPOCH3 = re.compile(rb"^> (\d{4}) ([ \d]\d) ([ \d]\d) ([ \d]\d) ([ \d]\d) ([ \d]\d\.\d{7})  [0-6]", re.M)
_EPOCH2 = re.compile(rb"^ ([ \d]\d) ([ \d]\d) ([ \d]\d) ([ \d]\d) ([ \d]\d) ([ \d]\d\.\d{7})  [0-6]", re.M)
# File names: RINEX 3/4 long "ESBC00DNK_R_2020177...", RINEX 2 short "07590920.05o" (ssssdddf.yyt).
_LONG_NAME = re.compile(r"^([A-Za-z0-9]{4}\d\d[A-Za-z]{3})_[RSU]_\d{11}_")
_SHORT_NAME = re.compile(r"^([A-Za-z0-9]{4})\d{3}[a-xA-X0-9]\.\d\d[oOdD]")


def _header_lines(path: Path) -> list[str]:
    """The header of a plain, gzip or bzip2 RINEX file read line by line (Hatanaka headers
    are plain text), or of the whole decompressed file for other packagings."""
    raw = path.open("rb")
    with raw:
        magic = raw.read(3)
        raw.seek(0)
        if magic[:2] == b"\x1f\x8b" or magic == b"BZh":
            stream = gzip.GzipFile(fileobj=raw) if magic[:2] == b"\x1f\x8b" else bz2.BZ2File(raw)
        elif magic[:2] in (b"\x1f\x9d", b"PK"):
            stream = None
        else:
            stream = raw
        if stream is None:
            content = open_bytes(path)
            return content[: content.find(b"END OF HEADER") + 13].decode("ascii", "replace").splitlines()
        lines: list[str] = []
        try:
            for line in stream:
                lines.append(line.decode("ascii", "replace").rstrip("\r\n"))
                if "END OF HEADER" in lines[-1] or len(lines) > 5000:
                    break
        except (OSError, EOFError) as exc:
            raise RinexFormatError(f"{path}: cannot read file ({exc})") from None
    return lines


def _header_time_s(line: str) -> float | None:
    """``TIME OF FIRST/LAST OBS`` fields (6I6 years..minutes, F13.7 seconds) -> GPS s, or None."""
    try:
        year, month, day, hour, minute = (int(v) for v in line[:30].split())
        seconds = float(line[30:43])
    except ValueError:
        return None
    return _civil_gps_s(year, month, day, hour, minute, seconds)


def _civil_gps_s(year: int, month: int, day: int, hour: int, minute: int, seconds: float) -> float:
    if year < 100:
        year += 1900 if year >= 80 else 2000
    t = np.datetime64(f"{year:04d}-{month:02d}-{day:02d}T{hour:02d}:{minute:02d}", "ns")
    return float(timestamps_gps_s(t)) + seconds


def _epoch_match_s(match: re.Match[bytes]) -> float:
    y, mo, d, h, mi = (int(g) for g in match.groups()[:5])
    return _civil_gps_s(y, mo, d, h, mi, float(match.group(6)))


def _body_span_s(path: Path) -> tuple[float, float]:
    """First and last epoch from the epoch lines of the (decompressed) file."""
    content = open_bytes(path)
    body = content[content.find(b"END OF HEADER"):]
    pattern = _EPOCH3 if _EPOCH3.search(body[:200_000]) else _EPOCH2
    first = pattern.search(body)
    if first is None:
        raise RinexFormatError(f"{path}: no epoch line found")
    tail = body[-200_000:]
    matches = list(pattern.finditer(tail)) or list(pattern.finditer(body))
    return _epoch_match_s(first), _epoch_match_s(matches[-1])


def obs_time_span(path: str | Path) -> tuple[float, float]:
    """First and last epoch of a RINEX observation file, seconds since the GPS epoch.

    From the header's ``TIME OF FIRST OBS`` and ``TIME OF LAST OBS`` when both are there
    (reading only the header); else from the first and last epoch lines of the file
    (``TIME OF LAST OBS`` is optional in RINEX).

    Parameters
    ----------
    path : str or Path
        Plain or compressed RINEX 2, 3 or 4 observation file (Hatanaka allowed).

    Returns
    -------
    (float, float)
        First and last epoch, s since 1980-01-06 00:00:00 (the header's time system).

    Raises
    ------
    InputError
        Missing or unreadable file, or no epoch time in it.
    """
    p = Path(path)
    if not p.is_file():
        raise InputFileNotFoundError(f"{p}: {'not a regular file' if p.exists() else 'no such file'}")
    first = last = None
    for line in _header_lines(p):
        label = line[60:].strip()
        if label == "TIME OF FIRST OBS":
            first = _header_time_s(line)
        elif label == "TIME OF LAST OBS":
            last = _header_time_s(line)
    if first is not None and last is not None and last >= first:
        return first, last
    return _body_span_s(p)


def nav_toc_span(path: str | Path) -> tuple[float, float]:
    """Earliest and latest time of clock (toc) of the records of a navigation file, GPS s.

    RINEX 3/4 files: the record start lines as :func:`gnss_cli.io.rinex3_nav.record_tocs` reads
    them (a fourth of the time of the whole reading); others with :func:`gnss_cli.io.rinex.read_nav`
    (every version and packaging).

    Raises
    ------
    InputError
        The file is missing, not RINEX navigation, or holds no record.
    """
    from gnss_cli.io.rinex import read_nav, rinex_info

    info = rinex_info(path)
    if info.kind != "nav":
        raise RinexFormatError(f"{info.path}: is a RINEX observation file, expected a navigation file (OBS and NAV swapped?)")
    if info.version >= 3:
        from gnss_cli.io.rinex3_nav import record_tocs

        t = timestamps_gps_s(record_tocs(path))
    else:
        t = timestamps_gps_s(read_nav(path)["time"].values)
    if not t.size:
        raise RinexFormatError(f"{path}: no navigation record")
    return float(t.min()), float(t.max())


def covering_navs(obs_span: tuple[float, float], nav_spans: Sequence[tuple[float, float]],
                  margin_s: float = NAV_MARGIN_S) -> list[int]:
    """Indices of the navigation files whose toc span overlaps an observation span.

    When none overlaps, those within ``margin_s`` of it (a short file just after the last
    record of the day, for instance); an empty list when none is that close either.

    Parameters
    ----------
    obs_span : (float, float)
        First and last epoch, s (any common time origin).
    nav_spans : sequence of (float, float)
        Earliest and latest toc of each navigation file, s.
    margin_s : float
        Seconds a toc span is widened on each side in the second pass.

    Examples
    --------
    Two daily files and a 10-minute observation file on the second day:

    >>> day = 86400.0
    >>> covering_navs((day + 0.0, day + 600.0), [(0.0, day - 900.0), (day, 2 * day - 900.0)])
    [1]
    >>> covering_navs((day - 600.0, day - 300.0), [(0.0, day - 900.0), (day, 2 * day - 900.0)])
    [0, 1]
    >>> covering_navs((5 * day, 5 * day + 60.0), [(0.0, day)])
    []
    """
    a, b = obs_span
    core = [i for i, (s, e) in enumerate(nav_spans) if s <= b and e >= a]
    if core:
        return core
    return [i for i, (s, e) in enumerate(nav_spans) if s - margin_s <= b and e + margin_s >= a]


def station_id(path: str | Path, marker_name: str = "") -> str:
    """The station of an observation file: the file name's station field, else the marker name, else the file stem.

    RINEX 3/4 long names give the nine-character ID (``ESBC00DNK``), RINEX 2 short names
    the four-character one (``0759``). Characters other than letters, digits, ``-`` and
    ``_`` become ``_`` (the name is a folder name in a partitioned dataset).

    >>> station_id("/data/ESBC00DNK_R_20201770000_01D_30S_MO.crx.gz")
    'ESBC00DNK'
    >>> station_id("07590920.05o"), station_id("obs.rnx", "MY SITE"), station_id("obs.rnx")
    ('0759', 'MY_SITE', 'obs')
    """
    name = Path(path).name
    for pattern in (_LONG_NAME, _SHORT_NAME):
        m = pattern.match(name)
        if m:
            return m.group(1)
    raw = marker_name.strip() or name.split(".")[0] or name
    return re.sub(r"[^A-Za-z0-9_-]", "_", raw)
