"""The pseudorange model: from an observed pseudorange to the linearized system ``(A, q, W)``.

The whole model in one place, as RTKLIB keeps it in ``pntpos.c`` (``satposs``, ``rescode``).
The pseudorange ``P_i`` of satellite ``i`` received at ``t`` (GPST) by a receiver at ``x``
(ECEF, m) with the clock ``b`` of the satellite's system (m) is modelled (DESIGN.md section 2) as

``P_i = r_i(x) + b - c (dt_i - TGD_i) + I_i + T_i + e_i``,

computed in this order, vectorized over ``(T, n)`` epochs x satellites:

1. **Transmit time** (:func:`satellites_at_transmit_time`): the broadcast record of the
   observation (:mod:`gnss_cli.gnss.broadcast`) is evaluated at ``t - P/c`` and the position
   moved to the transmit time ``t - P/c - dt_i`` along the broadcast velocity (``|dt_i| < 1 ms``:
   the neglected acceleration term is below 1e-6 m; the broadcast velocity's own error,
   ~0.15 m/s, keeps it within 0.2 mm of the state evaluated at the transmit time).
2. **Satellite clock and group delay** (:func:`corrected_pseudoranges`): ``dt_i`` includes the
   relativistic term (:mod:`gnss_cli.gnss.orbits`; GLONASS: in ``TauN``); one frequency:
   ``P + c (dt_i - TGD_i)`` with the system's single-frequency group delay (GPS/QZSS TGD,
   Galileo BGD, BeiDou TGD1; 0 for GLONASS); iono-free: the combination of two signals with
   their group delays removed (:func:`~gnss_cli.gnss.signals.iono_free_pseudorange_m`) ``+ c dt_i``.
3. **Sagnac** (:func:`sagnac_range`): the geometric range with the rotation of the Earth during
   signal flight, ``r = |s - x| + (omega_E / c) (s_x x_y - s_y x_x)``; the design row is
   ``[-e, 1]`` with ``e = (s - x) / |s - x|``.
4. **Atmosphere** (in :func:`linearize`): Klobuchar ionosphere scaled to the signal's frequency
   and Saastamoinen troposphere (:mod:`gnss_cli.gnss.atmosphere`), above the elevation mask.
5. **Weights** (:func:`pseudorange_variance_m2`): RTKLIB's variance model, with the broadcast
   orbit-and-clock sigma of the record (:func:`~gnss_cli.gnss.broadcast.ephemeris_sigma_m`).
6. **Linearization** (:func:`linearize`): ``A`` (rows ``[-e, clock one-hot]``, one clock column per
   system), ``q`` (observed minus computed) and the variances (``W = diag(1 / var)``) of a block
   of epochs, in the dense or the compact layout (:func:`compact_width`, :func:`width_groups`).
   For STLS and WTLS the broadcast-orbit error also enters the geometry columns
   (:func:`stls_row_cov`, :func:`wtls_column_scale`).

Corrections, the mask and the weights apply to positions near the Earth's surface
(:data:`EARTH_SURFACE_BAND_M`) only: the first iterations from the Earth's centre use none of
them, as RTKLIB.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol

import numpy as np
from numpy.typing import NDArray

from gnss_cli.constants import C_M_S, OMEGA_E_RAD_S
from gnss_cli.errors import UsageError
from gnss_cli.gnss.atmosphere import klobuchar_delay_m, saastamoinen_delay_m
from gnss_cli.gnss.broadcast import GlonassRecords, KeplerRecords
from gnss_cli.gnss.frames import azimuth_elevation, ecef2enu_rotation, ecef2geodetic
from gnss_cli.gnss.observables import Pseudoranges
from gnss_cli.gnss.orbits import SatelliteStates
from gnss_cli.gnss.signals import carrier_frequency_hz, iono_free_pseudorange_m, signal_of

if TYPE_CHECKING:
    from gnss_cli.config import ProcessingConfig

F64 = NDArray[np.float64]

EARTH_SURFACE_BAND_M = (6.0e6, 7.0e6)
"""Geocentric radii (m) between which a position counts as near the Earth's surface."""


# Transmit time: the satellite states of every observation (RTKLIB satposs)


@dataclass
class SatelliteArrays:
    """Per-observation satellite quantities ``(T, n[, 3])`` at transmit time, filled one system at a time.

    Attributes
    ----------
    sat : ``(T, n, 3)`` positions, ECEF m.
    clk : ``(T, n)`` clock offsets ``dt_sv`` incl. the relativistic term, s.
    tgd : ``(T, n)`` single-frequency group delays, s (0 when not broadcast).
    ura : ``(T, n)`` broadcast orbit-and-clock sigma, m.
    iono_scale : ``(T, n)`` factor of the L1 ionospheric delay for the observed frequency.
    usable : ``(T, n)`` a record was selected and its state is finite.
    p_if : ``(T, n)`` iono-free pseudorange without group delays, m (NaN: one frequency).
    freq : ``(T, n)`` carrier frequency of each chosen code's signal, Hz (GLONASS per channel; NaN
        for a code of no known signal): the wavelength of its Doppler and carrier phase.
    vel, drift : ``(T, n, 3)`` velocity m/s and ``(T, n)`` clock drift s/s (Doppler; None without).
    freq2 : ``(T, n)`` carrier frequency of the second signal, Hz (iono-free, for the
        ionosphere-free carrier phase; None otherwise).
    """

    sat: F64
    clk: F64
    tgd: F64
    ura: F64
    iono_scale: F64
    usable: NDArray[np.bool_]
    p_if: F64
    freq: F64
    vel: F64 | None = None
    drift: F64 | None = None
    freq2: F64 | None = None

    @classmethod
    def empty(cls, t_n: int, n: int, rates: bool = False) -> SatelliteArrays:
        """NaN arrays; with ``rates`` also velocity and clock drift (for Doppler)."""
        nan = np.full((t_n, n), np.nan)
        return cls(
            sat=np.full((t_n, n, 3), np.nan), clk=nan.copy(), tgd=nan.copy(),
            ura=nan.copy(), iono_scale=np.ones((t_n, n)), usable=np.zeros((t_n, n), dtype=bool),
            p_if=nan.copy(), freq=nan.copy(), vel=np.full((t_n, n, 3), np.nan) if rates else None,
            drift=nan.copy() if rates else None,
        )


def satellites_at_transmit_time(
    prs: Pseudoranges,
    prs2: Pseudoranges | None,
    records_of: Callable[[str], GlonassRecords | KeplerRecords | None],
    systems: Sequence[str],
    healthy_only: bool,
    rates: bool = False,
) -> SatelliteArrays:
    """Satellite position, clock, group delay and orbit sigma of every observation at its transmit time.

    Parameters
    ----------
    prs
        The chosen pseudoranges ``(T, n)``, m, with their codes.
    prs2
        The second-frequency pseudoranges on the same axes (iono-free), else None.
    records_of
        The broadcast records of a system (None: none), asked only for systems with satellites
        in ``prs``.
    systems
        The systems to fill; the other satellites stay NaN and not usable.
    healthy_only
        Select healthy records only.
    rates
        Also the satellite velocity and clock drift (Doppler).

    Returns
    -------
    SatelliteArrays
        ``usable`` where a record was selected and its clock and position are finite.

    Notes
    -----
    Each state is evaluated once, at ``t - P/c``, and the position moved to the transmit time
    ``t - P/c - dt_sv`` along the broadcast velocity (``|dt_sv| < 1 ms``: the neglected
    acceleration term is below 1e-6 m; with the broadcast velocity good to ~0.15 m/s the
    position is within 0.2 mm of the state evaluated at ``t - P/c - dt_sv``, measured on
    rtklib-0759).
    """
    t = prs.time_gps_s
    sys_of = np.array([sv[0] for sv in prs.sv])
    arrays = SatelliteArrays.empty(t.size, prs.sv.size, rates=rates)
    if prs2 is not None:
        arrays.freq2 = np.full((t.size, prs.sv.size), np.nan)
    have_obs = np.isfinite(prs.pr_m)
    for system in systems:
        cols = np.flatnonzero(sys_of == system)
        records = records_of(system) if cols.size else None
        if records is not None:
            _fill_system(arrays, records, system, prs, prs2, cols, have_obs, healthy_only)
    return arrays


def _fill_system(out: SatelliteArrays, records: GlonassRecords | KeplerRecords, system: str,
                 prs: Pseudoranges, prs2: Pseudoranges | None, cols: NDArray[np.intp],
                 have_obs: NDArray[np.bool_], healthy_only: bool) -> None:
    """Satellite states of one system's observations, at ``t - P/c`` moved by ``-dt_sv`` along the velocity."""
    t = prs.time_gps_s
    pr = prs.pr_m[:, cols]
    idx = records.select(prs.sv[cols], t, healthy_only)
    ii, jj = np.nonzero(have_obs[:, cols] & (idx >= 0))
    kk, cc = idx[ii, jj], cols[jj]
    st = records.states(kk, t[ii] - pr[ii, jj] / C_M_S)
    out.sat[ii, cc] = st.pos_ecef_m - st.vel_ecef_m_s * st.clock_s[:, None]
    out.clk[ii, cc] = st.clock_s
    out.tgd[ii, cc] = np.nan_to_num(st.tgd_s)
    out.ura[ii, cc] = records.sigma_m(kk)
    out.iono_scale[ii, cc] = records.iono_scale(kk)
    out.usable[ii, cc] = np.isfinite(st.clock_s) & np.isfinite(out.sat[ii, cc]).all(axis=-1)
    out.freq[ii, cc] = _carrier_frequencies(records, system, prs.code[ii, cc], kk)
    if out.vel is not None:
        _fill_rates(out, records, (ii, cc, kk), t[ii] - pr[ii, jj] / C_M_S, st)
    if prs2 is not None:
        assert out.freq2 is not None  # allocated with prs2
        out.freq2[ii, cc] = _carrier_frequencies(records, system, prs2.code[ii, cc], kk)
        out.p_if[ii, cc] = iono_free_pseudorange_m(
            system, prs.code[ii, cc], pr[ii, jj], prs2.code[ii, cc], prs2.pr_m[ii, cc], **records.delays(kk)
        )


_DRIFT_STEP_S = 1.0  # forward difference of the broadcast clock: af2 and relativistic curvature < 1e-15 s/s


def _fill_rates(out: SatelliteArrays, records: GlonassRecords | KeplerRecords,
                where: tuple[NDArray[np.intp], NDArray[np.intp], NDArray[np.intp]], t_tx: F64, st: SatelliteStates) -> None:
    """Satellite velocity (m/s) and clock drift (s/s, forward difference of the broadcast clock with its
    relativistic term)."""
    assert out.vel is not None and out.drift is not None
    ii, cc, kk = where
    out.vel[ii, cc] = st.vel_ecef_m_s
    out.drift[ii, cc] = (records.clock_s(kk, t_tx + _DRIFT_STEP_S) - st.clock_s) / _DRIFT_STEP_S


def _carrier_frequencies(records: GlonassRecords | KeplerRecords, system: str, code: NDArray[np.str_],
                         kk: NDArray[np.intp]) -> F64:
    """Carrier frequency (Hz; GLONASS per the channel of record ``kk``) of each observation code
    ``code``; NaN for a code of no known signal."""
    channel = np.asarray(records.delays(kk).get("glonass_channel", np.zeros(kk.shape)), dtype=np.float64)
    freq = np.full(kk.shape, np.nan)
    for c in np.unique(code):
        signal = signal_of(system, str(c))
        if signal is not None:
            sel = code == c
            freq[sel] = carrier_frequency_hz(signal, channel[sel])
    return freq


# Satellite clock and group delay


def corrected_pseudoranges(pr_m: F64, sats: SatelliteArrays, usable: NDArray[np.bool_], iono_free: bool) -> F64:
    """Pseudoranges corrected for the satellite clock and group delay (m; NaN where not ``usable``).

    One frequency: ``P + c (dt_sv - TGD)``; iono-free: ``P_IF + c dt_sv`` (the combination
    ``sats.p_if`` has both signals' group delays removed). ``dt_sv`` includes the relativistic
    term. ``pr_m`` ``(T, n)`` are the observed pseudoranges of the first frequency, m.
    """
    if iono_free:
        return np.where(usable, sats.p_if + C_M_S * sats.clk, np.nan)
    return np.where(usable, pr_m + C_M_S * (sats.clk - sats.tgd), np.nan)


# Geometric range with the Sagnac term


def sagnac_range(sat_ecef_m: F64, rx_ecef_m: F64) -> tuple[F64, F64]:
    """Geometric ranges (m) with the Sagnac term, and unit vectors receiver -> satellite.

    Parameters
    ----------
    sat_ecef_m
        ``(T, n, 3)`` satellite positions at transmit time, m.
    rx_ecef_m
        ``(T, 3)`` receiver positions, m.

    Returns
    -------
    range_m : ``(T, n)``
    unit : ``(T, n, 3)`` line-of-sight unit vectors.
    """
    d = sat_ecef_m - rx_ecef_m[:, None, :]
    rho = np.linalg.norm(d, axis=-1)
    unit = d / rho[..., None]
    sagnac = OMEGA_E_RAD_S / C_M_S * (
        sat_ecef_m[..., 0] * rx_ecef_m[:, None, 1] - sat_ecef_m[..., 1] * rx_ecef_m[:, None, 0]
    )
    return rho + sagnac, unit


# Weights: the pseudorange variance model (RTKLIB varerr)


def cn0_variance_m2(cn0_dbhz: F64, c_m2hz: float, ref_dbhz: float) -> F64:
    """The SIGMA-epsilon term of a pseudorange variance above a strong signal's, m^2.

    ``c 10^(-C/N0 / 10) - c 10^(-ref / 10)``, clipped at 0: SIGMA-epsilon's code variance
    ``c 10^(-C/N0/10)`` (Hartinger and Brunner 1999; ``c`` in m^2 Hz, 1.61e4 for the L1 C/A code)
    less its value at ``ref_dbhz``, so that a signal at least as strong as ``ref_dbhz`` keeps the
    variance of the elevation model and a weak one (a reflection, an attenuated line of sight)
    gets the rest (with the defaults, 1.61e4 m^2 Hz and 40 dB-Hz: 35 dB-Hz +3.5 m^2, 25 dB-Hz
    +49 m^2, 20 dB-Hz +159 m^2). A missing C/N0 (NaN: the file has no S code for the signal) adds nothing.
    """
    extra = c_m2hz * (10.0 ** (-np.asarray(cn0_dbhz, dtype=np.float64) / 10.0) - 10.0 ** (-ref_dbhz / 10.0))
    return np.where(np.isfinite(extra), np.maximum(extra, 0.0), 0.0)


def pseudorange_variance_m2(
    config: ProcessingConfig, el_rad: F64, ura_m: F64, iono_m: F64, efact: F64 | float = 1.0,
    cn0_dbhz: F64 | None = None,
) -> F64:
    """Pseudorange variances (m^2) of the configured weight model (see ``gnss_cli/configs/default.toml``).

    ``ura_m`` is the broadcast orbit-and-clock sigma (:func:`~gnss_cli.gnss.broadcast.ephemeris_sigma_m`);
    ``efact`` scales the code-noise term per satellite (RTKLIB: 1.5 for GLONASS, else 1);
    ``cn0_dbhz`` the signals' C/N0 (dB-Hz), which adds :func:`cn0_variance_m2` with
    ``[weights] cn0_model = "sigma-epsilon"``.
    """
    w = config.weights
    var = _model_variance_m2(config, el_rad, ura_m, iono_m, efact)
    if w.cn0_model == "sigma-epsilon" and cn0_dbhz is not None:
        var = var + cn0_variance_m2(cn0_dbhz, w.cn0_c_m2hz, w.cn0_ref_dbhz)
    return var


def _model_variance_m2(config: ProcessingConfig, el_rad: F64, ura_m: F64, iono_m: F64, efact: F64 | float) -> F64:
    """The ``[weights] model`` part of :func:`pseudorange_variance_m2` (m^2), without the C/N0 term."""
    w = config.weights
    sin_el = np.sin(np.clip(el_rad, np.deg2rad(0.1), None))
    if w.model == "equal":
        return np.full_like(el_rad, w.a_m**2)
    if w.model == "elevation":
        return w.a_m**2 + w.b_m**2 / sin_el**2
    var = (w.a_m**2 + w.b_m**2 / sin_el) * np.asarray(efact) ** 2
    if config.iono == "iono-free":  # RTKLIB dual-freq: noise x iono_free_factor, no code-bias or iono term
        return var * w.iono_free_factor**2 + ura_m**2 + (
            (w.saas_sigma_m / (sin_el + 0.1)) ** 2 if config.tropo == "saastamoinen" else w.tropo_off_sigma_m**2
        )
    var = var + ura_m**2 + w.code_bias_m**2
    var = var + ((w.iono_factor * iono_m) ** 2 if config.iono == "klobuchar" else w.iono_off_sigma_m**2)
    var = var + ((w.saas_sigma_m / (sin_el + 0.1)) ** 2 if config.tropo == "saastamoinen" else w.tropo_off_sigma_m**2)
    return var


# The linearized system A, q, W of a block of epochs, with the atmosphere (RTKLIB rescode)


class EpochArrays(Protocol):
    """What :func:`linearize` reads of the prepared epochs (:class:`gnss_cli.pipeline.EpochData`)."""

    time_gps_s: F64
    sv: NDArray[np.str_]
    pr_corrected_m: F64
    sat_ecef_m: F64
    ura_m: F64
    usable: NDArray[np.bool_]
    klobuchar: tuple[F64, F64] | None
    systems: tuple[str, ...]
    system_index: NDArray[np.int64] | None
    iono_scale: F64 | None
    snr_dbhz: F64 | None
    variance_scale: F64 | None


@dataclass
class Linearization:
    """Linearized pseudoranges of a block of epochs (``t`` epochs, ``n`` satellites, ``k`` clocks).

    Attributes
    ----------
    A : ``(t, n [+ k], 3 + k)`` design rows ``[-e, clock one-hot]``; with ``k > 1`` the last
        ``k`` rows are the clock-fixing constraints of systems without satellites.
    q : ``(t, n [+ k])`` observed minus computed, m.
    mask : ``(t, n [+ k])`` rows used (above the mask, usable; set constraint rows).
    var_m2 : ``(t, n [+ k])`` row variances, m^2 (:func:`pseudorange_variance_m2`).
    unit : ``(t, n [+ k], 3)`` line-of-sight unit vectors (0 for constraint rows).
    range_m : ``(t, n [+ k])`` geometric ranges, m (1 for constraint rows).
    rot : ``(t, 3, 3)`` ECEF -> local ENU rotation at each position.
    iono_m : ``(t, n [+ k])`` the modelled ionospheric delay of each row's signal (included in
        ``q``'s computed value), m; 0 where none is modelled (``--iono none`` or ``iono-free``,
        constraint rows, positions far from the Earth's surface). The carrier phase is advanced
        by it where the pseudorange is delayed.
    sv_col : ``(t, w)`` in the compact layout (``linearize(..., width=w)``): the satellite
        (column of ``data.sv``) of each of the ``w`` satellite rows, -1 for the padding rows
        (``mask`` False); None in the dense layout, where satellite row ``i`` is ``data.sv[i]``.
    """

    A: F64
    q: F64
    mask: NDArray[np.bool_]
    var_m2: F64
    unit: F64
    range_m: F64
    rot: F64
    iono_m: F64
    sv_col: NDArray[np.intp] | None = None

    @property
    def sat_rows(self) -> int:
        """Number of satellite rows (``n`` dense, ``w`` compact); the clock constraint rows follow."""
        k = self.A.shape[-1] - 3
        return self.q.shape[1] - (k if k > 1 else 0)

    @property
    def sv_index(self) -> NDArray[np.intp]:
        """``(t, sat_rows)`` satellite (column of ``data.sv``) of each satellite row; -1 for padding."""
        if self.sv_col is not None:
            return self.sv_col
        return np.broadcast_to(np.arange(self.sat_rows), self.q.shape[:1] + (self.sat_rows,))

    def scatter(self, values: F64, n: int, fill: float = np.nan) -> F64:
        """Per-satellite-row ``values`` (``(t, sat_rows)``) in the dense layout ``(t, n)``,
        ``fill`` where a satellite has no row (compact) or ``values`` itself (dense)."""
        if self.sv_col is None:
            return values[:, :n]
        out = np.full((values.shape[0], n), fill)
        t, j = np.nonzero(self.sv_col >= 0)
        out[t, self.sv_col[t, j]] = values[t, j]
        return out


ISB_CONSTRAINT_VAR_M2 = 0.01
"""Variance (m^2) of RTKLIB's pseudo-observation fixing the clock of a system without satellites."""


COMPACT_ROW_STEP = 8
"""The compact layout's satellite rows are a multiple of this (:func:`compact_width`)."""


def compact_width(n_usable: NDArray[np.int64]) -> NDArray[np.int64]:
    """Satellite rows of an epoch's compact linearization: its usable satellites (an upper bound of
    the used ones), rounded up to a multiple of :data:`COMPACT_ROW_STEP` (at least one step).

    The width is a function of the epoch alone, not of the epochs stacked with it: the last bits
    of a stacked factorization or sum change with the number of zero rows after the used ones,
    and an epoch must get the same numbers in a whole-file run and in a run by parts.
    """
    n = np.maximum(np.asarray(n_usable, dtype=np.int64), 1)
    return -(-n // COMPACT_ROW_STEP) * COMPACT_ROW_STEP


def width_groups(usable: NDArray[np.bool_], block: int) -> list[tuple[NDArray[np.intp], int]]:
    """The epochs of ``usable`` (``(t, n)``) by their :func:`compact_width`, in blocks of at most
    ``block`` epochs: ``(epoch indices (ascending), width)`` per block."""
    widths = compact_width(usable.sum(axis=1))
    groups: list[tuple[NDArray[np.intp], int]] = []
    for w in np.unique(widths):
        idx = np.flatnonzero(widths == w)
        groups += [(part, int(w)) for part in np.array_split(idx, -(-idx.size // block))]
    return groups


def linearize(data: EpochArrays, rows: NDArray[np.intp], x: F64, b: F64, config: ProcessingConfig,
              width: int | None = None) -> Linearization:
    """Linearized pseudoranges at ``x`` (ECEF m) and clocks ``b`` (``(t, k)``, m, one per system).

    Columns: ``[-e (3), clock of system 0, ..., clock of system k-1]``. With several systems,
    ``k`` constraint rows follow the ``n`` satellite rows: an epoch without satellites of a
    system gets ``clock_j = 0`` as a pseudo-observation (variance 0.01 m^2), as in RTKLIB.

    Parameters
    ----------
    data : EpochArrays
        The prepared epochs (:class:`gnss_cli.pipeline.EpochData`).
    rows : ``(t,)`` epoch indices of ``data`` to linearize.
    x : ``(t, 3)`` receiver positions, ECEF m.
    b : ``(t, k)`` receiver clocks, m (``(t,)``: one value for every system).
    config : ProcessingConfig
        Elevation mask, atmosphere models and the weight model. Corrections, the mask and
        the weights apply to positions near the Earth's surface (:data:`EARTH_SURFACE_BAND_M`)
        only: the first iterations from the Earth's centre use none of them, as RTKLIB.
    width : int, optional
        The compact layout: ``width`` satellite rows holding the satellites used (usable and
        above the mask) in the order of ``data.sv``, then padding rows (``mask`` False), with
        ``sv_col`` naming each row's satellite; at least the usable satellites of every epoch
        (:func:`compact_width`, :func:`width_groups`). An epoch has 30-50 of the ~110
        satellites of a multi-GNSS file: the solvers then factor ``(t, w + k, 3 + k)``
        instead of ``(t, n + k, 3 + k)`` matrices. Every number is the same as in the dense
        layout (the default); only the rows move.

    Raises
    ------
    UsageError
        ``width`` is smaller than an epoch's number of usable satellites.
    """
    k = len(data.systems)
    b = np.asarray(b, dtype=np.float64)
    if b.ndim == 1:  # one clock for all systems' columns given as (t,): broadcast
        b = np.repeat(b[:, None], k, axis=1)
    t_n, n = rows.size, data.sv.size
    # every per-satellite term is evaluated on the usable observations only, then scattered
    ti, si = np.nonzero(data.usable[rows])
    tr = rows[ti]
    rng_u, unit_u = sagnac_range(data.sat_ecef_m[tr, si][:, None, :], x[ti])
    rng_u, unit_u = rng_u[:, 0], unit_u[:, 0]
    radius = np.linalg.norm(x, axis=1)
    near = (radius > EARTH_SURFACE_BAND_M[0]) & (radius < EARTH_SURFACE_BAND_M[1])
    lat, lon, h = ecef2geodetic(x)
    rot = ecef2enu_rotation(lat, lon)
    az, el = azimuth_elevation(np.einsum("nij,nj->ni", rot[ti], unit_u))
    near_u = near[ti]
    mask_u = ~near_u | (el >= np.deg2rad(config.elevation_mask_deg))
    iono, tropo = _atmosphere_m(data, config, np.flatnonzero(near_u & mask_u), (ti, si, tr),
                                (lat, lon, h), (az, el))
    sysidx = data.system_index if data.system_index is not None else np.zeros(n, dtype=np.int64)
    efact = np.where(np.array([sv[0] for sv in data.sv]) == "R", 1.5, 1.0)  # RTKLIB EFACT_GLO
    cn0 = data.snr_dbhz  # C/N0 of each pseudorange's signal, dB-Hz (None: the file has no S code)
    var_u = np.where(near_u, pseudorange_variance_m2(config, el, data.ura_m[tr, si], iono, efact[si],
                                                     None if cn0 is None else cn0[tr, si]), 1.0)
    if data.variance_scale is not None:  # the NLOS detector's down-weighted reflections
        var_u = var_u * data.variance_scale[tr, si]
    q_u = data.pr_corrected_m[tr, si] - (rng_u + b[ti, sysidx[si]] + iono + tropo)
    sv_col = None
    if width is not None:  # the used observations only
        keep, col, sv_col = _compact_rows(ti, si, mask_u, t_n, width)
        ti, si, mask_u, q_u, var_u, unit_u, rng_u, iono = (v[keep] for v in (ti, si, mask_u, q_u, var_u, unit_u, rng_u, iono))
        n = width
    else:
        col = si
    # the k clock-constraint rows (several systems) follow the n satellite rows in the same arrays
    rows_n = n + (k if k > 1 else 0)
    mask = np.zeros((t_n, rows_n), dtype=bool)
    mask[ti, col] = mask_u
    q = np.zeros((t_n, rows_n))
    q[ti, col] = np.where(mask_u, q_u, 0.0)
    var = np.ones((t_n, rows_n))
    var[ti, col] = np.where(mask_u, var_u, 1.0)
    A = np.zeros((t_n, rows_n, 3 + k))
    A[ti, col, :3] = np.where(mask_u[:, None], -unit_u, 0.0)
    A[ti, col, 3 + sysidx[si]] = np.where(mask_u, 1.0, 0.0)
    unit_c = np.zeros((t_n, rows_n, 3))
    unit_c[ti, col] = unit_u
    rng_c = np.ones((t_n, rows_n))
    rng_c[ti, col] = rng_u
    iono_c = np.zeros((t_n, rows_n))
    iono_c[ti, col] = np.where(mask_u, iono, 0.0)
    if k > 1:
        present = np.zeros((t_n, k), dtype=bool)
        present[ti[mask_u], sysidx[si[mask_u]]] = True
        A[:, n + np.arange(k), 3 + np.arange(k)] = np.where(~present, 1.0, 0.0)
        q[:, n:] = np.where(~present, -b, 0.0)
        mask[:, n:] = ~present
        var[:, n:] = ISB_CONSTRAINT_VAR_M2
    return Linearization(A, q, mask, var, unit_c, rng_c, rot, iono_c, sv_col)


def _atmosphere_m(data: EpochArrays, config: ProcessingConfig, c: NDArray[np.intp],
                  where: tuple[NDArray[np.intp], NDArray[np.intp], NDArray[np.intp]],
                  geodetic: tuple[F64, F64, F64], az_el: tuple[F64, F64]) -> tuple[F64, F64]:
    """Ionospheric (Klobuchar, scaled to each signal) and tropospheric (Saastamoinen) delays (m) of
    the usable observations ``where = (ti, si, tr)`` (epoch in the block, satellite, epoch of the
    file) at the receivers' ``geodetic`` (lat, lon rad; h m) and the satellites' ``az_el`` (rad);
    0 but at the observations ``c`` that are corrected (near the Earth's surface, above the mask)."""
    ti, si, tr = where
    lat, lon, h = geodetic
    az, el = az_el
    iono, tropo = np.zeros(ti.size), np.zeros(ti.size)
    if config.iono == "klobuchar" and data.klobuchar is not None and c.size:
        alpha, beta = data.klobuchar
        iono[c] = klobuchar_delay_m(alpha, beta, lat[ti[c]], lon[ti[c]], az[c], el[c], data.time_gps_s[tr[c]])
        if data.iono_scale is not None:
            iono[c] *= data.iono_scale[tr[c], si[c]]
    if config.tropo == "saastamoinen" and c.size:
        tropo[c] = saastamoinen_delay_m(lat[ti[c]], h[ti[c]], el[c])
    return iono, tropo


def _compact_rows(ti: NDArray[np.intp], si: NDArray[np.intp], used: NDArray[np.bool_], t_n: int, width: int
                  ) -> tuple[NDArray[np.intp], NDArray[np.intp], NDArray[np.intp]]:
    """Where the usable observations ``(ti, si)`` (epoch-major, as ``np.nonzero`` gives them) go in
    the compact layout: the ``used`` ones (their indices), each at its rank among its epoch's
    (its row), and ``sv_col`` ``(t_n, width)``."""
    if ti.size and np.bincount(ti, minlength=t_n).max() > width:
        raise UsageError(f"width: expected at least the usable satellites of every epoch "
                         f"({np.bincount(ti, minlength=t_n).max()}); received {width}")
    keep = np.flatnonzero(used)
    counts = np.bincount(ti[keep], minlength=t_n)
    col = np.arange(keep.size) - (np.cumsum(counts) - counts)[ti[keep]]
    sv_col = np.full((t_n, width), -1, dtype=np.intp)
    sv_col[ti[keep], col] = si[keep]
    return keep, col, sv_col


# Weights of the errors-in-variables methods: the broadcast-orbit error in the geometry columns


def stls_row_cov(lin: Linearization, orbit_sigma_m: float) -> F64:
    """Row covariances ``(T, n, 4, 4)`` of ``[e_x, e_y, e_z, q]`` for single-epoch STLS.

    The pseudorange variance of each row plus the broadcast-orbit error ``orbit_sigma_m``
    (3D RMS, m; ``[stls] orbit_sigma_m``): ``orbit_sigma_m^2 / 3`` along the line of sight
    in ``q`` and across it in the direction cosines, divided by the range squared.
    """
    var_orb = orbit_sigma_m**2 / 3.0
    unit = lin.unit
    # |u|^2 I - u u^T: the projector across the line of sight (0 for constraint rows, u = 0)
    perp = np.sum(unit**2, axis=-1)[..., None, None] * np.eye(3) - unit[..., :, None] * unit[..., None, :]
    T, n = lin.q.shape
    cov = np.zeros((T, n, 4, 4))
    cov[..., :3, :3] = var_orb * perp / np.maximum(lin.range_m, 1.0)[..., None, None] ** 2
    cov[..., 3, 3] = lin.var_m2 + var_orb
    return cov


def wtls_column_scale(lin: Linearization, orbit_sigma_m: float) -> F64:
    """Column scales ``(m + 1,)`` of ``W^{1/2} [A q]`` for WTLS (``[wtls] column_scaling = "orbit"``).

    After row whitening by ``1/sigma_i`` (m), the pseudorange column has unit error and a
    direction cosine has error ``sigma_orbit / (sqrt(3) range_i) / sigma_i``. One scale per
    column cannot whiten every row, so the medians over the used satellite rows set it:
    ``d_A = median(sigma_i) median(range_i) sqrt(3) / sigma_orbit`` for every column of ``A``
    (the clock columns are exact 1s; they get the same, large, scale), ``d_q = 1``.
    """
    m = lin.A.shape[-1]
    sat_rows = lin.mask & (np.sum(lin.unit**2, axis=-1) > 0.5)  # constraint rows have u = 0
    if not sat_rows.any():
        return np.ones(m + 1)
    sigma_m = np.sqrt(np.median(lin.var_m2[sat_rows]))
    range_m = np.median(lin.range_m[sat_rows])
    d_a = sigma_m * range_m * np.sqrt(3.0) / orbit_sigma_m
    return np.concatenate([np.full(m, d_a), [1.0]])
