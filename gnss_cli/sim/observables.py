"""Simulated pseudoranges, Dopplers and SNRs from true orbits and a receiver trajectory.

Signal model (the convention a standard single-frequency receiver inverts, e.g. RTKLIB's
``P1 - c TGD``), for the first signal of each system::

    P1 = rho + b - c dt_sv + c TGD + I + T + noise + multipath + outlier

- ``rho``: geometric range from the satellite at the true transmit time ``t_tx`` to the
  antenna at the true reception time ``t_rx``, the satellite rotated by ``omega_e tau``
  about z (Earth rotation during the flight time ``tau = rho / c``; iterated to 1e-9 s).
- ``b`` is one receiver clock for every system (QZSS time is GPS time; Galileo and BeiDou
  times are simulated on GPS time too).
- The epoch label ``t`` is the receiver clock's reading: ``t_rx = t - b / c`` and the
  antenna position at ``t_rx`` is ``r(t) - v(t) b / c`` (what truth.csv reports).
- ``dt_sv``: the broadcast clock polynomial plus relativistic term at ``t_tx``
  (:func:`~gnss_cli.gnss.orbits.broadcast_states`), TGD excluded.
- ``TGD``: GPS and QZSS TGD (L1 C/A), Galileo BGD E5b/E1 (equal to BGD E5a/E1 here), BeiDou TGD1.
- Second signals: GPS L2 P(Y) and QZSS L2C ``+ gamma c TGD`` (``gamma = (f1/f2)^2``), Galileo E5b
  ``+ (f1/f7)^2 c BGD``, BeiDou B2I ``+ c TGD2``; ionosphere scaled by ``(f_L1/f)^2``.
- Doppler ``D = -(d rho/dt + b_dot - c dt_sv_dot) / lambda`` (Hz), the derivatives by central
  differences over 1 s of the light-time range and of the broadcast clock.
- Carrier phase (in the street canyon, and in open sky when asked):
  ``Phi = (rho + b - c dt_sv + T - I) / lambda + N`` cycles (no group delays; the ionosphere
  advances the phase); the canyon (:mod:`gnss_cli.sim.urban`) adds the NLOS path to code and
  carrier and chooses the integers ``N``. In open sky the carrier is continuous (no slips, one
  random ``N`` per satellite and signal), without multipath, and its noise (with ``noise``) the
  thermal jitter of a PLL at the written C/N0 (:func:`~gnss_cli.sim.urban.phase_sigma_m`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from gnss_cli.constants import C_M_S, FREQ_L1_HZ, OMEGA_E_RAD_S
from gnss_cli.gnss.atmosphere import klobuchar_delay_m, saastamoinen_delay_m
from gnss_cli.gnss.ephemeris import KeplerEphemeris, select_ephemeris
from gnss_cli.gnss.frames import azimuth_elevation, ecef2enu_rotation, ecef2geodetic
from gnss_cli.gnss.orbits import broadcast_states
from gnss_cli.sim.constellation import SYSTEMS
from gnss_cli.sim.error_sources import ErrorConfig, multipath_m, noise_sigma_m, random_outliers_m, receiver_clock_m
from gnss_cli.sim.trajectory import Trajectory
from gnss_cli.sim.urban import (
    ReceiverProfile,
    UrbanConfig,
    UrbanLabels,
    UrbanObservables,
    phase_sigma_m,
    street_heading_rad,
    urban_observables,
)

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class Observations:
    """Simulated observables of all satellites of the run (``visible`` says what is written).

    Attributes
    ----------
    t_gps_s : ``(T,)`` epoch labels (receiver clock), GPS seconds.
    sv : ``(n,)`` satellite ids.
    pseudorange_m : ``(T, n, 2)`` first and second signal pseudoranges, m.
    doppler_hz : ``(T, n, 2)`` Dopplers, Hz.
    snr_dbhz : ``(T, n, 2)`` carrier-to-noise densities, dB-Hz.
    visible : ``(T, n)`` elevation at or above the mask.
    el_rad, az_rad : ``(T, n)`` elevation and azimuth at the antenna, rad.
    range_m : ``(T, n)`` geometric range incl. Earth rotation, m.
    t_tx_gps_s : ``(T, n)`` true transmit times, GPS seconds.
    sv_pos_ecef_m : ``(T, n, 3)`` true satellite positions at ``t_tx`` (ECEF of ``t_tx``), m.
    sv_clock_m : ``(T, n)`` true ``c dt_sv`` incl. relativistic term, excl. TGD, m.
    iono_m, tropo_m : ``(T, n)`` delays on the first signal, m.
    rx_pos_ecef_m, rx_vel_ecef_m_s : ``(T, 3)`` antenna at the true reception time.
    rx_clock_m, rx_clock_drift_m_s : ``(T,)`` receiver clock bias (m) and drift (m/s).
    """

    t_gps_s: F64
    sv: NDArray[np.str_]
    pseudorange_m: F64
    doppler_hz: F64
    snr_dbhz: F64
    visible: NDArray[np.bool_]
    el_rad: F64
    az_rad: F64
    range_m: F64
    t_tx_gps_s: F64
    sv_pos_ecef_m: F64
    sv_clock_m: F64
    iono_m: F64
    tropo_m: F64
    rx_pos_ecef_m: F64
    rx_vel_ecef_m_s: F64
    rx_clock_m: F64
    rx_clock_drift_m_s: F64
    outlier_bias_m: F64 | None = None
    """``(T, n)`` random outlier biases put on both pseudoranges, m (0: none; None: no random outliers)."""
    phase_cycles: F64 | None = None
    """``(T, n, 2)`` carrier phases, cycles (None: not simulated; the street canyon only)."""
    urban: UrbanLabels | None = None
    """What the street canyon did (None: open sky)."""


def light_time_states(
    eph: KeplerEphemeris,
    sv: NDArray[np.str_],
    system: str,
    t_rx_gps_s: F64,
    rx_pos_ecef_m: F64,
    *,
    tol_s: float = 1e-12,
    max_iter: int = 10,
) -> tuple[F64, F64, F64, F64, F64]:
    """Solve the light-time equation for every (epoch, satellite).

    Parameters
    ----------
    eph
        Truth records of ``system``.
    sv
        Satellites ``(n,)`` of that system.
    system
        System letter (for the orbit constants).
    t_rx_gps_s
        True reception times ``(T,)``.
    rx_pos_ecef_m
        Antenna positions ``(T, 3)`` at those times.
    tol_s, max_iter
        Convergence of the flight time.

    Returns
    -------
    t_tx (T, n), satellite position at t_tx in the ECEF frame of t_tx (T, n, 3), the same rotated
    into the frame of t_rx (T, n, 3), satellite velocity rotated (T, n, 3), clock incl.
    relativistic term (T, n) in s.

    Notes
    -----
    ``tau_{k+1} = |R_z(omega_e tau_k) s(t_rx - tau_k) - r| / c``; the map contracts by
    ``|v_sv| / c ~ 1e-5`` per step.
    """
    spec = SYSTEMS[system]
    t_rx = np.asarray(t_rx_gps_s, dtype=np.float64)
    idx = select_ephemeris(eph, sv, t_rx, healthy_only=False)
    tau = np.full(idx.shape, 0.075)
    r = np.asarray(rx_pos_ecef_m, dtype=np.float64)[:, None, :]
    for _ in range(max_iter):
        st = broadcast_states(eph, idx, t_rx[:, None] - tau, gm_m3_s2=spec.gm_m3_s2, omega_e_rad_s=spec.omega_e_rad_s)
        rot = _rotate_z(st.pos_ecef_m, OMEGA_E_RAD_S * tau)
        tau_new = np.linalg.norm(rot - r, axis=-1) / C_M_S
        done = np.max(np.abs(tau_new - tau)) < tol_s
        tau = tau_new
        if done:
            break
    st = broadcast_states(eph, idx, t_rx[:, None] - tau, gm_m3_s2=spec.gm_m3_s2, omega_e_rad_s=spec.omega_e_rad_s)
    rot = _rotate_z(st.pos_ecef_m, OMEGA_E_RAD_S * tau)
    vel = _rotate_z(st.vel_ecef_m_s, OMEGA_E_RAD_S * tau)
    return t_rx[:, None] - tau, st.pos_ecef_m, rot, vel, st.clock_s


def _rotate_z(v: F64, angle_rad: F64) -> F64:
    """Coordinates of vectors ``(..., 3)`` in a frame rotated by ``angle`` about z (ECEF at a later time)."""
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.stack([c * v[..., 0] + s * v[..., 1], -s * v[..., 0] + c * v[..., 1], v[..., 2]], axis=-1)


def simulate_observations(
    trajectory: Trajectory,
    truth: dict[str, KeplerEphemeris],
    tgd2_s: dict[str, F64],
    cfg: ErrorConfig,
    rng: np.random.Generator,
    *,
    klobuchar_alpha: F64,
    klobuchar_beta: F64,
    elevation_mask_deg: float = 5.0,
    canyon: tuple[UrbanConfig, ReceiverProfile, np.random.Generator] | None = None,
    phase_pll_bandwidth_hz: float | None = None,
) -> Observations:
    """Observables of every satellite of the systems in ``truth`` at the trajectory's epochs.

    Parameters
    ----------
    trajectory : antenna positions/velocities at the epoch labels (receiver clock time).
    truth : system letter -> truth broadcast records.
    tgd2_s : system letter -> second-signal group delay per record of ``truth`` (BeiDou TGD2), s.
    cfg, rng : error sources; the random generator (the only source of randomness).
    klobuchar_alpha, klobuchar_beta : broadcast ionosphere coefficients ``(4,)`` each.
    elevation_mask_deg : satellites below are marked not visible.
    canyon
        A street canyon, the receiver in it and the canyon's own generator
        (:func:`~gnss_cli.sim.urban.urban_observables`; it replaces the open-sky noise,
        multipath and SNR models and adds carrier phases); None: open sky.
    phase_pll_bandwidth_hz
        Open sky: also carrier phases, the noise of a PLL of this bandwidth (Hz); None: none.

    Returns
    -------
    Observations
    """
    t = trajectory.t_gps_s
    n_t = t.size
    t_rel = t - t[0]
    interval = float(np.median(np.diff(t))) if n_t > 1 else 1.0
    clock_m, drift_m_s = receiver_clock_m(cfg, t_rel, rng)
    rx_pos = trajectory.pos_ecef_m - trajectory.vel_ecef_m_s * (clock_m / C_M_S)[:, None]
    t_rx = t - clock_m / C_M_S
    lat, lon, h = ecef2geodetic(rx_pos)
    rx = _Receiver(t_rx, rx_pos, trajectory.vel_ecef_m_s, lat, lon, h, ecef2enu_rotation(lat, lon), clock_m,
                   drift_m_s)
    tropo_offset_m = rng.normal(0.0, cfg.tropo_zenith_sigma_m) if cfg.on("tropo") else 0.0

    parts: dict[str, list[F64]] = {k: [] for k in ("t_tx", "pos", "range", "el", "az", "clock", "pr", "dop", "phase", "snr", "iono", "tropo")}
    svs: list[NDArray[np.str_]] = []
    for system, eph in truth.items():
        sv, one = _system_observables(system, eph, np.asarray(tgd2_s[system]), rx, cfg, klobuchar_alpha,
                                      klobuchar_beta, tropo_offset_m)
        for key, value in one.items():
            parts[key].append(value)
        svs.append(sv)

    sv_all = np.concatenate(svs)
    el = np.concatenate(parts["el"], axis=1)
    az = np.concatenate(parts["az"], axis=1)
    visible = el >= np.deg2rad(elevation_mask_deg)
    phase = labels = None
    if canyon is None:
        pr, dop, snr = _add_errors(cfg, rng, sv_all, el, np.concatenate(parts["pr"], axis=1),
                                   np.concatenate(parts["dop"], axis=1), t_rel, interval)
    else:
        city = _canyon(canyon, cfg, rng, rx, trajectory, sv_all, parts, el, az, visible, t_rel)
        pr, dop, snr, phase, labels = city.pseudorange_m, city.doppler_hz, city.snr_dbhz, city.phase_cycles, city.labels
        visible = labels.received
    fault = random_outliers_m(cfg, el, rng.spawn(1)[0]) if cfg.outlier_rate > 0 else None
    if fault is not None:
        pr = pr + fault[..., None]
    if canyon is None and phase_pll_bandwidth_hz is not None:  # drawn last: the rest is the run's without phases
        phase = _open_sky_phase(cfg, rng.spawn(1)[0], np.concatenate(parts["phase"], axis=1), sv_all, snr, phase_pll_bandwidth_hz)
    return Observations(
        phase_cycles=phase,
        urban=labels,
        outlier_bias_m=fault,
        t_gps_s=t,
        sv=sv_all,
        pseudorange_m=pr,
        doppler_hz=dop,
        snr_dbhz=snr,
        visible=visible,
        el_rad=el,
        az_rad=az,
        range_m=np.concatenate(parts["range"], axis=1),
        t_tx_gps_s=np.concatenate(parts["t_tx"], axis=1),
        sv_pos_ecef_m=np.concatenate(parts["pos"], axis=1),
        sv_clock_m=np.concatenate(parts["clock"], axis=1),
        iono_m=np.concatenate(parts["iono"], axis=1),
        tropo_m=np.concatenate(parts["tropo"], axis=1),
        rx_pos_ecef_m=rx_pos,
        rx_vel_ecef_m_s=trajectory.vel_ecef_m_s,
        rx_clock_m=clock_m,
        rx_clock_drift_m_s=drift_m_s,
    )


@dataclass(frozen=True, slots=True)
class _Receiver:
    """The receiver at the reception epochs: time, position, velocity, geodetic frame, clock."""

    t_rx: F64
    pos: F64
    vel: F64
    lat: F64
    lon: F64
    h: F64
    rot_enu: F64
    clock_m: F64
    drift_m_s: F64


def _system_observables(
    system: str, eph: KeplerEphemeris, tgd2_all: F64, rx: _Receiver, cfg: ErrorConfig, klobuchar_alpha: F64,
    klobuchar_beta: F64, tropo_offset_m: float,
) -> tuple[NDArray[np.str_], dict[str, F64]]:
    """Error-free observables (and their parts) of the satellites of one system, ``(T, n_sv)`` each."""
    spec = SYSTEMS[system]
    rx_pos, lat, lon, h, t_rx = rx.pos, rx.lat, rx.lon, rx.h, rx.t_rx
    sv = np.unique(eph.sv)
    t_tx, pos, pos_rot, _, clk_s = light_time_states(eph, sv, system, t_rx, rx_pos)
    los = pos_rot - rx_pos[:, None, :]
    rho = np.linalg.norm(los, axis=-1)
    az, el = azimuth_elevation(np.einsum("tij,tnj->tni", rx.rot_enu, los))
    idx = select_ephemeris(eph, sv, t_rx, healthy_only=False)
    tgd = eph.tgd_s[idx]
    tgd2 = tgd2_all[idx]
    # satellite clock rate by a central difference of the broadcast clock
    cp = broadcast_states(eph, idx, t_tx + 0.5, gm_m3_s2=spec.gm_m3_s2, omega_e_rad_s=spec.omega_e_rad_s).clock_s
    cm = broadcast_states(eph, idx, t_tx - 0.5, gm_m3_s2=spec.gm_m3_s2, omega_e_rad_s=spec.omega_e_rad_s).clock_s
    # range rate: central difference of the light-time range itself (h = 0.5 s, error
    # h^2/6 |d3 rho/dt3| < 1e-5 m/s); it keeps the Earth-rotation terms that los . v drops
    half_s = 0.5
    rho_pm = []
    for sgn in (1.0, -1.0):
        r_shift = rx_pos + sgn * half_s * rx.vel
        rot_shift = light_time_states(eph, sv, system, t_rx + sgn * half_s, r_shift)[2]
        rho_pm.append(np.linalg.norm(rot_shift - r_shift[:, None, :], axis=-1))
    range_rate = (rho_pm[0] - rho_pm[1]) / (2.0 * half_s)
    rate = range_rate + rx.drift_m_s[:, None] - C_M_S * (cp - cm)

    f1, f2 = spec.freqs_hz
    iono_l1 = np.zeros_like(rho)
    if cfg.on("iono"):
        iono_l1 = cfg.iono_factor * klobuchar_delay_m(
            klobuchar_alpha, klobuchar_beta, lat[:, None], lon[:, None], az, el, t_rx[:, None]
        )
    tropo = np.zeros_like(rho)
    if cfg.on("tropo"):
        tropo = saastamoinen_delay_m(lat[:, None], h[:, None], el) + tropo_offset_m / np.maximum(np.sin(el), 0.05)
    if system in ("G", "J"):
        gd = (tgd, (f1 / f2) ** 2 * tgd)
    elif system == "E":
        gd = (tgd, (f1 / f2) ** 2 * tgd)
    else:
        gd = (tgd, tgd2)
    common = rho + rx.clock_m[:, None] - C_M_S * clk_s + tropo
    pr = np.stack(
        [common + C_M_S * gd[k] + iono_l1 * (FREQ_L1_HZ / f) ** 2 for k, f in enumerate((f1, f2))], axis=-1
    )
    dop = np.stack([-rate / (C_M_S / f) for f in (f1, f2)], axis=-1)
    phase = np.stack([common - iono_l1 * (FREQ_L1_HZ / f) ** 2 for f in (f1, f2)], axis=-1)
    return sv, {"t_tx": t_tx, "pos": pos, "range": rho, "el": el, "az": az, "clock": C_M_S * clk_s, "pr": pr,
                "dop": dop, "phase": phase, "iono": iono_l1 * (FREQ_L1_HZ / f1) ** 2, "tropo": tropo}


def _add_errors(
    cfg: ErrorConfig, rng: np.random.Generator, sv_all: NDArray[np.str_], el: F64, pr: F64, dop: F64, t_rel: F64,
    interval: float,
) -> tuple[F64, F64, F64]:
    """Noise, multipath and outliers on the pseudoranges ``(T, n, 2)``, noise on the Doppler; the SNR."""
    n_t, n = el.shape
    wavelengths = _wavelengths(sv_all)
    if cfg.on("noise"):
        sigma = noise_sigma_m(cfg, el)
        pr = pr + rng.normal(0.0, 1.0, (n_t, n, 2)) * sigma[..., None]
        dop = dop + rng.normal(0.0, cfg.doppler_sigma_m_s, (n_t, n, 2)) / wavelengths[None]
    if cfg.on("multipath"):
        pr = pr + np.stack([multipath_m(cfg, el, interval, rng) for _ in range(2)], axis=-1)
    pr = _add_named_outliers(cfg, sv_all, pr, t_rel)
    snr1 = np.clip(30.0 + 20.0 * np.sin(np.maximum(el, 0.0)), 25.0, 55.0)
    if cfg.on("noise"):
        snr1 = snr1 + rng.normal(0.0, 0.5, snr1.shape)
    snr = np.stack([snr1, snr1 - 3.0], axis=-1)
    return pr, dop, snr


def _open_sky_phase(cfg: ErrorConfig, rng: np.random.Generator, phase_m: F64, sv_all: NDArray[np.str_], snr_dbhz: F64,
                    pll_bandwidth_hz: float) -> F64:
    """Open-sky carrier phases ``(T, n, 2)``, cycles: the error-free phase ``phase_m`` (m), one
    random integer per satellite and signal, and (with ``noise``) the PLL's thermal jitter at
    ``snr_dbhz``. Its draws come from ``rng``, a child spawned after all others, so the other
    observables are those of the same run without phases."""
    wavelength_m = _wavelengths(sv_all)
    cycles = phase_m / wavelength_m[None] + rng.integers(-100_000, 100_000, (1, *phase_m.shape[1:]))
    if cfg.on("noise"):
        sigma_m = phase_sigma_m(wavelength_m[None], snr_dbhz, pll_bandwidth_hz)
        cycles = cycles + rng.normal(0.0, 1.0, phase_m.shape) * sigma_m / wavelength_m[None]
    return np.asarray(cycles)


def _canyon(
    canyon: tuple[UrbanConfig, ReceiverProfile, np.random.Generator], cfg: ErrorConfig, rng: np.random.Generator,
    rx: _Receiver, trajectory: Trajectory, sv_all: NDArray[np.str_], parts: dict[str, list[F64]], el: F64, az: F64,
    above_mask: NDArray[np.bool_], t_rel: F64,
) -> UrbanObservables:
    """The error-free observables (with the named outliers) put through the street canyon."""
    urban_cfg, profile, env_rng = canyon
    vel_enu = np.einsum("tij,tj->ti", rx.rot_enu, trajectory.vel_ecef_m_s)
    heading, distance = street_heading_rad(vel_enu, t_rel, np.deg2rad(urban_cfg.street_azimuth_deg))
    pr = _add_named_outliers(cfg, sv_all, np.concatenate(parts["pr"], axis=1), t_rel)
    return urban_observables(
        urban_cfg, profile, t_rel_s=t_rel, heading_rad=heading, distance_m=distance, el_rad=el, az_rad=az,
        above_mask=above_mask, pseudorange_m=pr, doppler_hz=np.concatenate(parts["dop"], axis=1),
        phase_m=np.concatenate(parts["phase"], axis=1), wavelength_m=_wavelengths(sv_all), noise=cfg.on("noise"),
        multipath=cfg.on("multipath"), doppler_sigma_m_s=cfg.doppler_sigma_m_s, env_rng=env_rng, noise_rng=rng,
    )


def _wavelengths(sv_all: NDArray[np.str_]) -> F64:
    """Carrier wavelengths ``(n, 2)`` of the two signals of each satellite, m."""
    return np.concatenate(
        [np.broadcast_to(np.array([C_M_S / f for f in SYSTEMS[s[0]].freqs_hz]), (1, 2)) for s in sv_all]
    )


def _add_named_outliers(cfg: ErrorConfig, sv_all: NDArray[np.str_], pr: F64, t_rel: F64) -> F64:
    """The ``outlier_m`` bias on ``outlier_sats`` over the outlier window, both pseudoranges ``(T, n, 2)``."""
    if cfg.on("outliers") and cfg.outlier_sats:
        hit_sv = np.isin(sv_all, np.asarray(cfg.outlier_sats))
        hit_t = (t_rel >= cfg.outlier_start_s) & (t_rel < cfg.outlier_end_s)
        pr = pr + cfg.outlier_m * (hit_t[:, None] & hit_sv[None, :])[..., None]
    return pr
