"""Physical plausibility of broadcast navigation records, checked after reading.

A navigation record whose values could not have been broadcast is corrupt: a bit error in a
receiver's log, a transcription error, a damaged file. Used as it is, one such record moves a
fix by kilometres (measured: ``Cic = 1.5`` on one GPS record of rtklib-0759 moved the fix
277 km). :func:`reject_implausible_records` removes such records from a navigation dataset
(georinex layout, dims ``(time, sv)``), so that the satellite is served by its next nearest
record or not at all, and names each one in a warning.

A record is rejected when

- a field the orbit or clock needs is missing or not finite;
- a field lies outside the range its interface specification can represent (the number of
  bits times the scale factor: IS-GPS-200 table 20-III, Galileo OS SIS ICD table 60, BeiDou
  ICD B1I table 5-11, GLONASS ICD table 4.5; the widest of the Kepler systems is used for all
  of them, so that no valid record of any system is refused);
- its orbit leaves the shell of 15,000-50,000 km radius: for the Kepler systems
  ``a (1 - e) - |Crs| - |Crc| < 15,000 km`` or ``a (1 + e) + |Crs| + |Crc| > 50,000 km``
  (a bound over the whole orbit, no propagation needed), for GLONASS and SBAS the radius of
  the broadcast state vector;
- its clock offset exceeds what the system can broadcast: ``|af0|`` 0.98 ms for GPS, QZSS,
  NavIC and BeiDou (22 / 24 bits), ``|-tau_n|`` 1.95 ms for GLONASS, 1 ms for SBAS, but
  62.5 ms for Galileo (31 bits x 2^-34 s), whose real clocks exceed 1 ms: E12 broadcast
  5.7 ms on 2020-06-25 (ESBC) and 4.6 ms on 2022-06-08 (KMS3), so a 1 ms limit for all
  systems would refuse valid Galileo records;
- its time of ephemeris (week and ``Toe``) is more than 6 h from its time of clock (modulo
  1024 weeks, for writers that roll the week over): on every shared file GPS, QZSS and
  BeiDou records have ``toe = toc`` and Galileo records differ by at most 1.5 h, while a
  record whose date was damaged (a GPS record of 2020 dated 1980) keeps its week;
- its time of clock is before the start of its system's time scale (GPS 1980-01-06, Galileo
  1999-08-22, BeiDou 2006-01-01; GLONASS and SBAS: 1980-01-06 as well, a record of 1980 is
  still refused by the other checks when its values are absurd).

All checks are vectorized over the ``(time, sv)`` grid. Units: the dataset's (s, s/s, m, rad,
rad/s, sqrt(m); GLONASS and SBAS positions in m as the readers convert them from km).
"""

from __future__ import annotations

import math

import numpy as np
import xarray as xr
from numpy.typing import NDArray

from gnss_cli.io.rinex3_header import SYSTEM_NAMES

__all__ = ["reject_implausible_records", "klobuchar_problem", "KEPLER_LIMITS", "STATE_LIMITS", "KLOBUCHAR_LIMITS"]

F64 = NDArray[np.float64]

_PI = math.pi * (1 + 1e-12)
_HARMONIC_RAD = 2.0**15 * 2.0**-29  # Cuc, Cus, Cic, Cis: 16 bits x 2^-29 rad (BeiDou: 18 bits x 2^-31, equal)
_SEMICIRCLE_RAD = math.pi

KEPLER_LIMITS: dict[str, tuple[float, float]] = {
    "SVclockBias": (-2.0**21 * 2.0**-31, 2.0**21 * 2.0**-31),  # s; GPS 22 bits x 2^-31 = 0.98 ms
    "SVclockDrift": (-2.0**20 * 2.0**-46, 2.0**20 * 2.0**-46),  # s/s; Galileo 21 bits x 2^-46 (widest)
    "SVclockDriftRate": (-2.0**7 * 2.0**-55, 2.0**7 * 2.0**-55),  # s/s^2; GPS 8 bits x 2^-55 (widest)
    "Crs": (-2.0**17 * 2.0**-6, 2.0**17 * 2.0**-6),  # m; BeiDou 18 bits x 2^-6 (widest)
    "Crc": (-2.0**17 * 2.0**-6, 2.0**17 * 2.0**-6),
    "DeltaN": (-2.0**15 * 2.0**-43 * _SEMICIRCLE_RAD, 2.0**15 * 2.0**-43 * _SEMICIRCLE_RAD),  # rad/s
    "M0": (-_PI, _PI),
    "Omega0": (-_PI, _PI),
    "Io": (-_PI, _PI),
    "omega": (-_PI, _PI),
    "Cuc": (-_HARMONIC_RAD, _HARMONIC_RAD),
    "Cus": (-_HARMONIC_RAD, _HARMONIC_RAD),
    "Cic": (-_HARMONIC_RAD, _HARMONIC_RAD),
    "Cis": (-_HARMONIC_RAD, _HARMONIC_RAD),
    "Eccentricity": (0.0, 0.5),  # 32 bits x 2^-33
    "sqrtA": (0.0, 8192.0),  # sqrt(m); 32 bits x 2^-19
    "Toe": (0.0, 604_800.0),  # s of week
    "OmegaDot": (-2.0**23 * 2.0**-43 * _SEMICIRCLE_RAD, 2.0**23 * 2.0**-43 * _SEMICIRCLE_RAD),  # rad/s
    "IDOT": (-2.0**13 * 2.0**-43 * _SEMICIRCLE_RAD, 2.0**13 * 2.0**-43 * _SEMICIRCLE_RAD),  # rad/s
}
"""Representable ranges ``(low, high)`` of the Kepler-system fields the orbit and clock use."""

_SYSTEM_LIMITS: dict[str, dict[str, tuple[float, float]]] = {
    "E": {"SVclockBias": (-2.0**30 * 2.0**-34, 2.0**30 * 2.0**-34)},  # s; 31 bits x 2^-34 = 62.5 ms
    "C": {"SVclockBias": (-2.0**23 * 2.0**-33, 2.0**23 * 2.0**-33)},  # s; 24 bits x 2^-33 = 0.98 ms
    "R": {"SVclockBias": (-2.0**21 * 2.0**-30, 2.0**21 * 2.0**-30)},  # s; -tau_n 22 bits x 2^-30
    "S": {  # RTCA DO-229 message 9: a_Gf0 12 bits x 2^-31 s; accelerations to 10 bits x 6.25e-5 m/s^2
        "SVclockBias": (-1e-3, 1e-3),
        **{name: (-0.04, 0.04) for name in ("dX2", "dY2", "dZ2")},
    },
}
"""Per-system ranges that differ from :data:`KEPLER_LIMITS` / :data:`STATE_LIMITS`."""

_OPTIONAL_KEPLER_LIMITS: dict[str, tuple[float, float]] = {
    "TGD": (-2.0**9 * 2.0**-32, 2.0**9 * 2.0**-32),  # s; Galileo BGD 10 bits x 2^-32 (widest)
    "TGD1": (-2.0**9 * 1e-10, 2.0**9 * 1e-10),  # s; BeiDou 10 bits x 0.1 ns
    "TGD2": (-2.0**9 * 1e-10, 2.0**9 * 1e-10),
    "BGDe5a": (-2.0**9 * 2.0**-32, 2.0**9 * 2.0**-32),
    "BGDe5b": (-2.0**9 * 2.0**-32, 2.0**9 * 2.0**-32),
}
"""Group delays: checked when present and finite (blank fields are allowed)."""

STATE_LIMITS: dict[str, tuple[float, float]] = {
    "SVclockBias": (-2.0**21 * 2.0**-30, 2.0**21 * 2.0**-30),  # s; GLONASS -tau_n 22 bits x 2^-30
    "SVrelFreqBias": (-2.0**10 * 2.0**-40, 2.0**10 * 2.0**-40),  # GLONASS gamma_n, 11 bits x 2^-40
    "dX": (-8_000.0, 8_000.0),  # m/s; GLONASS 24 bits x 2^-20 km/s
    "dY": (-8_000.0, 8_000.0),
    "dZ": (-8_000.0, 8_000.0),
    "dX2": (-2.0**4 * 2.0**-30 * 1e3, 2.0**4 * 2.0**-30 * 1e3),  # m/s^2; 5 bits x 2^-30 km/s^2
    "dY2": (-2.0**4 * 2.0**-30 * 1e3, 2.0**4 * 2.0**-30 * 1e3),
    "dZ2": (-2.0**4 * 2.0**-30 * 1e3, 2.0**4 * 2.0**-30 * 1e3),
}
"""Representable ranges of the GLONASS / SBAS state-vector fields (SBAS's are narrower)."""

_RADIUS_M = (15_000e3, 50_000e3)
_SYSTEM_START = {
    "G": "1980-01-06", "R": "1980-01-06", "S": "1980-01-06", "J": "1980-01-06",
    "E": "1999-08-22", "C": "2006-01-01", "I": "1980-01-06",
}  # fmt: skip
_KEPLER_SYSTEMS = "GEJCI"
_WEEK_FIELDS = {"G": "GPSWeek", "J": "GPSWeek", "E": "GALWeek", "C": "BDTWeek", "I": "BDTWeek"}
_WEEK_ORIGIN = {"C": "2006-01-01"}  # BeiDou weeks count from BDT's start; the others from GPS's
_TOE_TOC_MAX_S = 6 * 3600.0
_ROLLOVER_S = 1024 * 604_800.0


def _toe_far_from_toc(ds: xr.Dataset, system: str, cols: NDArray[np.intp]) -> NDArray[np.bool_] | None:
    """Cells whose week and Toe put the ephemeris more than 6 h from the toc (module docstring)."""
    week, toe = _grid(ds, _WEEK_FIELDS.get(system, ""), cols), _grid(ds, "Toe", cols)
    if week is None or toe is None:
        return None
    origin = np.datetime64(_WEEK_ORIGIN.get(system, "1980-01-06"), "ns")
    toc_s = (np.asarray(ds["time"].values, dtype="datetime64[ns]") - origin).astype(np.int64) * 1e-9
    with np.errstate(invalid="ignore"):
        gap = np.abs(np.remainder(week * 604_800.0 + toe - toc_s[:, None] + _ROLLOVER_S / 2, _ROLLOVER_S) - _ROLLOVER_S / 2)
        return np.isfinite(week) & np.isfinite(toe) & (gap > _TOE_TOC_MAX_S)


def _outside(values: F64, low: float, high: float) -> NDArray[np.bool_]:
    """True where a value is not finite or outside ``[low, high]``."""
    with np.errstate(invalid="ignore"):
        return ~((values >= low) & (values <= high))


def _grid(ds: xr.Dataset, name: str, cols: NDArray[np.intp]) -> F64 | None:
    if name not in ds:
        return None
    return np.asarray(ds[name].values, dtype=np.float64)[:, cols]


def _kepler_reasons(ds: xr.Dataset, cols: NDArray[np.intp], present: NDArray[np.bool_],
                    system: str) -> list[tuple[NDArray[np.bool_], str]]:
    """``(bad cells, reason)`` for the Kepler-system records of ``system`` in columns ``cols``."""
    reasons: list[tuple[NDArray[np.bool_], str]] = []
    for name, (low, high) in {**KEPLER_LIMITS, **_SYSTEM_LIMITS.get(system, {})}.items():
        values = _grid(ds, name, cols)
        if values is None:
            continue
        reasons.append((present & _outside(values, low, high), f"{name} outside [{low:.4g}, {high:.4g}]"))
    for name, (low, high) in _OPTIONAL_KEPLER_LIMITS.items():
        values = _grid(ds, name, cols)
        if values is None:
            continue
        reasons.append((present & np.isfinite(values) & _outside(values, low, high), f"{name} outside [{low:.4g}, {high:.4g}]"))
    sqrt_a, ecc = _grid(ds, "sqrtA", cols), _grid(ds, "Eccentricity", cols)
    crs, crc = _grid(ds, "Crs", cols), _grid(ds, "Crc", cols)
    if sqrt_a is not None and ecc is not None and crs is not None and crc is not None:
        with np.errstate(invalid="ignore", over="ignore"):
            a_m = sqrt_a * sqrt_a
            harmonic = np.abs(crs) + np.abs(crc)
            low_r = a_m * (1 - ecc) - harmonic
            high_r = a_m * (1 + ecc) + harmonic
            off = (low_r < _RADIUS_M[0]) | (high_r > _RADIUS_M[1])
        reasons.append((present & off, "orbit radius outside 15,000-50,000 km"))
    return reasons


def _state_reasons(ds: xr.Dataset, cols: NDArray[np.intp], present: NDArray[np.bool_],
                   system: str) -> list[tuple[NDArray[np.bool_], str]]:
    """``(bad cells, reason)`` for the GLONASS / SBAS state-vector records in columns ``cols``."""
    reasons: list[tuple[NDArray[np.bool_], str]] = []
    for name, (low, high) in {**STATE_LIMITS, **_SYSTEM_LIMITS.get(system, {})}.items():
        values = _grid(ds, name, cols)
        if values is None:
            continue
        reasons.append((present & _outside(values, low, high), f"{name} outside [{low:.4g}, {high:.4g}]"))
    xyz = [_grid(ds, n, cols) for n in ("X", "Y", "Z")]
    if all(v is not None for v in xyz):
        with np.errstate(invalid="ignore", over="ignore"):
            radius = np.sqrt(sum(v * v for v in xyz))  # type: ignore[operator]
        reasons.append((present & _outside(radius, *_RADIUS_M), "orbit radius outside 15,000-50,000 km"))
    return reasons


def _present(ds: xr.Dataset, cols: NDArray[np.intp], kepler: bool) -> NDArray[np.bool_]:
    """Cells that hold a record: any of the fields the orbit or clock needs is given."""
    names = KEPLER_LIMITS if kepler else (*STATE_LIMITS, "X", "Y", "Z")
    present = np.zeros((ds.sizes["time"], cols.size), dtype=bool)
    for name in names:
        values = _grid(ds, name, cols)
        if values is not None:
            present |= np.isfinite(values)
    return present


def _toc_too_early(ds: xr.Dataset, system: str, n_cols: int) -> NDArray[np.bool_]:
    toc = np.asarray(ds["time"].values, dtype="datetime64[ns]")
    early = toc < np.datetime64(_SYSTEM_START.get(system, "1980-01-06"), "ns")
    return np.repeat(early[:, None], n_cols, axis=1)


def reject_implausible_records(ds: xr.Dataset, label: str = "") -> tuple[xr.Dataset, list[str]]:
    """Remove the navigation records that could not have been broadcast.

    Parameters
    ----------
    ds
        Navigation dataset, georinex layout: dims ``(time, sv)``, ``time`` the toc, one
        variable per broadcast field (NaN where a satellite has no record at that time).
    label
        Name of the file(s) the records come from, for the messages.

    Returns
    -------
    (dataset, messages)
        The dataset with every field of each rejected record set to NaN (same shape), and
        one message per system with rejections: how many records, and the first named
        (satellite, toc, reason, value). Empty when every record is plausible.

    Examples
    --------
    >>> import numpy as np, xarray as xr
    >>> grid = {k: (("time", "sv"), np.full((1, 1), 0.0)) for k in KEPLER_LIMITS}
    >>> grid["sqrtA"] = (("time", "sv"), np.array([[5153.6]]))
    >>> good = xr.Dataset(grid, coords={"time": [np.datetime64("2005-04-02T00:00")], "sv": ["G01"]})
    >>> reject_implausible_records(good)[1]
    []
    >>> bad = good.copy(deep=True)
    >>> bad["Cic"][:] = 1.5
    >>> out, messages = reject_implausible_records(bad, "x.05n")
    >>> messages[0]
    'x.05n: 1 GPS navigation record(s) rejected as physically impossible, e.g. G01 2005-04-02T00:00:00: Cic outside [-6.104e-05, 6.104e-05] (1.5)'
    >>> bool(np.isnan(out["sqrtA"].values[0, 0]))
    True
    """
    if ds.sizes.get("time", 0) == 0 or ds.sizes.get("sv", 0) == 0:
        return ds, []
    svs = np.asarray(ds["sv"].values).astype(str)
    system_of = np.array([s[:1] for s in svs])
    reject = np.zeros((ds.sizes["time"], svs.size), dtype=bool)
    messages: list[str] = []
    for system in dict.fromkeys(system_of.tolist()):
        cols = np.flatnonzero(system_of == system)
        kepler = system in _KEPLER_SYSTEMS
        present = _present(ds, cols, kepler)
        if not present.any():
            continue
        reasons = (_kepler_reasons if kepler else _state_reasons)(ds, cols, present, system)
        reasons.append((present & _toc_too_early(ds, system, cols.size), "time of clock before the system's start"))
        far = _toe_far_from_toc(ds, system, cols) if kepler else None
        if far is not None:
            reasons.append((present & far, "week and Toe more than 6 h from the time of clock"))
        bad = np.zeros_like(present)
        for cells, _ in reasons:
            bad |= cells
        if not bad.any():
            continue
        reject[:, cols] |= bad
        messages.append(_message(ds, label, system, cols, bad, reasons))
    if not reject.any():
        return ds, []
    out = ds.copy()
    for name, var in ds.data_vars.items():
        if var.dims == ("time", "sv") and np.issubdtype(var.dtype, np.floating):
            out[name] = var.where(~reject)
    return out, messages


def _message(ds: xr.Dataset, label: str, system: str, cols: NDArray[np.intp], bad: NDArray[np.bool_],
             reasons: list[tuple[NDArray[np.bool_], str]]) -> str:
    """One line: count of rejected records of a system, the first one named with its reason."""
    ti, ci = np.argwhere(bad)[0]
    reason = next(text for cells, text in reasons if cells[ti, ci])
    field = reason.split(" ", 1)[0]
    value = ""
    if field in ds.data_vars and ds[field].ndim == 2:
        value = f" ({float(ds[field].values[ti, cols[ci]]):.6g})"
    sv = str(ds["sv"].values[cols[ci]])
    toc = np.datetime_as_string(np.asarray(ds["time"].values[ti], dtype="datetime64[s]"))
    prefix = f"{label}: " if label else ""
    name = SYSTEM_NAMES.get(system, system)
    return (f"{prefix}{int(bad.sum())} {name} navigation record(s) rejected as physically impossible, "
            f"e.g. {sv} {toc}: {reason}{value}")


KLOBUCHAR_LIMITS = np.array([
    2.0**7 * 2.0**-30, 2.0**7 * 2.0**-27, 2.0**7 * 2.0**-24, 2.0**7 * 2.0**-24,  # alpha0..3: s, s/sc, s/sc^2, s/sc^3
    2.0**7 * 2.0**11, 2.0**7 * 2.0**14, 2.0**7 * 2.0**16, 2.0**7 * 2.0**16,  # beta0..3: s, s/sc, s/sc^2, s/sc^3
])
"""Largest magnitude of each Klobuchar coefficient (8 signed bits times the IS-GPS-200 scale)."""


def klobuchar_problem(raw: object) -> str | None:
    """Why the Klobuchar coefficients ``alpha0..3, beta0..3`` cannot be used, or None when they can.

    >>> klobuchar_problem([1.1176e-08, -1.4901e-08, -5.9605e-08, 1.1921e-07, 9.8304e+04, -1.1469e+05, -1.3107e+05, 7.2090e+05])
    >>> klobuchar_problem([1e300, 0, 0, 0, 0, 0, 0, 0])
    'alpha0 = 1e+300 outside +-1.192e-07'
    """
    arr = np.asarray(raw, dtype=np.float64).ravel()
    if arr.size != 8:
        return f"{arr.size} coefficients, expected 8"
    names = [f"alpha{i}" for i in range(4)] + [f"beta{i}" for i in range(4)]
    with np.errstate(invalid="ignore"):
        bad = ~(np.abs(arr) <= KLOBUCHAR_LIMITS)
    if not bad.any():
        return None
    i = int(np.argmax(bad))
    return f"{names[i]} = {arr[i]:.6g} outside +-{KLOBUCHAR_LIMITS[i]:.4g}"
