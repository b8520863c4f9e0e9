"""Broadcast Keplerian ephemerides as flat arrays, and their selection per epoch.

A :class:`KeplerEphemeris` holds one row per broadcast record (GPS LNAV; later Galileo,
BeiDou and QZSS records share the layout). Times are absolute GPS seconds
(:mod:`gnss_cli.gnss.time`), so week roll-overs need no special care.

Selection (IS-GPS-200 practice, as in RTKLIB): for each satellite and epoch, the record
whose ``toe`` is nearest to the epoch, provided the epoch lies within half the curve-fit
interval of ``toe`` (fit interval 4 h when the record does not say); the later toe at an
exact tie. When that record is unhealthy the satellite is not used at that epoch.
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace

import numpy as np
import xarray as xr
from numpy.typing import NDArray

from gnss_cli.constants import SECONDS_PER_WEEK
from gnss_cli.errors import RinexFormatError
from gnss_cli.gnss.time import datetime2gps_s

F64 = NDArray[np.float64]

# georinex variable name -> KeplerEphemeris field
_GEORINEX_NAMES = {
    "SVclockBias": "af0_s",
    "SVclockDrift": "af1_s_s",
    "SVclockDriftRate": "af2_s_s2",
    "Crs": "crs_m",
    "DeltaN": "delta_n_rad_s",
    "M0": "m0_rad",
    "Cuc": "cuc_rad",
    "Eccentricity": "e",
    "Cus": "cus_rad",
    "sqrtA": "sqrt_a_sqrt_m",
    "Cic": "cic_rad",
    "Omega0": "omega0_rad",
    "Cis": "cis_rad",
    "Io": "i0_rad",
    "Crc": "crc_m",
    "omega": "omega_rad",
    "OmegaDot": "omega_dot_rad_s",
    "IDOT": "idot_rad_s",
}


@dataclass(frozen=True)
class KeplerEphemeris:
    """Broadcast Keplerian ephemeris records, one row per record (arrays of shape ``(k,)``).

    Attributes
    ----------
    sv : satellite ids (``'G07'``).
    toc_gps_s, toe_gps_s : clock and ephemeris reference times, s since the GPS epoch.
    af0_s, af1_s_s, af2_s_s2 : clock polynomial (s, s/s, s/s^2).
    sqrt_a_sqrt_m, e, i0_rad, omega0_rad, omega_rad, m0_rad : Keplerian elements
        (``omega0_rad`` is the longitude of the ascending node at the start of the GPS
        week of ``toe``, as broadcast).
    delta_n_rad_s, idot_rad_s, omega_dot_rad_s : rates.
    cuc_rad, cus_rad, crc_m, crs_m, cic_rad, cis_rad : harmonic corrections.
    tgd_s : L1 group delay (s); ``health`` : 0 = healthy; ``fit_interval_h`` : curve-fit
        interval (h); ``iode`` : issue of data.
    """

    sv: NDArray[np.str_]
    toc_gps_s: F64
    toe_gps_s: F64
    af0_s: F64
    af1_s_s: F64
    af2_s_s2: F64
    sqrt_a_sqrt_m: F64
    e: F64
    i0_rad: F64
    omega0_rad: F64
    omega_rad: F64
    m0_rad: F64
    delta_n_rad_s: F64
    idot_rad_s: F64
    omega_dot_rad_s: F64
    cuc_rad: F64
    cus_rad: F64
    crc_m: F64
    crs_m: F64
    cic_rad: F64
    cis_rad: F64
    tgd_s: F64
    health: F64
    fit_interval_h: F64
    iode: F64
    ura_m: F64 | None = None
    """Broadcast user range accuracy (m, the RINEX SV accuracy field); None when unknown."""
    tgd2_s: F64 | None = None
    """Second broadcast group delay (s): BeiDou TGD2 (B2I); Galileo the BGD of the E5 pair the
    clock does not refer to (BGD(E1,E5a) of I/NAV records, BGD(E1,E5b) of F/NAV); else None."""
    fnav: NDArray[np.bool_] | None = None
    """Galileo: True for F/NAV records (clock for E1/E5a), False for I/NAV (E1/E5b); else None."""

    def __len__(self) -> int:
        return int(self.sv.shape[0])

    def subset(self, rows: NDArray[np.bool_] | NDArray[np.intp]) -> "KeplerEphemeris":
        """Records selected by a boolean mask or index array."""
        return replace(
            self, **{f.name: (None if getattr(self, f.name) is None else getattr(self, f.name)[rows]) for f in fields(self)}
        )

    @staticmethod
    def concatenate(parts: "list[KeplerEphemeris]") -> "KeplerEphemeris":
        """Records of several tables, in order."""
        out: dict[str, object] = {}
        for f in fields(KeplerEphemeris):
            arrays = [getattr(p, f.name) for p in parts]
            if any(a is None for a in arrays):
                arrays = [np.full(len(p), np.nan) if a is None else a for p, a in zip(parts, arrays)]
            out[f.name] = np.concatenate(arrays)
        return KeplerEphemeris(**out)  # type: ignore[arg-type]

    @classmethod
    def from_dataset(cls, nav: xr.Dataset, system: str = "G") -> "KeplerEphemeris":
        """Records of one system from a georinex-layout navigation dataset (dims ``time, sv``).

        ``time`` is the record's toc (GPS time). ``Toe`` is seconds of the GPS week; the week is
        taken from ``GPSWeek`` when present, else from toc (with the half-week roll-over rule).

        Raises
        ------
        RinexFormatError
            When a required variable is missing.
        """
        svs = np.asarray(nav["sv"].values).astype(str)
        keep = np.char.startswith(svs, system)
        if not keep.any():
            return cls.empty()
        sub = nav if keep.all() else nav.isel(sv=np.flatnonzero(keep))  # (an isel of a whole nav file: 4 ms)
        missing = [name for name in (*_GEORINEX_NAMES, "Toe") if name not in sub]
        if missing:
            raise RinexFormatError(f"{nav.attrs.get('filename', 'navigation data')}: missing ephemeris fields {missing}")
        # Stack (time, sv) -> records where sqrtA is present.
        sqrt_a = sub["sqrtA"].values
        ti, si = np.nonzero(np.isfinite(sqrt_a) & (sqrt_a > 0))
        toc = datetime2gps_s(sub["time"].values)[ti]
        values: dict[str, F64] = {}
        for name, field_name in _GEORINEX_NAMES.items():
            values[field_name] = np.asarray(sub[name].values, dtype=np.float64)[ti, si]
        toe_sow = np.asarray(sub["Toe"].values, dtype=np.float64)[ti, si]
        week_toc = np.floor(toc / SECONDS_PER_WEEK)
        toe = week_toc * SECONDS_PER_WEEK + toe_sow
        # toe within +-half a week of toc (records near a week boundary)
        toe = np.where(toe - toc > SECONDS_PER_WEEK / 2, toe - SECONDS_PER_WEEK, toe)
        toe = np.where(toe - toc < -SECONDS_PER_WEEK / 2, toe + SECONDS_PER_WEEK, toe)

        def optional(name: str, default: float) -> F64:
            if name in sub:
                arr = np.asarray(sub[name].values, dtype=np.float64)[ti, si]
                return np.where(np.isfinite(arr), arr, default)
            return np.full(ti.shape, default)

        fit = optional("FitIntvl", 4.0)
        fit = np.where(fit > 0, fit, 4.0)
        return cls(
            sv=svs[keep][si],
            toc_gps_s=toc,
            toe_gps_s=toe,
            tgd_s=optional("TGD", 0.0),
            health=optional("health", 0.0),
            fit_interval_h=fit,
            iode=optional("IODE", -1.0),
            ura_m=optional("SVacc", np.nan),
            tgd2_s=optional("TGD2", 0.0) if "TGD2" in sub else None,
            fnav=(optional("FNAV", 0.0) > 0) if "FNAV" in sub else None,
            **values,
        )

    @classmethod
    def empty(cls) -> "KeplerEphemeris":
        """A table with no records."""
        kwargs: dict[str, object] = {f.name: np.zeros(0) for f in fields(cls)}
        kwargs["sv"] = np.zeros(0, dtype="<U3")
        return cls(**kwargs)  # type: ignore[arg-type]


def records_by_satellite(
    record_sv: NDArray[np.str_], health: F64, sv: NDArray[np.str_], *, healthy_only: bool = True
) -> "list[tuple[int, NDArray[np.intp]]]":
    """``(column j, record rows)`` of every satellite in ``sv`` that has usable records."""
    usable = np.ones(record_sv.shape[0], dtype=bool)
    if healthy_only:
        usable &= health == 0
    out = []
    for j, s in enumerate(np.asarray(sv).astype(str)):
        rows = np.flatnonzero((record_sv == s) & usable)
        if rows.size:
            out.append((j, rows))
    return out


def select_nearest_record(
    record_sv: NDArray[np.str_],
    toe_gps_s: F64,
    health: F64,
    max_dt_s: F64 | float,
    sv: NDArray[np.str_],
    t_gps_s: F64,
    *,
    healthy_only: bool = True,
) -> NDArray[np.intp]:
    """Per epoch and satellite, the record with reference time nearest to the epoch (-1: none).

    Parameters
    ----------
    record_sv, toe_gps_s, health
        Per-record satellite id, reference time (s since the GPS epoch) and health (0 = ok).
    max_dt_s
        Largest ``|t - toe|`` (s), per record ``(k,)`` or one number.
    sv
        Satellite ids, shape ``(n,)``.
    t_gps_s
        Epochs, shape ``(T,)``, s since the GPS epoch.
    healthy_only
        When the nearest record is unhealthy the satellite is not used at that epoch (an
        older healthy record does not replace it).

    Returns
    -------
    ndarray of intp, shape ``(T, n)``

    Notes
    -----
    As RTKLIB's ``seleph`` and ``satexclude``: the record is chosen by time alone, its
    health is checked afterwards; at an exact tie the record with the later toe wins (and
    among records with the same toe, the later one in the table).
    """
    t = np.asarray(t_gps_s, dtype=np.float64)
    out = np.full((t.shape[0], len(sv)), -1, dtype=np.intp)
    limit = np.broadcast_to(np.asarray(max_dt_s, dtype=np.float64), toe_gps_s.shape)
    for j, rows in records_by_satellite(record_sv, health, sv, healthy_only=False):
        rows = rows[np.argsort(toe_gps_s[rows], kind="stable")][::-1]  # latest first: argmin keeps it on ties
        dt = np.abs(t[:, None] - toe_gps_s[rows][None, :])  # (T, r)
        dt = np.where(dt <= limit[rows][None, :] + 1e-6, dt, np.inf)
        best = np.argmin(dt, axis=1)
        ok = np.isfinite(dt[np.arange(t.shape[0]), best])
        if healthy_only:
            ok &= health[rows[best]] == 0
        out[:, j] = np.where(ok, rows[best], -1)
    return out


def select_ephemeris(
    eph: KeplerEphemeris,
    sv: NDArray[np.str_],
    t_gps_s: F64,
    *,
    healthy_only: bool = True,
) -> NDArray[np.intp]:
    """Index of the record to use for each satellite and epoch (-1: none usable).

    Parameters
    ----------
    eph
        Ephemeris table.
    sv
        Satellite ids, shape ``(n,)``.
    t_gps_s
        Epochs, shape ``(T,)``, s since the GPS epoch.
    healthy_only
        -1 where the nearest record has non-zero health.

    Returns
    -------
    ndarray of intp, shape ``(T, n)``
        Row of ``eph`` whose toe is nearest to the epoch within half its fit interval, or -1.
    """
    return select_nearest_record(
        eph.sv, eph.toe_gps_s, eph.health, eph.fit_interval_h * 1800.0, sv, t_gps_s, healthy_only=healthy_only
    )
