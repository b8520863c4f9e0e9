"""Solutions -> tables and statistics (pandas lives here and in io, not in the numerics).

Tables
------
positions : one row per epoch and method (the default CSV).
errors    : E/N/U and 3D errors against a reference (m).
dop       : satellites used and the five DOPs (+ ``gdop_paper`` with tls or stls --lag L).
summary   : one row per method: epochs, mean/std/RMS of E, N, U, 3D errors, the E/N/U
            error covariance, mean/median/max of every DOP.

DOP conventions with several systems (one receiver clock per system): ``gdop`` includes
every clock; ``tdop`` is the TDOP of the reference clock, the first system of the run
(``RunResult.epochs.systems``: G, E, C, J, R order by default, else the ``--systems``
order); and one extra column ``tdop_<letter>`` per processed system (``tdop_G``,
``tdop_E``, ...) holds that system's TDOP, ``sqrt(Q)`` of its clock's diagonal element of
the noise gain ``Q = J J^T``, so ``tdop`` equals ``tdop_<first system>``. A system without
satellites in an epoch has an empty ``tdop_<letter>`` cell there. With one system the
extra columns are not written.

Uncertainty columns (appended after every other column): ``sde_m``, ``sdn_m``, ``sdu_m``
are the square roots of the diagonal of ``R C R^T``, with ``C`` the position block of the
method's ``cov_m2`` (ECEF, m^2) and ``R`` the ECEF -> ENU rotation at the solution; ``sden_m2``,
``sdnu_m2``, ``sdue_m2`` are its off-diagonal elements (E-N, N-U, U-E covariances, m^2). For
the smoothed stls rows (``--lag``) ``cov_m2`` is the multi-epoch covariance of the window's
behavior (:func:`gnss_cli.behavior.multi_epoch.window_covs`); ``fallback_wls`` epochs keep the
WLS covariance; for kf the smoothed (or filtered) state covariance.

Velocity columns (the very last, :data:`VELOCITY_COLUMNS`): always written, empty when the
observation file has no Doppler.

Time: ``time`` is GPS time, or UTC with ``time_system="utc"`` (GPST minus
:func:`utc_offset_s`); ``gps_week`` and ``tow_s`` are GPS time in both.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from gnss_cli.gnss.frames import ecef2enu_rotation, ecef2geodetic
from gnss_cli.gnss.time import gps_minus_utc_s, gps_s2datetime, gps_s2week_tow
from gnss_cli.pipeline.identification import Identification
from gnss_cli.pipeline.results import EpochStatus, RunResult
from gnss_cli.stanford import integrity_statistics

F64 = NDArray[np.float64]

POSITION_COLUMNS = [
    "time", "gps_week", "tow_s", "method", "x_m", "y_m", "z_m", "lat_deg", "lon_deg", "height_m",
    "clock_m", "n_sat", "gdop", "pdop", "hdop", "vdop", "tdop", "status",
]
ERROR_COLUMNS = ["e_err_m", "n_err_m", "u_err_m", "err_3d_m"]
SD_COLUMNS = ["sde_m", "sdn_m", "sdu_m", "sden_m2", "sdnu_m2", "sdue_m2"]
DOP_NAMES = ["gdop", "pdop", "hdop", "vdop", "tdop"]
FLOAT_FORMATS = {
    "tow_s": "{:.3f}", "x_m": "{:.4f}", "y_m": "{:.4f}", "z_m": "{:.4f}", "lat_deg": "{:.9f}",
    "lon_deg": "{:.9f}", "height_m": "{:.4f}", "clock_m": "{:.4f}", "mean_lat_deg": "{:.9f}", "mean_lon_deg": "{:.9f}",
    "sden_m2": "{:.6f}", "sdnu_m2": "{:.6f}", "sdue_m2": "{:.6f}",
    "elevation_deg": "{:.2f}", "azimuth_deg": "{:.2f}", "snr_dbhz": "{:.1f}", "weight": "{:.6f}",
    "vx_m_s": "{:.4f}", "vy_m_s": "{:.4f}", "vz_m_s": "{:.4f}", "clock_drift_m_s": "{:.4f}",
}


def enu_errors(x_ecef_m: F64, reference_ecef_m: F64) -> F64:
    """E/N/U errors ``(T, 3)`` (m) of positions against a reference ``(3,)`` or ``(T, 3)``.

    The rotation is taken at the reference point (each epoch's, for a moving reference).
    """
    ref = np.broadcast_to(np.asarray(reference_ecef_m, dtype=np.float64), x_ecef_m.shape)
    lat, lon, _ = ecef2geodetic(ref)
    rot = ecef2enu_rotation(lat, lon)
    return np.einsum("tij,tj->ti", rot, x_ecef_m - ref)


def _iso(t_gps_s: F64) -> NDArray[np.str_]:
    return np.datetime_as_string(gps_s2datetime(t_gps_s), unit="ms")


def utc_offset_s(result: RunResult) -> F64:
    """GPS - UTC (s) at every epoch: the navigation header's ``LEAP SECONDS`` when it had one,
    else the built-in table (:data:`gnss_cli.gnss.time.GPS_UTC_STEPS`)."""
    t = result.epochs.time_gps_s
    leap = result.epochs.leap_seconds
    return np.full(t.shape, float(leap)) if leap is not None else gps_minus_utc_s(t)


def output_time_s(result: RunResult, time_system: str = "gpst") -> F64:
    """Epochs in the output time scale, s since 1980-01-06 00:00:00 of that scale."""
    t = result.epochs.time_gps_s
    return t - utc_offset_s(result) if time_system == "utc" else t


def enu_covariances(x_ecef_m: F64, cov_m2: F64) -> F64:
    """``(T, 3, 3)`` position covariances rotated to local ENU at each solution (m^2):
    ``R C R^T`` with ``C = cov_m2[:, :3, :3]`` (ECEF); NaN where the position is missing."""
    lat, lon, _ = ecef2geodetic(np.where(np.isfinite(x_ecef_m), x_ecef_m, 1.0))
    rot = ecef2enu_rotation(lat, lon)
    cov = np.einsum("tij,tjk,tlk->til", rot, cov_m2[:, :3, :3], rot)
    cov[~np.isfinite(x_ecef_m).all(axis=1)] = np.nan
    return cov


def tdop_columns(result: RunResult) -> list[str]:
    """``tdop_<letter>`` of every processed system when there are several, else ``[]``."""
    systems = result.epochs.systems
    return [f"tdop_{s}" for s in systems] if len(systems) > 1 else []


def positions_table(result: RunResult, reference_ecef_m: F64 | None = None, time_system: str = "gpst") -> pd.DataFrame:
    """One row per epoch and method (see the README for every column and unit).

    With several systems, ``tdop_<letter>`` columns follow ``tdop`` (module docstring); the
    uncertainty columns :data:`SD_COLUMNS` come last. ``time_system``: ``gpst`` or ``utc``
    for the ``time`` column.
    """
    t = result.epochs.time_gps_s
    week, tow = gps_s2week_tow(t)
    iso = _iso(output_time_s(result, time_system))
    frames = []
    with_paper = any(s.gdop_paper is not None for s in result.solutions.values())
    for method, s in result.solutions.items():
        lat, lon, h = ecef2geodetic(s.x_ecef_m)
        df = pd.DataFrame(
            {
                "time": iso, "gps_week": week, "tow_s": tow, "method": method,
                "x_m": s.x_ecef_m[:, 0], "y_m": s.x_ecef_m[:, 1], "z_m": s.x_ecef_m[:, 2],
                "lat_deg": np.rad2deg(lat), "lon_deg": np.rad2deg(lon), "height_m": h,
                "clock_m": s.clock_m, "n_sat": s.n_sat,
                "gdop": s.gdop, "pdop": s.pdop, "hdop": s.hdop, "vdop": s.vdop, "tdop": s.tdop,
                "status": s.status,
            }
        )
        for j, col in enumerate(tdop_columns(result)):
            values = s.tdops[:, j] if s.tdops is not None and s.tdops.shape[1] > j else np.nan
            df.insert(df.columns.get_loc("status"), col, values)
        if with_paper:
            df.insert(df.columns.get_loc("status"), "gdop_paper", s.gdop_paper if s.gdop_paper is not None else np.nan)
        if reference_ecef_m is not None:
            enu = enu_errors(s.x_ecef_m, reference_ecef_m)
            df["e_err_m"], df["n_err_m"], df["u_err_m"] = enu[:, 0], enu[:, 1], enu[:, 2]
            df["err_3d_m"] = np.linalg.norm(enu, axis=1)
        cov = enu_covariances(s.x_ecef_m, s.cov_m2)
        with np.errstate(invalid="ignore"):
            df["sde_m"], df["sdn_m"], df["sdu_m"] = (np.sqrt(cov[:, k, k]) for k in range(3))
        df["sden_m2"], df["sdnu_m2"], df["sdue_m2"] = cov[:, 0, 1], cov[:, 1, 2], cov[:, 2, 0]
        _add_integrity_columns(df, s, result.epochs.sv)
        _add_velocity_columns(df, s)
        frames.append(df)
    return pd.concat(frames, ignore_index=True)


INTEGRITY_COLUMNS = ["n_excluded", "excluded", "test_stat", "hpl_m", "vpl_m"]
"""Appended after every other column: FDE exclusions (the WLS set, for every method), the
chi-square statistic (every snapshot method) and the protection levels (ls/wls rows; README
"Integrity")."""


def _add_integrity_columns(df: pd.DataFrame, s, sv: NDArray[np.str_]) -> None:  # type: ignore[no-untyped-def]
    T = len(df)
    excluded = s.excluded if s.excluded is not None else np.zeros((T, sv.size), dtype=bool)
    names = np.full(T, "", dtype=object)
    for t in np.flatnonzero(excluded.any(axis=1)):  # only the epochs with exclusions
        names[t] = " ".join(sv[excluded[t]])
    df["n_excluded"] = excluded.sum(axis=1)
    df["excluded"] = names
    for col, values in (("test_stat", s.test_stat), ("hpl_m", s.hpl_m), ("vpl_m", s.vpl_m)):
        df[col] = values if values is not None else np.nan


VELOCITY_COLUMNS = ["vx_m_s", "vy_m_s", "vz_m_s", "clock_drift_m_s", "gdop_vel"]
"""The last columns: receiver velocity (ECEF, m/s), clock drift (m/s) and velocity DOP, from
the Doppler WLS at the fix (kf: the filter's state); empty cells when the file has no Doppler."""


def _add_velocity_columns(df: pd.DataFrame, s) -> None:  # type: ignore[no-untyped-def]
    v = s.vel_ecef_m_s if s.vel_ecef_m_s is not None else np.full((len(df), 3), np.nan)
    have = np.isfinite(s.x_ecef_m).all(axis=1)
    df["vx_m_s"], df["vy_m_s"], df["vz_m_s"] = (np.where(have, v[:, i], np.nan) for i in range(3))
    for col, values in (("clock_drift_m_s", s.clock_drift_m_s), ("gdop_vel", s.gdop_vel)):
        df[col] = np.where(have, values, np.nan) if values is not None else np.nan


def summary_table(result: RunResult, reference_ecef_m: F64 | None = None) -> pd.DataFrame:
    """One row per method: error statistics (m, m^2) and DOP statistics over solved epochs."""
    rows = []
    for method, s in result.solutions.items():
        ok = s.status == EpochStatus.OK
        row: dict[str, object] = {"method": method}
        settings = result.settings.get(method)
        row.update({k: v for k, v in settings.to_dict().items() if k != "method"} if settings is not None else
                   dict.fromkeys(SETTINGS_COLUMNS, ""))
        row.update({"epochs": int(s.status.size), "epochs_solved": int(ok.sum())})
        if reference_ecef_m is not None:
            enu = enu_errors(s.x_ecef_m, reference_ecef_m)
            integrity = integrity_statistics(ok, enu, s.hpl_m, s.vpl_m)
            matched = ok & np.isfinite(enu).all(axis=1)
            row["epochs_with_reference"] = int(matched.sum())
            enu = enu[matched]
            err3 = np.linalg.norm(enu, axis=1)
            for k, name in enumerate("enu"):
                row[f"mean_{name}_m"] = _stat(np.mean, enu[:, k])
                row[f"std_{name}_m"] = _stat(np.std, enu[:, k])
                row[f"rms_{name}_m"] = _stat(lambda v: np.sqrt(np.mean(v**2)), enu[:, k])
            row["mean_3d_m"] = _stat(np.mean, err3)
            row["std_3d_m"] = _stat(np.std, err3)
            row["rms_3d_m"] = _stat(lambda v: np.sqrt(np.mean(v**2)), err3)
            row.update(integrity)
            cov = np.cov(enu.T, ddof=0) if enu.shape[0] > 1 else np.full((3, 3), np.nan)
            for i, a in enumerate("enu"):
                for j, b in enumerate("enu"):
                    if j >= i:
                        row[f"cov_{a}{b}_m2"] = cov[i, j]
        dops = {d: getattr(s, d) for d in DOP_NAMES}
        for j, col in enumerate(tdop_columns(result)):
            if s.tdops is not None and s.tdops.shape[1] > j:
                dops[col] = s.tdops[:, j]
        if s.gdop_paper is not None:
            dops["gdop_paper"] = s.gdop_paper
        for d, v in dops.items():  # over the solved epochs, with or without a reference
            v = v[ok]
            row[f"mean_{d}"] = _stat(np.mean, v)
            row[f"median_{d}"] = _stat(np.median, v)
            row[f"max_{d}"] = _stat(np.max, v)
        row.update(_mean_position(s.x_ecef_m))
        rows.append(row)
    return pd.DataFrame(rows)


def _mean_position(x_ecef_m: F64) -> dict[str, float]:
    """Mean ECEF and geodetic position of the epochs with a position (``ok``, ``fallback_wls``), and the std of their E/N/U
    offsets from that mean (population std, ddof 0), in the local frame at the mean."""
    x = x_ecef_m[np.isfinite(x_ecef_m).all(axis=1)]
    if not x.size:
        return {k: float("nan") for k in MEAN_POSITION_COLUMNS}
    mean = x.mean(axis=0)
    lat, lon, h = ecef2geodetic(mean)
    enu = enu_errors(x, mean)
    out = {"mean_x_m": mean[0], "mean_y_m": mean[1], "mean_z_m": mean[2], "mean_lat_deg": float(np.rad2deg(lat)),
           "mean_lon_deg": float(np.rad2deg(lon)), "mean_height_m": float(h)}
    out.update({f"scatter_{c}_m": float(np.std(enu[:, k])) for k, c in enumerate("enu")})
    return {k: float(v) for k, v in out.items()}


SETTINGS_COLUMNS = ["estimator", "model", "lag", "window", "measurements", "integrity"]
"""``summary.csv`` columns after ``method``: what the method resolved to
(:class:`~gnss_cli.pipeline.methods.MethodSettings`)."""

MEAN_POSITION_COLUMNS = ["mean_x_m", "mean_y_m", "mean_z_m", "mean_lat_deg", "mean_lon_deg", "mean_height_m",
                         "scatter_e_m", "scatter_n_m", "scatter_u_m"]
"""``summary.csv`` columns of the mean position of a method's solved epochs (m, deg) and the
std of the E/N/U offsets about it (m)."""


def _stat(fn, v: F64) -> float:  # type: ignore[no-untyped-def]
    v = v[np.isfinite(v)]
    return float(fn(v)) if v.size else float("nan")


def to_csv_text(df: pd.DataFrame) -> str:
    """CSV text with fixed float formats, empty cells for missing values, header always.

    Float columns are formatted to text first (:func:`_float_cells`); pandas writes the rest.
    """
    out = df.copy()
    for col in out.columns:
        if out[col].dtype.kind == "f":
            out[col] = _float_cells(out[col], _float_format(str(col)))
    return out.to_csv(index=False, lineterminator="\n")


def _float_format(col: str) -> str:
    is_dop = col in DOP_NAMES or col == "gdop_paper" or col.startswith("tdop_")
    return FLOAT_FORMATS.get(col, "{:.3f}" if is_dop else "{:.4f}")


def _float_cells(values: pd.Series, fmt: str) -> NDArray[np.object_]:
    """A float column as text in the format ``fmt``; empty where the value is missing or not finite."""
    vals = values.to_numpy(dtype=np.float64, na_value=np.nan)
    finite = np.isfinite(vals)
    cells = np.full(vals.size, "", dtype=object)
    cells[finite] = [fmt.format(v) for v in vals[finite].tolist()]  # Python floats: numpy scalars format 1.7x slower
    return cells


def errors_table(positions: pd.DataFrame) -> pd.DataFrame:
    return positions[["time", "gps_week", "tow_s", "method", *ERROR_COLUMNS, "status"]]


def dop_table(positions: pd.DataFrame) -> pd.DataFrame:
    """Satellites used and the DOPs: the five DOPs, ``tdop_<letter>`` per system when there
    are several, ``gdop_paper`` when a method fills it (tls, stls --lag L)."""
    cols = ["time", "gps_week", "tow_s", "method", "n_sat", *DOP_NAMES]
    cols += [c for c in positions.columns if c.startswith("tdop_")]
    if "gdop_paper" in positions:
        cols.append("gdop_paper")
    return positions[[*cols, "status"]]


IDENTIFICATION_COLUMNS = ["time", "gps_week", "tow_s", "x_m", "y_m", "z_m", "e_m", "n_m", "u_m", "kind"]
"""Columns of the ``gnss-identify`` CSV."""


def identification_table(ident: Identification) -> pd.DataFrame:
    """One row per fitted or predicted sample: time, ECEF and ENU positions (m), ``kind``.

    With GPS time stamps ``time`` is ISO-8601 (GPS scale) with ``gps_week`` and ``tow_s``;
    with numeric input ``time`` is the input's seconds and the week columns are empty.
    """
    xyz, enu, times = ident.xyz_m, ident.enu_m, ident.t_s
    table = pd.DataFrame({"x_m": xyz[:, 0], "y_m": xyz[:, 1], "z_m": xyz[:, 2],
                          "e_m": enu[:, 0], "n_m": enu[:, 1], "u_m": enu[:, 2], "kind": ident.kinds})
    if ident.is_gps_time:
        week, tow = gps_s2week_tow(times)
        table.insert(0, "tow_s", np.round(tow, 3))
        table.insert(0, "gps_week", week)
        table.insert(0, "time", _iso(times))
    else:
        table.insert(0, "tow_s", np.nan)
        table.insert(0, "gps_week", pd.array([None] * len(times), dtype="Int64"))
        table.insert(0, "time", times)
    return table


SATELLITE_COLUMNS = ["time", "method", "satellite", "elevation_deg", "azimuth_deg", "snr_dbhz", "residual_m",
                     "sigma_m", "weight", "used", "reason"]
"""Columns of ``satellites.csv`` (one row per observed satellite and epoch, README)."""


def satellites_table(result: RunResult, config) -> pd.DataFrame:  # type: ignore[no-untyped-def]
    """Per-satellite rows of the wls solution (else the first method's): geometry at the fix,
    C/N0, post-fit residual, sigma, robust weight, and why a satellite was not used.

    ``weight``: the robust weight factor ``w_i`` of a used satellite (``--robust``; 1 for a
    plain fit), its effective sigma is ``sigma_m / sqrt(weight)``. ``reason``: ``no_ephemeris``,
    ``excluded_by_user``, ``snr_mask``, ``excluded_fde``, ``below_mask`` (elevation mask),
    ``no_second_frequency`` (iono-free), or, for a satellite of an epoch that was not solved,
    the epoch's status; for a used satellite ``downweighted`` when its weight is below
    :data:`~gnss_cli.pipeline.results.DOWNWEIGHTED_BELOW` or the NLOS detector multiplied its
    variance by more than its inverse (``[nlos] variance_factor``; ``sigma_m`` includes it), else empty.
    """
    from gnss_cli.gnss.frames import satellite_azimuth_elevation_deg
    from gnss_cli.pipeline.results import DOWNWEIGHTED_BELOW, UNUSED_REASONS

    data = result.epochs
    method = "wls" if "wls" in result.solutions else next(iter(result.solutions))
    s = result.solutions[method]
    T, n = data.sat_ecef_m.shape[:2]
    az, el = satellite_azimuth_elevation_deg(data.sat_ecef_m, s.x_ecef_m)  # NaN for unsolved epochs
    unused = data.unused if data.unused is not None else np.where(data.usable, 0, 1).astype(np.int8)
    used = np.isfinite(s.residuals_m)
    excluded = s.excluded if s.excluded is not None else np.zeros((T, n), dtype=bool)
    weight = s.robust_weights if s.robust_weights is not None else np.where(used, 1.0, np.nan)
    scaled = s.variance_scale if s.variance_scale is not None else np.ones((T, n))
    reason = np.select(
        [used & ((weight < DOWNWEIGHTED_BELOW) | (scaled * DOWNWEIGHTED_BELOW > 1.0)), used, unused > 0, excluded, el < config.elevation_mask_deg, ~data.usable],
        ["downweighted", "", np.asarray(UNUSED_REASONS, dtype=object)[np.clip(unused, 0, None)], "excluded_fde", "below_mask",
         "no_second_frequency"],
        default=np.broadcast_to(s.status[:, None], (T, n)).astype(object))
    ti, si = np.nonzero(unused >= 0)
    snr = data.snr_dbhz[ti, si] if data.snr_dbhz is not None else np.full(ti.size, np.nan)
    sigma = s.sigma_m[ti, si] if s.sigma_m is not None else np.full(ti.size, np.nan)
    return pd.DataFrame({
        "time": _iso(data.time_gps_s)[ti], "method": method, "satellite": data.sv[si], "elevation_deg": el[ti, si],
        "azimuth_deg": az[ti, si], "snr_dbhz": snr, "residual_m": s.residuals_m[ti, si], "sigma_m": sigma,
        "weight": weight[ti, si], "used": used[ti, si].astype(np.int64), "reason": reason[ti, si],
    })


__all__: Sequence[str] = [
    "satellites_table", "SATELLITE_COLUMNS",
    "positions_table", "summary_table", "errors_table", "dop_table", "to_csv_text",
    "enu_errors", "enu_covariances", "utc_offset_s", "output_time_s", "SD_COLUMNS", "MEAN_POSITION_COLUMNS", "SETTINGS_COLUMNS", "identification_table", "IDENTIFICATION_COLUMNS", "INTEGRITY_COLUMNS",
]
