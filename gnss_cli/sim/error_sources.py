"""The simulator's error sources: what each adds to a pseudorange, and their settings.

Sources (names as in ``--errors``): ``clock`` (receiver clock bias, drift and random walk),
``noise`` (white pseudorange noise, elevation dependent or constant), ``iono`` (Klobuchar
times a factor), ``tropo`` (Saastamoinen plus a random zenith offset), ``orbit`` (the
navigation file carries perturbed elements), ``multipath`` (a first-order Gauss-Markov
process per satellite, larger at low elevation) and ``outliers`` (a bias on chosen
satellites over a time window). Every random draw comes from the ``numpy.random.Generator``
passed in; nothing here reads global state.

The defaults of :class:`ErrorConfig` are the values of ``gnss_cli/configs/simulate.toml``.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray
from scipy.signal import lfilter

from gnss_cli.errors import ConfigError, UsageError
from gnss_cli.gnss.ephemeris import KeplerEphemeris
from gnss_cli.gnss.orbits import broadcast_states
from gnss_cli.sim.constellation import argument_of_latitude_rad

F64 = NDArray[np.float64]

ERROR_SOURCES: tuple[str, ...] = ("clock", "noise", "iono", "tropo", "orbit", "multipath", "outliers")
"""Names accepted by ``--errors`` (besides ``none`` and ``all``)."""


@dataclass(frozen=True)
class ErrorConfig:
    """Which error sources are on, and their sizes (SI units; angles in degrees as in the TOML).

    Attributes
    ----------
    enabled : the sources switched on (subset of :data:`ERROR_SOURCES`).
    clock_bias_m, clock_drift_m_s, clock_random_walk_m_sqrt_s : receiver clock
        ``b(t) = bias + drift (t - t0) + random walk`` (metres of range).
    noise_sigma_m : zenith standard deviation of the white pseudorange noise, m.
    noise_elevation_dependent : ``sigma(el) = noise_sigma sqrt((1 + 1/sin^2 el) / 2)``
        (equal to ``noise_sigma`` at the zenith) when True, else ``noise_sigma`` everywhere.
    iono_factor : true ionosphere = factor x the broadcast Klobuchar delay.
    tropo_zenith_sigma_m : standard deviation of a zenith delay offset drawn once per run and
        added to Saastamoinen through the ``1/sin el`` mapping, m.
    orbit_rms_m : 3-D RMS of broadcast-minus-true satellite positions, m.
    orbit_ric_weights : relative sizes of the radial, along-track and cross-track errors.
    multipath_sigma_m, multipath_tau_s, multipath_el_scale_deg : multipath standard deviation
        ``sigma exp(-el / el_scale)``, correlation time ``tau``.
    outlier_sats, outlier_m, outlier_start_s, outlier_end_s : bias added to the pseudoranges of
        these satellites for ``start <= t - t0 < end``.
    outlier_rate, outlier_range_m, outlier_min_elevation_deg : random outliers (with
        ``outliers`` on and ``outlier_rate > 0``): in each epoch with probability ``rate``, one
        satellite drawn among those at or above ``min_elevation`` gets a bias drawn uniformly from
        ``outlier_range_m`` (both signals; a separate random stream, so the other errors are those
        of the same seed without random outliers).
    doppler_sigma_m_s : white Doppler noise (range-rate units) when ``noise`` is on.
    """

    enabled: frozenset[str] = frozenset()
    clock_bias_m: float = 3000.0
    clock_drift_m_s: float = 0.5
    clock_random_walk_m_sqrt_s: float = 0.1
    noise_sigma_m: float = 1.0
    noise_elevation_dependent: bool = True
    iono_factor: float = 1.25
    tropo_zenith_sigma_m: float = 0.05
    orbit_rms_m: float = 1.5
    orbit_ric_weights: tuple[float, float, float] = (0.3, 0.8, 0.5)
    multipath_sigma_m: float = 1.0
    multipath_tau_s: float = 60.0
    multipath_el_scale_deg: float = 20.0
    outlier_sats: tuple[str, ...] = field(default_factory=tuple)
    outlier_m: float = 50.0
    outlier_start_s: float = 0.0
    outlier_end_s: float = float("inf")
    outlier_rate: float = 0.0
    outlier_range_m: tuple[float, float] = (50.0, 500.0)
    outlier_min_elevation_deg: float = 15.0
    doppler_sigma_m_s: float = 0.05

    def on(self, source: str) -> bool:
        """Whether ``source`` is switched on."""
        return source in self.enabled

    def with_sources(self, sources: frozenset[str]) -> "ErrorConfig":
        """The same settings with another set of sources switched on."""
        return replace(self, enabled=frozenset(sources))


def parse_error_list(text: str) -> frozenset[str]:
    """Sources from ``none``, ``all`` or a comma list (``noise,clock``).

    Raises
    ------
    UsageError
        For an unknown source name.
    """
    words = [w.strip().lower() for w in text.split(",") if w.strip()]
    if words in ([], ["none"]):
        return frozenset()
    if words == ["all"]:
        return frozenset(ERROR_SOURCES)
    unknown = sorted(set(words) - set(ERROR_SOURCES))
    if unknown:
        raise UsageError(f"--errors: unknown source(s) {unknown}; expected none, all or a list of {list(ERROR_SOURCES)}")
    return frozenset(words)


def receiver_clock_m(cfg: ErrorConfig, t_rel_s: F64, rng: np.random.Generator) -> tuple[F64, F64]:
    """Receiver clock bias (m) and drift (m/s) at times ``t_rel_s`` ``(T,)`` (s from the start).

    Zero when ``clock`` is off. The random walk adds ``N(0, q^2 dt)`` per step.
    """
    t = np.asarray(t_rel_s, dtype=np.float64)
    if not cfg.on("clock"):
        return np.zeros_like(t), np.zeros_like(t)
    steps = rng.normal(0.0, 1.0, t.size) * cfg.clock_random_walk_m_sqrt_s * np.sqrt(np.diff(t, prepend=t[0]))
    bias = cfg.clock_bias_m + cfg.clock_drift_m_s * (t - t[0]) + np.cumsum(steps)
    return bias, np.full_like(t, cfg.clock_drift_m_s)


def noise_sigma_m(cfg: ErrorConfig, el_rad: F64) -> F64:
    """Standard deviation (m) of the white pseudorange noise at elevations ``el_rad``."""
    el = np.asarray(el_rad, dtype=np.float64)
    if not cfg.noise_elevation_dependent:
        return np.full_like(el, cfg.noise_sigma_m)
    sin_el = np.maximum(np.sin(el), 0.02)
    return cfg.noise_sigma_m * np.sqrt(0.5 * (1.0 + 1.0 / sin_el**2))


def multipath_m(cfg: ErrorConfig, el_rad: F64, interval_s: float, rng: np.random.Generator) -> F64:
    """Multipath error (m), shape of ``el_rad`` ``(T, n)``: a unit first-order Gauss-Markov
    process per satellite (correlation time ``tau``) scaled by ``sigma exp(-el / el_scale)``."""
    el = np.asarray(el_rad, dtype=np.float64)
    phi = np.exp(-interval_s / cfg.multipath_tau_s)
    drive = rng.normal(0.0, np.sqrt(1.0 - phi**2), el.shape)
    drive[0] = rng.normal(0.0, 1.0, el.shape[1])  # start in the stationary distribution
    unit = lfilter([1.0], [1.0, -phi], drive, axis=0)
    return cfg.multipath_sigma_m * np.exp(-np.rad2deg(np.where(np.isfinite(el), el, 0.0)) / cfg.multipath_el_scale_deg) * unit


def perturb_ephemeris(
    eph: KeplerEphemeris,
    rms_m: float,
    rng: np.random.Generator,
    *,
    gm_m3_s2: float,
    omega_e_rad_s: float,
    ric_weights: tuple[float, float, float] = (0.3, 0.8, 0.5),
    half_span_s: float = 3600.0,
) -> KeplerEphemeris:
    """Records with perturbed elements whose position error has the 3-D RMS ``rms_m``.

    Each record gets a random radial / along-track / cross-track error at its toe (normal,
    relative sizes ``ric_weights``), realized in the elements as:
    radial ``dR``: ``A -> A + dR`` with ``delta_n`` changed so the mean motion stays;
    along-track ``dA``: ``m0 -> m0 + dA / A``; cross-track ``dC``: a rotation of the orbit
    plane by ``dC / A`` about the along-track axis at toe (``di = -theta sin u0``,
    ``dOmega = theta cos u0 / sin i`` and ``m0 -= dOmega cos i`` to keep the along-track
    position). The perturbation of each record is then scaled (the error is linear in it at
    metre level) so that ITS 3-D RMS over ``|t - toe| <= half_span_s`` (where a receiver uses
    it) equals ``rms_m``: every record, hence every subset of records, shows the asked RMS.

    Parameters
    ----------
    eph
        Truth records of one system.
    rms_m
        Asked 3-D RMS, m (0 returns ``eph``).
    rng
        Random generator.
    gm_m3_s2, omega_e_rad_s
        The system's constants.
    ric_weights
        Relative standard deviations of the radial, along-track and cross-track errors.
    half_span_s
        Half the interval over which a record's RMS is normalized, s.

    Raises
    ------
    UsageError
        For a negative ``rms_m``.
    """
    if rms_m < 0.0 or not np.isfinite(rms_m):
        raise UsageError(f"orbit error RMS must be a finite non-negative number of metres, got {rms_m}")
    if rms_m == 0.0 or len(eph) == 0:
        return eph
    k = len(eph)
    w = np.asarray(ric_weights, dtype=np.float64)
    d_r, d_a, d_c = (rng.normal(0.0, 1.0, (3, k)) * w[:, None])
    a_m = eph.sqrt_a_sqrt_m**2
    u0 = argument_of_latitude_rad(eph)
    inc = eph.i0_rad
    theta = d_c / a_m
    d_inc = -theta * np.sin(u0)
    d_node = theta * np.cos(u0) / np.sin(inc)
    d_m0 = d_a / a_m - d_node * np.cos(inc)

    def build(scale: F64) -> KeplerEphemeris:
        a_new = a_m + scale * d_r
        n_old = np.sqrt(gm_m3_s2 / a_m**3)
        n_new = np.sqrt(gm_m3_s2 / a_new**3)
        return replace(
            eph,
            sqrt_a_sqrt_m=np.sqrt(a_new),
            delta_n_rad_s=eph.delta_n_rad_s + n_old - n_new,
            m0_rad=eph.m0_rad + scale * d_m0,
            i0_rad=eph.i0_rad + scale * d_inc,
            omega0_rad=eph.omega0_rad + scale * d_node,
        )

    offsets = np.linspace(-half_span_s, half_span_s, 25)
    t = eph.toe_gps_s[:, None] + offsets[None, :]
    idx = np.broadcast_to(np.arange(k)[:, None], t.shape)
    truth = broadcast_states(eph, idx, t, gm_m3_s2=gm_m3_s2, omega_e_rad_s=omega_e_rad_s).pos_ecef_m
    scale = np.ones(k)
    for _ in range(2):  # the second pass removes the (tiny) non-linearity
        trial = broadcast_states(build(scale), idx, t, gm_m3_s2=gm_m3_s2, omega_e_rad_s=omega_e_rad_s).pos_ecef_m
        rms = np.sqrt(np.mean(np.sum((trial - truth) ** 2, axis=-1), axis=1))
        scale = scale * rms_m / rms
    return build(scale)


def random_outliers_m(cfg: ErrorConfig, el_rad: F64, rng: np.random.Generator) -> F64:
    """``(T, n)`` random outlier biases (m; 0 elsewhere): ``outlier_rate`` of the epochs get one
    on a random satellite at or above ``outlier_min_elevation_deg`` (:class:`ErrorConfig`)."""
    n_t, n = el_rad.shape
    bias = np.zeros((n_t, n))
    if not (cfg.on("outliers") and cfg.outlier_rate > 0):
        return bias
    hit = rng.random(n_t) < cfg.outlier_rate
    candidates = el_rad >= np.deg2rad(cfg.outlier_min_elevation_deg)
    hit &= candidates.any(axis=1)
    # a uniform pick among each epoch's candidates: the largest random key among them
    keys = np.where(candidates, rng.random((n_t, n)), -1.0)
    sat = np.argmax(keys, axis=1)
    size = rng.uniform(cfg.outlier_range_m[0], cfg.outlier_range_m[1], n_t)
    rows = np.flatnonzero(hit)
    bias[rows, sat[rows]] = size[rows]
    return bias


def validate(cfg: ErrorConfig) -> ErrorConfig:
    """Check the settings' ranges.

    Raises
    ------
    ConfigError
        For a negative standard deviation or time constant, or an unknown source.
    """
    unknown = sorted(set(cfg.enabled) - set(ERROR_SOURCES))
    if unknown:
        raise ConfigError(f"unknown error source(s) {unknown}")
    for name in (
        "clock_random_walk_m_sqrt_s",
        "noise_sigma_m",
        "tropo_zenith_sigma_m",
        "orbit_rms_m",
        "multipath_sigma_m",
        "doppler_sigma_m_s",
    ):
        value = getattr(cfg, name)
        if not np.isfinite(value) or value < 0.0:
            raise ConfigError(f"{name} must be a finite non-negative number, got {value}")
    if not cfg.multipath_tau_s > 0.0 or not cfg.multipath_el_scale_deg > 0.0:
        raise ConfigError("multipath_tau_s and multipath_el_scale_deg must be positive")
    if not 0.0 <= cfg.outlier_rate <= 1.0:
        raise ConfigError(f"outlier_rate must be within 0..1, got {cfg.outlier_rate}")
    if len(cfg.outlier_range_m) != 2 or not 0.0 <= cfg.outlier_range_m[0] <= cfg.outlier_range_m[1]:
        raise ConfigError(f"outlier_range_m must be two numbers 0 <= low <= high, got {cfg.outlier_range_m}")
    if len(cfg.orbit_ric_weights) != 3 or min(cfg.orbit_ric_weights) < 0 or sum(cfg.orbit_ric_weights) == 0:
        raise ConfigError(f"orbit_ric_weights must be three non-negative numbers, not all 0, got {cfg.orbit_ric_weights}")
    return cfg
