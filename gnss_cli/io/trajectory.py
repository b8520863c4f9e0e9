"""Trajectory CSV in: a uniformly sampled ECEF trajectory (``gnss-solve`` positions or ``time,x_m,y_m,z_m``)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from gnss_cli.errors import InputError, InputFileNotFoundError
from gnss_cli.io.reference import timestamps_gps_s

__all__ = ["Trajectory", "read_trajectory", "STEP_RTOL"]

#: Relative tolerance on the sampling interval (uniform sampling is required).
STEP_RTOL = 1e-6


@dataclass(frozen=True, slots=True)
class Trajectory:
    """A uniformly sampled ECEF trajectory read from CSV.

    Attributes
    ----------
    t_s : ndarray (T,)
        Seconds since the GPS epoch (ISO input) or the input's own seconds (numeric input).
    is_gps_time : bool
        Whether ``t_s`` came from ISO-8601 GPS time stamps.
    xyz_m : ndarray (T, 3)
        ECEF positions, metres.
    dt_s : float
        Sampling interval, seconds.
    """

    t_s: NDArray[np.float64]
    is_gps_time: bool
    xyz_m: NDArray[np.float64]
    dt_s: float


def read_trajectory(path: Path, source_method: str | None = None) -> Trajectory:
    """Read and validate a trajectory CSV.

    Raises
    ------
    InputFileNotFoundError
        The file does not exist.
    InputError
        Missing columns, several methods without ``source_method``, NaN positions,
        fewer than 2 samples, non-increasing or non-uniform time steps.
    """
    if not path.is_file():
        raise InputFileNotFoundError(f"{path}: no such file")
    try:
        frame = pd.read_csv(path)
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: not a readable CSV file ({exc})") from None
    cols = {c.strip(): c for c in frame.columns}
    if "time" not in cols:
        raise InputError(f"{path}: expected a 'time' column, found {list(frame.columns)}")
    names = next((n for n in (["x_m", "y_m", "z_m"], ["x", "y", "z"]) if all(c in cols for c in n)), None)
    if names is None:
        raise InputError(f"{path}: expected ECEF columns x_m,y_m,z_m (or x,y,z), found {list(frame.columns)}")
    if "method" in cols:
        methods = sorted(str(m) for m in frame[cols["method"]].dropna().unique())
        if source_method is not None:
            if source_method not in methods:
                raise InputError(f"{path}: --source-method {source_method!r} not in the file's methods {methods}")
            frame = frame[frame[cols["method"]] == source_method]
        elif len(methods) > 1:
            raise InputError(f"{path}: holds several methods {methods}; choose one with --source-method")
    xyz = frame[[cols[n] for n in names]].to_numpy(dtype=np.float64, na_value=np.nan)
    if xyz.shape[0] < 2:
        raise InputError(f"{path}: expected at least 2 samples, found {xyz.shape[0]}")
    bad = ~np.all(np.isfinite(xyz), axis=1)
    if np.any(bad):
        raise InputError(f"{path}: {int(bad.sum())} rows have missing or NaN positions (first at data row {int(np.argmax(bad)) + 1}); split the trajectory at gaps")
    raw_t = frame[cols["time"]]
    numeric = pd.to_numeric(raw_t, errors="coerce")
    if numeric.notna().all():
        t_s, is_gps = numeric.to_numpy(dtype=np.float64), False
    else:
        try:
            stamps = pd.to_datetime(raw_t, format="ISO8601").to_numpy(dtype="datetime64[ns]")
        except (ValueError, TypeError):
            raise InputError(f"{path}: column 'time' is neither seconds nor ISO-8601 time stamps") from None
        t_s, is_gps = timestamps_gps_s(stamps), True
    steps = np.diff(t_s)
    dt = float(np.median(steps))
    if not dt > 0 or np.any(steps <= 0):
        raise InputError(f"{path}: time stamps must increase strictly")
    worst = float(np.max(np.abs(steps - dt)))
    if worst > STEP_RTOL * dt + 1e-6:
        raise InputError(f"{path}: non-uniform time steps (median {dt:g} s, off by up to {worst:g} s); split the trajectory at gaps")
    return Trajectory(t_s, is_gps, xyz, dt)
