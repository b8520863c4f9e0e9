"""Mutators of the fuzzing harness (:mod:`fuzz`): each turns the bytes of one RINEX file into
a damaged copy and says what it changed.

A mutator is called as ``mutate(text, rng, kind)`` with the file's plain RINEX text as bytes
(the packaging is handled by :mod:`fuzz`), a seeded :class:`numpy.random.Generator` and
``kind`` (``'obs2'``, ``'obs3'``, ``'nav2'`` or ``'nav3'``); it returns the new bytes and a
dict of details. Two mutators work on the packed bytes instead (``gzip_corrupt`` on a gzip
stream, ``hatanaka_corrupt`` on Compact RINEX text). ``details['in_range']`` is True when
the mutation only replaced values by values inside their physical range (a navigation
field set inside the range the GPS interface specification can encode; two satellites'
observations exchanged; a digit of a number changed to another digit, with a pseudorange
staying between 15,000 and 50,000 km): such a run may legitimately report a wrong position
as ``ok``, since nothing in the file says the value is wrong.
"""

from __future__ import annotations

import gzip
import math
import re

import numpy as np

# ---------------------------------------------------------------------------------- lines

def _lines(text: bytes) -> list[bytes]:
    return text.split(b"\n")


def _join(lines: list[bytes]) -> bytes:
    return b"\n".join(lines)


def header_end(lines: list[bytes]) -> int:
    """Index of the first body line (after ``END OF HEADER``); 0 when there is none."""
    for i, line in enumerate(lines):
        if b"END OF HEADER" in line:
            return i + 1
    return 0


def _obs2_types(lines: list[bytes], hdr: int) -> int:
    n = 0
    for line in lines[:hdr]:
        if b"# / TYPES OF OBSERV" in line and line[:6].strip().isdigit():
            n = int(line[:6])
    return max(n, 1)


def epoch_records(lines: list[bytes], kind: str) -> list[tuple[int, int, int]]:
    """Observation epochs as ``(epoch line, first data line, end line)`` indices (best effort)."""
    hdr = header_end(lines)
    out: list[tuple[int, int, int]] = []
    if kind == "obs3":
        starts = [i for i in range(hdr, len(lines)) if lines[i].startswith(b">")]
        for a, b in zip(starts, starts[1:] + [len(lines)]):
            out.append((a, a + 1, b))
        return out
    per_sat = (_obs2_types(lines, hdr) + 4) // 5
    i = hdr
    while i < len(lines):
        line = lines[i]
        count = line[29:32].strip()
        if not line.strip() or not count.isdigit():
            i += 1
            continue
        nsat, flag = int(count), line[26:29].strip()
        if flag in (b"2", b"3", b"4", b"5"):
            i += 1 + nsat
            continue
        id_lines = max(1, (nsat + 11) // 12)
        end = i + id_lines + nsat * per_sat
        out.append((i, i + id_lines, end))
        i = max(end, i + 1)
    return out


# ------------------------------------------------------------------------------ byte level

def _token_value(text: bytes, pos: int) -> float | None:
    """The number (a run of digits, sign, point, exponent) around byte ``pos``, or None."""
    a = pos
    while a > 0 and text[a - 1:a] in b"0123456789.+-EeDd":
        a -= 1
    b = pos
    while b < len(text) and text[b:b + 1] in b"0123456789.+-EeDd":
        b += 1
    try:
        return float(text[a:b].replace(b"D", b"E").replace(b"d", b"e"))
    except ValueError:
        return None


def _digit_change_in_range(old: bytes, new: bytes, positions: list[int]) -> bool:
    """True when every changed byte is a digit replaced by a digit and every pseudorange-sized
    number stays between 15,000 and 50,000 km."""
    for p in positions:
        if not (old[p:p + 1].isdigit() and new[p:p + 1].isdigit()):
            return False
        before, after = _token_value(old, p), _token_value(new, p)
        if before is None or after is None:
            return False
        if 1.0e7 <= abs(before) <= 6.0e7 and not 1.5e7 <= abs(after) <= 5.0e7:
            return False
    return True


def byte_flip(text: bytes, rng: np.random.Generator, kind: str) -> tuple[bytes, dict]:
    """Flip one random bit in each of 1-8 random bytes."""
    data = bytearray(text)
    positions = sorted({int(p) for p in rng.integers(0, len(data), int(rng.integers(1, 9)))})
    for p in positions:
        data[p] ^= 1 << int(rng.integers(0, 7))
    new = bytes(data)
    return new, {"positions": positions, "in_range": _digit_change_in_range(text, new, positions)}


def byte_insert(text: bytes, rng: np.random.Generator, kind: str) -> tuple[bytes, dict]:
    """Insert 1-4 random printable (or control) bytes at a random place."""
    p = int(rng.integers(0, len(text) + 1))
    alphabet = b"0123456789 .-+EDGRX\r\t\x00\n"
    ins = bytes(alphabet[int(i)] for i in rng.integers(0, len(alphabet), int(rng.integers(1, 5))))
    return text[:p] + ins + text[p:], {"position": p, "inserted": ins.decode("latin-1")}


def byte_delete(text: bytes, rng: np.random.Generator, kind: str) -> tuple[bytes, dict]:
    """Delete 1-16 consecutive bytes at a random place."""
    p = int(rng.integers(0, max(1, len(text))))
    n = int(rng.integers(1, 17))
    return text[:p] + text[p + n:], {"position": p, "deleted": n}


def truncate(text: bytes, rng: np.random.Generator, kind: str) -> tuple[bytes, dict]:
    """Cut the file at a random byte."""
    p = int(rng.integers(0, len(text)))
    return text[:p], {"position": p, "of": len(text)}


# ------------------------------------------------------------------------------ line level

def line_swap(text: bytes, rng: np.random.Generator, kind: str) -> tuple[bytes, dict]:
    """Swap two adjacent lines."""
    lines = _lines(text)
    i = int(rng.integers(0, max(1, len(lines) - 1)))
    if i + 1 < len(lines):
        lines[i], lines[i + 1] = lines[i + 1], lines[i]
    return _join(lines), {"line": i + 1}


def line_delete(text: bytes, rng: np.random.Generator, kind: str) -> tuple[bytes, dict]:
    """Delete 1-3 consecutive lines."""
    lines = _lines(text)
    i, n = int(rng.integers(0, len(lines))), int(rng.integers(1, 4))
    return _join(lines[:i] + lines[i + n:]), {"line": i + 1, "deleted": n}


def line_duplicate(text: bytes, rng: np.random.Generator, kind: str) -> tuple[bytes, dict]:
    """Write one random line twice."""
    lines = _lines(text)
    i = int(rng.integers(0, len(lines)))
    return _join(lines[:i + 1] + lines[i:]), {"line": i + 1}


def header_corrupt(text: bytes, rng: np.random.Generator, kind: str) -> tuple[bytes, dict]:
    """Overwrite 1-20 columns of a random header line (values or label) with random characters."""
    lines = _lines(text)
    hdr = header_end(lines) or min(len(lines), 10)
    i = int(rng.integers(0, max(1, hdr)))
    line = bytearray(lines[i].ljust(80))
    a = int(rng.integers(0, 80))
    alphabet = b"0123456789 .-+EDX*"
    for k in range(a, min(80, a + int(rng.integers(1, 21)))):
        line[k] = alphabet[int(rng.integers(0, len(alphabet)))]
    lines[i] = bytes(line).rstrip()
    return _join(lines), {"line": i + 1, "column": a + 1}


# ------------------------------------------------------------------------- observation epochs

def _epoch_time_span(kind: str) -> tuple[int, int]:
    return (1, 29) if kind == "obs3" else (0, 26)


def epoch_corrupt(text: bytes, rng: np.random.Generator, kind: str) -> tuple[bytes, dict]:
    """Damage one epoch line: a time field, the flag, the satellite count or the satellite list."""
    lines = _lines(text)
    epochs = epoch_records(lines, kind)
    if not epochs:
        return byte_flip(text, rng, kind)
    e, first, end = epochs[int(rng.integers(0, len(epochs)))]
    line = bytearray(lines[e].ljust(80 if kind == "obs2" else 41))
    what = ["time", "flag", "count", "satellites"][int(rng.integers(0, 4))]
    detail: dict = {"line": e + 1, "part": what}
    if what == "time":
        spans = [(2, 6), (7, 9), (10, 12), (13, 15), (16, 18), (18, 29)] if kind == "obs3" else \
            [(1, 3), (4, 6), (7, 9), (10, 12), (13, 15), (15, 26)]
        a, b = spans[int(rng.integers(0, len(spans)))]
        choices = [b"99", b"13", b"00", b"-1", b"XX", b"  ", b"32", b"61", b"1.", b"60"]
        value = choices[int(rng.integers(0, len(choices)))]
        line[a:b] = value.rjust(b - a)[: b - a]
        detail["value"] = value.decode()
    elif what == "flag":
        col = 31 if kind == "obs3" else 28
        value = b"1234567 9X"[int(rng.integers(0, 10))]
        line[col] = value
        detail["value"] = chr(value)
    elif what == "count":
        a, b = (32, 35) if kind == "obs3" else (29, 32)
        nsat = int(line[a:b].strip() or 0) if line[a:b].strip().isdigit() else 0
        value = [-1, 0, nsat + 1, max(0, nsat - 1), int(rng.integers(0, 100)), 999][int(rng.integers(0, 6))]
        line[a:b] = str(value).rjust(3).encode()[-3:]
        detail["value"] = value
    else:
        ids = [b"G??", b"X12", b"  0", b"G99", b"R01", b"G 1", b"   "]
        value = ids[int(rng.integers(0, len(ids)))]
        if kind == "obs3" and first < end:
            k = int(rng.integers(first, end))
            lines[k] = value + lines[k][3:]
            detail["line"] = k + 1
        else:
            nsat = max(1, min(12, (len(lines[e].rstrip()) - 32) // 3))
            col = 32 + 3 * int(rng.integers(0, nsat))
            line[col:col + 3] = value
        detail["value"] = value.decode()
    lines[e] = bytes(line).rstrip()
    return _join(lines), detail


def restamp(text: bytes, rng: np.random.Generator, kind: str) -> tuple[bytes, dict]:
    """Give an epoch the time of the epoch before it."""
    lines = _lines(text)
    epochs = epoch_records(lines, kind)
    if len(epochs) < 2:
        return line_duplicate(text, rng, kind)
    k = int(rng.integers(1, len(epochs)))
    a, b = _epoch_time_span(kind)
    prev, cur = lines[epochs[k - 1][0]].ljust(b), lines[epochs[k][0]].ljust(b)
    lines[epochs[k][0]] = cur[:a] + prev[a:b] + cur[b:]
    return _join(lines), {"line": epochs[k][0] + 1, "epoch": k}


def sat_line_swap(text: bytes, rng: np.random.Generator, kind: str) -> tuple[bytes, dict]:
    """Exchange the observations of two satellites of one epoch (their ids stay in place)."""
    lines = _lines(text)
    per_sat = 1 if kind == "obs3" else (_obs2_types(lines, header_end(lines)) + 4) // 5
    epochs = [r for r in epoch_records(lines, kind) if (min(r[2], len(lines)) - r[1]) // per_sat >= 2]
    if not epochs:
        return line_swap(text, rng, kind)
    e, first, end = epochs[int(rng.integers(0, len(epochs)))]
    end = min(end, len(lines))
    nsat = (end - first) // per_sat
    i, j = (int(v) for v in rng.choice(nsat, 2, replace=False))
    a, b = first + i * per_sat, first + j * per_sat
    if kind == "obs3":
        lines[a], lines[b] = lines[a][:3] + lines[b][3:], lines[b][:3] + lines[a][3:]
    else:
        lines[a:a + per_sat], lines[b:b + per_sat] = lines[b:b + per_sat], lines[a:a + per_sat]
    return _join(lines), {"line": e + 1, "satellites": [i, j], "in_range": True}


def body_repeat(text: bytes, rng: np.random.Generator, kind: str) -> tuple[bytes, dict]:
    """The body (every record) written 2-10 times in a row."""
    lines = _lines(text)
    hdr = header_end(lines)
    body = [ln for ln in lines[hdr:]]
    while body and not body[-1].strip():
        body.pop()
    n = int(rng.integers(2, 11))
    return _join(lines[:hdr] + body * n) + b"\n", {"times": n}


# ---------------------------------------------------------------------------- navigation

GPS_FIELDS = (
    ("af0_s", -9.8e-4, 9.8e-4), ("af1_s_per_s", -3.7e-9, 3.7e-9), ("af2_s_per_s2", -3.6e-15, 3.6e-15),
    ("IODE", 0, 255), ("Crs_m", -1024, 1024), ("DeltaN_rad_s", -1.2e-8, 1.2e-8), ("M0_rad", -math.pi, math.pi),
    ("Cuc_rad", -6.2e-5, 6.2e-5), ("Eccentricity", 0, 0.03), ("Cus_rad", -6.2e-5, 6.2e-5), ("sqrtA", 3873, 7071),
    ("Toe_s", 0, 604800), ("Cic_rad", -6.2e-5, 6.2e-5), ("Omega0_rad", -math.pi, math.pi), ("Cis_rad", -6.2e-5, 6.2e-5),
    ("Io_rad", 0, math.pi), ("Crc_m", -1024, 1024), ("omega_rad", -math.pi, math.pi), ("OmegaDot_rad_s", -3.0e-6, 3.0e-6),
    ("IDOT_rad_s", -2.9e-9, 2.9e-9), ("CodesL2", 0, 3), ("GPSWeek", 0, 9999), ("L2Pflag", 0, 1),
    ("SVacc_m", 0, 6144), ("health", 0, 63), ("TGD_s", -6.0e-8, 6.0e-8), ("IODC", 0, 1023),
    ("TransTime_s", 0, 604800), ("FitIntvl_h", 0, 100),
)
"""GPS LNAV fields in record order with the range the interface specification can encode
(IS-GPS-200: bits times scale); sqrtA restricted to orbits of 15,000-50,000 km."""

_ABSURD = (math.inf, -math.inf, math.nan, 1e300, -1e300, -1.5, 1.5, 0.0, 1e9, -1e9)


def gps_records(lines: list[bytes], kind: str) -> list[int]:
    """Indices of the first lines of GPS records (RINEX 2 GPS nav, or ``Gnn`` lines of 3/4)."""
    hdr = header_end(lines)
    if kind == "nav2":
        return [i for i in range(hdr, len(lines) - 7) if re.match(rb"^[ \d]\d [ \d]\d [ \d]\d ", lines[i])]
    return [i for i in range(hdr, len(lines) - 7) if re.match(rb"^G\d\d \d{4} ", lines[i])]


def _field_span(kind: str, k: int) -> tuple[int, int]:
    """Line offset and first column of GPS field ``k`` of a record."""
    if k < 3:
        return 0, (22 if kind == "nav2" else 23) + 19 * k
    return 1 + (k - 3) // 4, (3 if kind == "nav2" else 4) + 19 * ((k - 3) % 4)


def _format19(value: float) -> bytes:
    if not math.isfinite(value):
        return str(value).rjust(19).encode()
    return f"{value:18.11E}".rjust(19).encode()[:19] if abs(value) < 1e100 else f"{value:17.10E}".rjust(19).encode()


def nav_perturb(text: bytes, rng: np.random.Generator, kind: str) -> tuple[bytes, dict]:
    """Set one field of one GPS record to a new value: a small relative change, a random value
    inside the field's encodable range, or an absurd value (inf, nan, 1e300, -1.5, ...)."""
    lines = _lines(text)
    recs = gps_records(lines, kind)
    if not recs:
        return byte_flip(text, rng, kind)
    r = recs[int(rng.integers(0, len(recs)))]
    k = int(rng.integers(0, len(GPS_FIELDS)))
    name, lo, hi = GPS_FIELDS[k]
    dl, col = _field_span(kind, k)
    line = lines[r + dl].ljust(col + 19)
    try:
        old = float(line[col:col + 19].replace(b"D", b"E"))
    except ValueError:
        old = math.nan
    mode = ["small", "in_range", "absurd"][int(rng.integers(0, 3))]
    if mode == "small":
        new = old * (1 + float(rng.normal(0, 10 ** rng.uniform(-6, -3))))
    elif mode == "in_range":
        new = float(rng.uniform(lo, hi))
    else:
        new = _ABSURD[int(rng.integers(0, len(_ABSURD)))]
    lines[r + dl] = line[:col] + _format19(new) + line[col + 19:]
    in_range = bool(math.isfinite(new) and lo <= new <= hi)
    return _join(lines), {"line": r + dl + 1, "field": name, "old": old, "new": new, "mode": mode,
                          "in_range": in_range}


def ion_alpha(text: bytes, rng: np.random.Generator, kind: str) -> tuple[bytes, dict]:
    """Garbage in the Klobuchar coefficients (``ION ALPHA`` / ``GPSA`` header line)."""
    lines = _lines(text)
    hdr = header_end(lines)
    targets = [i for i in range(hdr) if b"ION ALPHA" in lines[i] or lines[i].startswith((b"GPSA", b"GPSB"))
               or b"ION BETA" in lines[i]]
    if not targets:
        return header_corrupt(text, rng, kind)
    i = targets[int(rng.integers(0, len(targets)))]
    garbage = [b"1.0D+300", b"inf", b"nan", b"XXXX", b"", b"-1.5D+99", b"1e300", b"0.0"][int(rng.integers(0, 8))]
    start, width = (2, 12) if kind == "nav2" else (5, 12)
    line = bytearray(lines[i].ljust(80))
    k = int(rng.integers(0, 4))
    line[start + width * k:start + width * (k + 1)] = garbage.rjust(width)[:width]
    lines[i] = bytes(line).rstrip()
    return _join(lines), {"line": i + 1, "coefficient": k, "value": garbage.decode(),
                          "in_range": garbage == b"0.0"}  # zero is a valid coefficient


def nav_year_1980(text: bytes, rng: np.random.Generator, kind: str) -> tuple[bytes, dict]:
    """A record dated 1980 (a GLONASS record when the file has one)."""
    lines = _lines(text)
    hdr = header_end(lines)
    glo = [i for i in range(hdr, len(lines)) if re.match(rb"^R\d\d \d{4} ", lines[i])]
    recs = glo or gps_records(lines, kind)
    if not recs:
        return byte_flip(text, rng, kind)
    i = recs[int(rng.integers(0, len(recs)))]
    if kind == "nav2":
        lines[i] = lines[i][:3] + b"80" + lines[i][5:]
    else:
        lines[i] = lines[i][:4] + b"1980" + lines[i][8:]
    return _join(lines), {"line": i + 1, "system": "R" if glo else "G"}


# ------------------------------------------------------------------------------- packaging

def gzip_corrupt(raw: bytes, rng: np.random.Generator) -> tuple[bytes, dict]:
    """Damage a gzip stream: flip bytes of the deflate data, cut it short, or break the trailer."""
    how = ["flip", "cut", "trailer"][int(rng.integers(0, 3))]
    data = bytearray(raw)
    if how == "flip":
        positions = [int(p) for p in rng.integers(10, len(data) - 8, int(rng.integers(1, 5)))]
        for p in positions:
            data[p] ^= 1 << int(rng.integers(0, 8))
        return bytes(data), {"how": how, "positions": positions}
    if how == "cut":
        p = int(rng.integers(10, len(data)))
        return bytes(data[:p]), {"how": how, "position": p}
    data[-8 + int(rng.integers(0, 8))] ^= 0xFF
    return bytes(data), {"how": how}


def hatanaka_corrupt(crx: bytes, rng: np.random.Generator) -> tuple[bytes, dict]:
    """Damage Compact RINEX text: flip bytes, delete or duplicate a line, or cut it."""
    lines = _lines(crx)
    hdr = header_end(lines)
    how = ["flip", "delete", "duplicate", "cut"][int(rng.integers(0, 4))]
    i = int(rng.integers(hdr, max(hdr + 1, len(lines))))
    if how == "flip":
        return byte_flip(crx, rng, "crx")[0], {"how": how}
    if how == "delete":
        return _join(lines[:i] + lines[i + 1:]), {"how": how, "line": i + 1}
    if how == "duplicate":
        return _join(lines[:i + 1] + lines[i:]), {"how": how, "line": i + 1}
    return _join(lines[:i]), {"how": how, "line": i + 1}


def gzip_bytes(text: bytes) -> bytes:
    """``text`` as a gzip stream with a fixed time stamp (reproducible files)."""
    return gzip.compress(text, mtime=0)


OBS_MUTATORS = {
    "byte_flip": byte_flip, "byte_insert": byte_insert, "byte_delete": byte_delete, "line_swap": line_swap,
    "sat_line_swap": sat_line_swap, "line_delete": line_delete, "line_duplicate": line_duplicate,
    "truncate": truncate, "header_corrupt": header_corrupt, "epoch_corrupt": epoch_corrupt, "restamp": restamp,
    "body_repeat": body_repeat,
}
NAV_MUTATORS = {
    "byte_flip": byte_flip, "byte_insert": byte_insert, "byte_delete": byte_delete, "line_swap": line_swap,
    "line_delete": line_delete, "line_duplicate": line_duplicate, "truncate": truncate,
    "header_corrupt": header_corrupt, "nav_perturb": nav_perturb, "ion_alpha": ion_alpha,
    "nav_year_1980": nav_year_1980,
}
