"""The positions table in other formats: RTKLIB ``.pos``, GeoJSON, KML, NMEA, Parquet.

Every writer is a pure function of the positions table (:func:`gnss_cli.report.positions_table`,
one row per epoch and method) and returns text or bytes; the command line stages them
through its output set. The ``time`` column is already in the chosen time scale (GPST or
UTC, ``time_system``); ``gps_week`` and ``tow_s`` are GPS time.

==========  ==================================================================================
format      content
==========  ==================================================================================
csv         :func:`gnss_cli.report.to_csv_text` (the default)
pos         rnx2rtkp's solution file, ECEF, ``yyyy/mm/dd hh:mm:ss.sss`` time, CRLF line ends as
            RTKLIB writes them; one method per file; epochs without a position omitted; Q = 5
            (single) for the others; sdx..sdzx from the E/N/U covariance columns rotated back
            to ECEF, signed square roots of the off-diagonal elements as RTKLIB's ``sqvar``
            (age 0, ratio 0)
geojson     RFC 7946 FeatureCollection: a LineString ``[lon, lat, height]`` per method (two or
            more solved epochs), then a Point per epoch and method with properties time,
            time_system, method, status, n_sat, the DOPs and the uncertainty columns
            (geometry null for an epoch without a position)
kml         KML 2.2 Document with one Placemark LineString per method, ``lon,lat,height``
            (ellipsoidal height; no ``altitudeMode``, so viewers clamp the track to the ground)
nmea        GGA and RMC sentences per epoch of one method (talker GP, GN with several systems);
            altitude = ellipsoidal height with a geoid separation of 0; quality 1 / status A for
            an epoch with a position, 0 / V otherwise; RMC speed and course from the previous
            solved epoch (0 for the first)
parquet     typed columns: ``time`` datetime64[ns, UTC] (utc) or naive GPS time (gpst),
            ``gps_week`` and ``n_sat`` int64, ``method`` categorical, numbers float64,
            ``status`` string (pandas + pyarrow)
==========  ==================================================================================
"""

from __future__ import annotations

import io
import json
from collections.abc import Sequence
from pathlib import Path
from xml.sax.saxutils import escape

import numpy as np
import pandas as pd

from gnss_cli import __version__
from gnss_cli.gnss.frames import ecef2enu_rotation

FORMATS = ("csv", "pos", "geojson", "kml", "nmea", "parquet")
EXTENSIONS = {"csv": ".csv", "pos": ".pos", "geojson": ".geojson", "kml": ".kml", "nmea": ".nmea", "parquet": ".parquet"}
_FROM_SUFFIX = {**{ext: fmt for fmt, ext in EXTENSIONS.items()}, ".json": "geojson"}
PER_METHOD = ("pos", "nmea")
"""Formats that hold one method per file."""
BINARY = ("parquet",)
SOLVED = ("ok", "fallback_wls")
"""Statuses of the rows with a position."""

__all__ = ["FORMATS", "EXTENSIONS", "PER_METHOD", "BINARY", "format_from_path", "pos_text", "geojson_text",
           "kml_text", "nmea_text", "nmea_checksum", "parquet_bytes", "parquet_table", "pos_options", "render"]


def format_from_path(path: str | Path | None) -> str | None:
    """The format a file name implies (``.csv .pos .geojson .json .kml .nmea .parquet``), else None."""
    if path is None or str(path) == "-":
        return None
    return _FROM_SUFFIX.get(Path(path).suffix.lower())


def _solved(table: pd.DataFrame) -> pd.DataFrame:
    return table[table["status"].astype(str).isin(SOLVED) & np.isfinite(table["x_m"].to_numpy(dtype=float))]


def _one_method(table: pd.DataFrame, fmt: str) -> str:
    methods = list(pd.unique(table["method"]))
    if len(methods) != 1:
        raise ValueError(f"{fmt}: one method per file; the table has {methods}")
    return str(methods[0])


def _ecef_cov(rows: pd.DataFrame) -> np.ndarray:
    """``(n, 3, 3)`` ECEF position covariances (m^2) from the E/N/U uncertainty columns."""
    sd = rows[["sde_m", "sdn_m", "sdu_m", "sden_m2", "sdnu_m2", "sdue_m2"]].to_numpy(dtype=float)
    sd = np.where(np.isfinite(sd), sd, 0.0)
    e, n, u, en, nu, ue = sd.T
    enu = np.stack([np.stack([e * e, en, ue], -1), np.stack([en, n * n, nu], -1), np.stack([ue, nu, u * u], -1)], 1)
    rot = ecef2enu_rotation(np.deg2rad(rows["lat_deg"].to_numpy(dtype=float)), np.deg2rad(rows["lon_deg"].to_numpy(dtype=float)))
    return np.einsum("tji,tjk,tkl->til", rot, enu, rot)


def _sqvar(c: np.ndarray) -> np.ndarray:
    return np.sign(c) * np.sqrt(np.abs(c))


def _rtk_time(iso: str) -> str:
    return iso.replace("-", "/").replace("T", " ")


def pos_text(table: pd.DataFrame, time_system: str = "gpst", inputs: Sequence[str] = (), options: Sequence[str] = ()) -> str:
    """rnx2rtkp's ECEF solution file (``out-solformat = xyz``, ``out-timeform = hms``) of one method.

    ``inputs``: the ``inp file`` lines; ``options``: further ``%`` header lines after ``pos mode``
    (``elev mask : 10.0 deg``, ...), written as given after ``% ``.
    """
    method = _one_method(table, "pos")
    label = "UTC" if time_system == "utc" else "GPST"
    first, last = table.iloc[0], table.iloc[-1]

    def span(row: pd.Series) -> str:
        return f"{_rtk_time(str(row['time']))[:-2]} {label} (week{int(row['gps_week'])} {float(row['tow_s']):.1f}s)"

    lines = [f"% program   : gnss-solve ver.{__version__}"]
    lines += [f"% inp file  : {p}" for p in inputs]
    lines += [f"% obs start : {span(first)}", f"% obs end   : {span(last)}", "% pos mode  : Single",
              *(f"% {o}" for o in options), f"% method    : {method}", "%",
              "% (x/y/z-ecef=WGS84,Q=1:fix,2:float,3:sbas,4:dgps,5:single,6:ppp,ns=# of satellites)",
              f"%  {label:<26}" + "x-ecef(m)      y-ecef(m)      z-ecef(m)   Q  ns   sdx(m)   sdy(m)   sdz(m)  sdxy(m)"
              "  sdyz(m)  sdzx(m) age(s)  ratio"]
    rows = _solved(table)
    cov = _ecef_cov(rows)
    sd = np.stack([np.sqrt(np.maximum(cov[:, 0, 0], 0)), np.sqrt(np.maximum(cov[:, 1, 1], 0)),
                   np.sqrt(np.maximum(cov[:, 2, 2], 0)), _sqvar(cov[:, 0, 1]), _sqvar(cov[:, 1, 2]), _sqvar(cov[:, 2, 0])], 1)
    for (_, r), s in zip(rows.iterrows(), sd):
        lines.append(f"{_rtk_time(str(r['time']))} {r['x_m']:14.4f} {r['y_m']:14.4f} {r['z_m']:14.4f} {5:3d} "
                     f"{int(r['n_sat']):3d} " + " ".join(f"{v:8.4f}" for v in s) + f" {0.0:6.2f} {0.0:6.1f}")
    return "\r\n".join(lines) + "\r\n"


def _number(v: object) -> object:
    if isinstance(v, (float, np.floating)):
        return None if not np.isfinite(v) else float(v)
    if isinstance(v, np.integer):
        return int(v)
    return v


_PROPERTIES = ("n_sat", "gdop", "pdop", "hdop", "vdop", "tdop", "sde_m", "sdn_m", "sdu_m", "sden_m2", "sdnu_m2", "sdue_m2")


def _lonlath(r: pd.Series) -> list[float]:
    return [round(float(r["lon_deg"]), 10), round(float(r["lat_deg"]), 10), round(float(r["height_m"]), 4)]


def geojson_text(table: pd.DataFrame, time_system: str = "gpst") -> str:
    """RFC 7946 FeatureCollection (module docstring)."""
    features: list[dict[str, object]] = []
    for method, rows in table.groupby("method", sort=False):
        solved = _solved(rows)
        if len(solved) >= 2:
            features.append({"type": "Feature", "properties": {"method": str(method), "kind": "track"},
                             "geometry": {"type": "LineString", "coordinates": [_lonlath(r) for _, r in solved.iterrows()]}})
    solved_index = set(_solved(table).index)
    for i, r in table.iterrows():
        props = {"time": str(r["time"]), "time_system": time_system, "method": str(r["method"]), "status": str(r["status"])}
        props.update({k: _number(r[k]) for k in _PROPERTIES if k in r.index})
        geometry = {"type": "Point", "coordinates": _lonlath(r)} if i in solved_index else None
        features.append({"type": "Feature", "properties": props, "geometry": geometry})
    return json.dumps({"type": "FeatureCollection", "features": features}, allow_nan=False) + "\n"


def kml_text(table: pd.DataFrame) -> str:
    """KML 2.2: a Placemark LineString per method (module docstring)."""
    out = ['<?xml version="1.0" encoding="UTF-8"?>', '<kml xmlns="http://www.opengis.net/kml/2.2">',
           "<Document>", "<name>gnss-solve</name>"]
    for method, rows in table.groupby("method", sort=False):
        coords = " ".join(f"{r['lon_deg']:.10f},{r['lat_deg']:.10f},{r['height_m']:.4f}" for _, r in _solved(rows).iterrows())
        out += ["<Placemark>", f"<name>{escape(str(method))}</name>", "<LineString>", "<tessellate>1</tessellate>",
                f"<coordinates>{coords}</coordinates>", "</LineString>", "</Placemark>"]
    return "\n".join([*out, "</Document>", "</kml>"]) + "\n"


def nmea_checksum(body: str) -> str:
    """Two hex digits: the XOR of the characters between ``$`` and ``*``."""
    x = 0
    for ch in body:
        x ^= ord(ch)
    return f"{x:02X}"


def _sentence(body: str) -> str:
    return f"${body}*{nmea_checksum(body)}\r\n"


def _ddmm(deg: float, width: int) -> tuple[str, bool]:
    a = abs(deg)
    d = int(a)
    m = (a - d) * 60.0
    if round(m, 7) >= 60.0:
        d, m = d + 1, 0.0
    return f"{d:0{width}d}{m:010.7f}", deg >= 0


def _velocity_kn_deg(rows: pd.DataFrame) -> tuple[np.ndarray, np.ndarray]:
    """Horizontal speed (knots) and course over ground (deg) from the previous solved epoch."""
    t = pd.to_datetime(rows["time"]).to_numpy(dtype="datetime64[ns]").astype(np.int64) * 1e-9
    x = rows[["x_m", "y_m", "z_m"]].to_numpy(dtype=float)
    rot = ecef2enu_rotation(np.deg2rad(rows["lat_deg"].to_numpy(dtype=float)), np.deg2rad(rows["lon_deg"].to_numpy(dtype=float)))
    speed, course = np.zeros(len(rows)), np.zeros(len(rows))
    if len(rows) > 1:
        dt = np.diff(t)
        enu = np.einsum("tij,tj->ti", rot[1:], np.diff(x, axis=0)) / np.where(dt > 0, dt, np.inf)[:, None]
        speed[1:] = np.hypot(enu[:, 0], enu[:, 1]) / 0.514444
        course[1:] = np.rad2deg(np.arctan2(enu[:, 0], enu[:, 1])) % 360.0
    return speed, course


def nmea_text(table: pd.DataFrame) -> str:
    """GGA + RMC per epoch of one method (module docstring)."""
    _one_method(table, "nmea")
    talker = "GN" if any(c.startswith("tdop_") for c in table.columns) else "GP"
    solved = _solved(table)
    speed, course = _velocity_kn_deg(solved)
    motion = {i: (s, c) for i, s, c in zip(solved.index, speed, course)}
    out = []
    for i, r in table.iterrows():
        iso = str(r["time"])
        hms = iso[11:13] + iso[14:16] + f"{float(iso[17:]):05.2f}"
        ddmmyy = iso[8:10] + iso[5:7] + iso[2:4]
        if i in motion:
            lat, north = _ddmm(float(r["lat_deg"]), 2)
            lon, east = _ddmm(float(r["lon_deg"]), 3)
            pos = f"{lat},{'N' if north else 'S'},{lon},{'E' if east else 'W'}"
            hdop = f"{r['hdop']:.1f}" if np.isfinite(r["hdop"]) else ""
            out.append(_sentence(f"{talker}GGA,{hms},{pos},1,{int(r['n_sat']):02d},{hdop},{r['height_m']:.4f},M,0.000,M,,"))
            s, c = motion[i]
            out.append(_sentence(f"{talker}RMC,{hms},A,{pos},{s:.2f},{c:.2f},{ddmmyy},,,A"))
        else:
            out.append(_sentence(f"{talker}GGA,{hms},,,,,0,00,,,M,,M,,"))
            out.append(_sentence(f"{talker}RMC,{hms},V,,,,,,,{ddmmyy},,,N"))
    return "".join(out)


def parquet_table(table: pd.DataFrame, time_system: str = "gpst") -> pd.DataFrame:
    """The typed frame :func:`parquet_bytes` writes (module docstring)."""
    df = table.copy()
    t = pd.to_datetime(df["time"]).astype("datetime64[ns]")
    df["time"] = t.dt.tz_localize("UTC") if time_system == "utc" else t
    for col in df.columns:
        if col == "method":
            df[col] = df[col].astype("category")
        elif col == "status":
            df[col] = df[col].astype(str).astype("string")
        elif col in ("gps_week", "n_sat"):
            df[col] = df[col].astype(np.int64)
        elif col != "time":
            df[col] = pd.to_numeric(df[col], errors="coerce").astype(np.float64)
    return df


def parquet_bytes(table: pd.DataFrame, time_system: str = "gpst") -> bytes:
    """Parquet bytes of :func:`parquet_table` (pyarrow engine; Parquet format 2.6, the first
    with nanosecond timestamps: pyarrow before 13 writes 2.4 and would coerce them to us)."""
    buf = io.BytesIO()
    parquet_table(table, time_system).to_parquet(buf, engine="pyarrow", index=False, version="2.6")
    return buf.getvalue()


def pos_options(elevation_mask_deg: float, iono: str, tropo: str, systems: Sequence[str]) -> list[str]:
    """The processing-option lines of rnx2rtkp's ``.pos`` header for a run's settings."""
    names = {"G": "GPS", "E": "Galileo", "C": "BeiDou", "J": "QZSS", "R": "GLONASS"}
    ionos = {"klobuchar": "Broadcast", "iono-free": "Iono-Free LC", "none": "OFF"}.get(iono, iono)
    return [f"elev mask : {elevation_mask_deg:.1f} deg", f"ionos opt : {ionos}",
            f"tropo opt : {'Saastamoinen' if tropo == 'saastamoinen' else 'OFF'}", "ephemeris : Broadcast",
            f"navi sys  : {' '.join(names.get(s, s) for s in systems)}"]


def render(fmt: str, table: pd.DataFrame, time_system: str = "gpst", inputs: Sequence[str] = (),
           options: Sequence[str] = ()) -> str | bytes:
    """The positions ``table`` in format ``fmt`` (csv text, other text, or parquet bytes);
    ``inputs`` and ``options`` are the pos header lines (:func:`pos_text`)."""
    if fmt == "csv":
        from gnss_cli.report import to_csv_text

        return to_csv_text(table)
    if fmt == "pos":
        return pos_text(table, time_system, inputs, options)
    if fmt == "geojson":
        return geojson_text(table, time_system)
    if fmt == "kml":
        return kml_text(table)
    if fmt == "nmea":
        return nmea_text(table)
    if fmt == "parquet":
        return parquet_bytes(table, time_system)
    raise ValueError(f"unknown format {fmt!r}; expected one of {', '.join(FORMATS)}")
