"""Fast vectorized reader for RINEX 3.0x and 4.0x observation files.

The whole decompressed file is held as one ``uint8`` buffer. Line boundaries, epoch lines
(``>``), satellite ids and the fixed-width 16-character observation fields
(``F14.3`` value, loss-of-lock and signal-strength digits) are located and decoded with
numpy over all lines at once; there is no Python object per observation. The result has
the layout of ``georinex.load(path, use=systems, meas=codes)`` so the two readers are
interchangeable (and compared in the tests).

The header is decoded in :mod:`gnss_cli.io.rinex3_header`, the fixed-width fields with the
primitives of :mod:`gnss_cli.io.fixed_width` that the navigation reader shares. Compact RINEX 3
is decoded from its compressed records (:mod:`gnss_cli.io.crinex3`) into the same dataset.

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

from gnss_cli.errors import RinexFormatError
from gnss_cli.io.fixed_width import (
    DIGIT0,
    DOT,
    PAD,
    SPACE,
    civil2datetime64,
    civil_ranges_ok,
    gather_columns,
    lli_name,
    wants_lli,
    parse_f14_3,
    parse_float_fields,
    parse_lli,
    parse_uint_columns,
    parse_uint_fields,
    split_lines,
    sv_codes2str,
)
from gnss_cli.io.obs_checks import check_epochs_increasing, check_last_value_complete
from gnss_cli.io.compression import expand_crinex, open_bytes
from gnss_cli.io.crinex3 import Unsupported, crinex3_rinex_part, decode_body
from gnss_cli.io.rinex3_header import (
    SYSTEM_CHARS, header_end, read_header, read_obs_header, select_codes, validate_selection,
)

__all__ = ["read_obs3", "parse_obs3"]

_FIELD_WIDTH = 16
"""Width of one observation (F14.3 value + LLI + SSI), characters."""
_VALUE_WIDTH = 14
_SV_WIDTH = 3
_EPOCH_TIME_SPANS = ((2, 6), (7, 9), (10, 12), (13, 15), (16, 18), (18, 21), (22, 29))
"""Columns of year, month, day, hour, minute, second and 1e-7 s fraction on an epoch line."""


def _epoch_times(
    ep_chars: NDArray[np.uint8], ep_lineno: NDArray[np.int64], name: str
) -> tuple[NDArray[np.datetime64], NDArray[np.int64], NDArray[np.int64]]:
    """Decode epoch lines ``> yyyy mm dd hh mm ss.sssssss  f nnn``.

    Returns times (datetime64[ns]), epoch flags and satellite counts, shape (n_epochs,).
    """
    (year, month, day, hour, minute, sec, frac), ok_time = parse_uint_fields(ep_chars, _EPOCH_TIME_SPANS)
    flag, ok_fl = parse_uint_columns(ep_chars[:, 31:32])
    nsat, ok_n = parse_uint_columns(ep_chars[:, 32:35])
    ok = (
        ok_time & ok_fl & ok_n & (ep_chars[:, 1] == SPACE) & (ep_chars[:, 21] == DOT)
        & civil_ranges_ok(month, day, hour, minute, sec) & (flag <= 6)
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
    c1 = np.where(sv_chars[:, 1] == SPACE, DIGIT0, sv_chars[:, 1]).astype(np.int64)
    c2 = sv_chars[:, 2].astype(np.int64)
    known = np.isin(c0, np.frombuffer(SYSTEM_CHARS.encode(), dtype=np.uint8))
    ok = known & (c1 >= DIGIT0) & (c1 <= DIGIT0 + 9) & (c2 >= DIGIT0) & (c2 <= DIGIT0 + 9)
    return (c0 << 16) | (c1 << 8) | c2, ok


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
        header order); ``unlisted_systems`` (str of system letters) when the body holds
        records of systems the header gives no observation types for (they are not read).

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
    sorting; event epochs (flag 2-6) and their special records are skipped; an epoch that
    is not later than the one before it (the same epoch twice, a re-stamped epoch) is an
    error, as is a file cut inside its last value. Loss-of-lock indicators are read for the
    phase codes ``codes`` asks them for (``L1Clli``); signal-strength indicators are not read.
    Compact RINEX 3 is decoded directly (:mod:`gnss_cli.io.crinex3`, the same dataset as from
    its ``crx2rnx`` text), unless :func:`~gnss_cli.io.compression.prefetch` expanded it already.

    Examples
    --------
    The simulated sample of the repository (run from its root):

    >>> obs = read_obs3("sample_rinex/static/obs.rnx", pseudorange_only=True)
    >>> dict(obs.sizes)
    {'time': 121, 'sv': 24}
    >>> float(obs["C1C"].sel(sv="G02").values[0])
    21534747.83
    """
    validate_selection(systems, codes)
    content = open_bytes(path, keep_crinex3=True)
    part = crinex3_rinex_part(content)
    if part is not None:  # CRINEX 3: decoded directly, or by crx2rnx when it holds what only that reads
        name, hdr_end = Path(path).name, header_end(part, Path(path).name)
        crinex = parse_crinex3(name, part[:hdr_end].decode("ascii", "replace"), part[hdr_end:], systems, codes,
                               pseudorange_only)
        if crinex is not None:
            return crinex
        content = expand_crinex(content, name)
    name, content, hdr_end, header = read_header(path, content)
    return parse_obs3(name, header, content[hdr_end:], systems, codes, pseudorange_only=pseudorange_only)


def parse_obs3(
    name: str,
    header: str,
    body: bytes,
    systems: Sequence[str] | None = None,
    codes: Sequence[str] | None = None,
    *,
    pseudorange_only: bool = False,
    lines_before: int | None = None,
) -> xarray.Dataset:
    """:func:`read_obs3` of a header text and a body of whole epoch records (the file, or a run
    of its epochs: :mod:`gnss_cli.io.obs_chunks`). ``lines_before``: file lines before
    ``body`` (default: the header's), so that error messages name the file's line numbers."""
    systems, codes = validate_selection(systems, codes)
    attrs, obs_types = read_obs_header(header, name)
    chosen = select_codes(obs_types, systems, codes, pseudorange_only)
    if not chosen:
        raise RinexFormatError(
            f"{name}: none of the systems {systems} in the file (it has {''.join(obs_types)})"
        )
    lines = _body_lines(body, header.count("\n") if lines_before is None else lines_before)
    owner, times = _epochs(lines, name)
    data_idx, sv_code, sys_code, unlisted = _data_lines(lines, owner, times.flag, chosen, obs_types, name)
    if unlisted:
        attrs["unlisted_systems"] = unlisted
    _check_record_lengths(lines, data_idx, sys_code, obs_types, name)
    cells = _Cells(times.time[owner[data_idx]], sv_code)
    variables = _decode_values(lines, data_idx, sys_code, cells.flat, cells.size, chosen, name, codes)
    return _dataset(variables, cells.time_values, cells.sv_values, attrs, name)


class _Cells:
    """The ``(time, sv)`` axes of records at ``times`` of satellites ``sv_code`` and each record's flat cell."""

    def __init__(self, times: NDArray[np.datetime64], sv_code: NDArray[np.int64]) -> None:
        self.time_values, time_of = np.unique(times, return_inverse=True)
        self.sv_values, sv_of = np.unique(sv_code, return_inverse=True)
        self.flat = time_of * self.sv_values.size + sv_of
        self.size = self.time_values.size * self.sv_values.size


def parse_crinex3(
    name: str, header: str, body: bytes, systems: Sequence[str] | None, codes: Sequence[str] | None,
    pseudorange_only: bool = False,
) -> xarray.Dataset | None:
    """:func:`parse_obs3` of a CRINEX 3 ``body`` (:mod:`gnss_cli.io.crinex3`), the same dataset as
    :func:`parse_obs3` of the ``crx2rnx`` text; None where the body needs ``crx2rnx`` (events,
    damage: its messages name the problem) or would give an error message."""
    systems, codes = validate_selection(systems, codes)
    attrs, obs_types = read_obs_header(header, name)
    chosen = select_codes(obs_types, systems, codes, pseudorange_only)
    try:
        rec = decode_body(body, {k: len(v) for k, v in obs_types.items()}, chosen,
                          {c for pairs in chosen.values() for _, c in pairs if wants_lli(c, codes)})
        times = _epoch_times(rec.epoch_chars, rec.epoch_line, name)[0]  # (event records went to crx2rnx)
        check_epochs_increasing(times, rec.epoch_line, name)
    except (Unsupported, RinexFormatError):
        return None
    sv_code, sv_ok = _sv_codes(rec.sv_chars)
    keep = np.isin(rec.sv_chars[:, 0], np.frombuffer("".join(chosen).encode(), dtype=np.uint8))
    if not chosen or not np.all(sv_ok) or not np.any(keep):
        return None
    cells = _Cells(times[rec.record_epoch[keep]], sv_code[keep])
    cell_of = np.full(keep.size, -1)
    cell_of[keep] = cells.flat
    variables: dict[str, NDArray[np.float64]] = {}
    for code, rows, values in rec.values:
        variables.setdefault(code, np.full(cells.size, np.nan))[cell_of[rows]] = values
    return _dataset(variables, cells.time_values, cells.sv_values, attrs, name)


class _Lines:
    """The body as one byte buffer: line starts, lengths, first characters and file line numbers."""

    __slots__ = ("buf", "starts", "lengths", "first_char", "lineno")

    def __init__(self, buf: NDArray[np.uint8], starts: NDArray[np.int64], lengths: NDArray[np.int64],
                 first_char: NDArray[np.uint8], lineno: NDArray[np.int64]):
        self.buf = buf
        self.starts = starts
        self.lengths = lengths
        self.first_char = first_char
        self.lineno = lineno

    def columns(self, idx: NDArray[np.int64], first_col: int, width: int) -> NDArray[np.uint8]:
        """The columns ``first_col .. first_col + width`` of the lines ``idx``, blank padded."""
        return gather_columns(self.buf, self.starts[idx], self.lengths[idx], first_col, width)


class _EpochLines:
    """Decoded epoch lines: times, flags and satellite counts, shape (n_epochs,)."""

    __slots__ = ("time", "flag", "nsat")

    def __init__(self, time: NDArray[np.datetime64], flag: NDArray[np.int64], nsat: NDArray[np.int64]):
        self.time = time
        self.flag = flag
        self.nsat = nsat


def _body_lines(body: bytes, n_header_lines: int) -> _Lines:
    """Split the body into lines, dropping trailing blank lines (they are harmless)."""
    buf, starts, lengths = split_lines(body)
    nonblank = lengths > 0
    first_char = np.where(nonblank, buf[starts], np.uint8(SPACE))
    last = np.flatnonzero(first_char != SPACE)
    n_lines = int(last[-1]) + 1 if last.size else 0
    starts, lengths, first_char = starts[:n_lines], lengths[:n_lines], first_char[:n_lines]
    lineno = np.arange(n_lines, dtype=np.int64) + n_header_lines + 1
    return _Lines(buf, starts, lengths, first_char, lineno)


def _epochs(lines: _Lines, name: str) -> tuple[NDArray[np.int64], _EpochLines]:
    """Epoch index of each line (-1 before the first) and the decoded epoch lines.

    Raises when there is no epoch line, text precedes the first one, an epoch announces
    another number of satellite lines than follow it, or an observation epoch (flag 0/1) is
    not later than the one before it.
    """
    n_lines = lines.starts.size
    is_epoch = lines.first_char == ord(">")
    ep_idx = np.flatnonzero(is_epoch)
    if ep_idx.size == 0:
        raise RinexFormatError(f"{name}: no observation records (no epoch line '>' after the header)")
    if ep_idx[0] != 0:
        stray = np.flatnonzero(lines.lengths[: ep_idx[0]] > 0)
        if stray.size:
            raise RinexFormatError(
                f"{name}: unexpected text on line {int(lines.lineno[stray[0]])} before the first epoch line"
            )
    ep_chars = lines.columns(ep_idx, 0, 35)
    times, flag, nsat = _epoch_times(ep_chars, lines.lineno[ep_idx], name)
    follow = np.diff(np.concatenate((ep_idx, [n_lines]))) - 1
    mismatch = follow != nsat
    if np.any(mismatch):
        i = int(np.flatnonzero(mismatch)[0])
        raise RinexFormatError(
            f"{name}: bad epoch line {int(lines.lineno[ep_idx[i]])}: it announces {int(nsat[i])} "
            f"records but {int(follow[i])} lines follow"
        )
    observed = flag <= 1
    check_epochs_increasing(times[observed], lines.lineno[ep_idx][observed], name)
    last = n_lines - 1
    if lines.buf[lines.starts[last] + lines.lengths[last]] != ord("\n") and not is_epoch[last]:
        check_last_value_complete(int(lines.lengths[last]), _SV_WIDTH, int(lines.lineno[last]), name)
    return np.cumsum(is_epoch) - 1, _EpochLines(times, flag, nsat)


def _data_lines(
    lines: _Lines, owner: NDArray[np.int64], flag: NDArray[np.int64], chosen: dict[str, list[tuple[int, str]]],
    obs_types: dict[str, list[str]], name: str,
) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.uint8], str]:
    """Observation lines of ordinary epochs (flag 0/1) of the chosen systems: line index, sv code,
    system; and the letters of the systems with records but no observation types in the header."""
    is_epoch = lines.first_char == ord(">")
    is_obs_epoch = flag <= 1
    is_data = ~is_epoch & (owner >= 0)
    is_data &= is_obs_epoch[np.maximum(owner, 0)]
    data_idx = np.flatnonzero(is_data)
    sv_chars = lines.columns(data_idx, 0, _SV_WIDTH)
    sv_code, sv_ok = _sv_codes(sv_chars)
    if not np.all(sv_ok):
        i = int(np.flatnonzero(~sv_ok)[0])
        raise RinexFormatError(
            f"{name}: bad satellite id {sv_chars[i].tobytes().decode('ascii', 'replace')!r} "
            f"on line {int(lines.lineno[data_idx[i]])}"
        )
    sys_code = sv_chars[:, 0]
    unlisted = "".join(sorted(set(bytes(np.unique(sys_code)).decode("ascii")) - set(obs_types)))
    keep = np.isin(sys_code, np.frombuffer("".join(chosen).encode(), dtype=np.uint8))
    data_idx, sv_code, sys_code = data_idx[keep], sv_code[keep], sys_code[keep]
    if data_idx.size == 0:
        raise RinexFormatError(f"{name}: no observation records of the systems {''.join(chosen)}")
    return data_idx, sv_code, sys_code, unlisted


def _check_record_lengths(lines: _Lines, data_idx: NDArray[np.int64], sys_code: NDArray[np.uint8],
                          obs_types: dict[str, list[str]], name: str) -> None:
    """Raise when an observation line holds more fields than its system's header types."""
    n_types = np.zeros(256, dtype=np.int64)
    for sys_char, types in obs_types.items():
        n_types[ord(sys_char)] = len(types)
    used = _SV_WIDTH + _FIELD_WIDTH * n_types[sys_code]
    long = np.flatnonzero(lines.lengths[data_idx] > used)
    if long.size == 0:
        return
    width = int(min(PAD, np.max(lines.lengths[data_idx[long]] - used[long])))
    tail = lines.columns(data_idx[long], used[long], width)
    bad = np.flatnonzero(np.any(tail != SPACE, axis=1))
    if bad.size:
        i = long[bad[0]]
        sys_char = chr(int(sys_code[i]))
        raise RinexFormatError(
            f"{name}: line {int(lines.lineno[data_idx[i]])}: more observations than the {int(n_types[sys_code[i]])} "
            f"of the header's 'SYS / # / OBS TYPES' for system {sys_char}"
        )


def _decode_values(
    lines: _Lines, data_idx: NDArray[np.int64], sys_code: NDArray[np.uint8], flat: NDArray[np.int64], size: int,
    chosen: dict[str, list[tuple[int, str]]], name: str, codes: Sequence[str] | None = None,
) -> dict[str, NDArray[np.float64]]:
    """One flat ``(time * sv)`` array per chosen code, NaN where missing; ``flat`` is each line's cell.
    The loss-of-lock indicators of the phase codes that ``codes`` asks them for (``L1Clli``:
    :func:`~gnss_cli.io.fixed_width.wants_lli`), NaN where there is no phase."""
    variables: dict[str, NDArray[np.float64]] = {}
    for sys_char, pairs in chosen.items():
        rows = np.flatnonzero(sys_code == ord(sys_char))
        if rows.size == 0:
            continue
        for k, code in pairs:
            chars = lines.columns(data_idx[rows], _SV_WIDTH + _FIELD_WIDTH * k, _VALUE_WIDTH)
            values, odd = parse_f14_3(chars)
            if np.any(odd):
                values[odd] = parse_float_fields(
                    chars[odd], lines.lineno[data_idx[rows[odd]]], name, f"{code} value"
                )
            if code not in variables:
                variables[code] = np.full(size, np.nan)
            variables[code][flat[rows]] = values
            if wants_lli(code, codes):  # carrier phase: its loss-of-lock indicator, NaN where no phase
                lli = lines.columns(data_idx[rows], _SV_WIDTH + _FIELD_WIDTH * k + _VALUE_WIDTH, 1)
                variables.setdefault(lli_name(code), np.full(size, np.nan))[flat[rows]] = np.where(
                    np.isfinite(values), parse_lli(lli), np.nan)
    return variables


def _dataset(
    variables: dict[str, NDArray[np.float64]], time_values: NDArray[np.datetime64], sv_values: NDArray[np.int64],
    attrs: dict[str, Any], name: str,
) -> xarray.Dataset:
    """The ``(time, sv)`` dataset with the header attributes, ``interval`` and ``filename``."""
    n_t, n_sv = time_values.size, sv_values.size
    data_vars = {code: (("time", "sv"), arr.reshape(n_t, n_sv)) for code, arr in variables.items()}
    ds = xarray.Dataset(data_vars, coords={"time": time_values, "sv": sv_codes2str(sv_values)})
    if "interval" not in attrs and n_t > 1:
        attrs["interval"] = float(np.median(np.diff(time_values) / np.timedelta64(1, "s")))
    attrs["filename"] = name
    ds.attrs.update(attrs)
    return ds
