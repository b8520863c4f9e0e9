"""Fixed-width text grids shared by the RINEX 3/4 observation and navigation readers.

A decompressed file body is held as one ``uint8`` buffer (:func:`split_lines`); the same column
range of many lines is cut out as a character grid (:func:`gather_columns`) and decoded with
numpy over all lines at once (:func:`parse_uint_columns`, :func:`parse_f14_3`,
:func:`parse_float_fields`, :func:`civil2datetime64`). Satellite ids travel as integer codes
``(system << 16) | (tens << 8) | units`` (:func:`sv_codes2str`).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from gnss_cli.errors import RinexFormatError, UsageError

__all__ = [
    "split_lines", "gather_columns", "parse_uint_columns", "parse_uint_fields", "civil_ranges_ok",
    "civil2datetime64", "parse_f14_3", "parse_float_fields", "sv_codes2str", "parse_decimal_ns", "days_in_month",
    "parse_lli", "lli_name", "wants_lli",
]

SPACE = 32
DIGIT0 = 48
MINUS = 45
DOT = 46

PAD = 512
"""Blanks appended to the text buffer, >= the widest column range ever cut."""

# F14.3: ten integer characters (sign and digits), the point, three decimals.
# Integer value in units of 1e-3 = sum(digit_j * weight_j); exact in float64 (< 2**53).
_F14_WEIGHTS = np.array([10.0 ** (12 - j) for j in range(10)] + [0.0, 100.0, 10.0, 1.0])


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
    buf = np.concatenate((text, np.full(PAD, SPACE, dtype=np.uint8)))
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
    if width > PAD:
        raise UsageError(f"width: at most {PAD} columns, got {width}")
    first = np.broadcast_to(np.asarray(first_col, dtype=np.int64), starts.shape)
    # row i of the window view is buf[i : i + width]; one fancy index copies all rows
    windows = np.lib.stride_tricks.sliding_window_view(buf, width)
    rows = np.minimum(starts + first, windows.shape[0] - 1)
    chars = windows[rows]
    n_inside = np.clip(lengths - first, 0, width)
    short = np.flatnonzero(n_inside < width)  # lines that end inside the range
    if short.size:
        outside = np.arange(width) >= n_inside[short, None]
        chars[short] = np.where(outside, np.uint8(SPACE), chars[short])
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
    is_digit = (chars >= DIGIT0) & (chars <= DIGIT0 + 9)
    is_space = chars == SPACE
    # exactly one run of digits, blanks around it (trailing blanks occur in the wild
    # when a line is cut short, e.g. '  0 2' for flag 0 and 2 satellites)
    run_starts = np.count_nonzero(is_digit[:, 1:] & ~is_digit[:, :-1], axis=1) + is_digit[:, 0]
    ok = np.all(is_digit | is_space, axis=1) & (run_starts == 1)
    digits = np.where(is_digit, chars - DIGIT0, 0).astype(np.int64)
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
    digit = chars - np.uint8(DIGIT0)  # wraps around for characters below '0'
    is_digit = digit < 10
    is_minus = chars[:, :10] == MINUS
    n_minus = np.count_nonzero(is_minus, axis=1)
    n_space = np.count_nonzero(chars == SPACE, axis=1)
    # F14.3: blanks, at most one '-', digits; '.' in column 10; digits in columns 11-13
    standard = (
        (chars[:, 10] == DOT)
        & (np.count_nonzero(is_digit, axis=1) + n_space + n_minus == 13)
        & is_digit[:, 11:].all(axis=1)
        & (n_minus <= 1)
    )
    digits = np.where(is_digit, digit, np.uint8(0)).astype(np.float64)
    values = (digits @ _F14_WEIGHTS) / 1000.0
    np.negative(values, out=values, where=n_minus > 0)
    values[~standard] = np.nan
    return values, ~standard & (n_space < chars.shape[1])


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


def parse_uint_fields(
    chars: NDArray[np.uint8], spans: tuple[tuple[int, int], ...]
) -> tuple[list[NDArray[np.int64]], NDArray[np.bool_]]:
    """Decode the unsigned integer fields ``chars[:, a:b]`` for each ``(a, b)`` of ``spans``.

    Returns the values of each field (in the order of ``spans``) and one mask, true where
    every field of a line is a number.
    """
    values: list[NDArray[np.int64]] = []
    ok = np.ones(chars.shape[0], dtype=bool)
    for first, end in spans:
        v, ok_v = parse_uint_columns(chars[:, first:end])
        values.append(v)
        ok &= ok_v
    return values, ok


def civil_ranges_ok(
    month: NDArray[np.int64], day: NDArray[np.int64], hour: NDArray[np.int64], minute: NDArray[np.int64],
    sec: NDArray[np.int64],
) -> NDArray[np.bool_]:
    """True where a civil date and time of day lie in their ranges (a leap second allowed)."""
    return ((month >= 1) & (month <= 12) & (day >= 1) & (day <= 31) & (hour <= 23) & (minute <= 59)
            & (sec <= 60))  # fmt: skip


def days_in_month(year: NDArray[np.int64], month: NDArray[np.int64]) -> NDArray[np.int64]:
    """Number of days of each month (Gregorian calendar); 0 where ``month`` is not 1-12.

    >>> days_in_month(np.array([2000, 1900, 2005]), np.array([2, 2, 4])).tolist()
    [29, 28, 30]
    """
    leap = (year % 4 == 0) & ((year % 100 != 0) | (year % 400 == 0))
    table = np.array([0, 31, 28, 31, 30, 31, 30, 31, 31, 30, 31, 30, 31], dtype=np.int64)
    valid = (month >= 1) & (month <= 12)
    return np.where(valid, table[np.where(valid, month, 0)] + ((month == 2) & leap), 0)


def parse_decimal_ns(chars: NDArray[np.uint8]) -> tuple[NDArray[np.int64], NDArray[np.bool_]]:
    """Decode unsigned decimal seconds (``F5.1``, ``F11.7``, ...) into integer nanoseconds, exactly.

    Parameters
    ----------
    chars : numpy.ndarray of uint8, shape (n, width)
        One field per row: digits with at most one point, blanks around them.

    Returns
    -------
    ns : numpy.ndarray of int64, shape (n,)
        The value in nanoseconds (digits beyond the ninth decimal dropped); 0 where invalid.
    ok : numpy.ndarray of bool, shape (n,)
        False where the field is blank, is not one run of digits with at most one point,
        or is 1e9 s or more (beyond int64 nanoseconds arithmetic here).

    Notes
    -----
    Each digit is weighted by its integer power of ten in nanoseconds, so ``'59.9'`` gives
    59,900,000,000 ns; a binary float (``59.9 % 1 * 1e6``) would give 59.899999 s.

    >>> ns, ok = parse_decimal_ns(np.frombuffer(b" 59.9 44.0   12", dtype=np.uint8).reshape(3, 5))
    >>> ns.tolist(), ok.tolist()
    ([59900000000, 44000000000, 12000000000], [True, True, True])
    """
    is_digit = (chars >= DIGIT0) & (chars <= DIGIT0 + 9)
    is_dot = chars == DOT
    filled = chars != SPACE
    n_runs = np.count_nonzero(filled[:, 1:] & ~filled[:, :-1], axis=1) + filled[:, 0]
    ok = (np.all(is_digit | is_dot | ~filled, axis=1) & (n_runs == 1) & (np.count_nonzero(is_dot, axis=1) <= 1)
          & np.any(is_digit, axis=1))  # fmt: skip
    width = chars.shape[1]
    end_of_run = width - np.argmax(filled[:, ::-1], axis=1)
    point = np.where(np.any(is_dot, axis=1), np.argmax(is_dot, axis=1), end_of_run)
    col = np.arange(width)
    power = point[:, None] - col - (col < point[:, None])  # 10**power s: 0 for the units digit, -1 for tenths
    ok &= ~np.any(is_digit & (power > 8), axis=1)
    weight = np.where(power >= -9, 10 ** np.clip(power + 9, 0, 17), 0).astype(np.int64)
    ns = np.sum(np.where(is_digit, chars.astype(np.int64) - DIGIT0, 0) * weight, axis=1)
    return np.where(ok, ns, 0), ok


def sv_codes2str(codes: NDArray[np.int64]) -> NDArray[np.str_]:
    """Turn integer satellite codes ``(system << 16) | (tens << 8) | units`` into ``'<U3'`` ids."""
    chars = np.stack([(codes >> 16) & 255, (codes >> 8) & 255, codes & 255], axis=1).astype(np.uint8)
    return np.ascontiguousarray(chars).view("S3").ravel().astype("<U3")


def lli_name(code: str) -> str:
    """Name of the variable holding the loss-of-lock indicators of a phase code: ``L1C`` -> ``L1Clli``
    (georinex's name with ``useindicators=True``)."""
    return code + "lli"


def wants_lli(code: str, codes: object) -> bool:
    """Whether the loss-of-lock indicators of observation ``code`` are asked for: a phase code
    (``L...``) and ``codes`` (the readers' code prefixes; None = every code, without indicators)
    holds ``<prefix>lli`` for a prefix of it.

    >>> wants_lli("L1C", ["C1", "L1", "L1lli"]), wants_lli("L1C", ["L1"]), wants_lli("L1C", None)
    (True, False, False)
    """
    if not code.startswith("L") or codes is None:
        return False
    return any(str(p).endswith("lli") and code.startswith(str(p)[:-3]) for p in codes)  # type: ignore[attr-defined]


def parse_lli(chars: NDArray[np.uint8]) -> NDArray[np.float64]:
    """Loss-of-lock indicators from the one character after each F14.3 value (RINEX 2/3/4).

    Parameters
    ----------
    chars : ``(n, 1)`` uint8, the column after the value.

    Returns
    -------
    ``(n,)`` float64: the digit 0-7 (bit 0: lost lock before this observation, a possible cycle
    slip; bit 1: half-cycle ambiguity / opposite wavelength factor); 0 for a blank or any other
    character (RINEX: blank means "not known to be lost").

    >>> parse_lli(np.frombuffer(b"1 3x", dtype=np.uint8)[:, None]).tolist()
    [1.0, 0.0, 3.0, 0.0]
    """
    c = chars[:, 0].astype(np.int64) - DIGIT0
    return np.where((c >= 0) & (c <= 9), c, 0).astype(np.float64)
