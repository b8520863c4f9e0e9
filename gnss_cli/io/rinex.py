"""RINEX observation and navigation input, validated before any computation.

This is the only module that imports :mod:`georinex`. RINEX 2 files are read with
georinex; RINEX 3 and 4 files with the fast reader of :mod:`gnss_cli.io.rinex3_obs` /
:mod:`gnss_cli.io.rinex3_nav` when it is available, else with georinex (which rejects
RINEX 4). Every reader is filtered to the systems and signals needed: unfiltered,
georinex needs minutes and hundreds of MB on a 24 h multi-GNSS RINEX 3 file.

Validation (each failure raises :class:`~gnss_cli.errors.InputError` naming the file):
missing or unreadable file, not RINEX, observation/navigation files swapped, epoch lines
that do not parse, a header that contradicts its records, no records at all.
"""

from __future__ import annotations

import logging
import re
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import xarray as xr

from gnss_cli.errors import InputFileNotFoundError, RinexFormatError

_RINEX2_EPOCH = re.compile(
    r"^ (?P<yy>[ \d]\d) (?P<mo>[ \d]\d) (?P<dd>[ \d]\d) (?P<hh>[ \d]\d) (?P<mi>[ \d]\d)"
    r"(?P<ss>[ \d]{3}\.\d{7})  (?P<flag>\d)(?P<nsat>[ \d]{1,3})"
)


def _seconds(match: re.Match[str], path: Path, lineno: int, line: str) -> float:
    try:
        return float(match["ss"])
    except ValueError:
        raise RinexFormatError(f"{path}: line {lineno}: bad epoch seconds {line.rstrip()[:40]!r}") from None


_RINEX3_EPOCH = re.compile(
    r"^> (?P<yyyy>\d{4}) (?P<mo>[ \d]\d) (?P<dd>[ \d]\d) (?P<hh>[ \d]\d) (?P<mi>[ \d]\d)"
    r"(?P<ss>[ \d]{3}\.\d{7})  (?P<flag>\d)(?P<nsat>[ \d]{1,3})"
)


@dataclass(frozen=True)
class RinexInfo:
    """What a RINEX file's first header line says.

    Attributes
    ----------
    path : the file.
    version : RINEX version (2.11, 3.04, 4.0, ...).
    kind : ``'obs'`` or ``'nav'``.
    system : the system letter of the header (``'G'``, ``'M'`` mixed, ...).
    """

    path: Path
    version: float
    kind: str
    system: str


def _open_lines(path: Path, header_only: bool = False) -> list[str]:
    """Lines of a plain or compressed RINEX file (georinex's opener handles gz/Z/zip/Hatanaka)."""
    from georinex.rio import opener

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            with opener(path, header=header_only) as f:
                if header_only:
                    lines = []
                    for line in f:
                        lines.append(line)
                        if "END OF HEADER" in line or len(lines) > 2000:
                            break
                    return lines
                return f.read().splitlines()
    except (OSError, EOFError, ValueError, LookupError, RuntimeError) as exc:
        raise RinexFormatError(f"{path}: cannot read file ({type(exc).__name__}: {exc})") from exc


def rinex_info(path: str | Path) -> RinexInfo:
    """Validate that ``path`` is a readable RINEX file and return its type.

    Raises
    ------
    InputFileNotFoundError
        The path does not exist or is not a file.
    RinexFormatError
        The file is empty, not RINEX, or of an unknown type.
    """
    p = Path(path)
    if not p.exists():
        raise InputFileNotFoundError(f"{p}: no such file")
    if not p.is_file():
        raise InputFileNotFoundError(f"{p}: not a regular file")
    if p.stat().st_size == 0:
        raise RinexFormatError(f"{p}: empty file")
    lines = _open_lines(p, header_only=True)
    if lines and "CRINEX VERS" in lines[0]:
        lines = lines[2:]  # Hatanaka: two CRINEX lines precede the RINEX header
    if not lines or "RINEX VERSION / TYPE" not in lines[0]:
        raise RinexFormatError(f"{p}: not a RINEX file (first line has no 'RINEX VERSION / TYPE')")
    first = lines[0]
    try:
        version = float(first[:9])
    except ValueError:
        raise RinexFormatError(f"{p}: not a RINEX file (bad version field {first[:9].strip()!r})") from None
    ftype = first[20:21].upper()
    if ftype in ("O",):
        kind = "obs"
    elif ftype in ("N", "G", "H", "L", "J", "C"):
        kind = "nav"
    else:
        raise RinexFormatError(f"{p}: unsupported RINEX file type {ftype!r} (expected observation or navigation)")
    system = (first[40:41] if kind == "obs" or version >= 3 else "G").strip() or "G"
    if kind == "nav" and version < 3:
        system = {"N": "G", "G": "R", "H": "S", "L": "E", "J": "J", "C": "C"}.get(ftype, "G")
    return RinexInfo(p, version, kind, system)


def _check_obs_records(info: RinexInfo) -> None:
    """Scan the observation records and reject malformed epochs (cheap text pass)."""
    lines = _open_lines(info.path)
    try:
        end = next(i for i, line in enumerate(lines) if "END OF HEADER" in line)
    except StopIteration:
        raise RinexFormatError(f"{info.path}: no 'END OF HEADER' line") from None
    header, body = lines[: end + 1], lines[end + 1 :]
    if info.version < 3:
        _check_rinex2_obs(info.path, header, body, end + 1)
    else:
        _check_rinex3_obs(info.path, body, end + 1)


def _check_rinex2_obs(path: Path, header: list[str], body: list[str], offset: int) -> None:
    n_types = None
    listed: list[str] = []
    for line in header:
        if "# / TYPES OF OBSERV" in line:
            if line[:6].strip():
                try:
                    n_types = int(line[:6])
                except ValueError:
                    raise RinexFormatError(f"{path}: bad '# / TYPES OF OBSERV' count {line[:6]!r}") from None
            listed += line[6:60].split()
    if n_types is None:
        raise RinexFormatError(f"{path}: header has no '# / TYPES OF OBSERV' line")
    if n_types != len(listed):
        raise RinexFormatError(
            f"{path}: header declares {n_types} observation types but lists {len(listed)} ({' '.join(listed)})"
        )
    lines_per_sat = (n_types + 4) // 5
    i, n_epochs = 0, 0
    while i < len(body):
        line = body[i]
        if not line.strip():
            i += 1
            continue
        flag_field = line[26:29].strip() if len(line) > 28 else ""
        if flag_field.isdigit() and int(flag_field) > 1 and not line[:26].strip():
            # Event record without a time (e.g. flag 4: header lines follow).
            nsat_field = line[29:32].strip()
            i += 1 + (int(nsat_field) if nsat_field.isdigit() else 0)
            continue
        m = _RINEX2_EPOCH.match(line)
        if m is None:
            raise RinexFormatError(f"{path}: line {offset + i + 1}: bad epoch line {line.rstrip()[:40]!r}")
        flag, nsat = int(m["flag"]), int(m["nsat"])
        sec = _seconds(m, path, offset + i + 1, line)
        if not (1 <= int(m["mo"]) <= 12 and 1 <= int(m["dd"]) <= 31 and int(m["hh"]) < 24 and int(m["mi"]) < 60 and 0 <= sec < 60.0):
            raise RinexFormatError(f"{path}: line {offset + i + 1}: epoch time out of range {line[:26].strip()!r}")
        sat_lines = (nsat + 11) // 12
        if flag > 1:  # event records: nsat header lines follow
            i += 1 + nsat
            continue
        i += sat_lines + nsat * lines_per_sat
        n_epochs += 1
    if n_epochs == 0:
        raise RinexFormatError(f"{path}: no observation records")


def _check_rinex3_obs(path: Path, body: list[str], offset: int) -> None:
    n_epochs = 0
    for i, line in enumerate(body):
        if line.startswith(">"):
            m = _RINEX3_EPOCH.match(line)
            if m is None:
                raise RinexFormatError(f"{path}: line {offset + i + 1}: bad epoch line {line.rstrip()[:40]!r}")
            sec = _seconds(m, path, offset + i + 1, line)
            if not (1 <= int(m["mo"]) <= 12 and 1 <= int(m["dd"]) <= 31 and int(m["hh"]) < 24 and int(m["mi"]) < 60 and 0 <= sec < 60.0):
                raise RinexFormatError(f"{path}: line {offset + i + 1}: epoch time out of range {line[:29].strip()!r}")
            n_epochs += int(m["flag"]) <= 1
    if n_epochs == 0:
        raise RinexFormatError(f"{path}: no observation records")


def _georinex_load(path: Path, **kwargs: object) -> xr.Dataset:
    import georinex

    logging.getLogger().setLevel(logging.CRITICAL)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            ds = georinex.load(path, **kwargs)
    except (ValueError, LookupError, OSError, EOFError, IndexError, KeyError, TypeError) as exc:
        raise RinexFormatError(f"{path}: cannot parse ({type(exc).__name__}: {exc})") from exc
    if ds is None:
        raise RinexFormatError(f"{path}: no data")
    return ds


def _fast_reader_available() -> bool:
    try:
        import gnss_cli.io.rinex3_nav  # noqa: F401
        import gnss_cli.io.rinex3_obs  # noqa: F401
    except ImportError:
        return False
    return True


def read_obs(path: str | Path, systems: Sequence[str] | None = None, codes: Sequence[str] | None = None) -> xr.Dataset:
    """Read and validate a RINEX observation file, filtered to systems and observation codes.

    Parameters
    ----------
    path
        RINEX 2.x, 3.x or 4.x observation file, plain or compressed (gz, Z, zip, Hatanaka).
    systems
        System letters to keep (``['G']``); None keeps all.
    codes
        Observation codes to keep (``['C1C', 'C1']``); None keeps all.

    Returns
    -------
    xarray.Dataset
        dims ``(time, sv)``, ``time`` as ``datetime64[ns]`` in the GPS time scale; attrs
        include ``position`` (header APPROX POSITION XYZ, m) and ``marker_name`` when present.

    Raises
    ------
    InputFileNotFoundError, RinexFormatError
        See the module docstring.
    """
    info = rinex_info(path)
    if info.kind != "obs":
        raise RinexFormatError(f"{info.path}: is a RINEX navigation file, expected an observation file (OBS and NAV swapped?)")
    if info.version >= 3 and _fast_reader_available():
        from gnss_cli.io.rinex3_obs import read_obs3

        ds = read_obs3(info.path, systems=list(systems) if systems else None, codes=list(codes) if codes else None)
    else:
        if info.version >= 4:
            raise RinexFormatError(f"{info.path}: RINEX {info.version} observation files need the built-in RINEX 3/4 reader")
        _check_obs_records(info)
        kwargs: dict[str, object] = {}
        if systems:
            kwargs["use"] = set(systems)
        if codes:
            kwargs["meas"] = list(codes)
        ds = _georinex_load(info.path, **kwargs)
        if "marker_name" not in ds.attrs:
            ds.attrs["marker_name"] = _header_value(info.path, "MARKER NAME")
    if ds.sizes.get("time", 0) == 0:
        raise RinexFormatError(f"{info.path}: no observation records" + (f" for systems {','.join(systems)}" if systems else ""))
    ds.attrs["filename"] = info.path.name
    ds.attrs["rinex_version"] = info.version
    return ds


def _header_value(path: Path, label: str) -> str:
    for line in _open_lines(path, header_only=True):
        if label in line[60:]:
            return line[:60].strip()
    return ""


def read_nav(paths: str | Path | Sequence[str | Path], systems: Sequence[str] | None = None) -> xr.Dataset:
    """Read, validate and merge RINEX navigation files.

    Parameters
    ----------
    paths
        One or several navigation files (RINEX 2 GPS nav, RINEX 3/4 mixed or per system).
        All RINEX 3/4 files are read in one pass by
        :func:`~gnss_cli.io.rinex3_nav.read_nav3`; RINEX 2 files by georinex, then merged.
    systems
        System letters to keep; None keeps all.

    Returns
    -------
    xarray.Dataset
        georinex layout: dims ``(time, sv)``, time = toc; attrs ``ionospheric_corr_GPS``
        (alpha0..3, beta0..3) when a file carries the Klobuchar coefficients.

    Raises
    ------
    InputFileNotFoundError, RinexFormatError
    """
    items = [paths] if isinstance(paths, (str, Path)) else list(paths)
    if not items:
        raise RinexFormatError("no navigation file given")
    infos = [rinex_info(item) for item in items]
    for info in infos:
        if info.kind != "nav":
            raise RinexFormatError(f"{info.path}: is a RINEX observation file, expected a navigation file (OBS and NAV swapped?)")
        if info.version >= 4 and not _fast_reader_available():
            raise RinexFormatError(f"{info.path}: RINEX {info.version} navigation files need the built-in RINEX 3/4 reader")
    fast = [info for info in infos if info.version >= 3 and _fast_reader_available()]
    datasets = []
    if fast:  # every RINEX 3/4 file in one pass: one record table, duplicates across files dropped
        from gnss_cli.io.rinex3_nav import read_nav3

        ds = read_nav3([info.path for info in fast], systems=list(systems) if systems else None)
        if ds.sizes.get("time", 0) == 0 or ds.sizes.get("sv", 0) == 0:
            raise RinexFormatError(f"{', '.join(str(i.path) for i in fast)}: no navigation records")
        ds.attrs["filename"] = ",".join(info.path.name for info in fast)
        datasets.append(ds)
    for info in infos:
        if info in fast:
            continue
        kwargs: dict[str, object] = {}
        if systems:
            kwargs["use"] = set(systems)
        ds = _georinex_load(info.path, **kwargs)
        if ds.sizes.get("time", 0) == 0 or ds.sizes.get("sv", 0) == 0:
            raise RinexFormatError(f"{info.path}: no navigation records")
        ds.attrs["filename"] = info.path.name
        datasets.append(ds)
    if len(datasets) == 1:
        return datasets[0]
    attrs: dict[str, object] = {}
    for ds in datasets:
        for key, value in ds.attrs.items():
            attrs.setdefault(key, value)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        merged = xr.merge(datasets, compat="override", join="outer", combine_attrs="drop")
    merged.attrs.update(attrs)
    merged.attrs["filename"] = ",".join(str(d.attrs.get("filename", "")) for d in datasets)
    return merged


def nav_leap_seconds(paths: str | Path | Sequence[str | Path]) -> float | None:
    """GPS - UTC (s) from the ``LEAP SECONDS`` header line of the first navigation file that
    has one (RINEX 2 and 3: the current leap seconds, columns 1-6), else None."""
    items = [paths] if isinstance(paths, (str, Path)) else list(paths)
    for item in items:
        text = _header_value(Path(item), "LEAP SECONDS")
        try:
            return float(int(text[:6]))
        except ValueError:
            continue
    return None


def klobuchar_coefficients(nav: xr.Dataset) -> tuple[np.ndarray, np.ndarray] | None:
    """Klobuchar ``(alpha (4,), beta (4,))`` from a navigation dataset's header, or None."""
    raw = nav.attrs.get("ionospheric_corr_GPS")
    if raw is None:
        return None
    arr = np.asarray(raw, dtype=np.float64).ravel()
    if arr.size != 8 or not np.all(np.isfinite(arr)) or not np.any(arr != 0):
        return None
    return arr[:4], arr[4:]
