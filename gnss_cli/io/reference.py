"""Reference positions for the error columns: ``X,Y,Z`` text, SINEX station, or a CSV trajectory.

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

__all__ = ["parse_reference", "reference_from_sinex", "reference_from_csv", "timestamps_gps_s"]

F64 = NDArray[np.float64]

GPS_EPOCH = np.datetime64(GPS_EPOCH_ISO, "ns")


def timestamps_gps_s(t: ArrayLike) -> F64:
    """``datetime64`` time stamps (GPS time scale) -> s since the GPS epoch, as
    :func:`gnss_cli.gnss.time.datetime2gps_s` (io sits below gnss in the layers)."""
    t64 = np.asarray(t, dtype="datetime64[ns]")
    return (t64 - GPS_EPOCH).astype(np.int64).astype(np.float64) * 1e-9


def parse_reference(text: str) -> F64:
    """``"X,Y,Z"`` (ECEF m) -> ``(3,)``; raises :class:`ConfigError`."""
    try:
        vals = np.array([float(v) for v in text.replace(" ", "").split(",")])
    except ValueError:
        raise ConfigError(f"--reference: expected X,Y,Z in metres; received {text!r}") from None
    if vals.size != 3 or not np.all(np.isfinite(vals)) or not 6.0e6 < np.linalg.norm(vals) < 7.0e6:
        raise ConfigError(f"--reference: expected an ECEF position X,Y,Z near the Earth's surface (m); received {text!r}")
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
    """Per-epoch reference positions ``(T, 3)`` (ECEF m) from a CSV with ``time, x_m, y_m, z_m``.

    ``time`` is ISO-8601 in the GPS time scale (as ``truth.csv`` of ``gnss-simulate`` and the
    positions CSV of ``gnss-solve``); epochs are matched to 1 ms. Epochs without a reference
    row get NaN (their error cells stay empty).
    """
    p = Path(path)
    if not p.is_file():
        raise InputFileNotFoundError(f"{p}: no such reference file")
    try:
        df = pd.read_csv(p)
    except (ValueError, pd.errors.ParserError) as exc:
        raise ConfigError(f"{p}: not a CSV file ({exc})") from None
    missing = [c for c in ("time", "x_m", "y_m", "z_m") if c not in df.columns]
    if missing:
        raise ConfigError(f"{p}: reference CSV lacks column(s) {missing}; expected time, x_m, y_m, z_m")
    try:
        t_ref = timestamps_gps_s(pd.to_datetime(df["time"]).to_numpy(dtype="datetime64[ns]"))
    except (ValueError, TypeError) as exc:
        raise ConfigError(f"{p}: bad time column ({exc})") from None
    xyz = df[["x_m", "y_m", "z_m"]].to_numpy(dtype=np.float64)
    order = np.argsort(t_ref)
    t_ref, xyz = t_ref[order], xyz[order]
    k = np.clip(np.searchsorted(t_ref, time_gps_s), 1, max(t_ref.size - 1, 1)) if t_ref.size > 1 else np.zeros(time_gps_s.size, dtype=int)
    k = np.where(np.abs(t_ref[k - 1] - time_gps_s) < np.abs(t_ref[k] - time_gps_s), k - 1, k) if t_ref.size > 1 else k
    out = xyz[k].copy()
    out[np.abs(t_ref[k] - time_gps_s) > 1e-3] = np.nan
    return out
