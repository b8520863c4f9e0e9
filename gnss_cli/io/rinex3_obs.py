"""Fast vectorized reader for RINEX 3.0x and 4.0x observation files.

The whole decompressed file is held as one ``uint8`` buffer. Line boundaries, epoch lines
(``>``), satellite ids and the fixed-width 16-character observation fields
(``F14.3`` value, loss-of-lock and signal-strength digits) are located and decoded with
numpy over all lines at once; there is no Python object per observation. The result has
the layout of ``georinex.load(path, use=systems, meas=codes)`` so the two readers are
interchangeable (and compared in the tests).

The module also holds the small fixed-width text-grid primitives that
:mod:`gnss_cli.io.rinex3_nav` shares (:func:`split_lines`, :func:`gather_columns`,
:func:`parse_uint_columns`, :func:`civil2datetime64`).

References
----------
RINEX 3.05 and 4.00 format descriptions (IGS/RTCM-SC104), section 5 and tables A2-A3.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import xarray
from numpy.typing import NDArray

from gnss_cli.errors import RinexFormatError, UsageError
from gnss_cli.io.compression import open_bytes

__all__ = ["read_obs3"]

SYSTEM_CHARS = "GRECJSI"
"""RINEX system letters read by this module (GPS, GLONASS, Galileo, BeiDou, QZSS, SBAS, NavIC)."""

_SPACE = 32
_DIGIT0 = 48
_MINUS = 45
_DOT = 46

_PAD = 512
"""Blanks appended to the text buffer, >= the widest column range ever cut."""

_FIELD_WIDTH = 16
"""Width of one observation (F14.3 value + LLI + SSI), characters."""
_VALUE_WIDTH = 14
_SV_WIDTH = 3

# F14.3: ten integer characters (sign and digits), the point, three decimals.
# Integer value in units of 1e-3 = sum(digit_j * weight_j); exact in float64 (< 2**53).
_F14_WEIGHTS = np.array([10.0 ** (12 - j) for j in range(10)] + [0.0, 100.0, 10.0, 1.0])

_TIME_SYSTEMS = {"G": "GPS", "R": "GLO", "E": "GAL", "J": "QZS", "C": "BDT", "I": "IRN"}


# --------------------------------------------------------------------------------------
# fixed-width text grids (shared with rinex3_nav)
# --------------------------------------------------------------------------------------


def split_lines(body: bytes) -> tuple[NDArray[np.uint8], NDArray[np.int64], NDArray[np.int64]]:
    """Locate the lines of a text buffer without creating one object per line.

    Parameters
    ----------
    body : bytes
        ASCII text; ``\\r`` characters are removed first.

    Returns
    -------
    buf : numpy.ndarray of uint8, shape (n_bytes + 512,)
        The text as bytes, followed by 512 blanks.
    starts : numpy.ndarray of int64, shape (n_lines,)
        Offset of the first character of each line.
    lengths : numpy.ndarray of int64, shape (n_lines,)
        Number of characters of each line, without the line end.
    """
    if b"\r" in body:
        body = body.replace(b"\r", b"")
    text = np.frombuffer(body, dtype=np.uint8)
    newlines = np.flatnonzero(text == 10)
    starts = np.concatenate(([0], newlines + 1)).astype(np.int64)
    ends = np.concatenate((newlines, [text.size])).astype(np.int64)
    if starts[-1] >= text.size:  # text ends with a newline: no last partial line
        starts, ends = starts[:-1], ends[:-1]
    # blank padding lets gather_columns cut fixed-width windows past the last line's end
    buf = np.concatenate((text, np.full(_PAD, _SPACE, dtype=np.uint8)))
    return buf, starts, ends - starts


def gather_columns(
    buf: NDArray[np.uint8],
    starts: NDArray[np.int64],
    lengths: NDArray[np.int64],
    first_col: int | NDArray[np.int64],
    width: int,
) -> NDArray[np.uint8]:
    """Cut the same column range out of many lines, padding short lines with blanks.

    Parameters
    ----------
    buf : numpy.ndarray of uint8, shape (n_bytes + 512,)
        Padded text buffer from :func:`split_lines`.
    starts, lengths : numpy.ndarray of int64, shape (n,)
        Start offsets and lengths of the selected lines.
    first_col : int or numpy.ndarray of int64, shape (n,)
        0-based first column (per line when an array).
    width : int
        Number of columns to cut.

    Returns
    -------
    numpy.ndarray of uint8, shape (n, width)
        The characters; positions beyond the end of a line hold a blank (32).
    """
    if width > _PAD:
        raise UsageError(f"width: at most {_PAD} columns, got {width}")
    first = np.broadcast_to(np.asarray(first_col, dtype=np.int64), starts.shape)
    # row i of the window view is buf[i : i + width]; one fancy index copies all rows
    windows = np.lib.stride_tricks.sliding_window_view(buf, width)
    rows = np.minimum(starts + first, windows.shape[0] - 1)
    chars = windows[rows]
    n_inside = np.clip(lengths - first, 0, width)
    short = np.flatnonzero(n_inside < width)  # lines that end inside the range
    if short.size:
        outside = np.arange(width) >= n_inside[short, None]
        chars[short] = np.where(outside, np.uint8(_SPACE), chars[short])
    return chars


def parse_uint_columns(chars: NDArray[np.uint8]) -> tuple[NDArray[np.int64], NDArray[np.bool_]]:
    """Decode right-aligned unsigned integers (``I`` format) from a character grid.

    Parameters
    ----------
    chars : numpy.ndarray of uint8, shape (n, width)
        One field per row: one run of digits with blanks before or after it.

    Returns
    -------
    values : numpy.ndarray of int64, shape (n,)
        Decoded integers (0 where invalid).
    ok : numpy.ndarray of bool, shape (n,)
        False where the field is blank or holds anything but one run of digits and blanks.
    """
    is_digit = (chars >= _DIGIT0) & (chars <= _DIGIT0 + 9)
    is_space = chars == _SPACE
    # exactly one run of digits, blanks around it (trailing blanks occur in the wild
    # when a line is cut short, e.g. '  0 2' for flag 0 and 2 satellites)
    run_starts = np.count_nonzero(is_digit[:, 1:] & ~is_digit[:, :-1], axis=1) + is_digit[:, 0]
    ok = np.all(is_digit | is_space, axis=1) & (run_starts == 1)
    digits = np.where(is_digit, chars - _DIGIT0, 0).astype(np.int64)
    # the value is the digit run read right-aligned: drop the trailing blanks' weights
    n_trailing = np.argmax(is_digit[:, ::-1], axis=1)
    weights = 10 ** np.arange(chars.shape[1] - 1, -1, -1, dtype=np.int64)
    return (digits @ weights) // 10 ** n_trailing.astype(np.int64), ok


def civil2datetime64(
    year: NDArray[np.int64],
    month: NDArray[np.int64],
    day: NDArray[np.int64],
    ns_of_day: NDArray[np.int64],
) -> NDArray[np.datetime64]:
    """Convert calendar dates and nanoseconds of day to ``datetime64[ns]``, vectorized.

    Parameters
    ----------
    year, month, day : numpy.ndarray of int64, shape (n,)
        Proleptic Gregorian date.
    ns_of_day : numpy.ndarray of int64, shape (n,)
        Nanoseconds since the start of the day.

    Returns
    -------
    numpy.ndarray of datetime64[ns], shape (n,)
        The instants, in the time scale of the input (no leap seconds applied).

    Notes
    -----
    Days since 1970-01-01 by the ``days_from_civil`` algorithm (H. Hinnant):
    ``y = year - (month <= 2)``, ``era = y // 400``, ``doy = (153 (m + 9 mod 12) + 2) // 5 + d - 1``,
    ``days = 146097 era + 365 yoe + yoe // 4 - yoe // 100 + doy - 719468``.
    """
    y = year - (month <= 2)
    era = np.floor_divide(y, 400)
    yoe = y - era * 400
    mp = (month + 9) % 12
    doy = (153 * mp + 2) // 5 + day - 1
    doe = yoe * 365 + yoe // 4 - yoe // 100 + doy
    days = era * 146097 + doe - 719468
    ns = days * 86_400_000_000_000 + ns_of_day
    return ns.astype("datetime64[ns]")


def parse_f14_3(chars: NDArray[np.uint8]) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Decode RINEX observation values (``F14.3``) from a character grid.

    Parameters
    ----------
    chars : numpy.ndarray of uint8, shape (n, 14)
        One value field per row.

    Returns
    -------
    values : numpy.ndarray of float64, shape (n,)
        Decoded values; NaN for blank fields and for fields that do not follow ``F14.3``.
    nonstandard : numpy.ndarray of bool, shape (n,)
        True where the field is neither blank nor plain ``F14.3`` (decode those another way).

    Notes
    -----
    The digits form an integer N (units of 1e-3) exactly representable in float64, and
    ``N / 1000`` is correctly rounded, so the result equals ``float(text)`` bit for bit.
    """
    digit = chars - np.uint8(_DIGIT0)  # wraps around for characters below '0'
    is_digit = digit < 10
    is_minus = chars[:, :10] == _MINUS
    n_minus = np.count_nonzero(is_minus, axis=1)
    n_space = np.count_nonzero(chars == _SPACE, axis=1)
    # F14.3: blanks, at most one '-', digits; '.' in column 10; digits in columns 11-13
    standard = (
        (chars[:, 10] == _DOT)
        & (np.count_nonzero(is_digit, axis=1) + n_space + n_minus == 13)
        & is_digit[:, 11:].all(axis=1)
        & (n_minus <= 1)
    )
    digits = np.where(is_digit, digit, np.uint8(0)).astype(np.float64)
    values = (digits @ _F14_WEIGHTS) / 1000.0
    np.negative(values, out=values, where=n_minus > 0)
    values[~standard] = np.nan
    return values, ~standard & (n_space < chars.shape[1])


# --------------------------------------------------------------------------------------
# header
# --------------------------------------------------------------------------------------


def _header_end(content: bytes, name: str) -> int:
    """Offset of the first byte after the ``END OF HEADER`` line."""
    pos = content.find(b"END OF HEADER")
    if pos < 0:
        raise RinexFormatError(f"{name}: no 'END OF HEADER' line (not a RINEX file, or truncated)")
    nl = content.find(b"\n", pos)
    return len(content) if nl < 0 else nl + 1


def parse_version_line(first_line: str, name: str) -> tuple[float, str, str]:
    """Decode the ``RINEX VERSION / TYPE`` line.

    Parameters
    ----------
    first_line : str
        The first line of the file.
    name : str
        File name for error messages.

    Returns
    -------
    version : float
        Format version, e.g. 3.05.
    file_type : str
        Column 21 letter: ``'O'`` observation, ``'N'`` navigation, ...
    system : str
        Column 41 letter (``'M'`` mixed, ``'G'``, ...; may be blank).

    Raises
    ------
    RinexFormatError
        The line is not a RINEX version line.
    """
    if "RINEX VERSION / TYPE" not in first_line[60:]:
        raise RinexFormatError(f"{name}: not a RINEX file (first line is not 'RINEX VERSION / TYPE')")
    try:
        version = float(first_line[:9])
    except ValueError:
        raise RinexFormatError(f"{name}: bad RINEX version {first_line[:9].strip()!r}") from None
    padded = first_line.ljust(60)
    return version, padded[20], padded[40]


def check_rinex34_type(first_line: str, name: str, file_type: str) -> tuple[float, str]:
    """Version and system letter of a RINEX 3/4 file of type ``file_type`` ('O' or 'N').

    Raises
    ------
    RinexFormatError
        The file is of another type or version.
    """
    version, found, system = parse_version_line(first_line, name)
    if found != file_type:
        kind = "observation" if file_type == "O" else "navigation"
        raise RinexFormatError(f"{name}: not a RINEX {kind} file (RINEX TYPE {found!r})")
    if not 3.0 <= version < 5.0:
        raise RinexFormatError(
            f"{name}: RINEX version {version} is not read by the RINEX 3/4 reader (expected 3.xx or 4.xx)"
        )
    return version, system


def _read_obs_header(
    header: str, name: str
) -> tuple[dict[str, Any], dict[str, list[str]]]:
    """Decode the header lines a reader needs; return (attributes, obs types per system)."""
    lines = header.splitlines()
    version, system = check_rinex34_type(lines[0], name, "O")
    attrs: dict[str, Any] = {"version": version, "rinextype": "obs"}
    obs_types: dict[str, list[str]] = {}
    current_sys = ""
    announced: dict[str, int] = {}
    time_system = _TIME_SYSTEMS.get(system, "")
    for lineno, line in enumerate(lines[1:], start=2):
        label = line[60:].strip()
        text = line[:60]
        if label == "SYS / # / OBS TYPES":
            if text[:1].strip():
                current_sys = text[0]
                try:
                    announced[current_sys] = int(text[3:6])
                except ValueError:
                    raise RinexFormatError(
                        f"{name}: bad observation-type count on header line {lineno}"
                    ) from None
                obs_types[current_sys] = []
            elif not current_sys:
                raise RinexFormatError(
                    f"{name}: continuation of 'SYS / # / OBS TYPES' without a system on line {lineno}"
                )
            obs_types[current_sys] += text[7:60].split()
        elif label == "APPROX POSITION XYZ" and "position" not in attrs:
            try:
                attrs["position"] = [float(text[i : i + 14]) for i in (0, 14, 28)]
            except ValueError:
                pass  # optional record; a blank or garbled one is simply absent
        elif label == "MARKER NAME":
            attrs["marker_name"] = text.strip()
        elif label == "REC # / TYPE / VERS":
            attrs["rxmodel"] = text[20:40].strip()
        elif label == "INTERVAL":
            try:
                attrs["interval"] = float(text[:10])
            except ValueError:
                pass
        elif label == "TIME OF FIRST OBS":
            if system == "M" or not time_system:
                time_system = text[48:51].strip() or time_system
        elif label == "RCV CLOCK OFFS APPL":
            try:
                attrs["receiver_clock_offset_applied"] = int(text[:6])
            except ValueError:
                pass
    for sys_char, n in announced.items():
        if len(obs_types[sys_char]) != n:
            raise RinexFormatError(
                f"{name}: system {sys_char} announces {n} observation types "
                f"but lists {len(obs_types[sys_char])}"
            )
    if not obs_types:
        raise RinexFormatError(f"{name}: no 'SYS / # / OBS TYPES' header records")
    attrs["time_system"] = time_system or "GPS"
    attrs["obs_types"] = obs_types
    return attrs, obs_types


# --------------------------------------------------------------------------------------
# body
# --------------------------------------------------------------------------------------


def _epoch_times(
    ep_chars: NDArray[np.uint8], ep_lineno: NDArray[np.int64], name: str
) -> tuple[NDArray[np.datetime64], NDArray[np.int64], NDArray[np.int64]]:
    """Decode epoch lines ``> yyyy mm dd hh mm ss.sssssss  f nnn``.

    Returns times (datetime64[ns]), epoch flags and satellite counts, shape (n_epochs,).
    """
    year, ok_y = parse_uint_columns(ep_chars[:, 2:6])
    month, ok_mo = parse_uint_columns(ep_chars[:, 7:9])
    day, ok_d = parse_uint_columns(ep_chars[:, 10:12])
    hour, ok_h = parse_uint_columns(ep_chars[:, 13:15])
    minute, ok_mi = parse_uint_columns(ep_chars[:, 16:18])
    sec, ok_s = parse_uint_columns(ep_chars[:, 18:21])
    frac, ok_f = parse_uint_columns(ep_chars[:, 22:29])
    flag, ok_fl = parse_uint_columns(ep_chars[:, 31:32])
    nsat, ok_n = parse_uint_columns(ep_chars[:, 32:35])
    ok = (
        ok_y & ok_mo & ok_d & ok_h & ok_mi & ok_s & ok_f & ok_fl & ok_n
        & (ep_chars[:, 1] == _SPACE) & (ep_chars[:, 21] == _DOT)
        & (month >= 1) & (month <= 12) & (day >= 1) & (day <= 31)
        & (hour <= 23) & (minute <= 59) & (sec <= 60) & (flag <= 6)
    )
    # event epochs (flag > 1) may leave the time blank: only the flag and count matter
    event = ok_fl & ok_n & (flag >= 2) & (flag <= 6)
    bad = ~ok & ~event
    if np.any(bad):
        i = int(np.flatnonzero(bad)[0])
        text = ep_chars[i].tobytes().decode("ascii", "replace").rstrip()
        raise RinexFormatError(f"{name}: bad epoch line {int(ep_lineno[i])}: {text!r}")
    ns_of_day = ((hour * 60 + minute) * 60 + sec) * 1_000_000_000 + frac * 100
    times = civil2datetime64(year, np.where(ok, month, 1), np.where(ok, day, 1), ns_of_day)
    return times, flag, nsat


def _sv_codes(sv_chars: NDArray[np.uint8]) -> tuple[NDArray[np.int64], NDArray[np.bool_]]:
    """Satellite ids ``Xnn`` (``'G 7'`` read as ``'G07'``) as sortable integers and a validity mask."""
    c0 = sv_chars[:, 0].astype(np.int64)
    c1 = np.where(sv_chars[:, 1] == _SPACE, _DIGIT0, sv_chars[:, 1]).astype(np.int64)
    c2 = sv_chars[:, 2].astype(np.int64)
    known = np.isin(c0, np.frombuffer(SYSTEM_CHARS.encode(), dtype=np.uint8))
    ok = known & (c1 >= _DIGIT0) & (c1 <= _DIGIT0 + 9) & (c2 >= _DIGIT0) & (c2 <= _DIGIT0 + 9)
    return (c0 << 16) | (c1 << 8) | c2, ok


def sv_codes2str(codes: NDArray[np.int64]) -> NDArray[np.str_]:
    """Turn integer satellite codes from :func:`_sv_codes` back into ``'<U3'`` ids."""
    chars = np.stack([(codes >> 16) & 255, (codes >> 8) & 255, codes & 255], axis=1).astype(np.uint8)
    return np.ascontiguousarray(chars).view("S3").ravel().astype("<U3")


def _select_codes(
    obs_types: dict[str, list[str]],
    systems: Sequence[str] | None,
    codes: Sequence[str] | None,
    pseudorange_only: bool,
) -> dict[str, list[tuple[int, str]]]:
    """Per system, the (field index, code) pairs to decode, in header order."""
    chosen: dict[str, list[tuple[int, str]]] = {}
    for sys_char, types in obs_types.items():
        if systems is not None and sys_char not in systems:
            continue
        pairs = []
        for k, code in enumerate(types):
            if pseudorange_only and not code.startswith("C"):
                continue
            if codes is not None and not any(code.startswith(c) for c in codes):
                continue
            pairs.append((k, code))
        chosen[sys_char] = pairs
    return chosen


def _validate_selection(
    systems: Sequence[str] | str | None, codes: Sequence[str] | str | None
) -> tuple[list[str] | None, list[str] | None]:
    if isinstance(systems, str):
        systems = [s.strip() for s in systems.replace(",", " ").split()]
    if systems is not None:
        systems = list(systems)
        bad = [s for s in systems if not isinstance(s, str) or len(s) != 1 or s not in SYSTEM_CHARS]
        if bad or not systems:
            raise UsageError(
                f"systems: expected RINEX system letters from {SYSTEM_CHARS!r}, got {systems!r}"
            )
    if isinstance(codes, str):
        codes = [codes]
    if codes is not None:
        codes = [c.strip() for c in codes]
        bad = [c for c in codes if not c or len(c) > 3 or not c.isalnum()]
        if bad or not codes:
            raise UsageError(
                f"codes: expected observation codes such as 'C1C' or prefixes 'C1', got {codes!r}"
            )
    return systems, codes


def read_obs3(
    path: str | os.PathLike[str],
    systems: Sequence[str] | None = None,
    codes: Sequence[str] | None = None,
    *,
    pseudorange_only: bool = False,
) -> xarray.Dataset:
    """Read a RINEX 3.0x / 4.0x observation file into an ``(time, sv)`` dataset.

    Parameters
    ----------
    path : str or os.PathLike
        Observation file: plain, ``.gz``, ``.Z``, ``.zip``, ``.bz2``, Hatanaka ``.crx`` /
        ``.??d``, or compressed Hatanaka.
    systems : sequence of str, optional
        System letters to keep (``"G"``, ``"R"``, ``"E"``, ``"C"``, ``"J"``, ``"S"``,
        ``"I"``); default all.
    codes : sequence of str, optional
        Observation codes to keep. As in georinex's ``meas``, each entry is a prefix:
        ``"C1C"`` keeps ``C1C``, ``"C1"`` keeps ``C1C``, ``C1W``, ... Default all.
    pseudorange_only : bool, default False
        Keep only code pseudoranges (codes ``C..``); combined with ``codes`` if both given.

    Returns
    -------
    xarray.Dataset
        Dims ``(time, sv)``; ``time`` datetime64[ns] in the file's time scale (GPS time
        for GPS and mixed files), sorted; ``sv`` ``'<U3'`` ids sorted as strings. One
        float64 variable per observation code (m for pseudoranges, cycles for phases,
        Hz for Doppler, dB-Hz for signal strength), NaN where missing. Attributes:
        ``version`` (float), ``rinextype`` = ``'obs'``, ``time_system``, ``interval``
        (s; header ``INTERVAL`` or the median epoch spacing), ``position`` (header
        ``APPROX POSITION XYZ``, m, 3 floats, when present), ``marker_name``,
        ``rxmodel``, ``filename`` and ``obs_types`` (dict: system -> list of codes in
        header order).

    Raises
    ------
    InputFileNotFoundError
        ``path`` does not exist.
    RinexFormatError
        Not a RINEX 3/4 observation file, no observation records, a bad epoch line, a
        satellite count that does not match the lines that follow, a bad satellite id or
        an undecodable value; the message names the file and the line.
    UsageError
        ``systems`` or ``codes`` malformed.

    Notes
    -----
    Layout follows ``georinex.load(path, use=systems, meas=codes)`` (georinex 1.16):
    times are the epochs that hold at least one satellite of the selected systems,
    satellites are all satellites of the selected systems that appear, even when every
    selected code is blank for them. Differences: ``'G 7'`` is read as ``'G07'`` before
    sorting; event epochs (flag 2-6) and their special records are skipped; when the same
    epoch appears twice, the later record wins. Loss-of-lock and signal-strength
    indicators are not read.

    Examples
    --------
    >>> obs = read_obs3("ESBC00DNK_R_20201770000_01D_30S_MO.crx.gz", pseudorange_only=True)  # doctest: +SKIP
    >>> obs.sizes  # doctest: +SKIP
    Frozen({'time': 2880, 'sv': 113})
    >>> obs["C1C"].sel(sv="G05").values[0]  # doctest: +SKIP
    20947300.931
    """
    systems, codes = _validate_selection(systems, codes)
    name = Path(path).name
    content = open_bytes(path)
    if not content or content.isspace():
        raise RinexFormatError(f"{name}: empty file")
    hdr_end = _header_end(content, name)
    header = content[:hdr_end].decode("ascii", errors="replace")
    attrs, obs_types = _read_obs_header(header, name)
    n_header_lines = header.count("\n")
    chosen = _select_codes(obs_types, systems, codes, pseudorange_only)
    if not chosen:
        raise RinexFormatError(
            f"{name}: none of the systems {systems} in the file (it has {''.join(obs_types)})"
        )

    buf, starts, lengths = split_lines(content[hdr_end:])
    # trailing blank lines are harmless
    nonblank = lengths > 0
    first_char = np.where(nonblank, buf[starts], np.uint8(_SPACE))
    last = np.flatnonzero(first_char != _SPACE)
    n_lines = int(last[-1]) + 1 if last.size else 0
    starts, lengths, first_char = starts[:n_lines], lengths[:n_lines], first_char[:n_lines]
    lineno = np.arange(n_lines, dtype=np.int64) + n_header_lines + 1

    is_epoch = first_char == ord(">")
    ep_idx = np.flatnonzero(is_epoch)
    if ep_idx.size == 0:
        raise RinexFormatError(f"{name}: no observation records (no epoch line '>' after the header)")
    if ep_idx[0] != 0:
        stray = np.flatnonzero(lengths[: ep_idx[0]] > 0)
        if stray.size:
            raise RinexFormatError(
                f"{name}: unexpected text on line {int(lineno[stray[0]])} before the first epoch line"
            )
    ep_chars = gather_columns(buf, starts[ep_idx], lengths[ep_idx], 0, 35)
    times, flag, nsat = _epoch_times(ep_chars, lineno[ep_idx], name)
    follow = np.diff(np.concatenate((ep_idx, [n_lines]))) - 1
    mismatch = follow != nsat
    if np.any(mismatch):
        i = int(np.flatnonzero(mismatch)[0])
        raise RinexFormatError(
            f"{name}: bad epoch line {int(lineno[ep_idx[i]])}: it announces {int(nsat[i])} "
            f"records but {int(follow[i])} lines follow"
        )

    owner = np.cumsum(is_epoch) - 1  # epoch index of each line
    is_obs_epoch = flag <= 1
    is_data = ~is_epoch & (owner >= 0)
    is_data &= is_obs_epoch[np.maximum(owner, 0)]
    data_idx = np.flatnonzero(is_data)
    sv_chars = gather_columns(buf, starts[data_idx], lengths[data_idx], 0, _SV_WIDTH)
    sv_code, sv_ok = _sv_codes(sv_chars)
    if not np.all(sv_ok):
        i = int(np.flatnonzero(~sv_ok)[0])
        raise RinexFormatError(
            f"{name}: bad satellite id {sv_chars[i].tobytes().decode('ascii', 'replace')!r} "
            f"on line {int(lineno[data_idx[i]])}"
        )
    sys_code = sv_chars[:, 0]
    keep = np.isin(sys_code, np.frombuffer("".join(chosen).encode(), dtype=np.uint8))
    data_idx, sv_code, sys_code = data_idx[keep], sv_code[keep], sys_code[keep]
    if data_idx.size == 0:
        raise RinexFormatError(f"{name}: no observation records of the systems {''.join(chosen)}")

    line_epoch = owner[data_idx]
    time_values, time_of_line = np.unique(times[line_epoch], return_inverse=True)
    sv_values, sv_of_line = np.unique(sv_code, return_inverse=True)
    n_t, n_sv = time_values.size, sv_values.size

    variables: dict[str, NDArray[np.float64]] = {}
    for sys_char, pairs in chosen.items():
        rows = np.flatnonzero(sys_code == ord(sys_char))
        if rows.size == 0:
            continue
        r_starts = starts[data_idx[rows]]
        r_lengths = lengths[data_idx[rows]]
        flat = time_of_line[rows] * n_sv + sv_of_line[rows]
        for k, code in pairs:
            chars = gather_columns(buf, r_starts, r_lengths, _SV_WIDTH + _FIELD_WIDTH * k, _VALUE_WIDTH)
            values, odd = parse_f14_3(chars)
            if np.any(odd):
                values[odd] = parse_float_fields(chars[odd], lineno[data_idx[rows[odd]]], name, f"{code} value")
            if code not in variables:
                variables[code] = np.full(n_t * n_sv, np.nan)
            variables[code][flat] = values

    data_vars = {code: (("time", "sv"), arr.reshape(n_t, n_sv)) for code, arr in variables.items()}
    ds = xarray.Dataset(data_vars, coords={"time": time_values, "sv": sv_codes2str(sv_values)})
    if "interval" not in attrs and n_t > 1:
        attrs["interval"] = float(np.median(np.diff(time_values) / np.timedelta64(1, "s")))
    attrs["filename"] = name
    ds.attrs.update(attrs)
    return ds


def parse_float_fields(
    chars: NDArray[np.uint8], lineno: NDArray[np.int64], name: str, what: str, strip: bool = False
) -> NDArray[np.float64]:
    """Decode fixed-width number fields ``(n, width)`` one conversion per field.

    A field that is not a number raises :class:`RinexFormatError` naming the file, ``what``
    was expected and the line (``lineno[i]`` of field ``i``).
    """
    text = np.ascontiguousarray(chars).view(f"S{chars.shape[1]}").ravel()
    try:
        return text.astype(np.float64)
    except ValueError:
        for i, t in enumerate(text):
            try:
                float(t)
            except ValueError:
                shown = t.decode("ascii", "replace")
                raise RinexFormatError(
                    f"{name}: bad {what} {(shown.strip() if strip else shown)!r} on line {int(lineno[i])}"
                ) from None
        raise  # pragma: no cover - astype failed but every field parses alone
