"""The sections of the processing configuration: pseudorange weights and the multi-epoch methods
and the NLOS detector (``[weights]``, ``[stls]``, ``[smoother]``, ``[kalman]``, ``[nlos]`` of ``gnss_cli/configs/default.toml``).

Re-exported by :mod:`gnss_cli.config`.
"""

from __future__ import annotations

from dataclasses import dataclass

from gnss_cli.errors import ConfigError

__all__ = [
    "WeightConfig", "CN0_MODELS", "StlsConfig", "SmootherConfig", "KalmanConfig", "STLS_KERNELS", "SMOOTHER_MOTIONS",
    "MEASUREMENT_KINDS", "KALMAN_MODELS", "KALMAN_OUTPUTS", "NlosConfig", "NLOS_DETECTORS", "NLOS_FAILED_EPOCHS", "NLOS_MULTI_EPOCH",
]


@dataclass(frozen=True)
class WeightConfig:
    """Pseudorange variance model (see ``gnss_cli/configs/default.toml``)."""

    model: str = "rtklib"
    a_m: float = 0.3
    b_m: float = 0.3
    code_bias_m: float = 0.3
    iono_factor: float = 0.5
    saas_sigma_m: float = 0.3
    iono_off_sigma_m: float = 5.0
    tropo_off_sigma_m: float = 3.0
    iono_free_factor: float = 3.0
    cn0_model: str = "sigma-epsilon"
    cn0_c_m2hz: float = 1.61e4
    cn0_ref_dbhz: float = 40.0

    def describe(self) -> str:
        """The model in words for the outputs: ``rtklib``, ``rtklib + sigma-epsilon C/N0 (ref 45 dB-Hz)``."""
        if self.cn0_model == "off":
            return self.model
        return f"{self.model} + {self.cn0_model} C/N0 (ref {self.cn0_ref_dbhz:g} dB-Hz)"


CN0_MODELS = ("off", "sigma-epsilon")
"""C/N0 terms of the pseudorange variance (``[weights] cn0_model``)."""
STLS_KERNELS = ("shared", "full")
"""Structures of the identified kernel of ``stls`` with ``lag >= 1``: ``r(z) I_3`` or a full ``3 x 3(L+1)`` kernel."""
SMOOTHER_MOTIONS = ("quadrature", "cv", "ca", "static")
"""Fixed motion models of the ``smoother`` method (``[smoother] motion``, ``--motion``)."""
MEASUREMENT_KINDS = ("pseudorange", "doppler", "phase")
"""What the multi-epoch methods (``stls`` with ``lag >= 1`` through its fixes, ``smoother``, ``kf``) may use."""


MIN_LATENCY_M = 1e-4
"""The smallest non-zero ``stls.latency_m``, m: at 1e-5 m the soft kernel rows (weight 1e10 per
m^2) made the tied runs of a simulated drive singular, so they were not tied; at 1e-4 m the
track is the exact behavior's to 1 mm (``tests/pipeline/test_tied.py``)."""


@dataclass(frozen=True)
class StlsConfig:
    """The ``stls`` method (``[stls]`` in ``gnss_cli/configs/default.toml``).

    ``lag = 0``: single-epoch structured TLS. ``lag >= 1``: the paper's behavioral method -- a
    kernel identified from the data by weighted Hankel STLS in whole segments (``window = 0``) or
    sliding windows of ``window`` epochs (``kernel`` shared or full; ``order = 0``: ``3 lag`` for a
    full kernel), each window's behavior tested at the false-alarm probability ``behavior_pfa``
    (:mod:`gnss_cli.pipeline.spans`; 0: not tested, whatever ``integrity`` says); where the spans
    are tied (range rates or phase), ``latency_m`` is the standard deviation of the latent input
    that may drive the trajectory out of each span's behavior (m; 0: exactly in it;
    :mod:`gnss_cli.behavior.piecewise`). The defaults equal the packaged TOML.
    """

    lag: int = 0
    kernel: str = "shared"
    order: int = 0
    window: int = 0
    tolerance: float = 1e-6
    max_iterations: int = 200
    behavior_pfa: float = 1e-6
    latency_m: float = 0.0

    @property
    def full_order(self) -> int | None:
        """Order of a full identified kernel (``order``, or ``3 lag`` for 0); None for the shared kernel."""
        if self.kernel != "full":
            return None
        return self.order if self.order > 0 else 3 * self.lag

    def min_window(self) -> int:
        """Shortest window (epochs) the kernel can be identified on: shared ``2 lag + 2``, full ``3 (lag + 1) + 1``."""
        return max(2 * self.lag + 2 if self.kernel == "shared" else 3 * (self.lag + 1) + 1, 2)

    def validated(self) -> "StlsConfig":
        """Self, after checking every value; raises :class:`ConfigError` naming the key."""
        for name in ("lag", "order", "window", "max_iterations"):
            value = getattr(self, name)
            low = 1 if name == "max_iterations" else 0
            if isinstance(value, bool) or not isinstance(value, int) or value < low:
                raise ConfigError(f"stls.{name}: expected an integer >= {low}; received {value!r}")
        if self.kernel not in STLS_KERNELS:
            raise ConfigError(f"stls.kernel: expected one of {', '.join(STLS_KERNELS)}; received {self.kernel!r}")
        if not self.tolerance > 0:
            raise ConfigError(f"stls.tolerance: expected > 0; received {self.tolerance}")
        if not (self.latency_m == 0 or MIN_LATENCY_M <= self.latency_m < float("inf")):
            raise ConfigError(f"stls.latency_m: expected 0 (the exact behavior) or a finite value >= {MIN_LATENCY_M:g} m "
                              f"(smaller ones leave the tied system ill-conditioned); received {self.latency_m}")
        if not 0 <= self.behavior_pfa < 1:
            raise ConfigError(f"stls.behavior_pfa: expected 0 (no behavior test) or a probability below 1; "
                              f"received {self.behavior_pfa}")
        if self.lag == 0:
            if self.order:
                raise ConfigError(f"stls.order = {self.order} needs stls.lag >= 1 (lag 0 = single-epoch STLS)")
            return self
        need = self.min_window()
        if 0 < self.window < need:
            raise ConfigError(f"stls.window: expected 0 (whole segments) or >= {need} epochs for lag {self.lag}, "
                              f"kernel {self.kernel}; received {self.window}")
        if self.kernel == "shared" and self.order:
            raise ConfigError(f"stls.order: applies to kernel = 'full' only; received order = {self.order} "
                              f"with kernel = 'shared'")
        order = self.full_order
        if order is not None:
            self._check_full_order(order)
        return self

    def _check_full_order(self, order: int) -> None:
        """A full ``3 x 3(l+1)`` kernel of order ``n`` has ``g = 3(l+1) - n`` rows, 1 <= g, and
        ``g (N - l) <= 3 N`` over a window of ``N`` epochs (else ``G Sigma G^T`` is singular)."""
        lag = self.lag
        if not 0 < order < 3 * (lag + 1):
            raise ConfigError(f"stls.order: expected 1 <= order < 3 (lag + 1) = {3 * (lag + 1)} for lag {lag}; received {order}")
        g = 3 * (lag + 1) - order
        n = self.window
        if g > 3 and (n == 0 or g * (n - lag) > 3 * n):
            span = "whole segments (window = 0)" if n == 0 else f"windows of {n} epochs"
            raise ConfigError(f"stls.order: order {order} with lag {lag} leaves {g} kernel rows, infeasible on {span}; "
                              f"use order >= {3 * lag} or a shorter window")


@dataclass(frozen=True)
class SmootherConfig:
    """The ``smoother`` method (``[smoother]`` in ``gnss_cli/configs/default.toml``): a batch
    least-squares smoother of whole segments in the measurement domain with a fixed motion model."""

    motion: str = "quadrature"
    lag: int = 3

    def validated(self) -> "SmootherConfig":
        """Self, after checking every value; raises :class:`ConfigError` naming the key."""
        if self.motion not in SMOOTHER_MOTIONS:
            raise ConfigError(f"smoother.motion: expected one of {', '.join(SMOOTHER_MOTIONS)}; received {self.motion!r}")
        if isinstance(self.lag, bool) or not isinstance(self.lag, int) or not 1 <= self.lag <= 3:
            raise ConfigError(f"smoother.lag: expected 1, 2 or 3 (the velocity quadrature's lag); received {self.lag!r}")
        return self


KALMAN_MODELS = ("cv", "ca")
KALMAN_OUTPUTS = ("smoothed", "filtered")
"""``[kalman] output``: the Rauch-Tung-Striebel smoothed estimates, or the filter's own."""


@dataclass(frozen=True)
class KalmanConfig:
    """The ``kf`` method (``[kalman]`` in ``gnss_cli/configs/default.toml``, which explains each value)."""

    model: str = "cv"
    output: str = "smoothed"
    accel_psd_m2_s3: float = 10.0
    jerk_psd_m2_s5: float = 10.0
    clock_psd_m2_s: float = 0.01
    drift_psd_m2_s3: float = 0.04
    initial_velocity_sigma_m_s: float = 100.0
    initial_drift_sigma_m_s: float = 1000.0
    gap_s: float = 60.0
    clock_reset_m: float = 1000.0

    def validated(self) -> "KalmanConfig":
        """Self, after checking every value; raises :class:`ConfigError` naming the key."""
        for name, allowed in (("model", KALMAN_MODELS), ("output", KALMAN_OUTPUTS)):
            if getattr(self, name) not in allowed:
                raise ConfigError(f"kalman.{name}: expected one of {', '.join(allowed)}; received {getattr(self, name)!r}")
        for name in ("accel_psd_m2_s3", "jerk_psd_m2_s5", "clock_psd_m2_s", "drift_psd_m2_s3", "initial_velocity_sigma_m_s",
                     "initial_drift_sigma_m_s", "gap_s", "clock_reset_m"):
            if not getattr(self, name) > 0:
                raise ConfigError(f"kalman.{name}: expected > 0; received {getattr(self, name)}")
        return self


NLOS_DETECTORS = ("off", "arcs")
NLOS_MULTI_EPOCH = ("off", "cusum")
"""``[nlos] multi_epoch``: none, or the CUSUM spans of the multi-epoch methods' residuals."""
NLOS_DELAY_SOURCES = ("fix", "doppler")
"""``[nlos] cn0_delay_source``: what measures a C/N0 span's delay (:func:`gnss_cli.pipeline.nlos.exclude_nlos`)."""
NLOS_FAILED_EPOCHS = ("keep", "retry")
"""``[nlos] failed_epochs``: an epoch that fails after the exclusions stays so, or is solved again with every satellite."""
"""``[nlos] detector``: none, or the per-satellite spans of :mod:`gnss_cli.pipeline.nlos`."""


@dataclass(frozen=True)
class NlosConfig:
    """The NLOS detector of the ls/wls fixes (``[nlos]`` in ``gnss_cli/configs/default.toml``,
    which explains each value; :mod:`gnss_cli.pipeline.nlos`)."""

    detector: str = "off"
    template_quantile: float = 0.9
    template_bin_deg: float = 5.0
    template_min_count: int = 10
    cn0_enter_db: float = 7.0
    cn0_exit_db: float = 4.0
    cn0_min_epochs: int = 2
    cn0_min_delay_m: float = 0.0
    cn0_delay_source: str = "fix"
    cn0_delay_sigmas: float = 1.0
    residual_k: float = 1.0
    residual_h: float = float("inf")
    min_dof: int = 2
    failed_epochs: str = "retry"
    variance_factor: float = 100.0
    min_direct_dof: int = 0
    multi_epoch: str = "cusum"
    multi_epoch_k: float = 1.5
    multi_epoch_h: float = 5.0
    multi_epoch_rounds: int = 3
    multi_epoch_min_dof: int = 1

    def validated(self) -> "NlosConfig":
        """Self, after checking every value; raises :class:`ConfigError` naming the key."""
        for name, allowed in (("detector", NLOS_DETECTORS), ("failed_epochs", NLOS_FAILED_EPOCHS),
                              ("cn0_delay_source", NLOS_DELAY_SOURCES), ("multi_epoch", NLOS_MULTI_EPOCH)):
            if getattr(self, name) not in allowed:
                raise ConfigError(f"nlos.{name}: expected one of {', '.join(allowed)}; received {getattr(self, name)!r}")
        if not 0.5 <= self.template_quantile < 1.0:
            raise ConfigError(f"nlos.template_quantile: expected 0.5 <= value < 1; received {self.template_quantile}")
        if not 0.0 < self.template_bin_deg <= 90.0:
            raise ConfigError(f"nlos.template_bin_deg: expected 0 < value <= 90 (deg); received {self.template_bin_deg}")
        for name in ("template_min_count", "cn0_min_epochs"):
            if getattr(self, name) < 1:
                raise ConfigError(f"nlos.{name}: expected >= 1; received {getattr(self, name)}")
        if not 0.0 <= self.cn0_exit_db <= self.cn0_enter_db < float("inf"):
            raise ConfigError(f"nlos.cn0_exit_db, cn0_enter_db: expected 0 <= exit <= enter (dB); received "
                              f"{self.cn0_exit_db}, {self.cn0_enter_db}")
        if not 0.0 < self.cn0_enter_db:
            raise ConfigError(f"nlos.cn0_enter_db: expected > 0 (dB); received {self.cn0_enter_db}")
        if not 0.0 < self.residual_k < float("inf"):
            raise ConfigError(f"nlos.residual_k: expected a positive number (sigmas); received {self.residual_k}")
        if not self.residual_h > 0.0:
            raise ConfigError(f"nlos.residual_h: expected > 0 (sigmas; inf: no residual test); received {self.residual_h}")
        if not 1.0 <= self.variance_factor < float("inf"):
            raise ConfigError(f"nlos.variance_factor: expected a finite value >= 1 (1: full weight); "
                              f"received {self.variance_factor}")
        if self.cn0_min_delay_m != self.cn0_min_delay_m:
            raise ConfigError("nlos.cn0_min_delay_m: expected a number (m; -inf: no delay test); received nan")
        if not 0.0 <= self.cn0_delay_sigmas < float("inf"):
            raise ConfigError(f"nlos.cn0_delay_sigmas: expected a finite number >= 0 (sigmas); "
                              f"received {self.cn0_delay_sigmas}")
        if not 0.0 <= self.multi_epoch_k < float("inf"):
            raise ConfigError(f"nlos.multi_epoch_k: expected a number >= 0 (sigmas); received {self.multi_epoch_k}")
        if not 0.0 < self.multi_epoch_h < float("inf"):
            raise ConfigError(f"nlos.multi_epoch_h: expected a positive number (sigmas); received {self.multi_epoch_h}")
        if self.multi_epoch_rounds < 1:
            raise ConfigError(f"nlos.multi_epoch_rounds: expected >= 1; received {self.multi_epoch_rounds}")
        for name in ("min_dof", "multi_epoch_min_dof"):
            if getattr(self, name) < 1:
                raise ConfigError(f"nlos.{name}: expected >= 1 (an epoch keeps a test); received {getattr(self, name)}")
        if self.min_direct_dof < 0:
            raise ConfigError(f"nlos.min_direct_dof: expected >= 0 (0: off); received {self.min_direct_dof}")
        return self


@dataclass(frozen=True)
class UrbanConfig:
    """What the urban environment sets (``[urban]`` in ``gnss_cli/configs/default.toml``; a run
    takes it with ``environment = "urban"``, or ``"auto"`` on a file judged a street canyon:
    :mod:`gnss_cli.pipeline.environment`). Each key stands for the key of the same name in
    ``[processing]``, or, after ``nlos_``, in ``[nlos]``."""

    max_simultaneous_faults: int = 3
    prior_fault_satellite: float = 1e-2
    nlos_detector: str = "arcs"
    nlos_min_direct_dof: int = 1

    def validated(self) -> "UrbanConfig":
        if not 1 <= self.max_simultaneous_faults <= 3:
            raise ConfigError(f"urban.max_simultaneous_faults: expected 1, 2 or 3; received {self.max_simultaneous_faults}")
        if not 0.0 < self.prior_fault_satellite < 1.0:
            raise ConfigError(f"urban.prior_fault_satellite: expected 0 < value < 1; received {self.prior_fault_satellite}")
        if self.nlos_detector not in NLOS_DETECTORS:
            raise ConfigError(f"urban.nlos_detector: expected one of {', '.join(NLOS_DETECTORS)}; received {self.nlos_detector!r}")
        if self.nlos_min_direct_dof < 0:
            raise ConfigError(f"urban.nlos_min_direct_dof: expected >= 0 (0: off); received {self.nlos_min_direct_dof}")
        return self
