"""A street canyon: building masks, NLOS reflections, C/N0, code noise and carrier cycle slips.

The receiver drives (or stands) in a street whose axis is the direction of travel (the last
one while stopped; ``street_azimuth_deg`` for a receiver that never moves). Each block of
``block_length_m`` along the path has its own street width ``w`` and building heights on the
left and right, drawn from the seed. A satellite at azimuth ``az`` relative to the street axis
``az_rel = az - heading`` is blocked when its elevation is below the wall on its side::

    mask(az_rel) = atan((H_side - h_ant) |sin az_rel| / (w / 2))

(the antenna in the middle of the street: the wall is ``w / 2 / |sin az_rel|`` away along the
line of sight), so the mask is high across the street and zero along it. A blocked satellite is
still received, as NLOS, in the arcs (durations ``nlos_arc_s``, drawn per satellite) chosen with
probability ``nlos_share``, when the opposite wall is high enough to reflect it; the reflected
path is longer by::

    d_nlos = w cos(el) |sin az_rel| + e,    e ~ Exponential(nlos_extra_m) per arc

(the image-antenna geometry of a wall at ``w / 2``, Groves 2013, ch. 10; ``e`` stands for the
farther reflectors). Its C/N0 is lower by a loss drawn per arc from ``nlos_cn0_loss_db``.

The line-of-sight C/N0 is ``C/N0(el) = C/N0_zenith - cn0_elevation_drop_db (1 - sin el)`` of the
receiver profile; the code noise follows the C/N0 (the SIGMA-epsilon model, Hartinger and
Brunner 1999; Kuusniemi et al. 2004)::

    sigma_code^2 = a + b 10^(-C/N0 / 10)      (m^2; C/N0 in dB-Hz)

and the carrier noise is the thermal jitter of a PLL of bandwidth ``B_n`` (Kaplan and Hegarty
2017, eq. 8.34): ``sigma_phase = lambda / (2 pi) sqrt(B_n / 10^(C/N0 / 10))``. Cycle slips occur
at the rate ``slip_rate_per_s 10^((35 - C/N0) / 10)`` (per second, 35 dB-Hz the reference);
lock is lost whenever a satellite is not tracked for an epoch and whenever its signal path
changes (direct to reflected and back, another reflecting arc or block). Each sets the loss-of-lock
indicator and changes the integer ambiguity; the carrier is continuous otherwise. The Doppler
carries the NLOS delay rate ``w d(cos(el) |sin az_rel|)/dt`` (central differences).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.signal import lfilter

from gnss_cli.errors import ConfigError

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class UrbanConfig:
    """The street canyon (defaults = the ``[urban]`` table of ``gnss_cli/configs/simulate.toml``).

    Attributes
    ----------
    street_azimuth_deg : street axis of a receiver that never moves, deg from north.
    block_length_m : length of a block (one draw of width and heights) along the path, m.
    street_width_m : range of the street width (uniform), m.
    building_height_m : range of the building heights (uniform, each side of each block), m.
    gap_share : probability that a side of a block has no building (a crossing or a square).
    antenna_height_m : antenna above the street, m.
    nlos_share : probability that an arc of a blocked satellite is received by reflection.
    nlos_arc_s : range of the arc durations (uniform), s.
    nlos_extra_m : mean of the exponential extra path of farther reflectors, m.
    nlos_cn0_loss_db : range of the NLOS C/N0 loss (uniform per arc), dB.
    cn0_elevation_drop_db : line-of-sight C/N0 at the horizon below that at the zenith, dB.
    cn0_sigma_db : white C/N0 noise (with the ``noise`` error source), dB.
    multipath_tau_s : correlation time of the code multipath (with ``multipath``), s.
    pll_bandwidth_hz : carrier loop noise bandwidth ``B_n``, Hz.
    slip_rate_per_s : cycle-slip rate at 35 dB-Hz, per second.
    drive_speed_m_s : mean cruising speed of the ``drive`` trajectory, m/s.
    """

    street_azimuth_deg: float = 30.0
    block_length_m: float = 80.0
    street_width_m: tuple[float, float] = (12.0, 30.0)
    building_height_m: tuple[float, float] = (8.0, 40.0)
    gap_share: float = 0.15
    antenna_height_m: float = 1.5
    nlos_share: float = 0.5
    nlos_arc_s: tuple[float, float] = (3.0, 40.0)
    nlos_extra_m: float = 5.0
    nlos_cn0_loss_db: tuple[float, float] = (8.0, 16.0)
    cn0_elevation_drop_db: float = 10.0
    cn0_sigma_db: float = 1.0
    multipath_tau_s: float = 2.0
    pll_bandwidth_hz: float = 10.0
    slip_rate_per_s: float = 0.01
    drive_speed_m_s: float = 10.0


@dataclass(frozen=True)
class ReceiverProfile:
    """What a receiver tracks and how noisy it is (``--receiver``).

    Attributes
    ----------
    systems : system letters tracked.
    dual_frequency : whether the second signal is tracked.
    cn0_zenith_dbhz : line-of-sight C/N0 at the zenith, dB-Hz.
    sigma_a_m2, sigma_b_m2_hz : code noise ``sigma^2 = a + b 10^(-C/N0 / 10)``, m^2 and m^2 Hz.
    """

    systems: tuple[str, ...]
    dual_frequency: bool
    cn0_zenith_dbhz: float
    sigma_a_m2: float
    sigma_b_m2_hz: float


RECEIVERS: dict[str, ReceiverProfile] = {
    # a mass-market single-frequency module with a patch antenna: 1 m code noise at 44 dB-Hz
    "single": ReceiverProfile(("G", "C"), False, 44.0, 0.25, 2.5e4),
    # a dual-frequency multi-GNSS receiver: 0.5 m at 48 dB-Hz
    "dual": ReceiverProfile(("G", "E", "C", "J"), True, 48.0, 0.09, 1.0e4),
}
"""The receiver profiles by their ``--receiver`` name."""


@dataclass(frozen=True)
class UrbanLabels:
    """What the canyon did to each satellite and epoch, ``(T, n)`` each.

    Attributes
    ----------
    los : direct signal not blocked.
    received : tracked (line of sight, or NLOS by reflection).
    nlos_bias_m : extra path of the NLOS signals, m (0 for line of sight).
    cn0_dbhz : C/N0 of the first signal as written, dB-Hz.
    slip : carrier continuity lost since the previous epoch (cycle slip or reacquisition).
    mask_el_rad : the buildings' elevation mask in the satellite's direction, rad.
    """

    los: NDArray[np.bool_]
    received: NDArray[np.bool_]
    nlos_bias_m: F64
    cn0_dbhz: F64
    slip: NDArray[np.bool_]
    mask_el_rad: F64


@dataclass(frozen=True)
class UrbanObservables:
    """Observables in the canyon: pseudoranges and Dopplers ``(T, n, 2)``, C/N0 ``(T, n, 2)``,
    carrier phases ``(T, n, 2)`` in cycles, and the labels."""

    pseudorange_m: F64
    doppler_hz: F64
    snr_dbhz: F64
    phase_cycles: F64
    labels: UrbanLabels


def validate_urban(cfg: UrbanConfig) -> UrbanConfig:
    """Check the ranges of the settings.

    Raises
    ------
    ConfigError
        For a negative size, a share outside 0..1 or a range whose low end exceeds its high end.
    """
    for name in ("street_width_m", "building_height_m", "nlos_arc_s", "nlos_cn0_loss_db"):
        lo_hi = getattr(cfg, name)
        if len(lo_hi) != 2 or not 0.0 <= lo_hi[0] <= lo_hi[1]:
            raise ConfigError(f"[urban] {name} must be two numbers 0 <= low <= high, got {lo_hi}")
    for name in ("gap_share", "nlos_share"):
        if not 0.0 <= getattr(cfg, name) <= 1.0:
            raise ConfigError(f"[urban] {name} must be within 0..1, got {getattr(cfg, name)}")
    for name in ("block_length_m", "multipath_tau_s", "pll_bandwidth_hz", "drive_speed_m_s"):
        if not getattr(cfg, name) > 0.0:
            raise ConfigError(f"[urban] {name} must be positive, got {getattr(cfg, name)}")
    if cfg.nlos_arc_s[0] <= 0.0:
        raise ConfigError(f"[urban] nlos_arc_s must start above 0 s, got {cfg.nlos_arc_s}")
    for name in ("antenna_height_m", "nlos_extra_m", "cn0_elevation_drop_db", "cn0_sigma_db", "slip_rate_per_s"):
        if not np.isfinite(getattr(cfg, name)) or getattr(cfg, name) < 0.0:
            raise ConfigError(f"[urban] {name} must be a finite non-negative number, got {getattr(cfg, name)}")
    return cfg


def street_heading_rad(vel_enu_m_s: F64, t_rel_s: F64, street_azimuth_rad: float, *,
                       min_speed_m_s: float = 0.5) -> tuple[F64, F64]:
    """Street axis and distance along the path at each epoch.

    Parameters
    ----------
    vel_enu_m_s
        Receiver velocity ``(T, 3)``, east/north/up, m/s.
    t_rel_s
        Times since the start ``(T,)``, s.
    street_azimuth_rad
        Axis of a receiver that never moves, rad (one that moves starts in the street of its
        first heading).
    min_speed_m_s
        Below this speed the last heading is kept (a stopped car stays in its street).

    Returns
    -------
    heading (T,) rad from north, distance travelled (T,) m (trapezoidal rule).
    """
    speed = np.hypot(vel_enu_m_s[:, 0], vel_enu_m_s[:, 1])
    moving = speed >= min_speed_m_s
    raw = np.arctan2(vel_enu_m_s[:, 0], vel_enu_m_s[:, 1])
    if not moving.any():
        heading = np.full(speed.size, street_azimuth_rad)
    else:  # the last heading while stopped; before the first move, the street it starts in
        last = np.maximum.accumulate(np.where(moving, np.arange(speed.size), -1))
        heading = raw[np.where(last >= 0, last, np.argmax(moving))]
    distance = np.concatenate([[0.0], np.cumsum(0.5 * (speed[1:] + speed[:-1]) * np.diff(t_rel_s))])
    return heading, distance


def street_mask_rad(az_rel_rad: F64, half_width_m: F64, wall_height_m: F64) -> F64:
    """Elevation of the top of a wall parallel to the street, seen from its middle.

    Parameters
    ----------
    az_rel_rad
        Azimuth relative to the street axis, rad (any shape).
    half_width_m
        Distance of the wall from the antenna, perpendicular to the street, m (broadcasts).
    wall_height_m
        Wall height above the antenna, m (broadcasts; <= 0: no mask).

    Returns
    -------
    ``atan(max(H, 0) |sin az_rel| / (w / 2))``, rad: 0 along the street, ``atan(2 H / w)`` across.
    """
    return np.arctan2(np.maximum(wall_height_m, 0.0) * np.abs(np.sin(az_rel_rad)), half_width_m)


def _arc_index(t_rel_s: F64, n_sv: int, arc_s: tuple[float, float], rng: np.random.Generator) -> tuple[NDArray[np.intp], int]:
    """Each satellite's time line cut into arcs of uniform random length: the arc number
    ``(T, n)`` (unique over all satellites) and the number of arcs drawn."""
    span = float(t_rel_s[-1] - t_rel_s[0]) + arc_s[1]
    per_sv = int(np.ceil(span / arc_s[0])) + 1
    bounds = np.cumsum(rng.uniform(arc_s[0], arc_s[1], (n_sv, per_sv)), axis=1)
    # one sorted array: satellite j's boundaries shifted by j * (the last boundary + 1)
    shift = (bounds[:, -1].max() + 1.0) * np.arange(n_sv)
    flat = (bounds + shift[:, None]).ravel()
    query = (t_rel_s - t_rel_s[0])[:, None] + shift[None, :]
    return np.searchsorted(flat, query, side="right"), n_sv * per_sv


def los_cn0_dbhz(cfg: UrbanConfig, profile: ReceiverProfile, el_rad: F64) -> F64:
    """Line-of-sight C/N0 of the first signal, dB-Hz: ``C/N0_zenith - drop (1 - sin el)`` (el in rad,
    clipped at 0)."""
    return profile.cn0_zenith_dbhz - cfg.cn0_elevation_drop_db * (1.0 - np.sin(np.clip(el_rad, 0.0, None)))


def _street(
    cfg: UrbanConfig, distance_m: F64, heading_rad: F64, az_rad: F64, env_rng: np.random.Generator
) -> tuple[NDArray[np.intp], F64, F64, F64, F64]:
    """The buildings along the path: block number ``(T,)``, street width ``(T, 1)`` m, azimuth
    relative to the street ``(T, n)`` rad, and the heights above the antenna of the wall on the
    satellite's side and of the opposite one ``(T, n)``, m (negative: no building)."""
    block = np.floor(distance_m / cfg.block_length_m).astype(np.intp)
    n_blocks = int(block.max()) + 1
    width = env_rng.uniform(*cfg.street_width_m, n_blocks)[block][:, None]
    heights = env_rng.uniform(*cfg.building_height_m, (n_blocks, 2)) * (env_rng.random((n_blocks, 2)) >= cfg.gap_share)
    az_rel = az_rad - heading_rad[:, None]
    right = np.sin(az_rel) > 0.0
    h_near = np.where(right, heights[block, 1][:, None], heights[block, 0][:, None]) - cfg.antenna_height_m
    h_far = np.where(right, heights[block, 0][:, None], heights[block, 1][:, None]) - cfg.antenna_height_m
    return block, width, az_rel, h_near, h_far


def _carrier_slips(
    cfg: UrbanConfig, received: NDArray[np.bool_], new_path: NDArray[np.bool_], cn0_dbhz: F64, interval_s: float,
    env_rng: np.random.Generator,
) -> tuple[NDArray[np.bool_], NDArray[np.int64]]:
    """Where carrier continuity is lost ``(T, n)`` (reacquisition, a new path, or a slip at the rate
    ``slip_rate_per_s 10^((35 - C/N0) / 10)``; never at the first epoch) and the integer
    ambiguities ``(T, n, 2)``: random at the start, changed by a random non-zero integer at each loss."""
    n_t, n = received.shape
    tracked_before = np.vstack([np.ones((1, n), dtype=bool), received[:-1]])
    p_slip = np.minimum(cfg.slip_rate_per_s * interval_s * 10.0 ** ((35.0 - cn0_dbhz) / 10.0), 1.0)
    slip = received & (~tracked_before | new_path | (env_rng.random((n_t, n)) < p_slip))
    slip[0] = False
    jumps = env_rng.integers(1, 1000, (n_t, n, 2)) * env_rng.choice([-1, 1], (n_t, n, 2))
    start = env_rng.integers(-100_000, 100_000, (1, n, 2))
    return slip, start + np.cumsum(np.where(slip[..., None], jumps, 0), axis=0)


def _gauss_markov(shape: tuple[int, int], interval_s: float, tau_s: float, rng: np.random.Generator) -> F64:
    """Unit-variance first-order Gauss-Markov sequences along axis 0, started stationary."""
    phi = np.exp(-interval_s / tau_s)
    drive = rng.normal(0.0, 1.0, shape) * np.sqrt(1.0 - phi**2)
    drive[0] = rng.normal(0.0, 1.0, shape[1])
    return np.asarray(lfilter([1.0], [1.0, -phi], drive, axis=0))


def phase_sigma_m(wavelength_m: F64, cn0_dbhz: F64, pll_bandwidth_hz: float) -> F64:
    """Standard deviation of the carrier phase's thermal noise, m: ``lambda / (2 pi) sqrt(B_n / 10^(C/N0 / 10))``
    (the PLL's thermal jitter, Kaplan and Hegarty 2017, eq. 8.34; the arguments broadcast)."""
    return np.asarray(wavelength_m / (2.0 * np.pi) * np.sqrt(pll_bandwidth_hz * 10.0 ** (-np.asarray(cn0_dbhz) / 10.0)))


def urban_observables(
    cfg: UrbanConfig,
    profile: ReceiverProfile,
    *,
    t_rel_s: F64,
    heading_rad: F64,
    distance_m: F64,
    el_rad: F64,
    az_rad: F64,
    above_mask: NDArray[np.bool_],
    pseudorange_m: F64,
    doppler_hz: F64,
    phase_m: F64,
    wavelength_m: F64,
    noise: bool,
    multipath: bool,
    doppler_sigma_m_s: float,
    env_rng: np.random.Generator,
    noise_rng: np.random.Generator,
) -> UrbanObservables:
    """Put the canyon on error-free (or open-sky-error) observables.

    Parameters
    ----------
    cfg, profile
        The canyon and the receiver.
    t_rel_s
        Times since the start ``(T,)``, s.
    heading_rad, distance_m
        Street axis (rad from north) and distance travelled (m), ``(T,)`` each
        (:func:`street_heading_rad`).
    el_rad, az_rad
        Satellite elevations and azimuths ``(T, n)``, rad.
    above_mask
        ``(T, n)`` at or above the receiver's elevation mask (only those can be tracked).
    pseudorange_m, doppler_hz
        Observables ``(T, n, 2)`` without the canyon.
    phase_m
        Carrier phases ``(T, n, 2)`` without ambiguity and noise, m.
    wavelength_m
        Carrier wavelengths ``(n, 2)``, m.
    noise, multipath
        Whether the ``noise`` and ``multipath`` error sources are on (code noise, C/N0 noise,
        Doppler noise, carrier noise; Gauss-Markov code multipath, both scaled by the C/N0 sigma).
    doppler_sigma_m_s
        White Doppler noise with ``noise``, m/s.
    env_rng
        Generator of the canyon (buildings, arcs, slips, ambiguities): independent of the error
        sources, so runs that differ only in ``--errors`` see the same canyon.
    noise_rng
        Generator of the noise.

    Returns
    -------
    UrbanObservables
        The NLOS delay ``d_nlos`` (module docstring) is added to code and carrier, its rate
        (central differences in time) to the Doppler; blocked satellites not received by
        reflection are marked not received.
    """
    n_t, n = el_rad.shape
    interval = float(np.median(np.diff(t_rel_s))) if n_t > 1 else 1.0
    block, width, az_rel, h_near, h_far = _street(cfg, distance_m, heading_rad, az_rad, env_rng)
    mask = street_mask_rad(az_rel, 0.5 * width, h_near)
    los = el_rad >= mask
    # NLOS arcs: reflected or not, extra path and C/N0 loss, drawn per arc
    arc, n_arcs = _arc_index(t_rel_s, n, cfg.nlos_arc_s, env_rng)
    reflected = env_rng.random(n_arcs) < cfg.nlos_share
    extra = env_rng.exponential(cfg.nlos_extra_m, n_arcs) if cfg.nlos_extra_m > 0 else np.zeros(n_arcs)
    loss = env_rng.uniform(*cfg.nlos_cn0_loss_db, n_arcs)
    sin_rel = np.abs(np.sin(az_rel))
    # the reflection point on the far wall is (w / 2) / |sin az_rel| away, tan(el) times that higher
    point_m = np.tan(np.clip(el_rad, 0.0, 1.5)) * 0.5 * width / np.maximum(sin_rel, 1e-3)
    nlos = ~los & reflected[arc] & (point_m < h_far) & (el_rad > 0.0)
    geometry = np.cos(el_rad) * sin_rel
    bias = np.where(nlos, width * geometry + extra[arc], 0.0)
    # the rate within one reflector (width and extra path fixed): no spikes where they change
    delay_rate = width * (np.gradient(geometry, t_rel_s, axis=0) if n_t > 1 else np.zeros_like(geometry))
    received = (los | nlos) & above_mask
    cn0 = np.where(nlos, los_cn0_dbhz(cfg, profile, el_rad) - loss[arc], los_cn0_dbhz(cfg, profile, el_rad))
    cn0_2 = np.stack([cn0, cn0 - 3.0], axis=-1)  # the second signal 3 dB weaker, as in open sky
    sigma_code = np.sqrt(profile.sigma_a_m2 + profile.sigma_b_m2_hz * 10.0 ** (-cn0_2 / 10.0))
    sigma_phase = phase_sigma_m(wavelength_m[None], cn0_2, cfg.pll_bandwidth_hz)
    # a new signal path (direct <-> reflected, another reflector) breaks the carrier
    new_path = np.zeros((n_t, n), dtype=bool)
    new_path[1:] = (nlos[1:] != nlos[:-1]) | (nlos[1:] & ((arc[1:] != arc[:-1]) | (block[1:] != block[:-1])[:, None]))
    slip, ambiguity = _carrier_slips(cfg, received, new_path, cn0, interval, env_rng)
    pr = pseudorange_m + bias[..., None]
    dop = doppler_hz - np.where(nlos, delay_rate, 0.0)[..., None] / wavelength_m[None]
    phase = (phase_m + bias[..., None]) / wavelength_m[None] + ambiguity
    snr = cn0_2
    if noise:
        pr = pr + noise_rng.normal(0.0, 1.0, pr.shape) * sigma_code
        dop = dop + noise_rng.normal(0.0, doppler_sigma_m_s, dop.shape) / wavelength_m[None]
        phase = phase + noise_rng.normal(0.0, 1.0, phase.shape) * sigma_phase / wavelength_m[None]
        snr = snr + noise_rng.normal(0.0, cfg.cn0_sigma_db, (n_t, n))[..., None]
    if multipath:
        unit = np.stack([_gauss_markov((n_t, n), interval, cfg.multipath_tau_s, noise_rng) for _ in range(2)], axis=-1)
        pr = pr + unit * sigma_code
    labels = UrbanLabels(los=los, received=received, nlos_bias_m=bias, cn0_dbhz=snr[..., 0], slip=slip, mask_el_rad=mask)
    return UrbanObservables(pr, dop, snr, phase, labels)
