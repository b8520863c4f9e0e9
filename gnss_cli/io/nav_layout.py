"""Where the records of a RINEX 3/4 navigation body are: one layout per format version.

RINEX 3: a record starts on each line whose first column is not blank. RINEX 4: ``> EPH G01
LNAV`` lines open typed records; the EPH types whose body has the RINEX 3 layout are kept
(:data:`RINEX4_EPH_TYPES`) and ION records of known types decoded on the way. The values of
the records are decoded in :mod:`gnss_cli.io.rinex3_nav`.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from gnss_cli.errors import RinexFormatError
from gnss_cli.io.fixed_width import SPACE

__all__ = ["Layout", "layout_v3", "layout_v4", "RINEX4_EPH_TYPES"]

_FIELD_WIDTH = 19

RINEX4_EPH_TYPES = {
    "G": {"LNAV"}, "J": {"LNAV"}, "I": {"LNAV"}, "E": {"INAV", "FNAV"},
    "C": {"D1", "D2"}, "R": {"FDMA"}, "S": {"SBAS"},
}  # fmt: skip
"""RINEX 4 EPH message types whose body has the RINEX 3 layout (read); others are skipped."""

_ION_ATTRS = {("G", "LNAV"): "ionospheric_corr_GPS", ("E", "IFNV"): "ionospheric_corr_GAL",
              ("C", "D1D2"): "ionospheric_corr_BDS", ("J", "LNAV"): "ionospheric_corr_QZS",
              ("I", "LNAV"): "ionospheric_corr_IRN"}  # fmt: skip
_ION_COUNTS = {"ionospheric_corr_GAL": 3}  # others: alpha0..3, beta0..3

Layout = tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int64], NDArray[np.int64]]
"""Body lines of the records, their ordinal in the record, their record number, each record's first line."""


def _stray_check(
    owner: NDArray[np.int64], head: NDArray[np.uint8], lineno: NDArray[np.int64], name: str
) -> None:
    """Refuse non-blank text between the header and the first record."""
    stray = (owner < 0) & np.any(head != SPACE, axis=1)
    if np.any(stray):
        line = int(lineno[np.flatnonzero(stray)[0]])
        raise RinexFormatError(f"{name}: unexpected text on line {line} before the first record")


def layout_v3(head: NDArray[np.uint8], lineno: NDArray[np.int64], name: str) -> Layout:
    """RINEX 3 records: a record starts on each line whose first column is not blank.

    Returns the body lines of the records, their ordinal within the record (0 = the
    satellite / toc line), their record number and the first line of each record.
    """
    is_start = head[:, 0] != SPACE
    owner = np.cumsum(is_start) - 1
    _stray_check(owner, head, lineno, name)
    line_idx = np.flatnonzero(owner >= 0)
    record_first = np.flatnonzero(is_start)
    ordinal = line_idx - record_first[owner[line_idx]]
    return line_idx, ordinal, owner[line_idx], record_first


def layout_v4(
    buf: NDArray[np.uint8],
    starts: NDArray[np.int64],
    lengths: NDArray[np.int64],
    head: NDArray[np.uint8],
    lineno: NDArray[np.int64],
    attrs: dict[str, Any],
    name: str,
) -> Layout:
    """RINEX 4 records: ``> EPH G01 LNAV`` lines open records; keep the readable EPH types.

    ION records of known types are decoded into ``attrs`` on the way. Returns the same
    arrays as :func:`layout_v3`.
    """
    is_marker = head[:, 0] == ord(">")
    markers = np.flatnonzero(is_marker)
    owner = np.cumsum(is_marker) - 1
    _stray_check(owner, head, lineno, name)
    kinds = [
        (head[m, 2:5].tobytes().decode("ascii", "replace"), chr(head[m, 6]),
         head[m, 10:14].tobytes().decode("ascii", "replace").strip())
        for m in markers
    ]  # fmt: skip
    eph_ok = np.array([t == "EPH" and msg in RINEX4_EPH_TYPES.get(s, ()) for t, s, msg in kinds], dtype=bool)
    for m_i, (t, s, msg) in enumerate(kinds):
        key = _ION_ATTRS.get((s, msg))
        if t == "ION" and key is not None and key not in attrs:
            attrs[key] = _ion_record(buf, starts, lengths, markers, m_i, starts.size, key, name, lineno)
    if not eph_ok.any():
        found = sorted({f"{t} {msg}" for t, _, msg in kinds})
        raise RinexFormatError(
            f"{name}: no navigation records of a readable type (LNAV, INAV, FNAV, D1, D2, FDMA, SBAS); "
            f"found {found}"
        )
    in_record = (owner >= 0) & ~is_marker
    in_record &= eph_ok[np.maximum(owner, 0)]
    line_idx = np.flatnonzero(in_record)
    ordinal = line_idx - markers[owner[line_idx]] - 1
    return line_idx, ordinal, owner[line_idx], line_idx[ordinal == 0]


def _ion_record(
    buf: NDArray[np.uint8],
    starts: NDArray[np.int64],
    lengths: NDArray[np.int64],
    markers: NDArray[np.int64],
    m_i: int,
    n_lines: int,
    key: str,
    name: str,
    lineno: NDArray[np.int64],
) -> NDArray[np.float64]:
    """Decode one RINEX 4 ION record body into alpha/beta (or a_i0..a_i2) coefficients."""
    first = int(markers[m_i]) + 1
    last = int(markers[m_i + 1]) if m_i + 1 < markers.size else n_lines
    fields: list[str] = []
    for j, li in enumerate(range(first, last)):
        text = buf[starts[li] : starts[li] + lengths[li]].tobytes().decode("ascii", "replace")
        cols = (23, 42, 61) if j == 0 else (4, 23, 42, 61)
        fields += [text[c : c + _FIELD_WIDTH] for c in cols]
    count = _ION_COUNTS.get(key, 8)
    try:
        vals = np.array([float(f.upper().replace("D", "E")) for f in fields[:count]], dtype=np.float64)
    except ValueError:
        raise RinexFormatError(f"{name}: bad ION record on line {int(lineno[first])}") from None
    if vals.size != count:
        raise RinexFormatError(f"{name}: short ION record on line {int(lineno[first])}")
    return vals
