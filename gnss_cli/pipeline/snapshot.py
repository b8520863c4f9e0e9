"""Files -> epochs -> solutions: the per-epoch positioning run (no terminal I/O).

For every method the same Gauss-Newton iteration runs on all epochs at once (DESIGN.md
section 2): linearize the pseudoranges at the current position, solve the linear step with
the method, update, until the step is below ``convergence_m``. Corrections (Klobuchar,
Saastamoinen), the elevation mask and the weights are evaluated at the current position
once it is near the Earth's surface (the first iterations from the Earth's centre use none
of them, as in RTKLIB).

Observations are padded to a common satellite axis; rows of unusable satellites are masked,
so every epoch is one slice of stacked ``(T, n, 4)`` arrays.
"""

from __future__ import annotations

import time

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from gnss_cli.config import SYSTEM_LETTERS, ProcessingConfig
from gnss_cli.constants import C_M_S
from gnss_cli.errors import NoSolutionError, RinexFormatError
from gnss_cli.gnss.atmosphere import klobuchar_delay_m, saastamoinen_delay_m
from gnss_cli.constants import FREQ_B1I_HZ, FREQ_L1_HZ
from gnss_cli.gnss.ephemeris import KeplerEphemeris
from gnss_cli.gnss.glonass import GlonassEphemeris, glonass_states, select_glonass_ephemeris
from gnss_cli.gnss.multi_gnss import ephemeris_for_system, select_system_ephemeris, system_states
from gnss_cli.gnss.frames import azimuth_elevation, ecef2enu_rotation, ecef2geodetic
from gnss_cli.gnss.geometry import sagnac_range
from gnss_cli.gnss.observables import (
    DEFAULT_SECOND_SIGNAL_PRIORITY,
    DEFAULT_SIGNAL_PRIORITY,
    align_pseudoranges,
    codes_for,
    select_pseudoranges,
)
from gnss_cli.gnss.signals import iono_free_pseudorange_m
from gnss_cli.gnss.time import gps_s2datetime
from gnss_cli.io.rinex import klobuchar_coefficients, read_nav, read_obs
from gnss_cli.solvers import Status, solve_batch
from gnss_cli.solvers.dop import dop_from_cov, tls_paper_cov

F64 = NDArray[np.float64]
Progress = Callable[[str, float], None]

# Methods whose definition includes row weights get the configured pseudorange variances.
WEIGHTED_METHODS = frozenset({"wls", "wtls", "stls"})
# URA index table of IS-GPS-200 (m), as RTKLIB uses it for the ephemeris variance.
_URA_TABLE_M = np.array([2.4, 3.4, 4.85, 6.85, 9.65, 13.65, 24.0, 48.0, 96.0, 192.0, 384.0, 768.0, 1536.0, 3072.0, 6144.0])
_EARTH_SURFACE_BAND_M = (6.0e6, 7.0e6)

STATUS_OK = "ok"


@dataclass(frozen=True)
class EpochData:
    """Everything the estimators need, prepared once per run.

    Attributes
    ----------
    time_gps_s : ``(T,)`` epochs, s since the GPS epoch.
    sv : ``(n,)`` satellite ids.
    pr_corrected_m : ``(T, n)`` pseudorange + c (satellite clock - TGD), m (NaN = unusable).
    sat_ecef_m : ``(T, n, 3)`` satellite positions at transmit time, m.
    ura_m : ``(T, n)`` broadcast orbit-and-clock error sigma, m (:func:`ephemeris_sigma_m`).
    usable : ``(T, n)`` observation with a usable ephemeris.
    klobuchar : ``(alpha, beta)`` or None.
    approx_ecef_m : ``(3,)`` header approximate position or None.
    marker_name : from the observation header.
    """

    time_gps_s: F64
    sv: NDArray[np.str_]
    pr_corrected_m: F64
    sat_ecef_m: F64
    ura_m: F64
    usable: NDArray[np.bool_]
    klobuchar: tuple[F64, F64] | None
    approx_ecef_m: F64 | None
    marker_name: str = ""
    obs_path: str = ""
    nav_paths: tuple[str, ...] = ()
    warnings: tuple[str, ...] = ()
    systems: tuple[str, ...] = ("G",)
    """Systems with usable data, in clock-column order (column 3 + j is system j's clock)."""
    system_index: NDArray[np.int64] | None = None
    """``(n,)`` index into ``systems`` of every satellite."""
    iono_scale: F64 | None = None
    """``(T, n)`` factor taking the L1 Klobuchar delay to the signal's frequency."""


@dataclass(frozen=True)
class MethodSolution:
    """Per-epoch results of one method.

    Attributes
    ----------
    method : registry key.
    x_ecef_m : ``(T, 3)`` receiver positions (NaN where the epoch failed).
    clock_m : ``(T,)`` receiver clock bias, m.
    n_sat : ``(T,)`` satellites used.
    gdop, pdop, hdop, vdop, tdop : ``(T,)`` DOPs from the method's noise gain ``J J^T``
        at the solution, position rotated to local ENU (unitless). ``tdop`` is the TDOP of
        the reference clock, the first of ``EpochData.systems`` (= ``tdops[:, 0]``); ``gdop``
        includes every clock.
    gdop_paper : ``(T,)`` for TLS: the paper's ``(A^T A - s^2 I)^-1 A^T A (...)^-1``; else None.
    cov_m2 : ``(T, 3 + k, 3 + k)`` the estimator covariance ``J Sigma J^T`` for the
        configured pseudorange variances (ECEF position, one clock per system), m^2.
    status : ``(T,)`` status words (``ok``, ``iteration_limit``, ``too_few_satellites``, ...).
    iterations : ``(T,)`` Gauss-Newton iterations.
    residuals_m : ``(T, n)`` post-fit residuals of the used rows (NaN elsewhere).
    """

    method: str
    x_ecef_m: F64
    clock_m: F64
    n_sat: NDArray[np.int64]
    gdop: F64
    pdop: F64
    hdop: F64
    vdop: F64
    tdop: F64
    gdop_paper: F64 | None
    cov_m2: F64
    status: NDArray[np.str_]
    iterations: NDArray[np.int64]
    residuals_m: F64
    clocks_m: F64 | None = None
    """``(T, k)`` receiver clock of every system (column j: ``EpochData.systems[j]``), m."""
    tdops: F64 | None = None
    """``(T, k)`` TDOP of every system's clock, ``sqrt((J J^T)_{3+j,3+j})``; NaN where the
    epoch failed or used no satellite of that system (its clock is then fixed by a constraint)."""


@dataclass(frozen=True)
class RunResult:
    """A whole run: the prepared epochs and one solution per method."""

    epochs: EpochData
    solutions: dict[str, MethodSolution] = field(default_factory=dict)

    @property
    def warnings(self) -> tuple[str, ...]:
        return self.epochs.warnings


def _status_word(code: int) -> str:
    try:
        return Status(code).name.lower()
    except ValueError:
        return f"status_{code}"


def load_epochs(
    obs_path: str | Path,
    nav_paths: Sequence[str | Path],
    config: ProcessingConfig,
    timings: dict[str, float] | None = None,
) -> EpochData:
    """Read and validate the files, select pseudoranges, and compute satellite states.

    ``config.systems`` empty means every system of :data:`~gnss_cli.config.SYSTEM_LETTERS`
    that the observation file has and the navigation files have records of. With
    ``config.iono == "iono-free"`` ``pr_corrected_m`` is the ionosphere-free combination of
    the first and second frequency (:mod:`gnss_cli.gnss.signals`); satellites without a
    usable second frequency are not usable.

    Satellite states are evaluated once per observation, at ``t - P/c``, and moved to the
    transmit time ``t - P/c - dt_sv`` along the broadcast velocity (``|dt_sv| < 1 ms``: the
    neglected acceleration term is below 1e-6 m).

    ``timings``, when given, receives the wall time (s) of the stages ``read`` and ``orbits``.

    Raises
    ------
    InputError
        Unreadable, malformed or mismatched files (no common time span, no ephemeris, no
        system in both files, no dual-frequency pseudorange in iono-free mode).
    """
    clock = time.perf_counter()
    explicit = bool(config.systems)
    systems = list(config.systems) if explicit else list(SYSTEM_LETTERS)
    iono_free = config.iono == "iono-free"
    priority = {**DEFAULT_SIGNAL_PRIORITY, **{k: tuple(v) for k, v in config.signals.items()}}
    priority2 = {**DEFAULT_SECOND_SIGNAL_PRIORITY, **{k: tuple(v) for k, v in config.signals_second.items()}}
    codes = codes_for(systems, priority)
    if iono_free:
        codes += [c for c in codes_for(systems, priority2) if c not in codes]
    obs = read_obs(obs_path, systems=systems, codes=codes)
    nav = read_nav(list(nav_paths), systems=systems)
    nav_name = ",".join(Path(p).name for p in nav_paths)
    warnings: list[str] = []
    if not explicit:
        in_obs = {str(v)[:1] for v in obs["sv"].values}
        in_nav = {str(v)[:1] for v in nav["sv"].values}
        systems = [sy for sy in SYSTEM_LETTERS if sy in in_obs and sy in in_nav]
        if not systems:
            raise RinexFormatError(
                f"{nav_name}: no system of {','.join(SYSTEM_LETTERS)} is both observed in {Path(obs_path).name} "
                f"(has {','.join(sorted(in_obs)) or 'none'}) and in the navigation files (have {','.join(sorted(in_nav)) or 'none'})"
            )

    if timings is not None:
        timings["read"] = time.perf_counter() - clock
        clock = time.perf_counter()
    prs = select_pseudoranges(obs, systems, priority)
    if prs.sv.size == 0:
        raise RinexFormatError(f"{obs_path}: no pseudoranges of {','.join(systems)} (codes {', '.join(codes_for(systems, priority))})")
    prs2 = align_pseudoranges(select_pseudoranges(obs, systems, priority2), prs.sv) if iono_free else None
    t = prs.time_gps_s
    n = prs.sv.size
    sys_of = np.array([sv[0] for sv in prs.sv])
    p_if = np.full((t.size, n), np.nan)
    sat = np.full((t.size, n, 3), np.nan)
    clk = np.full((t.size, n), np.nan)
    tgd = np.full((t.size, n), np.nan)
    ura = np.full((t.size, n), np.nan)
    iono_scale = np.ones((t.size, n))
    usable = np.zeros((t.size, n), dtype=bool)
    have_obs = np.isfinite(prs.pr_m)
    toe_lo, toe_hi = np.inf, -np.inf
    for system in systems:
        cols = np.flatnonzero(sys_of == system)
        if cols.size == 0:
            continue
        pr = prs.pr_m[:, cols]
        if system == "R":
            geph = GlonassEphemeris.from_dataset(nav)
            if len(geph) == 0:
                warnings.append(f"{nav_name}: no GLONASS ephemeris; GLONASS not used")
                continue
            toe_lo, toe_hi = min(toe_lo, geph.toe_gps_s.min()), max(toe_hi, geph.toe_gps_s.max())
            idx = select_glonass_ephemeris(geph, prs.sv[cols], t, healthy_only=config.healthy_only)

            def states_at(i: NDArray[np.intp], tt: F64, _e: GlonassEphemeris = geph):  # type: ignore[no-untyped-def]
                return glonass_states(_e, i, tt)

            freq = geph.g1_frequency_hz()
            scale_of = lambda i, _f=freq: (FREQ_L1_HZ / _f[np.where(i >= 0, i, 0)]) ** 2  # noqa: E731
            ura_of = lambda i: ephemeris_sigma_m("R", np.full(i.shape, np.nan))  # noqa: E731
            delays_of = lambda i, _e=geph: {"tgd_s": np.zeros(i.shape), "glonass_channel": _e.freq_num[i]}  # noqa: E731
        else:
            keph = ephemeris_for_system(nav, system)
            if len(keph) == 0:
                warnings.append(f"{nav_name}: no {system} ephemeris; system {system} not used")
                continue
            toe_lo, toe_hi = min(toe_lo, keph.toe_gps_s.min()), max(toe_hi, keph.toe_gps_s.max())
            idx = select_system_ephemeris(keph, prs.sv[cols], t, system, healthy_only=config.healthy_only)

            def states_at(i: NDArray[np.intp], tt: F64, _e: KeplerEphemeris = keph, _s: str = system):  # type: ignore[no-untyped-def]
                return system_states(_e, i, tt, _s)

            factor = (FREQ_L1_HZ / FREQ_B1I_HZ) ** 2 if system == "C" else 1.0
            scale_of = lambda i, _k=factor: np.full(i.shape, _k)  # noqa: E731
            ura_of = lambda i, _e=keph, _s=system: ephemeris_sigma_m(  # noqa: E731
                _s, _e.ura_m[np.where(i >= 0, i, 0)] if _e.ura_m is not None else np.full(i.shape, np.nan)
            )
            delays_of = lambda i, _e=keph: {  # noqa: E731
                "tgd_s": _e.tgd_s[i],
                "tgd2_s": None if _e.tgd2_s is None else _e.tgd2_s[i],
                "fnav": None if _e.fnav is None else _e.fnav[i],
            }
        # one state per observation with a record, at t - P/c, moved by -dt_sv along the velocity
        ii, jj = np.nonzero(have_obs[:, cols] & (idx >= 0))
        kk, cc = idx[ii, jj], cols[jj]
        st = states_at(kk, t[ii] - pr[ii, jj] / C_M_S)
        sat[ii, cc] = st.pos_ecef_m - st.vel_ecef_m_s * st.clock_s[:, None]
        clk[ii, cc] = st.clock_s
        tgd[ii, cc] = np.nan_to_num(st.tgd_s)
        ura[ii, cc] = ura_of(kk)
        iono_scale[ii, cc] = scale_of(kk)
        usable[ii, cc] = np.isfinite(st.clock_s) & np.isfinite(sat[ii, cc]).all(axis=-1)
        if prs2 is not None:
            p_if[ii, cc] = iono_free_pseudorange_m(
                system, prs.code[ii, cc], pr[ii, jj], prs2.code[ii, cc], prs2.pr_m[ii, cc], **delays_of(kk)
            )
    if not np.isfinite(toe_lo):
        raise RinexFormatError(f"{nav_name}: no ephemeris records for {','.join(systems)}")
    if t.max() < toe_lo - 4 * 3600.0 or t.min() > toe_hi + 4 * 3600.0:
        span = lambda a, b: f"{np.datetime_as_string(gps_s2datetime(a), 'm')} to {np.datetime_as_string(gps_s2datetime(b), 'm')}"  # noqa: E731
        raise RinexFormatError(
            f"{nav_name}: no common time span with {Path(obs_path).name} "
            f"(observations {span(t.min(), t.max())}, ephemerides {span(toe_lo, toe_hi)} GPST)"
        )
    if not usable.any():
        raise RinexFormatError(f"{nav_name}: no usable ephemeris for any satellite observed in {Path(obs_path).name}")
    missing = sorted(set(prs.sv[have_obs.any(axis=0) & ~usable.any(axis=0)]))
    if missing:
        warnings.append(f"no usable ephemeris for {len(missing)} observed satellite(s): {' '.join(missing)}")
    if iono_free:
        dual = usable & np.isfinite(p_if)
        if not dual.any():
            second = ", ".join(c for c in codes_for(systems, priority2))
            raise RinexFormatError(
                f"{Path(obs_path).name}: no satellite has a second-frequency pseudorange for the iono-free combination "
                f"(codes {second}); use --iono klobuchar"
            )
        dropped = sorted(set(prs.sv[usable.any(axis=0) & ~dual.any(axis=0)]))
        if dropped:
            warnings.append(f"iono-free: {len(dropped)} satellite(s) without a usable second frequency not used: {' '.join(dropped)}")
        usable = dual
    used_systems = tuple(sy for sy in systems if usable[:, sys_of == sy].any())
    system_index = np.array([used_systems.index(x) if x in used_systems else 0 for x in sys_of], dtype=np.int64)
    if iono_free:
        pr_corr = np.where(usable, p_if + C_M_S * clk, np.nan)
    else:
        pr_corr = np.where(usable, prs.pr_m + C_M_S * (clk - tgd), np.nan)
    klob = klobuchar_coefficients(nav)
    if klob is None and config.iono == "klobuchar":
        warnings.append(f"{nav_name}: no Klobuchar coefficients in the header; continuing without ionospheric correction")
    if timings is not None:
        timings["orbits"] = time.perf_counter() - clock
    approx = np.asarray(obs.attrs.get("position", []) or [], dtype=np.float64).ravel()
    approx_ok = approx.size == 3 and _EARTH_SURFACE_BAND_M[0] < np.linalg.norm(approx) < _EARTH_SURFACE_BAND_M[1]
    return EpochData(
        time_gps_s=t,
        sv=prs.sv,
        pr_corrected_m=pr_corr,
        sat_ecef_m=sat,
        ura_m=ura,
        usable=usable,
        klobuchar=klob,
        approx_ecef_m=approx if approx_ok else None,
        marker_name=str(obs.attrs.get("marker_name", "") or ""),
        obs_path=str(obs_path),
        nav_paths=tuple(str(p) for p in nav_paths),
        warnings=tuple(warnings),
        systems=used_systems,
        system_index=system_index,
        iono_scale=iono_scale,
    )


def _ura_from_index_table(ura_m: F64) -> F64:
    """Broadcast URA (m) rounded up to the IS-GPS-200 URA table, as RTKLIB does; NaN -> 2.4 m."""
    u = np.where(np.isfinite(ura_m), ura_m, 0.0)
    k = np.searchsorted(_URA_TABLE_M, u - 1e-9)
    return np.where(k < _URA_TABLE_M.size, _URA_TABLE_M[np.minimum(k, _URA_TABLE_M.size - 1)], 6144.0)


GLONASS_EPHEMERIS_SIGMA_M = 5.0
"""GLONASS broadcast orbit-and-clock error sigma (RTKLIB ``ERREPH_GLO``): RINEX 3 records carry no URA."""
GALILEO_NAPA_SIGMA_M = 500.0
"""Galileo SISA 'no accuracy prediction available' (RTKLIB ``STD_GAL_NAPA``)."""


def ephemeris_sigma_m(system: str, accuracy_m: F64) -> F64:
    """Orbit-and-clock error sigma (m) of broadcast records, as RTKLIB's ``var_uraeph``.

    GPS, QZSS, BeiDou: the URA field rounded up to the IS-GPS-200 table (blank: 2.4 m).
    Galileo: the SISA field, 0 < SISA <= 6 m; larger or negative values mean NAPA (500 m);
    blank: 2.4 m. GLONASS: 5 m for every record.
    """
    acc = np.asarray(accuracy_m, dtype=np.float64)
    if system == "R":
        return np.full(acc.shape, GLONASS_EPHEMERIS_SIGMA_M)
    if system == "E":
        napa = np.isfinite(acc) & ((acc <= 0.0) | (acc > 6.0))
        return np.where(np.isfinite(acc), np.where(napa, GALILEO_NAPA_SIGMA_M, acc), _URA_TABLE_M[0])
    return _ura_from_index_table(acc)


def pseudorange_variance_m2(
    config: ProcessingConfig, el_rad: F64, ura_m: F64, iono_m: F64, efact: F64 | float = 1.0
) -> F64:
    """Pseudorange variances (m^2) of the configured weight model (see ``configs/default.toml``).

    ``ura_m`` is the broadcast orbit-and-clock sigma (:func:`ephemeris_sigma_m`); ``efact``
    scales the code-noise term per satellite (RTKLIB: 1.5 for GLONASS, else 1).
    """
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


@dataclass
class _Linearization:
    A: F64
    q: F64
    mask: NDArray[np.bool_]
    var_m2: F64
    unit: F64
    range_m: F64
    rot: F64


_ISB_CONSTRAINT_VAR_M2 = 0.01  # RTKLIB's pseudo-observation fixing the clock of an absent system


def _linearize(data: EpochData, rows: NDArray[np.intp], x: F64, b: F64, config: ProcessingConfig) -> _Linearization:
    """Linearized pseudoranges at ``x`` (ECEF m) and clocks ``b`` (``(t, k)``, m, one per system).

    Columns: ``[-e (3), clock of system 0, ..., clock of system k-1]``. With several systems,
    ``k`` constraint rows follow the ``n`` satellite rows: an epoch without satellites of a
    system gets ``clock_j = 0`` as a pseudo-observation (variance 0.01 m^2), as in RTKLIB.
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
    near = (radius > _EARTH_SURFACE_BAND_M[0]) & (radius < _EARTH_SURFACE_BAND_M[1])
    lat, lon, h = ecef2geodetic(x)
    rot = ecef2enu_rotation(lat, lon)
    az, el = azimuth_elevation(np.einsum("nij,nj->ni", rot[ti], unit_u))
    near_u = near[ti]
    mask_u = ~near_u | (el >= np.deg2rad(config.elevation_mask_deg))
    corrected = near_u & mask_u
    iono = np.zeros_like(rng_u)
    if config.iono == "klobuchar" and data.klobuchar is not None and corrected.any():
        alpha, beta = data.klobuchar
        c = np.flatnonzero(corrected)
        iono[c] = klobuchar_delay_m(alpha, beta, lat[ti[c]], lon[ti[c]], az[c], el[c], data.time_gps_s[tr[c]])
        if data.iono_scale is not None:
            iono[c] *= data.iono_scale[tr[c], si[c]]
    tropo = np.zeros_like(rng_u)
    if config.tropo == "saastamoinen" and corrected.any():
        c = np.flatnonzero(corrected)
        tropo[c] = saastamoinen_delay_m(lat[ti[c]], h[ti[c]], el[c])
    sysidx = data.system_index if data.system_index is not None else np.zeros(n, dtype=np.int64)
    onehot = (sysidx[:, None] == np.arange(k)[None, :]).astype(np.float64)  # (n, k)
    efact = np.where(np.array([sv[0] for sv in data.sv]) == "R", 1.5, 1.0)  # RTKLIB EFACT_GLO
    var_u = np.where(near_u, pseudorange_variance_m2(config, el, data.ura_m[tr, si], iono, efact[si]), 1.0)
    q_u = data.pr_corrected_m[tr, si] - (rng_u + b[ti, sysidx[si]] + iono + tropo)
    mask = np.zeros((t_n, n), dtype=bool)
    mask[ti, si] = mask_u
    q = np.zeros((t_n, n))
    q[ti, si] = np.where(mask_u, q_u, 0.0)
    var = np.ones((t_n, n))
    var[ti, si] = np.where(mask_u, var_u, 1.0)
    A = np.zeros((t_n, n, 3 + k))
    A[ti, si, :3] = np.where(mask_u[:, None], -unit_u, 0.0)
    A[ti, si, 3 + sysidx[si]] = np.where(mask_u, 1.0, 0.0)
    unit = np.zeros((t_n, n, 3))
    unit[ti, si] = unit_u
    rng = np.ones((t_n, n))
    rng[ti, si] = rng_u
    unit_c = unit
    rng_c = rng
    if k > 1:
        present = (mask[:, :, None] & (onehot[None, :, :] > 0)).any(axis=1)  # (t, k)
        t_n = rows.size
        a_c = np.zeros((t_n, k, 3 + k))
        a_c[:, np.arange(k), 3 + np.arange(k)] = 1.0
        q_c = -b
        A = np.concatenate([A, np.where(~present[..., None], a_c, 0.0)], axis=1)
        q = np.concatenate([q, np.where(~present, q_c, 0.0)], axis=1)
        mask = np.concatenate([mask, ~present], axis=1)
        var = np.concatenate([var, np.full((t_n, k), _ISB_CONSTRAINT_VAR_M2)], axis=1)
        unit_c = np.concatenate([unit, np.zeros((t_n, k, 3))], axis=1)
        rng_c = np.concatenate([rng, np.full((t_n, k), 1.0)], axis=1)
    return _Linearization(A, q, mask, var, unit_c, rng_c, rot)


def _stls_row_cov(lin: _Linearization, config: ProcessingConfig) -> F64:
    """Row covariances ``(T, n, 4, 4)`` of ``[e_x, e_y, e_z, q]`` for single-epoch STLS."""
    var_orb = config.orbit_sigma_m**2 / 3.0
    unit = lin.unit
    # |u|^2 I - u u^T: the projector across the line of sight (0 for constraint rows, u = 0)
    perp = np.sum(unit**2, axis=-1)[..., None, None] * np.eye(3) - unit[..., :, None] * unit[..., None, :]
    T, n = lin.q.shape
    cov = np.zeros((T, n, 4, 4))
    cov[..., :3, :3] = var_orb * perp / np.maximum(lin.range_m, 1.0)[..., None, None] ** 2
    cov[..., 3, 3] = lin.var_m2 + var_orb
    return cov


ITERATED_METHODS = frozenset({"ls", "wls"})
_ITERATION_BLOCK = 1024  # epochs per stacked Gauss-Newton solve of LS/WLS


def _solver_options(method: str, lin: _Linearization, config: ProcessingConfig) -> dict[str, object]:
    kwargs: dict[str, object] = {}
    if method in WEIGHTED_METHODS:
        kwargs["weights"] = 1.0 / lin.var_m2
    if method in ("mtls", "stls"):
        kwargs["exact_columns"] = list(range(3, lin.A.shape[-1]))
    if method == "stls":
        kwargs.pop("weights", None)
        kwargs["row_cov"] = _stls_row_cov(lin, config)
    if method == "wtls" and config.wtls_column_scaling == "orbit":
        kwargs["column_scale"] = _wtls_column_scale(lin, config)
    return kwargs


def _wtls_column_scale(lin: _Linearization, config: ProcessingConfig) -> F64:
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
    d_a = sigma_m * range_m * np.sqrt(3.0) / config.orbit_sigma_m
    return np.concatenate([np.full(m, d_a), [1.0]])


def solve_method(
    data: EpochData,
    method: str,
    config: ProcessingConfig,
    progress: Progress | None = None,
    linearization: MethodSolution | None = None,
) -> MethodSolution:
    """Solve every epoch with one method of the solver family.

    ``ls`` and ``wls`` iterate Gauss-Newton to convergence (DESIGN.md section 2). The other
    methods solve the linear system once, linearized at the converged WLS fix
    (``linearization``; computed when not given): iterating them with their own steps does
    not work on pseudorange data. TLS, DLS, MTLS and unscaled WTLS treat the unit-vector columns of
    ``A`` as being as noisy as the pseudoranges in metres, so ``sigma_min(A) < sigma_min([A q])``
    and the iteration overshoots without converging (measured on rtklib-0759: no epoch
    converged in 60 iterations); where the steps do vanish (TLS, MTLS, STLS) they vanish at
    the (W)LS point. One solve at a common linearization point is what tells the estimators
    apart, and it is the comparison the paper makes.

    Returns
    -------
    MethodSolution
        Failed epochs keep a row: NaN position and a status word.
    """
    if method not in ITERATED_METHODS:
        base = linearization if linearization is not None else solve_method(data, "wls", config, progress)
        return _solve_once(data, method, config, base)
    T = data.time_gps_s.size
    n = data.sv.size
    x = np.zeros((T, 3))
    if data.approx_ecef_m is not None:
        x[:] = data.approx_ecef_m
    k = len(data.systems)
    b = np.zeros((T, k))
    status = np.full(T, "iteration_limit", dtype="<U24")
    iterations = np.zeros(T, dtype=np.int64)
    active = np.ones(T, dtype=bool)
    out = _Accumulator(T, n, k, method)
    for it in range(config.max_iterations):
        unconverged = np.flatnonzero(active)
        if unconverged.size == 0:
            break
        # epochs are independent: blocks of _ITERATION_BLOCK bound the memory of the stacked arrays
        for rows in np.array_split(unconverged, -(-unconverged.size // _ITERATION_BLOCK)):
            lin = _linearize(data, rows, x[rows], b[rows], config)
            n_used, enough = _count_used(lin, n, k, config)
            res = solve_batch(method, lin.A, lin.q, lin.mask & enough[:, None], **_solver_options(method, lin, config))
            ok = (res.status > 0) & enough
            step = np.where(ok[:, None], res.x, 0.0)
            x[rows] += step[:, :3]
            b[rows] += step[:, 3:]
            iterations[rows] = it + 1
            radius = np.linalg.norm(x[rows], axis=1)
            near = (radius > _EARTH_SURFACE_BAND_M[0]) & (radius < _EARTH_SURFACE_BAND_M[1])
            converged = ok & near & (np.linalg.norm(step, axis=1) < config.convergence_m)
            out.record(rows, lin, res, n_used)
            _set_status(status, rows, converged, enough, ok, res.status)
            active[rows[converged | ~ok]] = False
        if progress is not None:
            progress(f"{method}: iteration {it + 1}", float(1.0 - active.mean()))
    return out.finish(x, b, status, iterations)


def _set_status(status: NDArray[np.str_], rows: NDArray[np.intp], converged: NDArray[np.bool_],
                enough: NDArray[np.bool_], ok: NDArray[np.bool_], codes: NDArray[np.int8]) -> None:
    status[rows[converged]] = STATUS_OK
    status[rows[~enough]] = "too_few_satellites"
    solver_failed = ~ok & enough
    for r, code in zip(rows[solver_failed], codes[solver_failed]):
        status[r] = _status_word(int(code))


def _solve_once(data: EpochData, method: str, config: ProcessingConfig, base: MethodSolution) -> MethodSolution:
    T, n, k = data.time_gps_s.size, data.sv.size, len(data.systems)
    x = base.x_ecef_m.copy()
    b = base.clocks_m.copy() if base.clocks_m is not None else base.clock_m[:, None].copy()
    status = base.status.copy()
    iterations = np.where(status == STATUS_OK, 1, 0).astype(np.int64)
    out = _Accumulator(T, n, k, method)
    rows = np.flatnonzero(status == STATUS_OK)
    if rows.size:
        lin = _linearize(data, rows, x[rows], b[rows], config)
        n_used, enough = _count_used(lin, n, k, config)
        res = solve_batch(method, lin.A, lin.q, lin.mask & enough[:, None], **_solver_options(method, lin, config))
        ok = (res.status > 0) & enough
        step = np.where(ok[:, None], res.x, 0.0)
        x[rows] += step[:, :3]
        b[rows] += step[:, 3:]
        out.record(rows, lin, res, n_used)
        _set_status(status, rows, ok, enough, ok, res.status)
    return out.finish(x, b, status, iterations)


def _count_used(lin: _Linearization, n: int, k: int, config: ProcessingConfig) -> tuple[NDArray[np.int64], NDArray[np.bool_]]:
    """Satellites used per epoch, and whether they determine position and every present clock."""
    n_used = lin.mask[:, :n].sum(axis=1)
    n_clocks = k - lin.mask[:, n:].sum(axis=1) if k > 1 else np.ones_like(n_used)
    return n_used, n_used >= np.maximum(config.min_satellites, 3 + n_clocks)


class _Accumulator:
    """Keeps the last linear-step quantities of every epoch and builds the MethodSolution."""

    def __init__(self, T: int, n: int, k: int, method: str) -> None:
        self.method = method
        self.n = n
        m = 3 + k
        self.cov = np.full((T, m, m), np.nan)
        self.gain_q = np.full((T, m, m), np.nan)
        self.paper_cov = np.full((T, m, m), np.nan) if method == "tls" else None
        self.residuals = np.full((T, n), np.nan)
        self.n_sat = np.zeros(T, dtype=np.int64)
        self.rot = np.full((T, 3, 3), np.nan)
        self.present = np.zeros((T, k), dtype=bool)

    def record(self, rows: NDArray[np.intp], lin: _Linearization, res, n_used: NDArray[np.int64]) -> None:  # type: ignore[no-untyped-def]
        self.cov[rows] = res.cov
        gain = res.gain[:, :, : self.n]  # satellites only: constraint rows are not geometry
        self.gain_q[rows] = np.einsum("tmn,tkn->tmk", gain, gain)
        if self.paper_cov is not None and res.details is not None and hasattr(res.details, "sigma_min"):
            self.paper_cov[rows] = tls_paper_cov(lin.A, res.details.sigma_min, mask=lin.mask)
        self.residuals[rows] = np.where(lin.mask[:, : self.n], res.residuals[:, : self.n], np.nan)
        self.n_sat[rows] = n_used
        self.rot[rows] = lin.rot
        k = self.present.shape[1]
        # with several systems, a set constraint row (after the n satellite rows) marks an absent system
        self.present[rows] = ~lin.mask[:, self.n :] if k > 1 else True

    def finish(self, x: F64, b: F64, status: NDArray[np.str_], iterations: NDArray[np.int64]) -> MethodSolution:
        bad = status != STATUS_OK
        x = np.where(bad[:, None], np.nan, x)
        b = np.where(bad[:, None], np.nan, b)
        gain_q = np.where(bad[:, None, None], np.eye(self.gain_q.shape[-1]), self.gain_q)
        rot = np.where(bad[:, None, None], np.eye(3), self.rot)
        dop = dop_from_cov(gain_q, rot)
        gdop_paper = None
        if self.paper_cov is not None:
            gdop_paper = np.sqrt(np.clip(np.trace(self.paper_cov, axis1=1, axis2=2), 0.0, None))
            gdop_paper = np.where(bad, np.nan, gdop_paper)

        def masked(v: F64) -> F64:
            return np.where(bad, np.nan, v)

        k = self.present.shape[1]
        q_clk = self.gain_q[:, 3 + np.arange(k), 3 + np.arange(k)]
        tdops = np.where(self.present & ~bad[:, None], np.sqrt(np.clip(q_clk, 0.0, None)), np.nan)

        return MethodSolution(
            method=self.method,
            x_ecef_m=x,
            clock_m=b[:, 0],
            clocks_m=b,
            n_sat=self.n_sat,
            gdop=masked(dop.gdop),
            pdop=masked(dop.pdop),
            hdop=masked(dop.hdop),
            vdop=masked(dop.vdop),
            tdop=np.where(self.present[:, 0], masked(dop.tdop), np.nan),
            tdops=tdops,
            gdop_paper=gdop_paper,
            cov_m2=np.where(bad[:, None, None], np.nan, self.cov),
            status=status,
            iterations=iterations,
            residuals_m=np.where(bad[:, None], np.nan, self.residuals),
        )


def run(
    obs_path: str | Path,
    nav_paths: Sequence[str | Path],
    config: ProcessingConfig,
    progress: Progress | None = None,
) -> RunResult:
    """Read, validate and solve every epoch with every configured method.

    Raises
    ------
    InputError
        Bad input files.
    NoSolutionError
        No epoch could be solved by any method.
    """
    if progress:
        progress("reading", 0.0)
    data = load_epochs(obs_path, nav_paths, config)
    solutions: dict[str, MethodSolution] = {}
    base: MethodSolution | None = None
    for m in config.methods:
        if progress:
            progress(f"solving {m}", 0.0)
        if m not in ITERATED_METHODS and base is None:
            base = solutions.get("wls") or solve_method(data, "wls", config, progress)
        solutions[m] = solve_method(data, m, config, progress, linearization=base)
        if m == "wls":
            base = solutions[m]
    if not any((s.status == STATUS_OK).any() for s in solutions.values()):
        raise NoSolutionError(f"{Path(obs_path).name}: no epoch could be solved ({_status_summary(solutions)})")
    return RunResult(data, solutions)


def _status_summary(solutions: dict[str, MethodSolution]) -> str:
    parts = []
    for m, s in solutions.items():
        words, counts = np.unique(s.status, return_counts=True)
        parts.append(f"{m}: " + ", ".join(f"{c} {w}" for w, c in zip(words, counts)))
    return "; ".join(parts)
