"""Compact RINEX 3 (CRINEX 3.0, Hatanaka) observation bodies decoded straight into arrays.

A 24 h, 30 s multi-GNSS ``.crx`` file takes ``crx2rnx`` about 0.45 s of CPU to expand into 33 MB
of RINEX text, which the fixed-width reader then parses again (0.12 s). Here the compressed
records are decoded with numpy (about 0.2 s for the codes gnss-solve reads), and only the
observation codes asked for are restored. The result is the text reader's, bit for bit
(``tests/io/test_crinex3.py``: random files through ``rnx2crx``, the shared real files, and
damaged files).

The format (Hatanaka, Y., 2008: A Compression Format and Tools for GNSS Observation Data,
Bulletin of the GSI 55; the RNXCMP documentation):

* two ``CRINEX`` lines, then the RINEX header as it is;
* per epoch: the epoch line as a text difference from the previous one (an unchanged character
  is a blank, a character blanked is ``&``; a line beginning with ``>`` is given in full and
  starts every arc anew), whose column 41 onwards lists the epoch's satellites; a receiver-clock
  line; one line per satellite, in that order;
* a satellite line (no id: the list gives it) holds one field per observation type of its
  system, separated by one blank, then the text difference of its loss-of-lock /
  signal-strength characters. A field is empty (no observation), ``M&N`` (an arc of difference
  order ``M`` starts with the value ``N``) or ``N``, the ``min(k, M)``-th difference of the
  value, ``k`` observations into the arc. Values are integers in units of 1e-3;
* lines starting with ``&`` before an epoch are escape lines (skipped).

Anything else is left to ``crx2rnx``: :func:`decode_body` raises :class:`Unsupported` and the
caller expands the file instead, so that damaged files get the reference program's messages.
That covers event records, and every structural fault ``crx2rnx`` stops at, in every field of
every system, read or not: a character other than digits, ``-`` and ``&`` in a field, an arc
that goes on without a start, a difference order above 5, flags that do not cover a new
satellite's fields, an epoch line that does not restore to an epoch, a cut last line. Values
beyond an F14.3 field are caught in the codes that are read (the text reader, too, checks only
the fields it decodes).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from gnss_cli.io.fixed_width import SPACE, lli_name, parse_lli, split_lines

__all__ = ["Unsupported", "Records", "crinex3_rinex_part", "decode_body"]

_SV_COL = 41
"""First column of the satellite list on a CRINEX 3 epoch line."""
_EPOCH_WIDTH = 35
"""Columns of an epoch line up to the satellite count (``> yyyy mm dd hh mm ss.sssssss  f nnn``)."""
_MAX_DIGITS = 18
"""Digits of one field at most (int64 holds 10**18)."""
_F14_3_LIMIT = 10**13
"""Values in units of 1e-3 that fill an F14.3 field: ``-10**12 < N < 10**13`` (crx2rnx stops beyond)."""
_AMP = ord("&")
_FIELD_CHARS = np.zeros(256, dtype=bool)
_FIELD_CHARS[[*b"0123456789-& "]] = True
_MINUS = ord("-")
_CHANGED = re.compile(rb"[^ ]+")


class Unsupported(Exception):
    """The body holds something this decoder leaves to ``crx2rnx`` (the reason is the message)."""


def crinex3_rinex_part(content: bytes) -> bytes | None:
    """The RINEX header and the compressed body of CRINEX 3.0 ``content`` (its two ``CRINEX``
    lines cut off), or None when ``content`` is not CRINEX 3.0."""
    first = content[:160].split(b"\n", 1)[0]
    if not (first.startswith(b"3.0") and b"CRINEX VERS" in first[60:]):
        return None
    second_end = content.find(b"\n", len(first) + 1)
    return None if second_end < 0 else content[second_end + 1:]


@dataclass
class Records:
    """The decoded epochs and satellite records of a body.

    Attributes
    ----------
    epoch_chars : ``(n_epochs, 35)`` uint8, the restored epoch lines up to the satellite count.
    epoch_line : ``(n_epochs,)`` int64, 0-based line of each epoch line in the body.
    sv_chars : ``(n_records, 3)`` uint8, the satellite id of each record.
    record_epoch : ``(n_records,)`` int64, the epoch of each record.
    values : ``(code, rows, values)`` per system and code: the records of the system (indices
        into the records) and their values (float64; m, cycles, Hz or dB-Hz; NaN where empty); for the
        names ``lli_name(code)`` the loss-of-lock indicators (NaN where the value is empty).
    """

    epoch_chars: NDArray[np.uint8]
    epoch_line: NDArray[np.int64]
    sv_chars: NDArray[np.uint8]
    record_epoch: NDArray[np.int64]
    values: list[tuple[str, NDArray[np.int64], NDArray[np.float64]]] = field(default_factory=list)


def _repair(old: bytes, diff: bytes) -> bytes:
    """``old`` changed by the text difference ``diff`` (blank: kept; ``&``: blanked), trailing blanks cut."""
    out = bytearray(old.ljust(len(diff)))
    for m in _CHANGED.finditer(diff):
        out[m.start():m.end()] = m.group().replace(b"&", b" ")
    return bytes(out).rstrip(b" ")


def _epochs(text: bytes, starts: list[int], lengths: list[int]) -> tuple[list[bytes], list[int], list[bytes], list[bool]]:
    """Walk the epoch records: restored epoch lines, their line indices, satellite lists and
    whether each was given in full (arcs restart)."""
    lines, where, sats, full = [], [], [], []
    line = b""
    n, i = len(starts), 0
    while i < n:
        d = text[starts[i]:starts[i] + lengths[i]]
        if d[:1] == b"&":
            i += 1
            continue
        if not d:
            if any(lengths[i:]):
                raise Unsupported(f"blank line {i + 1} where an epoch line was expected")
            break
        if d[:1] == b">":
            if d[31:32] not in (b"0", b"1"):
                raise Unsupported(f"event record on line {i + 1}")
            line = b""
        line = _repair(line, d)
        if (len(line) < _EPOCH_WIDTH or line[:1] != b">" or line[29:31] != b"  " or not line[31:32].isdigit()
                or line[_EPOCH_WIDTH:_SV_COL].strip()):
            raise Unsupported(f"epoch line {i + 1} does not restore to an epoch")
        if not line[32:35].strip().isdigit():
            raise Unsupported(f"epoch line {i + 1}: no satellite count")
        nsat = int(line[32:35])
        listed = line[_SV_COL:_SV_COL + 3 * nsat]
        if len(listed) != 3 * nsat or i + 1 + nsat >= n:
            raise Unsupported(f"epoch line {i + 1}: satellite list or records incomplete")
        lines.append(line[:_EPOCH_WIDTH].ljust(_EPOCH_WIDTH))
        where.append(i)
        sats.append(listed)
        full.append(d[:1] == b">")
        i += 2 + nsat
    if not lines:
        raise Unsupported("no epoch")
    return lines, where, sats, full


def _fields(spaces: NDArray[np.int64], first: NDArray[np.int64], count: NDArray[np.int64], start: NDArray[np.int64],
            end: NDArray[np.int64], j: int) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Start and end (exclusive) of the ``j``-th blank-separated field of the lines ``[start, end)``
    whose blanks are ``spaces[first : first + count]`` (start == end: empty)."""
    last = spaces.size - 1
    s = start if j == 0 else np.where(j - 1 < count, spaces[np.minimum(first + j - 1, last)] + 1, end)
    e = np.where(j < count, spaces[np.minimum(first + j, last)], end)
    return s, e


def _integers(buf: NDArray[np.uint8], s: NDArray[np.int64], e: NDArray[np.int64]) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Decode non-empty fields ``[M&][-]digits``: the integers and the arc orders (-1: no ``M&``)."""
    init = (e - s >= 3) & (buf[s + 1] == _AMP)
    order = np.where(init, buf[s].astype(np.int64) - 48, -1)
    if np.any(init & ((order < 0) | (order > 9))):
        raise Unsupported("bad arc order")
    num = s + 2 * init
    neg = buf[num] == _MINUS
    first = num + neg
    length = e - first
    if np.any((length < 1) | (length > _MAX_DIGITS)):
        raise Unsupported("a field without digits or with too many")
    width = int(length.max())
    idx = e[:, None] - width + np.arange(width)
    inside = idx >= first[:, None]
    digit = buf[np.maximum(idx, 0)] - np.uint8(48)
    if np.any(inside & (digit > 9)):
        raise Unsupported("a field that is not an integer")
    value = np.where(inside, digit, 0).astype(np.int64) @ (10 ** np.arange(width - 1, -1, -1, dtype=np.int64))
    return np.where(neg, -value, value), order


def _undifference(given: NDArray[np.int64], arc_start: NDArray[np.bool_], order: NDArray[np.int64]) -> NDArray[np.int64]:
    """Values from their differences: ``given[k]`` is the ``min(k, M)``-th difference ``k`` steps into its
    arc (arcs start where ``arc_start``; ``order`` is each arc's M at its start). Level by level, the
    entries from ``M - 1`` steps in are cumulative sums within the arc (int64 wrap-around cancels)."""
    arc = np.cumsum(arc_start) - 1
    starts = np.flatnonzero(arc_start)
    pos = np.arange(given.size) - starts[arc]
    m = order[starts][arc]
    y = given.copy()
    for level in range(int(m.max()), 0, -1):
        sel = (pos >= level - 1) & (m >= level)
        c = np.cumsum(np.where(sel, y, 0))
        before = np.concatenate(([0], c))[starts][arc]
        y = np.where(sel, c - before, y)
    return y


def _runs(sv: NDArray[np.int64], epoch: NDArray[np.int64], full: NDArray[np.bool_]) -> tuple[NDArray[np.int64], NDArray[np.bool_]]:
    """Order of the records by satellite (then epoch) and where a run of consecutive epochs of the
    same satellite starts in that order (a satellite missing at the epoch before, or a full epoch line)."""
    order = np.argsort(sv, kind="stable")
    s, e = sv[order], epoch[order]
    start = np.ones(order.size, dtype=bool)
    start[1:] = (s[1:] != s[:-1]) | (e[1:] != e[:-1] + 1)
    start |= full[e]
    return order, start


def _code_values(buf: NDArray[np.uint8], s: NDArray[np.int64], e: NDArray[np.int64], sv: NDArray[np.int64],
                 epoch: NDArray[np.int64], full: NDArray[np.bool_]) -> NDArray[np.float64]:
    """One code's values of the records whose fields are ``[s, e)``; NaN where empty."""
    out = np.full(s.size, np.nan)
    has = np.flatnonzero(e > s)
    if has.size == 0:
        return out
    given, arc_order = _integers(buf, s[has], e[has])
    order, run_start = _runs(sv[has], epoch[has], full)
    arc_start = arc_order[order] >= 0
    if np.any(run_start & ~arc_start):
        raise Unsupported("an arc continues across a gap without a new start")
    restored = _undifference(given[order], arc_start, arc_order[order])
    if np.any((restored >= _F14_3_LIMIT) | (restored <= -_F14_3_LIMIT // 10)):
        raise Unsupported("a value beyond the RINEX F14.3 field")
    out[has[order]] = restored / 1000.0
    return out


def _check_structure(buf: NDArray[np.uint8], odd: NDArray[np.int64], line: tuple[NDArray[np.int64], ...], n_types: int,
                     sv: NDArray[np.int64], epoch: NDArray[np.int64], full: NDArray[np.bool_]) -> None:
    """Every field of a system's records, read or not, as ``crx2rnx`` would accept it: only digits,
    ``-`` and ``M&`` (M <= 5) before the flags, flags for every field where a satellite's run of
    epochs starts, and no arc that goes on without a start (after an empty field, a missing
    satellite or an epoch line given in full); ``odd``: where the body holds
    other characters. Raises :class:`Unsupported`."""
    start, flags = line[3], _fields(*line, n_types)[0]
    if np.any(np.searchsorted(odd, start) != np.searchsorted(odd, flags)):
        raise Unsupported("a character other than digits, '-' and '&' in a field")
    bounds = [_fields(*line, j) for j in range(n_types)]
    s = np.stack([b[0] for b in bounds], axis=1)
    filled = np.stack([b[1] for b in bounds], axis=1) > s
    starts_arc = filled & (buf[s + 1] == _AMP)
    if np.any(starts_arc & (buf[s] > ord("5"))):
        raise Unsupported("a difference order above 5")
    order, run_start = _runs(sv, epoch, full)
    if np.any(line[4][order[run_start]] - flags[order[run_start]] < 2 * n_types):
        raise Unsupported("a satellite's first flags do not cover its fields (crx2rnx would print NULs)")
    before = np.zeros_like(filled)
    before[order[1:]] = filled[order[:-1]] & ~run_start[1:, None]
    if np.any(filled & ~starts_arc & ~before):
        raise Unsupported("an arc goes on without a start")


def _lli(buf: NDArray[np.uint8], flag_start: NDArray[np.int64], end: NDArray[np.int64], j: int, sv: NDArray[np.int64],
         epoch: NDArray[np.int64], full: NDArray[np.bool_]) -> NDArray[np.float64]:
    """Loss-of-lock indicators of field ``j``: its flag character restored through each satellite's run."""
    at = flag_start + 2 * j
    char = np.where(at < end, buf[np.minimum(at, buf.size - 1)], np.uint8(SPACE))
    order, run_start = _runs(sv, epoch, full)
    c = char[order]
    mark = (c != SPACE) | run_start
    last = np.maximum.accumulate(np.where(mark, np.arange(c.size), 0))
    restored = np.where(c[last] == _AMP, np.uint8(SPACE), c[last])
    out = np.empty(c.size)
    out[order] = parse_lli(restored[:, None])
    return out


def decode_body(body: bytes, n_types: dict[str, int], chosen: dict[str, list[tuple[int, str]]],
                lli_codes: set[str]) -> Records:
    """Decode a CRINEX 3 body (after ``END OF HEADER``).

    Parameters
    ----------
    body : bytes
        The compressed records.
    n_types : dict
        System letter -> number of observation types (header ``SYS / # / OBS TYPES``).
    chosen : dict
        System letter -> ``(field index, code)`` pairs to restore.
    lli_codes : set of str
        Codes whose loss-of-lock indicators are wanted too (as ``lli_name(code)``).

    Raises
    ------
    Unsupported
        Event records, an arc not started where it must be, a damaged field or epoch line, a
        system of the satellite list without observation types: decode with ``crx2rnx``.
    """
    if body and not body.endswith(b"\n"):
        raise Unsupported("the last line is cut (no line end)")
    buf, starts_a, lengths_a = split_lines(body)
    text = body if b"\r" not in body else body.replace(b"\r", b"")
    lines, where, sats, full_list = _epochs(text, starts_a.tolist(), lengths_a.tolist())
    nsat = np.array([len(s) // 3 for s in sats], dtype=np.int64)
    first = np.asarray(where, dtype=np.int64) + 2
    record_epoch = np.repeat(np.arange(nsat.size), nsat)
    record_line = first[record_epoch] + np.arange(record_epoch.size) - np.repeat(np.cumsum(nsat) - nsat, nsat)
    sv_chars = np.frombuffer(b"".join(sats), dtype=np.uint8).reshape(-1, 3)
    records = Records(np.frombuffer(b"".join(lines), dtype=np.uint8).reshape(-1, _EPOCH_WIDTH),
                      np.asarray(where, dtype=np.int64), sv_chars, record_epoch)
    unknown = set(np.unique(sv_chars[:, 0]).tobytes().decode("ascii", "replace")) - set(n_types)
    if unknown:
        raise Unsupported(f"satellites of systems without observation types: {''.join(sorted(unknown))}")
    full = np.asarray(full_list)
    spaces = np.flatnonzero(buf[:len(text)] == SPACE)
    line_start = starts_a[record_line]
    line_end = line_start + lengths_a[record_line]
    first_space = np.searchsorted(spaces, line_start)
    n_spaces = np.searchsorted(spaces, line_end) - first_space
    odd = np.flatnonzero(~_FIELD_CHARS[buf])
    sv = sv_chars.astype(np.int64) @ np.array([1 << 16, 1 << 8, 1], dtype=np.int64)
    for sys_char, n in n_types.items():  # every system checked, read or not, as crx2rnx checks them
        rows = np.flatnonzero(sv_chars[:, 0] == ord(sys_char))
        if rows.size == 0:
            continue
        line = (spaces, first_space[rows], n_spaces[rows], line_start[rows], line_end[rows])
        _check_structure(buf, odd, line, n, sv[rows], record_epoch[rows], full)
        pairs = chosen.get(sys_char, [])
        end = line[-1]
        flag_start = _fields(*line, n)[0] if lli_codes else None
        for j, code in pairs:
            s, e = _fields(*line, j)
            values = _code_values(buf, s, e, sv[rows], record_epoch[rows], full)
            records.values.append((code, rows, values))
            if code in lli_codes and flag_start is not None:
                lli = _lli(buf, flag_start, end, j, sv[rows], record_epoch[rows], full)
                records.values.append((lli_name(code), rows, np.where(np.isfinite(values), lli, np.nan)))
    return records
