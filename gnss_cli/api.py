"""The public Python API: ``gnss_cli.solve(obs, nav, **options) -> xarray.Dataset``.

The same run as ``gnss-solve`` (:class:`gnss_cli.pipeline.run.Run`, its parts joined by
:func:`gnss_cli.pipeline.process`), returned as a dataset instead of CSV text::

    import gnss_cli
    ds = gnss_cli.solve("obs.rnx", "nav.rnx", methods="ls,wls", elevation_mask_deg=15)
    ds["x_m"].sel({"method": "wls"})     # (time,) ECEF X, m (a dict: ``sel``'s own ``method=`` is the lookup method)
    ds.to_dataframe()                    # one row per (time, method)

Dimensions: ``time`` (``datetime64[ns]`` in the **GPS time scale**, not UTC) and ``method``;
``tdop_<letter>`` variables per system when several systems are processed, ``gdop_paper``
with TLS, and the error variables when a reference is given. Every variable has ``units``
and ``long_name`` attributes.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np
import xarray as xr
from numpy.typing import ArrayLike, NDArray

from gnss_cli.config import load_config
from gnss_cli.gnss.frames import ecef2geodetic
from gnss_cli.gnss.time import gps_s2datetime
from gnss_cli.io.reference import Reference
from gnss_cli.pipeline import RunResult, process
from gnss_cli.report import enu_errors, tdop_columns, utc_offset_s

__all__ = ["solve", "to_dataset"]

F64 = NDArray[np.float64]
PathArg = str | PathLike[str]

_SECTIONS = ("weights", "signals", "stls", "wtls", "smoother", "kalman")
_DIRECT_KEYS = {"lag": ("stls.lag", "smoother.lag"), "kernel": ("stls.kernel",), "order": ("stls.order",),
                "window": ("stls.window",), "motion": ("smoother.motion",)}
"""Multi-epoch keys that may be given directly, as on the command line (``lag=3``, ``motion="cv"``)."""
_UNITS = {
    "x_m": ("m", "ECEF X"), "y_m": ("m", "ECEF Y"), "z_m": ("m", "ECEF Z"),
    "lat_deg": ("degree", "geodetic latitude (WGS-84)"), "lon_deg": ("degree", "geodetic longitude (WGS-84)"),
    "height_m": ("m", "ellipsoidal height (WGS-84)"),
    "clock_m": ("m", "receiver clock bias of the reference system, times c"),
    "n_sat": ("1", "satellites used"), "gdop": ("1", "geometric DOP"), "pdop": ("1", "position DOP"),
    "hdop": ("1", "horizontal DOP"), "vdop": ("1", "vertical DOP"), "tdop": ("1", "time DOP of the reference clock"),
    "gdop_paper": ("1", "TLS GDOP of the paper's covariance"), "status": ("", "epoch status (README: Epoch status)"),
    "e_err_m": ("m", "east error against the reference"), "n_err_m": ("m", "north error against the reference"),
    "u_err_m": ("m", "up error against the reference"), "err_3d_m": ("m", "3D error against the reference"),
    "n_excluded": ("1", "satellites excluded by the integrity monitoring (FDE) of the WLS fix"),
    "test_stat": ("1", "chi-square statistic of the pseudorange residuals at the fix"),
    "hpl_m": ("m", "horizontal protection level (ls, wls)"), "vpl_m": ("m", "vertical protection level (ls, wls)"),
    "vx_m_s": ("m/s", "ECEF X velocity (Doppler)"), "vy_m_s": ("m/s", "ECEF Y velocity (Doppler)"),
    "vz_m_s": ("m/s", "ECEF Z velocity (Doppler)"), "clock_drift_m_s": ("m/s", "receiver clock drift, times c"),
    "gdop_vel": ("1", "velocity DOP of velocity and clock drift"),
}


def solve(
    obs: PathArg,
    nav: PathArg | Sequence[PathArg],
    *,
    reference: ArrayLike | PathArg | None = None,
    config: PathArg | None = None,
    **options: Any,
) -> xr.Dataset:
    """Solve every epoch of a RINEX observation file; the ``gnss-solve`` run as a dataset.

    Parameters
    ----------
    obs : path
        RINEX observation file (2, 3, 4; Hatanaka and gzip allowed).
    nav : path or list of paths
        RINEX navigation file(s).
    reference : array (3,) or path, optional
        Reference for the error variables: an ECEF position (m) or ``"X,Y,Z"``, a SINEX file
        (the station is the observation file's marker name), a CSV with ``time, x_m, y_m, z_m``
        (a moving reference, matched within 10 ms; ``.csv`` suffix) or an RTKLIB ``.pos`` file.
    config : path, optional
        TOML file of processing options (as ``--config``).
    **options
        Processing options by their ``[processing]`` key (``methods="ls,wls"``,
        ``systems="G,E"``, ``measurements="pseudorange,doppler"``, ``iono``, ``tropo``,
        ``elevation_mask_deg``, ...); another table as a mapping (``weights={"model": "equal"}``,
        ``stls={"lag": 3}``, ``smoother={"motion": "cv"}``); ``lag`` (stls and smoother), ``kernel``,
        ``order``, ``window`` (stls) and ``motion`` (smoother) also directly.

    Returns
    -------
    xarray.Dataset
        Dimensions ``time`` (GPS time scale) and ``method`` (module docstring).

    Raises
    ------
    ConfigError
        Unknown or invalid options, or an unreadable reference.
    InputError
        Bad input files.
    NoSolutionError
        No epoch could be solved by any method.
    """
    cfg = load_config(config, _overrides(options))
    ref = Reference.from_value(reference)
    navs = [nav] if isinstance(nav, (str, PathLike)) else list(nav)
    result = process(obs, navs, cfg)
    epochs = result.epochs
    return to_dataset(result, ref.of(epochs.time_gps_s, epochs.marker_name, utc_offset_s(result), Path(obs).name))


def _overrides(options: Mapping[str, Any]) -> dict[str, Any]:
    """Keyword options -> :func:`~gnss_cli.config.load_config` overrides (``"section.key"`` for tables)."""
    out: dict[str, Any] = {}
    for key, value in options.items():
        if key in _SECTIONS and isinstance(value, Mapping):
            out.update({f"{key}.{k}": v for k, v in value.items()})
        elif key in _DIRECT_KEYS:
            out.update(dict.fromkeys(_DIRECT_KEYS[key], value))
        else:
            out[key] = value
    return out


def to_dataset(result: RunResult, reference_ecef_m: F64 | None = None) -> xr.Dataset:
    """A :class:`~gnss_cli.pipeline.RunResult` as a dataset (dims ``time``, ``method``).

    ``reference_ecef_m`` ``(3,)`` or ``(T, 3)`` (ECEF m) adds the E/N/U and 3D errors.
    """
    epochs = result.epochs
    methods = list(result.solutions)
    columns: dict[str, list[np.ndarray]] = {}
    for s in result.solutions.values():
        lat, lon, h = ecef2geodetic(s.x_ecef_m)
        values = {
            "x_m": s.x_ecef_m[:, 0], "y_m": s.x_ecef_m[:, 1], "z_m": s.x_ecef_m[:, 2],
            "lat_deg": np.rad2deg(lat), "lon_deg": np.rad2deg(lon), "height_m": h, "clock_m": s.clock_m,
            "n_sat": s.n_sat, "gdop": s.gdop, "pdop": s.pdop, "hdop": s.hdop, "vdop": s.vdop, "tdop": s.tdop,
        }
        for j, col in enumerate(tdop_columns(result)):
            values[col] = s.tdops[:, j] if s.tdops is not None and s.tdops.shape[1] > j else np.full(s.n_sat.shape, np.nan)
        if "tls" in result.solutions:
            values["gdop_paper"] = s.gdop_paper if s.gdop_paper is not None else np.full(s.n_sat.shape, np.nan)
        values["status"] = s.status.astype(str)
        if reference_ecef_m is not None:
            enu = enu_errors(s.x_ecef_m, reference_ecef_m)
            values.update({"e_err_m": enu[:, 0], "n_err_m": enu[:, 1], "u_err_m": enu[:, 2],
                           "err_3d_m": np.linalg.norm(enu, axis=1)})
        nan = np.full(s.n_sat.shape, np.nan)
        values["n_excluded"] = s.excluded.sum(axis=1) if s.excluded is not None else np.zeros_like(s.n_sat)
        values.update({k: (v if v is not None else nan) for k, v in (("test_stat", s.test_stat), ("hpl_m", s.hpl_m), ("vpl_m", s.vpl_m))})
        vel = s.vel_ecef_m_s if s.vel_ecef_m_s is not None else np.full((nan.size, 3), np.nan)
        values.update({"vx_m_s": vel[:, 0], "vy_m_s": vel[:, 1], "vz_m_s": vel[:, 2]})
        values.update({k: (v if v is not None else nan) for k, v in (("clock_drift_m_s", s.clock_drift_m_s), ("gdop_vel", s.gdop_vel))})
        for name, v in values.items():
            columns.setdefault(name, []).append(np.asarray(v))
    data_vars = {}
    for name, per_method in columns.items():
        units, long_name = _UNITS.get(name, ("1", f"time DOP of the {name[5:]} clock"))
        data_vars[name] = (("time", "method"), np.stack(per_method, axis=1), {"units": units, "long_name": long_name})
    coords = {
        "time": ("time", gps_s2datetime(epochs.time_gps_s),
                 {"time_scale": "GPS", "long_name": "epoch (GPS time scale, not UTC)"}),
        "method": ("method", np.array(methods)),
    }
    attrs = {
        "time_scale": "GPS", "obs_path": epochs.obs_path, "nav_paths": list(epochs.nav_paths),
        "marker_name": epochs.marker_name, "systems": list(epochs.systems), "warnings": list(epochs.warnings),
        "reference_clock_system": epochs.systems[0] if epochs.systems else "",
    }
    return xr.Dataset(data_vars, coords=coords, attrs=attrs)
