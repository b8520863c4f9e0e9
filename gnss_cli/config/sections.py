"""The sections of the processing configuration: pseudorange weights, behavioral smoothing,
Kalman filter (``[weights]``, ``[smoothing]``, ``[kalman]`` of ``gnss_cli/configs/default.toml``).

Re-exported by :mod:`gnss_cli.config`.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

from gnss_cli.errors import ConfigError

__all__ = [
    "WeightConfig", "SmoothingConfig", "KalmanConfig", "SMOOTHING_MODELS", "SMOOTHING_KERNELS",
    "FIXED_MODEL_LAGS", "KALMAN_MODELS", "SMOOTHERS",
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


SMOOTHING_MODELS = ("auto", "doppler", "identify", "pva", "static", "kinematic")
SMOOTHING_KERNELS = ("shared", "full")
FIXED_MODEL_LAGS = {"static": 1, "pva": 3, "kinematic": 1}
"""Lags of the fixed kernels ``(z-1) I`` and ``(z-1)^3 I`` (they ignore ``lag``)."""
IDENTIFY_WINDOW = 15
"""The window (epochs) of ``window = "auto"`` for the pva and identified kernels (measured on the
simulated flights; see ``gnss_cli/configs/default.toml``)."""


@dataclass(frozen=True)
class SmoothingConfig:
    """Behavioral multi-epoch smoothing of the stls rows (``[smoothing]`` in ``gnss_cli/configs/default.toml``).

    ``lag = 0``: no smoothing (the stls rows are single-epoch STLS). ``order = 0``: the
    default order ``3 lag`` of a full identified kernel. ``model = "auto"``: ``"doppler"`` when the
    observation file has Doppler (and ``[kalman] doppler``) and no full kernel is asked for, else ``"identify"``
    (:meth:`resolved`). The defaults equal the packaged TOML.
    """

    lag: int = 0
    model: str = "auto"
    kernel: str = "shared"
    order: int = 0
    window: int | str = "auto"
    window_pfa: float = 1e-3
    tolerance: float = 1e-6
    max_iterations: int = 200
    carrier_phase: bool = True
    phase_sigma_m: float = 0.02
    phase_slip_m: float = 1.0

    def resolved(self, has_doppler: bool) -> "SmoothingConfig":
        """Self with ``model = "auto"`` replaced by ``"doppler"`` (range rates available, and no full
        kernel asked for) or ``"identify"``."""
        if self.model != "auto":
            return self
        identify = not has_doppler or self.kernel == "full" or self.order > 0
        return replace(self, model="identify" if identify else "doppler")

    @property
    def effective_lag(self) -> int:
        """The kernel's lag: ``lag`` for an identified kernel, 1 (static) or 3 (pva) for the fixed ones."""
        return FIXED_MODEL_LAGS.get(self.model, self.lag)

    @property
    def structure(self) -> str:
        """Kernel structure of the fits: ``kernel`` when identified; the fixed kernels are shared."""
        return self.kernel if self.model in ("identify", "auto") else "shared"

    @property
    def full_order(self) -> int | None:
        """Order of a full identified kernel (``order``, or ``3 lag`` for 0); None for the other models."""
        if self.model not in ("identify", "auto") or self.kernel != "full":
            return None
        return self.order if self.order > 0 else 3 * self.effective_lag

    @property
    def window_ladder(self) -> bool:
        """Whether the windows are chosen from the data (``window = "auto"`` with the static kernel):
        the longest window around each epoch whose misfit passes the chi-square test
        (:func:`gnss_cli.pipeline.smoothing.ladder_schedule`). A static model that passes is
        exact (only motion makes it wrong, and motion is what the test sees); for ``pva`` and
        identified kernels the error of a longer window is an approximation error that the test
        lets through while it is below the noise (Yamatogawa walk, pva: 4.14 m with the ladder,
        2.99 m in 15-epoch windows), so they keep :data:`IDENTIFY_WINDOW`."""
        return self.window == "auto" and self.model == "static"

    @property
    def window_epochs(self) -> int:
        """The window length (epochs; 0 = whole segments) of a fixed schedule: ``window``, or
        :data:`IDENTIFY_WINDOW` for ``"auto"`` (the static model's ladder does not use it)."""
        return IDENTIFY_WINDOW if self.window == "auto" else int(self.window)

    def min_window(self) -> int:
        """Shortest window (epochs) the model can be fitted on: static 3, pva 5 (the lag + 2 samples a window needs), shared
        ``2 lag + 2``, full ``3 (lag + 1) + 1``."""
        lag = self.effective_lag
        need = {"static": 3, "pva": 5, "kinematic": 2, "doppler": 2}.get(self.model)
        if need is None:
            need = 2 * lag + 2 if self.kernel == "shared" else 3 * (lag + 1) + 1
        return max(need, 2)

    def validated(self) -> "SmoothingConfig":
        """Self, after checking every value; raises :class:`ConfigError` naming the option."""
        for name in ("lag", "order", "window", "max_iterations"):
            value = getattr(self, name)
            if name == "window" and value == "auto":
                continue
            if isinstance(value, bool) or not isinstance(value, int) or value < (1 if name == "max_iterations" else 0):
                low = 1 if name == "max_iterations" else 0
                what = "an integer >= 0 or 'auto'" if name == "window" else f"an integer >= {low}"
                raise ConfigError(f"smoothing.{name}: expected {what}; received {value!r}")
        if self.model not in SMOOTHING_MODELS:
            raise ConfigError(f"smoothing.model: expected one of {', '.join(SMOOTHING_MODELS)}; received {self.model!r}")
        if self.kernel not in SMOOTHING_KERNELS:
            raise ConfigError(f"smoothing.kernel: expected one of {', '.join(SMOOTHING_KERNELS)}; received {self.kernel!r}")
        if not self.tolerance > 0:
            raise ConfigError(f"smoothing.tolerance: expected > 0; received {self.tolerance}")
        if isinstance(self.window_pfa, bool) or not isinstance(self.window_pfa, (int, float)) \
                or not 0 < self.window_pfa < 0.5:
            raise ConfigError(f"smoothing.window_pfa: expected a probability in (0, 0.5); received {self.window_pfa!r}")
        if not isinstance(self.carrier_phase, bool):
            raise ConfigError(f"smoothing.carrier_phase: expected true or false; received {self.carrier_phase!r}")
        for name in ("phase_sigma_m", "phase_slip_m"):
            value = getattr(self, name)
            if not value > 0:  # also NaN
                raise ConfigError(f"smoothing.{name}: expected > 0; received {value!r}")
        if self.model == "auto" and self.lag > 0:  # without Doppler it is "identify": check that
            replace(self, model="identify").validated()
            return self
        if self.lag == 0:
            if self.model not in ("identify", "auto") or self.order:
                what = f"model = {self.model!r}" if self.model != "identify" else f"order = {self.order}"
                raise ConfigError(f"smoothing.{what} needs smoothing.lag >= 1 (lag 0 = no smoothing)")
            return self
        need = self.min_window()
        if self.window != "auto" and 0 < self.window < need:
            raise ConfigError(f"smoothing.window: expected 0, 'auto' or >= {need} epochs for model {self.model} "
                              f"(lag {self.effective_lag}, kernel {self.structure}); received {self.window}")
        order = self.full_order
        if order is None and self.order:
            raise ConfigError(f"smoothing.order: applies to model = 'identify' with kernel = 'full' only; "
                              f"received order = {self.order} with model = {self.model!r}, kernel = {self.kernel!r}")
        if order is not None:
            self._check_full_order(order)
        return self

    def _check_full_order(self, order: int) -> None:
        """A full ``3 x 3(l+1)`` kernel of order ``n`` has ``g = 3(l+1) - n`` rows, 1 <= g, and
        ``g (N - l) <= 3 N`` over a window of ``N`` epochs (else ``G Sigma G^T`` is singular)."""
        lag = self.effective_lag
        if not 0 < order < 3 * (lag + 1):
            raise ConfigError(f"smoothing.order: expected 1 <= order < 3 (lag + 1) = {3 * (lag + 1)} for lag {lag}; received {order}")
        g = 3 * (lag + 1) - order
        n = self.window_epochs
        if g > 3 and (n == 0 or g * (n - lag) > 3 * n):
            span = "whole segments (window = 0)" if n == 0 else f"windows of {n} epochs"
            raise ConfigError(f"smoothing.order: order {order} with lag {lag} leaves {g} kernel rows, infeasible on {span}; "
                              f"use order >= {3 * lag} or a shorter window")


KALMAN_MODELS = ("cv", "ca")
SMOOTHERS = ("rts", "none")


@dataclass(frozen=True)
class KalmanConfig:
    """The ``kf`` method (``[kalman]`` in ``gnss_cli/configs/default.toml``, which explains each value)."""

    model: str = "cv"
    smoother: str = "rts"
    accel_psd_m2_s3: float = 10.0
    jerk_psd_m2_s5: float = 10.0
    clock_psd_m2_s: float = 0.01
    drift_psd_m2_s3: float = 0.04
    initial_velocity_sigma_m_s: float = 100.0
    initial_drift_sigma_m_s: float = 1000.0
    doppler: bool = True
    gap_s: float = 60.0
    clock_reset_m: float = 1000.0
    innovation_gate: float = 3.29

    def validated(self) -> "KalmanConfig":
        """Self, after checking every value; raises :class:`ConfigError` naming the key."""
        for name, allowed in (("model", KALMAN_MODELS), ("smoother", SMOOTHERS)):
            if getattr(self, name) not in allowed:
                raise ConfigError(f"kalman.{name}: expected one of {', '.join(allowed)}; received {getattr(self, name)!r}")
        for name in ("accel_psd_m2_s3", "jerk_psd_m2_s5", "clock_psd_m2_s", "drift_psd_m2_s3", "initial_velocity_sigma_m_s",
                     "initial_drift_sigma_m_s", "gap_s", "clock_reset_m"):
            if not getattr(self, name) > 0:
                raise ConfigError(f"kalman.{name}: expected > 0; received {getattr(self, name)}")
        if not self.innovation_gate >= 0:
            raise ConfigError(f"kalman.innovation_gate: expected >= 0 (0 = off); received {self.innovation_gate}")
        return self
