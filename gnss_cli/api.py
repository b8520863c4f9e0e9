"""The public Python API: ``gnss_cli.solve(obs, nav, **options) -> xarray.Dataset``.

The same run as ``gnss-solve`` (:class:`gnss_cli.pipeline.run.Run`, its parts joined by
:func:`gnss_cli.pipeline.process`), returned as a dataset instead of CSV text::

    import gnss_cli
    ds = gnss_cli.solve("obs.rnx", "nav.rnx", methods="ls,wls", elevation_mask_deg=15)
    ds.sel(method="wls")["x_m"]          # (time,) ECEF X, m, of WLS only
    ds.to_dataframe()                    # one row per (time, method)

Dimensions: ``time`` (``datetime64[ns]`` in the **GPS time scale**, not UTC) and ``method``
(:class:`SolutionDataset`: ``sel(method="wls")`` selects a method, although xarray's ``sel``
has a ``method=`` argument of its own, the lookup rule; ``sel(time=t, method="nearest")`` still
means that);
``tdop_<letter>`` variables per system when several systems are processed, ``gdop_paper``
with TLS, and the error variables when a reference is given. Every variable has ``units``
and ``long_name`` attributes; the dataset's ``attrs`` say what the run read and took:
``obs_path``, ``nav_paths``, ``systems``, ``warnings`` and ``environment`` (``urban (auto:
variance factor 1.62 > 0.6)``: docs/integrity.md, "The environment").
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
from gnss_cli.errors import KeywordError
from gnss_cli.gnss.frames import ecef2geodetic
from gnss_cli.gnss.time import gps_s2datetime
from gnss_cli.io.reference import Reference
from gnss_cli.pipeline import RunResult, process
from gnss_cli.report import enu_errors, tdop_columns, utc_offset_s

__all__ = ["solve", "to_dataset", "SolutionDataset"]

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
    "gdop_paper": ("1 (tls), 1/m (stls)", "the paper's GDOP formula for the row's method (TLS; STLS on H_{l+1}(w))"), "status": ("", "epoch status (README: Epoch status)"),
    "e_err_m": ("m", "east error against the reference"), "n_err_m": ("m", "north error against the reference"),
    "u_err_m": ("m", "up error against the reference"), "err_3d_m": ("m", "3D error against the reference"),
    "n_excluded": ("1", "satellites excluded by the integrity monitoring (FDE) of the WLS fix"),
    "test_stat": ("1", "chi-square statistic of the pseudorange residuals at the fix"),
    "hpl_m": ("m", "horizontal protection level by solution separation (ls, wls)"), "vpl_m": ("m", "vertical protection level by solution separation (ls, wls)"),
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
    _check_keywords(options)
    cfg = load_config(config, _overrides(options))
    ref = Reference.from_value(reference)
    navs = [nav] if isinstance(nav, (str, PathLike)) else list(nav)
    result = process(obs, navs, cfg)
    epochs = result.epochs
    return to_dataset(result, ref.of(epochs.time_gps_s, epochs.marker_name, utc_offset_s(result), Path(obs).name))


def _keyword_names() -> dict[str, set[str] | None]:
    """Every keyword :func:`solve` takes -> the keys of its table (None: not a table, or any key)."""
    from dataclasses import fields

    from gnss_cli.config import ProcessingConfig

    cfg = load_config()
    tables = {"weights": {f.name for f in fields(cfg.weights)}, "stls": {f.name for f in fields(cfg.stls)} | {"orbit_sigma_m"},
              "smoother": {f.name for f in fields(cfg.smoother)}, "kalman": {f.name for f in fields(cfg.kalman)},
              "wtls": {"column_scaling"}, "signals": None}
    names: dict[str, set[str] | None] = {f.name: None for f in fields(ProcessingConfig)}
    for own in ("signals_second", "orbit_sigma_m", "wtls_column_scaling"):
        names.pop(own, None)
    names.update(tables)
    names.update(dict.fromkeys(_DIRECT_KEYS))
    names.update({"reference": None, "config": None})
    return names


def _check_keywords(options: Mapping[str, Any]) -> None:
    """Unknown keywords (and unknown keys of a table given as a mapping) raise
    :class:`~gnss_cli.errors.KeywordError` naming the nearest valid one (difflib)."""
    import difflib

    names = _keyword_names()
    for key, value in options.items():
        if key not in names:
            near = difflib.get_close_matches(key, sorted(names), n=1)
            hint = f"; did you mean {near[0]!r}?" if near else f"; expected one of {', '.join(sorted(names))}"
            raise KeywordError(f"gnss_cli.solve: unknown keyword {key!r}{hint}")
        table = names[key]
        if table is not None and isinstance(value, Mapping):
            for sub in value:
                if sub not in table:
                    near = difflib.get_close_matches(str(sub), sorted(table), n=1)
                    hint = f"did you mean {near[0]!r}?" if near else f"expected some of {', '.join(sorted(table))}"
                    raise KeywordError(f"gnss_cli.solve: {key}=: unknown key {sub!r}; {hint}")


class SolutionDataset(xr.Dataset):
    """The dataset :func:`solve` returns: an :class:`xarray.Dataset` whose ``sel`` (and its
    variables' ``sel``) also takes ``method="wls"`` (or a list of method keys) as the selection of
    the ``method`` dimension. xarray's own ``method=`` (the lookup rule: ``"nearest"``, ``"pad"``,
    ...) keeps its meaning for any value that is not a method key of the dataset.

    >>> import numpy as np
    >>> ds = SolutionDataset({"x_m": (("time", "method"), np.arange(4.0).reshape(2, 2))},
    ...                      coords={"method": ["ls", "wls"]})
    >>> ds.sel(method="wls")["x_m"].values.tolist()
    [1.0, 3.0]
    """

    __slots__ = ()

    def sel(self, indexers: Mapping[Any, Any] | None = None, method: Any = None, tolerance: Any = None,  # type: ignore[override]
            drop: bool = False, **indexers_kwargs: Any) -> Any:
        indexers, method = _method_selection(self, indexers, method, indexers_kwargs)
        return super().sel(indexers, method=method, tolerance=tolerance, drop=drop, **indexers_kwargs)

    def __getitem__(self, key: Any) -> Any:
        out = super().__getitem__(key)
        return SolutionArray(out) if type(out) is xr.DataArray else out


class SolutionArray(xr.DataArray):
    """A variable of a :class:`SolutionDataset`: ``sel(method="wls")`` selects the method."""

    __slots__ = ()

    def sel(self, indexers: Mapping[Any, Any] | None = None, method: Any = None, tolerance: Any = None,  # type: ignore[override]
            drop: bool = False, **indexers_kwargs: Any) -> Any:
        indexers, method = _method_selection(self, indexers, method, indexers_kwargs)
        return super().sel(indexers, method=method, tolerance=tolerance, drop=drop, **indexers_kwargs)


def _method_selection(obj: Any, indexers: Mapping[Any, Any] | None, method: Any,
                      kwargs: dict[str, Any]) -> tuple[Mapping[Any, Any] | None, Any]:
    """``method=`` as the selection of the ``method`` dimension when its value(s) are method keys
    of ``obj`` and the dimension is not selected otherwise; else xarray's lookup rule."""
    if method is None or "method" not in obj.dims or "method" in (indexers or {}) or "method" in kwargs:
        return indexers, method
    keys = set(np.asarray(obj["method"].values).tolist())
    values = [method] if isinstance(method, str) else list(method) if isinstance(method, (list, tuple)) else None
    if values and all(isinstance(v, str) and v in keys for v in values):
        return {**(indexers or {}), "method": method}, None
    if isinstance(method, str) and method not in _LOOKUP_RULES:  # a mistyped method key, not a lookup rule
        import difflib

        near = difflib.get_close_matches(method, sorted(keys), n=1)
        raise KeyError(f"sel(method={method!r}): not a method of this dataset ({', '.join(sorted(keys))})"
                       + (f"; did you mean {near[0]!r}?" if near else ""))
    return indexers, method


_LOOKUP_RULES = ("nearest", "pad", "ffill", "backfill", "bfill")
"""xarray's own values of ``sel(method=...)``."""


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


def to_dataset(result: RunResult, reference_ecef_m: F64 | None = None) -> "SolutionDataset":
    """A :class:`~gnss_cli.pipeline.RunResult` as a dataset (dims ``time``, ``method``;
    ``sel(method="wls")`` selects a method: :class:`SolutionDataset`).

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
        if any(o.gdop_paper is not None for o in result.solutions.values()):
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
        "environment": result.environment,
    }
    return SolutionDataset(data_vars, coords=coords, attrs=attrs)
