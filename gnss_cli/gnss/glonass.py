"""GLONASS broadcast orbits and clocks: state vectors integrated with RK4 (GLONASS ICD A.3.1.2).

A GLONASS record gives position, velocity and the luni-solar acceleration in PZ-90
(equal to ITRF at the metre level) at ``tb``, plus the clock ``-TauN`` and ``GammaN``.
RINEX writes ``tb`` in UTC(SU) (UTC + 3 h is removed by the RINEX writer); it is
converted to GPST by adding the leap seconds (GPST - UTC).

Equations of motion in the rotating PZ-90 frame, J2 only, the broadcast acceleration
held constant over the integration (as in RTKLIB ``glorbit``)::

    a = 3/2 J2 mu ae^2 / r^5;  c = -mu / r^3 - a (1 - 5 z^2 / r^2)
    x'' = (c + wE^2) x + 2 wE y' + ax
    y'' = (c + wE^2) y - 2 wE x' + ay
    z'' = (c - 2 a) z + az

Clock: ``dt_sv = -TauN + GammaN (t - tb)`` (relativity is included in TauN).
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace

import numpy as np
import xarray as xr
from numpy.typing import NDArray

from gnss_cli.errors import RinexFormatError, UsageError
from gnss_cli.gnss.ephemeris import select_nearest_record
from gnss_cli.gnss.orbits import SatelliteStates
from gnss_cli.gnss.time import datetime2gps_s, gps_minus_utc_s

F64 = NDArray[np.float64]

MU_GLO_M3_S2 = 3.9860044e14
"""PZ-90 gravitational constant, m^3/s^2."""
J2_GLO = 1.0826257e-3
"""PZ-90 second zonal harmonic."""
RE_GLO_M = 6_378_136.0
"""PZ-90 equatorial radius, m."""
OMEGA_E_GLO_RAD_S = 7.292115e-5
"""PZ-90 Earth rotation rate, rad/s."""

FREQ_G1_HZ = 1_602.0e6
DFREQ_G1_HZ = 0.5625e6
FREQ_G2_HZ = 1_246.0e6
DFREQ_G2_HZ = 0.4375e6

MAX_DTOE_GLO_S = 1800.0
"""Largest |t - tb| at which a record is used, s (RTKLIB MAXDTOE_GLO)."""

@dataclass(frozen=True)
class GlonassEphemeris:
    """GLONASS broadcast records, one row per record.

    Attributes
    ----------
    sv : ``(k,)`` ids (``'R07'``).
    toe_gps_s : ``(k,)`` tb converted to GPST, s since the GPS epoch.
    clock_bias_s : ``(k,)`` ``-TauN``, s.
    gamma_n : ``(k,)`` relative frequency bias ``GammaN``, s/s.
    pos_m, vel_m_s, acc_m_s2 : ``(k, 3)`` PZ-90 state at tb, m, m/s, m/s^2.
    health : ``(k,)`` 0 = healthy.
    freq_num : ``(k,)`` frequency channel k (-7..+6).
    frame_time_s : ``(k,)`` message frame time (tk) as written, s of the UTC day.
    """

    sv: NDArray[np.str_]
    toe_gps_s: F64
    clock_bias_s: F64
    gamma_n: F64
    pos_m: F64
    vel_m_s: F64
    acc_m_s2: F64
    health: F64
    freq_num: F64
    frame_time_s: F64

    def __len__(self) -> int:
        return int(self.sv.shape[0])

    def subset(self, rows: NDArray[np.bool_] | NDArray[np.intp]) -> "GlonassEphemeris":
        """Records selected by a boolean mask or index array."""
        return replace(self, **{f.name: getattr(self, f.name)[rows] for f in fields(self)})

    def g1_frequency_hz(self) -> F64:
        """G1 carrier frequency of every record, Hz (1602 MHz + k 0.5625 MHz)."""
        return FREQ_G1_HZ + self.freq_num * DFREQ_G1_HZ

    @classmethod
    def from_dataset(cls, nav: xr.Dataset, *, leap_seconds_s: float | None = None) -> "GlonassEphemeris":
        """GLONASS records from a georinex-layout navigation dataset (dims ``time, sv``).

        Parameters
        ----------
        nav
            ``time`` is tb in UTC(SU) as written in RINEX; X.. in m, m/s, m/s^2.
        leap_seconds_s
            GPST - UTC, s. Default: ``nav.attrs['leap_seconds']`` when the reader stored the
            header's LEAP SECONDS, else the table value at each record's own date (18 s from
            2017; a record dated wrongly must not shift the others).

        Raises
        ------
        RinexFormatError
            When a required variable is missing.
        """
        svs = np.asarray(nav["sv"].values).astype(str)
        keep = np.char.startswith(svs, "R")
        if not keep.any():
            return cls.empty()
        sub = nav.isel(sv=np.flatnonzero(keep))
        names = ["SVclockBias", "SVrelFreqBias", "X", "Y", "Z", "dX", "dY", "dZ", "dX2", "dY2", "dZ2", "health", "FreqNum"]
        missing = [n for n in names if n not in sub]
        if missing:
            raise RinexFormatError(f"{nav.attrs.get('filename', 'navigation data')}: missing GLONASS fields {missing}")
        x = np.asarray(sub["X"].values, dtype=np.float64)
        ti, si = np.nonzero(np.isfinite(x))
        t_utc = np.asarray(sub["time"].values, dtype="datetime64[ns]")
        if leap_seconds_s is None:
            leap_seconds_s = nav.attrs.get("leap_seconds")
        t_rec_s = datetime2gps_s(t_utc)[ti]
        if leap_seconds_s is None:  # each record its own: one record's date must not shift the others
            toe = t_rec_s + gps_minus_utc_s(t_rec_s, utc=True)
        else:
            toe = t_rec_s + float(leap_seconds_s)

        def col(name: str) -> F64:
            return np.asarray(sub[name].values, dtype=np.float64)[ti, si]

        frame = col("MessageFrameTime") if "MessageFrameTime" in sub else np.full(ti.shape, np.nan)
        return cls(
            sv=np.array([s[:3] for s in svs[keep][si]], dtype="<U3"),
            toe_gps_s=toe,
            clock_bias_s=col("SVclockBias"),
            gamma_n=col("SVrelFreqBias"),
            pos_m=np.stack([col("X"), col("Y"), col("Z")], axis=-1),
            vel_m_s=np.stack([col("dX"), col("dY"), col("dZ")], axis=-1),
            acc_m_s2=np.stack([col("dX2"), col("dY2"), col("dZ2")], axis=-1),
            health=col("health"),
            freq_num=col("FreqNum"),
            frame_time_s=frame,
        )

    @classmethod
    def empty(cls) -> "GlonassEphemeris":
        """A table with no records."""
        z = np.zeros(0)
        z3 = np.zeros((0, 3))
        return cls(np.zeros(0, dtype="<U3"), z, z, z, z3, z3, z3, z, z, z)


def select_glonass_ephemeris(
    eph: GlonassEphemeris,
    sv: NDArray[np.str_],
    t_gps_s: F64,
    *,
    max_dt_s: float = MAX_DTOE_GLO_S,
    healthy_only: bool = True,
) -> NDArray[np.intp]:
    """Index of the record with tb nearest to each epoch within ``max_dt_s`` (-1: none).

    Parameters
    ----------
    eph
        GLONASS records.
    sv
        Satellite ids, shape ``(n,)``.
    t_gps_s
        Epochs, shape ``(T,)``, s since the GPS epoch.
    max_dt_s
        Largest ``|t - tb|``, s (default 1800 s: records are broadcast every 30 min).
    healthy_only
        Skip records with non-zero health.

    Returns
    -------
    ndarray of intp, shape ``(T, n)``
    """
    return select_nearest_record(eph.sv, eph.toe_gps_s, eph.health, max_dt_s, sv, t_gps_s, healthy_only=healthy_only)


def _derivative(state: F64, acc: F64) -> F64:
    """Time derivative of ``(..., 6)`` states [x y z vx vy vz] in PZ-90 (module equations)."""
    r2 = np.sum(state[..., :3] ** 2, axis=-1)
    r3 = r2 * np.sqrt(r2)
    a = 1.5 * J2_GLO * MU_GLO_M3_S2 * RE_GLO_M**2 / r2 / r3
    b = 5.0 * state[..., 2] ** 2 / r2
    c = -MU_GLO_M3_S2 / r3 - a * (1.0 - b)
    w = OMEGA_E_GLO_RAD_S
    out = np.empty_like(state)
    out[..., :3] = state[..., 3:]
    out[..., 3] = (c + w * w) * state[..., 0] + 2.0 * w * state[..., 4] + acc[..., 0]
    out[..., 4] = (c + w * w) * state[..., 1] - 2.0 * w * state[..., 3] + acc[..., 1]
    out[..., 5] = (c - 2.0 * a) * state[..., 2] + acc[..., 2]
    return out


def _rk4_step(state: F64, acc: F64, h: F64) -> F64:
    """One classical Runge-Kutta step of ``h`` (s, per state) of the equations of motion."""
    hh = h[..., None]
    k1 = _derivative(state, acc)
    k2 = _derivative(state + 0.5 * hh * k1, acc)
    k3 = _derivative(state + 0.5 * hh * k2, acc)
    k4 = _derivative(state + hh * k3, acc)
    return state + hh / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)


def _integrate(eph: GlonassEphemeris, k: NDArray[np.intp], dt: F64, step_s: float, n_steps: int) -> F64:
    """States ``(n, 6)`` of the records ``k`` integrated over ``dt`` (s): full steps of ``step_s``
    towards ``t``, then one shorter step to land on it, at most ``n_steps`` steps in all.

    The full steps of one record in one direction are the same for every time it serves, so
    they are integrated once per (record, direction) and each time adds its last, shorter
    step: the states are those of stepping every element on its own, bit for bit (``dt - j
    step_s`` is exact in floating point), at a fraction of the work on a day of data.
    """
    direction = np.sign(dt)
    size = np.abs(dt)
    full = np.minimum(np.floor(size / step_s).astype(np.int64), n_steps)
    full = np.where(size - full * step_s >= step_s, np.minimum(full + 1, n_steps), full)  # (floor of a rounded quotient)
    rest = size - full * step_s
    # after a full step a remainder below 1e-9 s is dropped; a lone step of any length is taken
    partial = np.where(full > 0, rest >= 1e-9, rest > 0.0) & (full < n_steps)
    groups, group = np.unique(k * 3 + (direction.astype(np.int64) + 1), return_inverse=True)
    g_rec, g_dir = groups // 3, (groups % 3 - 1).astype(np.float64)
    state = np.concatenate([eph.pos_m[g_rec], eph.vel_m_s[g_rec]], axis=-1)
    acc = eph.acc_m_s2[g_rec]
    steps = int(full.max()) if full.size else 0
    track = np.empty((steps + 1, *state.shape))
    track[0] = state
    for j in range(steps):
        track[j + 1] = state = _rk4_step(state, acc, g_dir * step_s)
    out = track[full, group]
    if partial.any():
        sel = np.flatnonzero(partial)
        out[sel] = _rk4_step(out[sel], eph.acc_m_s2[k[sel]], direction[sel] * rest[sel])
    return out


def _clock_s(eph: GlonassEphemeris, k: NDArray[np.intp], dt: F64) -> F64:
    """``-TauN + GammaN (t - tb)`` (s) of the records ``k`` at ``dt = t - tb`` (s)."""
    return eph.clock_bias_s[k] + eph.gamma_n[k] * dt


def glonass_clock_s(eph: GlonassEphemeris, idx: NDArray[np.intp], t_gps_s: F64) -> F64:
    """The ``clock_s`` of :func:`glonass_states` without the orbit integration (NaN where ``idx < 0``)."""
    idx = np.asarray(idx)
    valid = idx >= 0
    if len(eph) == 0 or not valid.any():
        return np.full(idx.shape, np.nan)
    t = np.broadcast_to(np.asarray(t_gps_s, dtype=np.float64), idx.shape)
    k = np.where(valid, idx, 0)
    dt = np.where(valid, t - eph.toe_gps_s[k], 0.0)
    return np.where(valid, _clock_s(eph, k, dt), np.nan)


def glonass_states(
    eph: GlonassEphemeris,
    idx: NDArray[np.intp],
    t_gps_s: F64,
    *,
    step_s: float = 60.0,
) -> SatelliteStates:
    """Positions, velocities and clocks of GLONASS satellites at GPS times ``t_gps_s``.

    Parameters
    ----------
    eph
        GLONASS records.
    idx
        Record index per element, any shape; -1 = no record (NaN, ``valid`` False).
    t_gps_s
        Times broadcastable to ``idx``, s since the GPS epoch.
    step_s
        RK4 step, s (0 < step <= 60); the last step is shortened to land on ``t``.

    Returns
    -------
    SatelliteStates
        PZ-90 (~ITRF) position m and velocity m/s; ``clock_s = -TauN + GammaN (t - tb)``;
        ``tgd_s`` and ``relativistic_s`` are 0 (the broadcast clock includes relativity).

    Raises
    ------
    UsageError
        For a step outside (0, 60] s or shapes that do not broadcast.

    Notes
    -----
    Classical fourth-order Runge-Kutta on the equations in the module docstring, from tb
    towards ``t`` in steps of ``step_s``; every element advances at once (vectorized).
    """
    if not 0.0 < step_s <= 60.0:
        raise UsageError(f"step_s must be in (0, 60] s, got {step_s}")
    idx = np.asarray(idx)
    try:
        t = np.broadcast_to(np.asarray(t_gps_s, dtype=np.float64), idx.shape)
    except ValueError:
        raise UsageError(f"t_gps_s shape {np.shape(t_gps_s)} does not broadcast to idx shape {idx.shape}") from None
    valid = idx >= 0
    if len(eph) == 0 or not valid.any():
        nan = np.full(idx.shape, np.nan)
        nan3 = np.full((*idx.shape, 3), np.nan)
        return SatelliteStates(nan3, nan3.copy(), nan, nan.copy(), nan.copy(), valid & False)
    k = np.where(valid, idx, 0)
    dt = np.where(valid, t - eph.toe_gps_s[k], 0.0)
    n_steps = int(np.ceil(np.max(np.abs(dt)) / step_s - 1e-12)) if dt.size else 0
    state = _integrate(eph, k.ravel(), dt.ravel(), step_s, n_steps).reshape(*idx.shape, 6)
    clock = _clock_s(eph, k, dt)
    pos = np.where(valid[..., None], state[..., :3], np.nan)
    vel = np.where(valid[..., None], state[..., 3:], np.nan)
    zero = np.where(valid, 0.0, np.nan)
    return SatelliteStates(pos, vel, np.where(valid, clock, np.nan), zero, zero.copy(), valid)
