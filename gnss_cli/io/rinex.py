"""RINEX observation and navigation input, validated before any computation.

RINEX 2 observation files are read by :mod:`gnss_cli.io.rinex2_obs` (exact time tags),
RINEX 2 navigation files by :mod:`gnss_cli.io.rinex2_nav` (exact toc), RINEX 3 and 4 files by
:mod:`gnss_cli.io.rinex3_obs` / :mod:`gnss_cli.io.rinex3_nav`. Every reader is filtered to the
systems and signals needed. The datasets have georinex's layout (dims ``(time, sv)``, its
variable names); georinex itself serves as the tests' independent reference.

Validation (each failure raises :class:`~gnss_cli.errors.InputError` naming the file):
missing or unreadable file, not RINEX, observation/navigation files swapped, epoch lines
that do not parse, a header that contradicts its records, no records at all.
"""

from __future__ import annotations

import warnings
import zlib
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import xarray as xr

from gnss_cli.errors import InputFileNotFoundError, RinexFormatError

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


def _open_lines(path: Path) -> list[str]:
    """The header lines of a plain or compressed RINEX file (:func:`~gnss_cli.io.compression.open_header_lines`)."""
    from gnss_cli.io.compression import fault_text, open_header_lines

    try:
        return open_header_lines(path)
    except (OSError, EOFError, ValueError, LookupError, RuntimeError, zlib.error, ImportError) as exc:
        raise RinexFormatError(f"{path}: cannot read file ({fault_text(exc)})") from exc


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
    lines = _open_lines(p)
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


def read_obs(path: str | Path, systems: Sequence[str] | None = None, codes: Sequence[str] | None = None) -> xr.Dataset:
    """Read and validate a RINEX observation file, filtered to systems and observation codes.

    Parameters
    ----------
    path
        RINEX 2.x, 3.x or 4.x observation file, plain or compressed (gz, Z, zip, Hatanaka).
    systems
        System letters to keep (``['G']``); None keeps all.
    codes
        Observation codes to keep (``['C1C', 'C1']``); None keeps all. A phase code (or prefix)
        followed by ``lli`` (``'L1Clli'``, ``'L1lli'``) also asks for the loss-of-lock indicators
        of the matching phase codes, as variables ``L1Clli`` (georinex's names; 0 where blank, NaN
        where there is no phase).

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
    if info.version < 3:
        from gnss_cli.io.rinex2_obs import read_obs2

        ds = read_obs2(info.path, systems=list(systems) if systems else None, codes=list(codes) if codes else None)
    else:
        from gnss_cli.io.rinex3_obs import read_obs3

        ds = read_obs3(info.path, systems=list(systems) if systems else None, codes=list(codes) if codes else None)
    if ds.sizes.get("time", 0) == 0:
        raise RinexFormatError(f"{info.path}: no observation records" + (f" for systems {','.join(systems)}" if systems else ""))
    ds.attrs["filename"] = info.path.name
    ds.attrs["rinex_version"] = info.version
    return ds


def _header_value(path: Path, label: str) -> str:
    for line in _open_lines(path):
        if label in line[60:]:
            return line[:60].strip()
    return ""


def read_nav(paths: str | Path | Sequence[str | Path], systems: Sequence[str] | None = None) -> xr.Dataset:
    """Read, validate and merge RINEX navigation files; drop physically impossible records.

    Records that could not have been broadcast (:func:`~gnss_cli.io.nav_checks.reject_implausible_records`)
    are set to NaN; one line per system naming the first of them is kept in the attribute
    ``rejected_records`` (a list of str, empty when none) for the run's warnings.
    See :func:`_read_nav_files` for the parameters.
    """
    from gnss_cli.io.nav_checks import klobuchar_problem, reject_implausible_records

    ds = _read_nav_files(paths, systems)
    label = str(ds.attrs.get("filename", ""))
    ds, messages = reject_implausible_records(ds, label)
    raw = ds.attrs.get("ionospheric_corr_GPS")
    problem = None if raw is None else klobuchar_problem(raw)
    if problem is not None:
        del ds.attrs["ionospheric_corr_GPS"]
        messages.append(f"{label}: Klobuchar coefficients not used: {problem}")
    ds.attrs["rejected_records"] = messages
    return ds


def _read_nav_files(paths: str | Path | Sequence[str | Path], systems: Sequence[str] | None = None) -> xr.Dataset:
    """Read, validate and merge RINEX navigation files.

    Parameters
    ----------
    paths
        One or several navigation files (RINEX 2 GPS nav, RINEX 3/4 mixed or per system).
        All RINEX 3/4 files are read in one pass by
        :func:`~gnss_cli.io.rinex3_nav.read_nav3`; RINEX 2 files by
        :func:`~gnss_cli.io.rinex2_nav.read_nav2` (all their records, as georinex read them), then merged.
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
    v3 = [info for info in infos if info.version >= 3]
    datasets = []
    if v3:  # every RINEX 3/4 file in one pass: one record table, duplicates across files dropped
        from gnss_cli.io.rinex3_nav import read_nav3

        ds = read_nav3([info.path for info in v3], systems=list(systems) if systems else None)
        if ds.sizes.get("time", 0) == 0 or ds.sizes.get("sv", 0) == 0:
            raise RinexFormatError(f"{', '.join(str(i.path) for i in v3)}: no navigation records")
        ds.attrs["filename"] = ",".join(info.path.name for info in v3)
        datasets.append(ds)
    for info in infos:
        if info.version >= 3:
            continue
        from gnss_cli.io.rinex2_nav import read_nav2

        ds = read_nav2(info.path)
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
    valid = [ds.attrs["ionospheric_corr_GPS"] for ds in datasets if klobuchar_coefficients(ds) is not None]
    if valid:  # Klobuchar coefficients from any file of the run that has them
        attrs["ionospheric_corr_GPS"] = valid[0]
    # Union of the (time, sv) grids, each cell from the first file that has it. (xr.merge with
    # compat="override" took a variable present in several files, e.g. SVclockBias of a GPS and
    # a GLONASS file, from the first file alone: the GLONASS clocks were lost.)
    merged = datasets[0]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for ds in datasets[1:]:
            merged = merged.combine_first(ds)
    merged.attrs = {}
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
    from gnss_cli.io.nav_checks import klobuchar_problem

    arr = np.asarray(raw, dtype=np.float64).ravel()
    if klobuchar_problem(arr) is not None or not np.any(arr != 0):
        return None
    return arr[:4], arr[4:]
