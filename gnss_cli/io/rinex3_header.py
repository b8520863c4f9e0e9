"""Headers of RINEX 3.0x / 4.0x observation and navigation files.

:func:`read_header` opens a file and cuts its header off the body; :func:`read_obs_header`
and :func:`read_nav_header` decode the records the readers need; :func:`select_codes` picks the
observation codes to decode. The bodies are decoded in
:mod:`gnss_cli.io.rinex3_obs` and :mod:`gnss_cli.io.rinex3_nav`.

References
----------
RINEX 3.05 and 4.00 format descriptions (IGS/RTCM-SC104), section 5 and tables A1-A5.
"""

from __future__ import annotations

import os
import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from gnss_cli.errors import RinexFormatError, UsageError
from gnss_cli.io.compression import open_bytes

__all__ = [
    "SYSTEM_CHARS", "SYSTEM_NAMES", "OBS_CODE", "validate_systems", "read_header", "header_end", "parse_version_line", "check_rinex34_type",
    "read_obs_header", "read_nav_header", "validate_selection", "select_codes",
]

SYSTEM_CHARS = "GRECJSI"
"""RINEX system letters read by the RINEX 3/4 readers (GPS, GLONASS, Galileo, BeiDou, QZSS, SBAS, NavIC)."""
SYSTEM_NAMES = {"G": "GPS", "R": "GLONASS", "E": "Galileo", "C": "BeiDou", "J": "QZSS", "I": "NavIC", "S": "SBAS"}
"""The system of each RINEX letter, for messages and legends."""

OBS_CODE = re.compile(r"[CLDS][0-9][A-Z]|X[0-9][A-Z]?")
"""A RINEX 3/4 observation code (tables A1-A14): type (C code, L phase, D Doppler, S signal
strength; X receiver channel), band digit, attribute letter."""

_TIME_SYSTEMS = {"G": "GPS", "R": "GLO", "E": "GAL", "J": "QZS", "C": "BDT", "I": "IRN"}


def validate_systems(systems: Sequence[str] | str | None) -> list[str] | None:
    """System letters from a sequence or a comma/space separated string; None keeps every system.

    Raises
    ------
    UsageError
        An entry is not one of :data:`SYSTEM_CHARS`, or the selection is empty.
    """
    if isinstance(systems, str):
        systems = [s.strip() for s in systems.replace(",", " ").split()]
    if systems is None:
        return None
    systems = list(systems)
    bad = [s for s in systems if not isinstance(s, str) or len(s) != 1 or s not in SYSTEM_CHARS]
    if bad or not systems:
        raise UsageError(f"systems: expected RINEX system letters from {SYSTEM_CHARS!r}, got {systems!r}")
    return systems


def read_header(path: str | os.PathLike[str], content: bytes | None = None) -> tuple[str, bytes, int, str]:
    """Open a RINEX file (or take its ``content``, read already); return its name, whole content,
    the offset of the body and the header text.

    Raises
    ------
    InputFileNotFoundError
        ``path`` does not exist.
    RinexFormatError
        The file is empty or has no ``END OF HEADER`` line.
    """
    name = Path(path).name
    content = open_bytes(path) if content is None else content
    if not content or content.isspace():
        raise RinexFormatError(f"{name}: empty file")
    hdr_end = header_end(content, name)
    return name, content, hdr_end, content[:hdr_end].decode("ascii", errors="replace")


def header_end(content: bytes, name: str) -> int:
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


def read_obs_header(
    header: str, name: str
) -> tuple[dict[str, Any], dict[str, list[str]]]:
    """Decode the header lines a reader needs; return (attributes, obs types per system)."""
    lines = header.splitlines()
    version, system = check_rinex34_type(lines[0], name, "O")
    attrs: dict[str, Any] = {"version": version, "rinextype": "obs"}
    obs_types: dict[str, list[str]] = {}
    current_sys = ""
    announced: dict[str, tuple[int, int]] = {}  # system -> (count, header line)
    time_system = _TIME_SYSTEMS.get(system, "")
    for lineno, line in enumerate(lines[1:], start=2):
        label = line[60:].strip()
        text = line[:60]
        if label == "SYS / # / OBS TYPES":
            if text[:1].strip():
                current_sys = text[0]
                try:
                    announced[current_sys] = (int(text[3:6]), lineno)
                except ValueError:
                    raise RinexFormatError(
                        f"{name}: bad observation-type count {text[3:6].strip()!r} on header line {lineno}"
                    ) from None
                obs_types[current_sys] = []
            elif not current_sys:
                raise RinexFormatError(
                    f"{name}: continuation of 'SYS / # / OBS TYPES' without a system on line {lineno}"
                )
            codes = text[7:60].split()
            bad = [c for c in codes if not OBS_CODE.fullmatch(c)]
            if bad:
                raise RinexFormatError(
                    f"{name}: header line {lineno}: {bad[0]!r} is not a RINEX observation code "
                    f"(a type C, L, D or S, a band digit and an attribute letter, such as C1C)"
                )
            obs_types[current_sys] += codes
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
    for sys_char, (n, lineno) in announced.items():
        if len(obs_types[sys_char]) != n:
            raise RinexFormatError(
                f"{name}: header line {lineno}: system {sys_char} announces {n} observation types "
                f"but lists {len(obs_types[sys_char])}"
            )
    if not obs_types:
        raise RinexFormatError(f"{name}: no 'SYS / # / OBS TYPES' record in the header (lines 1-{len(lines)})")
    attrs["time_system"] = time_system or "GPS"
    attrs["obs_types"] = obs_types
    return attrs, obs_types


def read_nav_header(header: str, name: str) -> dict[str, Any]:
    """Decode the header of a navigation file: version and the ``IONOSPHERIC CORR`` records."""
    lines = header.splitlines()
    version, _ = check_rinex34_type(lines[0], name, "N")
    attrs: dict[str, Any] = {"version": version, "rinextype": "nav"}
    iono: dict[str, NDArray[np.float64]] = {}
    for lineno, line in enumerate(lines[1:], start=2):
        if line[60:].strip() != "IONOSPHERIC CORR":
            continue
        kind = line[:4].strip()
        n = 3 if kind == "GAL" else 4
        try:
            iono[kind] = np.array(
                [float(line[5 + 12 * i : 17 + 12 * i].upper().replace("D", "E")) for i in range(n)]
            )
        except ValueError:
            raise RinexFormatError(f"{name}: bad IONOSPHERIC CORR header line {lineno}") from None
    for a, b, key in (("GPSA", "GPSB", "GPS"), ("QZSA", "QZSB", "QZS"), ("BDSA", "BDSB", "BDS"),
                      ("IRNA", "IRNB", "IRN")):  # fmt: skip
        if a in iono and b in iono:
            attrs[f"ionospheric_corr_{key}"] = np.hstack((iono[a], iono[b]))
    if "GAL" in iono:
        attrs["ionospheric_corr_GAL"] = iono["GAL"]
    return attrs


def select_codes(
    obs_types: dict[str, list[str]],
    systems: Sequence[str] | None,
    codes: Sequence[str] | None,
    pseudorange_only: bool,
) -> dict[str, list[tuple[int, str]]]:
    """Per system of ``obs_types`` (system -> codes in header order) among ``systems``, the
    (field index, code) pairs to decode: the codes that start with one of ``codes`` (all when
    None), only pseudoranges when ``pseudorange_only``."""
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


def validate_selection(
    systems: Sequence[str] | str | None, codes: Sequence[str] | str | None
) -> tuple[list[str] | None, list[str] | None]:
    """``systems`` and ``codes`` checked (:class:`UsageError`) and as lists (None: all)."""
    systems = validate_systems(systems)
    if isinstance(codes, str):
        codes = [codes]
    if codes is not None:
        codes = [c.strip() for c in codes]
        base = [c[:-3] if len(c) > 3 and c.endswith("lli") else c for c in codes]  # 'L1Clli': L1C's indicators
        bad = [c for c in base if not c or len(c) > 3 or not c.isalnum()]
        if bad or not codes:
            raise UsageError(
                f"codes: expected observation codes such as 'C1C', prefixes 'C1' or phase indicators 'L1Clli', got {codes!r}"
            )
    return systems, codes
