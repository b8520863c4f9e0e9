"""Reference positions for the error columns: ``X,Y,Z`` text, SINEX station, a CSV trajectory,
or an RTKLIB ``.pos`` solution file.

Every function returns ECEF positions in metres: ``(3,)`` for a fixed reference, ``(T, 3)``
matched to the epochs for a moving one. Errors name the file and the option.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
from numpy.typing import ArrayLike, NDArray

from gnss_cli.constants import GPS_EPOCH_ISO
from gnss_cli.errors import ConfigError, InputFileNotFoundError

__all__ = ["parse_reference", "reference_from_sinex", "reference_from_csv", "reference_from_pos", "read_pos", "timestamps_gps_s",
           "read_reference_csv", "match_reference", "Reference", "coverage_warning"]

F64 = NDArray[np.float64]

GPS_EPOCH = np.datetime64(GPS_EPOCH_ISO, "ns")


def timestamps_gps_s(t: ArrayLike) -> F64:
    """``datetime64`` time stamps (GPS time scale) -> s since the GPS epoch, as
    :func:`gnss_cli.gnss.time.datetime2gps_s` (io sits below gnss in the layers)."""
    t64 = np.asarray(t, dtype="datetime64[ns]")
    return (t64 - GPS_EPOCH).astype(np.int64).astype(np.float64) * 1e-9


def parse_reference(text: str) -> F64:
    """``"X,Y,Z"`` or ``"ecef:X,Y,Z"`` (ECEF m), or ``"geodetic:LAT,LON,H"`` (WGS-84 degrees,
    degrees, ellipsoidal metres) -> ECEF ``(3,)`` m; raises :class:`ConfigError`.

    The explicit ``geodetic:`` prefix (rather than guessing from the magnitudes) keeps the value
    self-describing wherever the settings are recorded.

    >>> parse_reference("geodetic:0,0,0")
    array([6378137.,       0.,       0.])
    """
    kind, sep, body = text.strip().partition(":")
    kind = kind.strip().lower() if sep else "ecef"
    if not sep:
        body = text
    if kind not in ("ecef", "geodetic"):
        raise ConfigError(f"--reference: expected X,Y,Z (ECEF, m) or geodetic:LAT,LON,H; received {text!r}")
    what = "X,Y,Z in metres" if kind == "ecef" else "geodetic:LAT,LON,H (degrees, degrees, m)"
    try:
        vals = np.array([float(v) for v in body.replace(" ", "").split(",")])
    except ValueError:
        raise ConfigError(f"--reference: expected {what}; received {text!r}") from None
    if vals.size != 3 or not np.all(np.isfinite(vals)):
        raise ConfigError(f"--reference: expected {what}; received {text!r}")
    if kind == "geodetic":
        if not (-90.0 <= vals[0] <= 90.0 and -180.0 <= vals[1] <= 360.0 and -1.0e4 < vals[2] < 1.0e5):
            raise ConfigError(f"--reference: expected geodetic:LAT,LON,H with |LAT| <= 90 deg, LON in [-180, 360] deg "
                              f"and H in metres near the Earth's surface; received {text!r}")
        return _llh_to_ecef(vals[0:1], vals[1:2], vals[2:3])[0]
    if not 6.0e6 < np.linalg.norm(vals) < 7.0e6:
        hint = (" (latitude, longitude, height? write geodetic:LAT,LON,H)"
                if abs(vals[0]) <= 90.0 and abs(vals[1]) <= 360.0 else "")
        raise ConfigError(f"--reference: expected an ECEF position X,Y,Z near the Earth's surface (m); "
                          f"received {text!r}{hint}")
    return vals


def reference_from_sinex(path: str | Path, station: str) -> F64:
    """Station ECEF position (m) from a SINEX ``SOLUTION/ESTIMATE`` block (STAX/STAY/STAZ).

    ``station`` is matched on its first four characters, case-insensitively.
    """
    p = Path(path)
    if not p.is_file():
        raise InputFileNotFoundError(f"{p}: no such SINEX file")
    code = station.strip()[:4].upper()
    if len(code) < 4:
        raise ConfigError(f"--reference-sinex: the observation file's marker name {station!r} is not a 4-character station code")
    found: dict[str, float] = {}
    inside = False
    with open(p, errors="replace") as f:
        for line in f:
            if line.startswith("+SOLUTION/ESTIMATE"):
                inside = True
                continue
            if line.startswith("-SOLUTION/ESTIMATE"):
                break
            if inside and not line.startswith("*"):
                parts = line.split()
                if len(parts) >= 9 and parts[1] in ("STAX", "STAY", "STAZ") and parts[2].upper() == code:
                    found.setdefault(parts[1], float(parts[8]))
    if len(found) != 3:
        raise ConfigError(f"{p}: station {code} not found in SOLUTION/ESTIMATE")
    return np.array([found["STAX"], found["STAY"], found["STAZ"]])


def reference_from_csv(path: str | Path, time_gps_s: F64) -> F64:
    """Per-epoch reference positions ``(T, 3)`` (ECEF m) from a reference CSV
    (:func:`read_reference_csv`), matched to the epochs within 10 ms (:data:`MATCH_TOLERANCE_S`). Epochs without a reference
    row get NaN (their error cells stay empty).
    """
    t_ref, xyz, tow_only = read_reference_csv(path)
    t = np.asarray(time_gps_s, dtype=np.float64)
    return match_reference(t_ref, xyz, np.mod(t, SECONDS_PER_WEEK) if tow_only else t)


SECONDS_PER_WEEK = 604800.0

_TIME_COLUMNS = ("time", "gps_week", "tow_s")
_ECEF_COLUMNS = ("x_m", "y_m", "z_m")
_GEODETIC_NAMES = {"lat_deg": ("lat_deg", "latitude_deg", "lat", "latitude"),
                   "lon_deg": ("lon_deg", "longitude_deg", "lon", "longitude"),
                   "height_m": ("height_m", "h_m", "height", "ellipsoidal_height_m")}
"""Accepted spellings of the geodetic columns (degrees, degrees, ellipsoidal metres)."""
_HEADERLESS = ("week", "tow", "lat", "lon", "height")


def read_reference_csv(path: str | Path) -> tuple[F64, F64, bool]:
    """The rows of a reference CSV: ``(t_s (n,), ECEF (n, 3) m, tow_only)``.

    Time: a ``time`` column (ISO-8601, GPS time scale, as ``truth.csv`` of ``gnss-simulate``
    and the positions CSV of ``gnss-solve``), or ``gps_week`` and ``tow_s`` columns. Position:
    ``x_m, y_m, z_m`` (ECEF m) or ``lat_deg, lon_deg, height_m`` (WGS-84 degrees and
    ellipsoidal metres; also ``latitude``/``longitude``/``height``). A file without a header
    is read as ``week, tow, lat, lon, height`` (the layout of the UrbanNav ground truth).

    ``t_s`` is in s since the GPS epoch, or, when ``tow_only``, in seconds of week: a week
    column that is no GPS week number (outside 0-9999, as the UrbanNav files that repeat the
    seconds of week there) is ignored and the rows are matched by their seconds of week.
    Raises :class:`ConfigError` naming the file.
    """
    p = Path(path)
    if not p.is_file():
        raise InputFileNotFoundError(f"{p}: no such reference file")
    try:
        first = p.read_text(errors="replace").lstrip().split("\n", 1)[0]
        headerless = bool(first) and _is_number(first.split(",")[0])
        df = pd.read_csv(p, header=None, names=list(_HEADERLESS)) if headerless else pd.read_csv(p)
    except (ValueError, pd.errors.ParserError) as exc:
        raise ConfigError(f"{p}: not a CSV file ({exc})") from None
    if df.empty:
        raise ConfigError(f"{p}: reference CSV has no rows")
    if headerless:
        df = df.rename(columns={"week": "gps_week", "tow": "tow_s", "lat": "lat_deg", "lon": "lon_deg",
                                "height": "height_m"})
    else:
        df.columns = [str(c).strip() for c in df.columns]
        for name, spellings in _GEODETIC_NAMES.items():
            for c in spellings:
                if c in df.columns and name not in df.columns:
                    df = df.rename(columns={c: name})
    expected = ("expected a time column or gps_week, tow_s, and x_m, y_m, z_m (ECEF) or lat_deg, lon_deg, height_m; "
                "or no header: week, tow, lat, lon, height")
    try:
        if "time" in df.columns:
            t_ref = timestamps_gps_s(pd.to_datetime(df["time"]).to_numpy(dtype="datetime64[ns]"))
            tow_only = False
        elif "gps_week" in df.columns and "tow_s" in df.columns:
            week = df["gps_week"].to_numpy(dtype=np.float64)
            tow = df["tow_s"].to_numpy(dtype=np.float64)
            tow_only = not bool(np.all((week >= 0) & (week < 10000) & (week == np.round(week))))
            t_ref = tow if tow_only else week * SECONDS_PER_WEEK + tow
        else:
            raise ConfigError(f"{p}: reference CSV has no time; {expected}")
        if all(c in df.columns for c in _ECEF_COLUMNS):
            xyz = df[list(_ECEF_COLUMNS)].to_numpy(dtype=np.float64)
        elif all(c in df.columns for c in _GEODETIC_NAMES):
            llh = df[list(_GEODETIC_NAMES)].to_numpy(dtype=np.float64)
            if np.any(np.abs(llh[:, 0]) > 90.0):
                raise ConfigError(f"{p}: reference latitude outside -90..90 degrees")
            xyz = _llh_to_ecef(llh[:, 0], llh[:, 1], llh[:, 2])
        else:
            raise ConfigError(f"{p}: reference CSV has no position columns; {expected}")
    except (ValueError, TypeError) as exc:
        if isinstance(exc, ConfigError):
            raise
        raise ConfigError(f"{p}: bad time or position value ({' '.join(str(exc).split())})") from None
    if not np.all(np.isfinite(t_ref)):
        raise ConfigError(f"{p}: reference CSV has rows without a time")
    return t_ref, xyz, tow_only


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


MATCH_TOLERANCE_S = 0.01
"""A reference row belongs to the nearest epoch within 10 ms: receivers tag their epochs some
milliseconds off the whole second (the UrbanNav u-blox file: 4 ms after it, against a ground
truth on whole seconds); at 30 m/s 10 ms are 0.3 m of reference motion."""


def match_reference(t_ref: F64, xyz: F64, time_gps_s: F64) -> F64:
    """Reference rows nearest to each epoch, NaN where none is within :data:`MATCH_TOLERANCE_S`."""
    order = np.argsort(t_ref)
    t_ref, xyz = t_ref[order], xyz[order]
    k = np.clip(np.searchsorted(t_ref, time_gps_s), 1, max(t_ref.size - 1, 1)) if t_ref.size > 1 else np.zeros(time_gps_s.size, dtype=int)
    k = np.where(np.abs(t_ref[k - 1] - time_gps_s) < np.abs(t_ref[k] - time_gps_s), k - 1, k) if t_ref.size > 1 else k
    out = xyz[k].copy()
    out[np.abs(t_ref[k] - time_gps_s) > MATCH_TOLERANCE_S] = np.nan
    return out


_A_WGS84 = 6378137.0
_E2_WGS84 = 6.69437999014e-3


def _llh_to_ecef(lat_deg: F64, lon_deg: F64, h_m: F64) -> F64:
    lat, lon = np.deg2rad(lat_deg), np.deg2rad(lon_deg)
    n = _A_WGS84 / np.sqrt(1.0 - _E2_WGS84 * np.sin(lat) ** 2)
    return np.stack([(n + h_m) * np.cos(lat) * np.cos(lon), (n + h_m) * np.cos(lat) * np.sin(lon),
                     (n * (1.0 - _E2_WGS84) + h_m) * np.sin(lat)], axis=-1)


def read_pos(path: str | Path) -> tuple[F64, F64, str]:
    """An RTKLIB solution file: ``(t_s (n,), ECEF (n, 3) m, time system)``.

    Time is ``yyyy/mm/dd hh:mm:ss.sss`` or ``week tow``, in seconds since 1980-01-06 00:00:00
    of the file's time scale (``"GPST"`` or ``"UTC"``, from the ``%`` column header; GPST when
    it does not say); positions are ``x/y/z-ecef`` or ``latitude(deg) longitude(deg) height(m)``
    (WGS-84 ellipsoidal height), or latitude/longitude in ``d m s``. Raises :class:`ConfigError`.
    """
    p = Path(path)
    if not p.is_file():
        raise InputFileNotFoundError(f"{p}: no such reference file")
    scale, layout, times, coords = "GPST", "xyz", [], []
    with open(p, errors="replace") as f:
        for lineno, line in enumerate(f, 1):
            if line.startswith(("%", "#", ";")):
                if "x-ecef" in line or "latitude" in line:
                    scale = "UTC" if "UTC" in line.split()[1:3] else "GPST"
                    layout = "xyz" if "x-ecef" in line else ("dms" if "latitude(d'" in line else "llh")
                continue
            parts = line.split()
            if not parts:
                continue
            try:
                if "/" in parts[0]:
                    times.append(np.datetime64(parts[0].replace("/", "-") + "T" + parts[1], "ns"))
                else:
                    times.append(np.datetime64("1980-01-06", "ns") + np.timedelta64(
                        int(round((int(parts[0]) * 604800 + float(parts[1])) * 1e9)), "ns"))
                if layout == "dms":
                    v = [float(x) for x in parts[2:9]]
                    sign = [-1.0 if parts[k].startswith("-") else 1.0 for k in (2, 5)]
                    coords.append([sign[0] * (abs(v[0]) + v[1] / 60 + v[2] / 3600), sign[1] * (abs(v[3]) + v[4] / 60 + v[5] / 3600), v[6]])
                else:
                    coords.append([float(x) for x in parts[2:5]])
            except (ValueError, IndexError):
                raise ConfigError(f"{p}:{lineno}: not an RTKLIB solution line: {line.strip()[:60]!r}") from None
    if not times:
        raise ConfigError(f"{p}: no solution lines (expected an RTKLIB .pos file)")
    xyz = np.asarray(coords, dtype=np.float64)
    if layout != "xyz":
        xyz = _llh_to_ecef(xyz[:, 0], xyz[:, 1], xyz[:, 2])
    return timestamps_gps_s(np.array(times, dtype="datetime64[ns]")), xyz, scale


def reference_from_pos(path: str | Path, time_gps_s: F64, gps_minus_utc_s: F64 | float = 0.0) -> F64:
    """Per-epoch reference positions ``(T, 3)`` (ECEF m) from an RTKLIB ``.pos`` file
    (:func:`read_pos`), matched to the epochs within 10 ms as :func:`reference_from_csv`.

    A UTC file is compared with ``time_gps_s - gps_minus_utc_s`` (the leap seconds of each
    epoch, s). Epochs without a solution line get NaN.
    """
    t_ref, xyz, scale = read_pos(path)
    t = np.asarray(time_gps_s, dtype=np.float64)
    if scale == "UTC":
        t = t - np.broadcast_to(np.asarray(gps_minus_utc_s, dtype=np.float64), t.shape)
    return match_reference(t_ref, xyz, t)


class Reference:
    """The one reference resolver of a run: a fixed ECEF position, a SINEX station, or a moving
    reference (CSV or RTKLIB ``.pos``), resolved for any run of epochs.

    Build it with :meth:`from_options` (the command line's four options) or :meth:`from_value`
    (the Python API's ``reference=``); the files are read once. :meth:`of` gives the reference of
    a run's epochs: ``(3,)`` (fixed) or ``(T, 3)`` (moving; NaN rows where no reference epoch is
    within 10 ms), ECEF m, or None when no reference was given.
    """

    def __init__(self, fixed: F64 | None = None, sinex: Path | None = None,
                 rows: tuple[F64, F64, bool] | None = None, pos: tuple[F64, F64, str] | None = None,
                 source: str = "") -> None:
        self.fixed, self.sinex, self.rows, self.pos = fixed, sinex, rows, pos
        self.source = source
        """What was given, for the outputs that record the settings (``none`` without a reference)."""

    @classmethod
    def from_options(cls, reference: str | None = None, sinex: Path | None = None, csv: Path | None = None,
                     pos: Path | None = None) -> "Reference":
        """From ``--reference X,Y,Z`` (or ``geodetic:LAT,LON,H``), ``--reference-sinex``, ``--reference-csv`` or ``--reference-pos`` (at most one)."""
        given = [v for v in (reference, sinex, csv, pos) if v is not None]
        if len(given) > 1:
            raise ConfigError("give one of --reference, --reference-sinex, --reference-csv, --reference-pos")
        source = str(given[0]) if given else "none"
        return cls(parse_reference(reference) if reference else None, Path(sinex) if sinex is not None else None,
                   read_reference_csv(csv) if csv is not None else None, read_pos(pos) if pos is not None else None,
                   source)

    @classmethod
    def from_value(cls, value: ArrayLike | str | Path | None) -> "Reference":
        """From the Python API's ``reference=``: an ECEF position ``(3,)`` (m), ``"X,Y,Z"`` or
        ``"geodetic:LAT,LON,H"`` (:func:`parse_reference`), or a
        path: ``.csv`` (moving reference), ``.pos`` (RTKLIB solution) or a SINEX file (by the
        observation file's marker name)."""
        if value is None:
            return cls(source="none")
        if isinstance(value, (str, Path)):
            path = Path(value)
            if isinstance(value, str) and not path.exists() and ("," in value or value.lower().startswith(("ecef:", "geodetic:"))):
                return cls.from_options(reference=value)
            suffix = path.suffix.lower()
            if suffix == ".csv":
                return cls.from_options(csv=path)
            if suffix == ".pos":
                return cls.from_options(pos=path)
            return cls.from_options(sinex=path)
        ref = np.asarray(value, dtype=np.float64)
        if ref.shape != (3,) or not np.all(np.isfinite(ref)):
            raise ConfigError(f"reference: expected a finite ECEF position of shape (3,) in metres, or a path; received {value!r}")
        return cls(ref, source=",".join(f"{v:.4f}" for v in ref))

    @property
    def given(self) -> bool:
        return self.fixed is not None or self.sinex is not None or self.rows is not None or self.pos is not None

    def of(self, time_gps_s: F64, marker_name: str, gps_minus_utc_s: F64 | float, obs_name: str = "") -> F64 | None:
        """The reference of the epochs ``time_gps_s`` (s, GPS) of an observation file whose marker
        is ``marker_name``; ``gps_minus_utc_s`` turns a ``.pos`` reference in UTC to GPS time."""
        if self.sinex is not None and self.fixed is None:
            if not marker_name:
                raise ConfigError(f"--reference-sinex: {obs_name or 'the observation file'} has no MARKER NAME to look up")
            self.fixed = reference_from_sinex(self.sinex, marker_name)
        if self.rows is not None:
            t_ref, xyz, tow_only = self.rows
            t = np.asarray(time_gps_s, dtype=np.float64)
            return match_reference(t_ref, xyz, np.mod(t, SECONDS_PER_WEEK) if tow_only else t)
        if self.pos is not None:
            t_ref, xyz, scale = self.pos
            return match_reference(t_ref, xyz, time_gps_s - (gps_minus_utc_s if scale == "UTC" else 0.0))
        return self.fixed

    @property
    def moving(self) -> bool:
        """A reference given per epoch (CSV or ``.pos``), which may miss epochs."""
        return self.rows is not None or self.pos is not None


def coverage_warning(matched: int, solved: int, source: str) -> str | None:
    """The warning of a moving reference that matches no solved epoch, or fewer than half of them.

    >>> coverage_warning(10, 100, "truth.csv")
    'reference truth.csv matches 10 of the 100 solved epochs (errors are computed on those only)'
    >>> coverage_warning(60, 100, "truth.csv") is None
    True
    """
    if solved <= 0 or 2 * matched >= solved:
        return None
    if matched == 0:
        return (f"reference {source} matches none of the {solved} solved epochs (within 10 ms): no error statistics; "
                f"check its time scale (GPS time) and span")
    return f"reference {source} matches {matched} of the {solved} solved epochs (errors are computed on those only)"
