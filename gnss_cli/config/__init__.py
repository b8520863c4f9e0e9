"""Processing configuration: defaults from ``gnss_cli/configs/default.toml``, a user TOML, and flags.

Precedence: command-line flags > ``--config FILE`` > the packaged defaults.

Modules, one job each::

    sections  The sections of the processing configuration: pseudorange weights and the multi-epoch...
    toml      The effective configuration as TOML (gnss-solve --print-config).
"""

from __future__ import annotations

import sys
from collections.abc import Mapping
from dataclasses import dataclass, field, fields, replace
from importlib.resources import files
from pathlib import Path
from typing import TYPE_CHECKING, Any

from gnss_cli.config.sections import (
    CN0_MODELS,
    KALMAN_MODELS,
    KALMAN_OUTPUTS,
    MEASUREMENT_KINDS,
    NLOS_DETECTORS,
    SMOOTHER_MOTIONS,
    STLS_KERNELS,
    KalmanConfig,
    NlosConfig,
    SmootherConfig,
    StlsConfig,
    UrbanConfig,
    WeightConfig,
)
from gnss_cli.constants import METHOD_KEYS, MULTI_EPOCH_METHOD_KEYS

ALL_METHOD_KEYS = METHOD_KEYS + MULTI_EPOCH_METHOD_KEYS
from gnss_cli.errors import ConfigError, InputError, InputFileNotFoundError

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib
if TYPE_CHECKING:
    from importlib.resources.abc import Traversable

__all__ = [
    "ProcessingConfig", "WeightConfig", "StlsConfig", "SmootherConfig", "KalmanConfig", "NlosConfig", "UrbanConfig",
    "load_config",
    "packaged_defaults", "parse_methods", "parse_systems", "parse_satellites", "parse_measurements", "ALL_METHOD_KEYS",
    "parse_alert_limits",
    "IONO_OPTIONS", "TIME_SYSTEMS", "INTEGRITY_OPTIONS", "ENVIRONMENTS", "ROBUST_OPTIONS", "SYSTEM_LETTERS", "DEFAULT_CONFIG_PATH",
    "STLS_KERNELS", "SMOOTHER_MOTIONS", "MEASUREMENT_KINDS", "KALMAN_MODELS", "KALMAN_OUTPUTS", "NLOS_DETECTORS", "RENAMED",
]

IONO_OPTIONS = ("klobuchar", "iono-free", "none")
TIME_SYSTEMS = ("gpst", "utc")
"""Time scale of the output time stamps (``--time-system``)."""
INTEGRITY_OPTIONS = ("fde", "check", "off")
ENVIRONMENTS = ("auto", "open", "urban")
"""``[processing] environment``: judged from the file, open sky, or street canyon."""
ROBUST_OPTIONS = ("off", "huber", "cauchy")
"""``robust``: plain ls/wls, or an M-estimator by IRLS (:mod:`gnss_cli.solvers.robust`)."""
SYSTEM_LETTERS = ("G", "E", "C", "J", "R")
"""GPS, Galileo, BeiDou, QZSS, GLONASS (RINEX letters)."""
DEFAULT_CONFIG_PATH = files("gnss_cli") / "configs" / "default.toml"
"""The packaged defaults (package data, so a non-editable install has them too)."""


@dataclass(frozen=True)
class ProcessingConfig:
    """Every processing option, with units in the names."""

    methods: tuple[str, ...] = ("wls",)
    systems: tuple[str, ...] = ()
    """Constellations in clock-column order; empty = every system of :data:`SYSTEM_LETTERS`
    observed in the observation file and present in the navigation files."""
    elevation_mask_deg: float = 10.0
    iono: str = "klobuchar"
    tropo: str = "saastamoinen"
    max_iterations: int = 10
    convergence_m: float = 1e-4
    min_satellites: int = 4
    healthy_only: bool = True
    qzss_own_clock: bool = False
    """QZSS gets a receiver clock of its own; by default its satellites share GPS's (see default.toml)."""
    weights: WeightConfig = field(default_factory=WeightConfig)
    signals: Mapping[str, tuple[str, ...]] = field(default_factory=dict)
    signals_second: Mapping[str, tuple[str, ...]] = field(default_factory=dict)
    """Second-frequency code priority per system, for ``iono = "iono-free"``."""
    orbit_sigma_m: float = 1.7
    wtls_column_scaling: str = "orbit"
    stls: StlsConfig = field(default_factory=StlsConfig)
    smoother: SmootherConfig = field(default_factory=SmootherConfig)
    measurements: tuple[str, ...] = ()
    """What the multi-epoch methods use, some of :data:`MEASUREMENT_KINDS`; empty = every kind
    the observation file has (see default.toml)."""
    time_system: str = "gpst"
    """Time scale of the output time stamps: ``gpst`` or ``utc`` (GPST - leap seconds)."""
    integrity: str = "fde"
    """``fde`` (test, exclude, re-solve), ``check`` (test only) or ``off`` (see default.toml)."""
    environment: str = "auto"
    """``auto``, ``open`` or ``urban``: the street-canyon settings (:attr:`urban`, the ``[urban]``
    table) never, always, or when the file's WLS
    variance factor exceeds ``urban_variance_factor`` (:mod:`gnss_cli.pipeline.environment`)."""
    urban_variance_factor: float = 0.6
    """The median WLS variance factor (chi-square over degrees of freedom, dimensionless) above
    which ``auto`` takes a file for a street canyon (see default.toml)."""
    environment_judgement: str = ""
    """Set by a run, not a key: what judged ``auto`` (``auto: variance factor 1.62 > 0.6``; empty: given)."""
    integrity_pfa: float = 1e-3
    max_gdop: float = 30.0
    alert_limit_h_m: float = float("inf")
    """An ``ok`` epoch whose HPL exceeds this (m) gets ``hpl_limit``; inf: no limit (see default.toml)."""
    alert_limit_v_m: float = float("inf")
    """An ``ok`` epoch whose VPL exceeds this (m) gets ``vpl_limit``; inf: no limit (see default.toml)."""
    integrity_risk: float = 1e-3
    """Probability per epoch that the error exceeds a protection level (solution separation)."""
    prior_fault_satellite: float = 1e-3
    """Prior probability per epoch that one satellite's pseudorange is faulty."""
    prior_fault_constellation: float = 1e-4
    """Prior probability per epoch that a whole constellation is faulty."""
    max_simultaneous_faults: int = 1
    """Largest number of simultaneously faulty satellites the protection levels monitor (see default.toml)."""
    nominal_bias_cn0_sigmas: float = 4.0
    """Nominal bias bound of each pseudorange in the protection levels, in units of the C/N0 part
    of its sigma (SIGMA-epsilon term; 0: none; see default.toml)."""
    max_exclusions: int = 4
    max_segment_misfit: float = 5.0
    """Misfit per degree of freedom above which a smoother or kf segment is solved again in halves
    (``inf``: no test; :mod:`gnss_cli.pipeline.segment_misfit`, see default.toml)."""
    fde_min_dof: int = 3
    """Degrees of freedom an epoch needs before FDE may exclude a satellite (see default.toml)."""
    exclude: tuple[str, ...] = ()
    """Satellite ids never used (``G07``)."""
    snr_mask_dbhz: float = 0.0
    robust: str = "off"
    """``off``, ``huber`` or ``cauchy``: M-estimation of the ls/wls fixes (see default.toml)."""
    robust_huber_k: float = 1.345
    robust_cauchy_c: float = 2.385
    robust_tolerance: float = 1e-8
    robust_max_iterations: int = 1000
    doppler_sigma_m_s: float = 0.1
    """Range-rate sigma (m/s, ``-lambda D``) of a typical satellite of the epoch (see default.toml)."""
    phase_sigma_m: float = 0.02
    """Sigma (m) of a typical satellite's time-differenced carrier phase (see default.toml)."""
    phase_slip_m: float = 1.0
    """A phase difference further than this (m) from the range rates' trapezoid is a slip (see default.toml)."""
    kalman: KalmanConfig = field(default_factory=lambda: KalmanConfig())
    nlos: NlosConfig = field(default_factory=NlosConfig)
    """The NLOS detector of the ls/wls fixes (``[nlos]``, :mod:`gnss_cli.pipeline.nlos`)."""
    urban: UrbanConfig = field(default_factory=UrbanConfig)
    """What the urban environment sets (``[urban]``; :mod:`gnss_cli.pipeline.environment`)."""
    chunk_epochs: int = 1200
    """Epochs per part of a long observation file (``gnss-solve``'s streamed run, see default.toml); 0 = whole file."""
    stream_above_epochs: int = 3600
    """Files of more epochs than this (and than ``chunk_epochs``) are solved in parts (see default.toml)."""
    processes: int = 0
    """Processes that solve the halves of a file at once (``gnss-solve --processes``, see default.toml); 0 = one per core."""

    def validated(self) -> "ProcessingConfig":
        """Self, after checking every value; raises :class:`ConfigError` naming the option."""
        from gnss_cli.gnss.signals import IONO_FREE_SIGNALS, signal_of  # numpy: not needed for --help

        bad = [m for m in self.methods if m not in ALL_METHOD_KEYS]
        if bad or not self.methods:
            raise ConfigError(f"methods: expected some of {', '.join(ALL_METHOD_KEYS)} or 'all'; received {list(self.methods)}")
        if self.iono not in IONO_OPTIONS:
            raise ConfigError(f"iono: expected one of {', '.join(IONO_OPTIONS)}; received {self.iono!r}")
        if self.tropo not in ("saastamoinen", "none"):
            raise ConfigError(f"tropo: expected 'saastamoinen' or 'none'; received {self.tropo!r}")
        if not isinstance(self.qzss_own_clock, bool):
            raise ConfigError(f"qzss_own_clock: expected true or false; received {self.qzss_own_clock!r}")
        if not 0.0 <= self.elevation_mask_deg < 90.0:
            raise ConfigError(f"elevation_mask_deg: expected 0 <= value < 90; received {self.elevation_mask_deg}")
        for key in ("chunk_epochs", "stream_above_epochs", "processes"):
            value = getattr(self, key)
            if isinstance(value, bool) or not isinstance(value, int) or value < 0:
                what = {"chunk_epochs": " (0: the whole file at once)", "processes": " (0: one per core)"}.get(key, "")
                raise ConfigError(f"{key}: expected an integer >= 0{what}; received {value!r}")
        if self.max_iterations < 1:
            raise ConfigError(f"max_iterations: expected >= 1; received {self.max_iterations}")
        if not self.convergence_m > 0:
            raise ConfigError(f"convergence_m: expected > 0; received {self.convergence_m}")
        if self.min_satellites < 4:
            raise ConfigError(f"min_satellites: expected >= 4; received {self.min_satellites}")
        if self.weights.model not in ("rtklib", "elevation", "equal"):
            raise ConfigError(f"weights.model: expected 'rtklib', 'elevation' or 'equal'; received {self.weights.model!r}")
        if self.weights.cn0_model not in CN0_MODELS:
            raise ConfigError(f"weights.cn0_model: expected 'off' or 'sigma-epsilon'; received {self.weights.cn0_model!r}")
        if not self.weights.cn0_c_m2hz >= 0:
            raise ConfigError(f"weights.cn0_c_m2hz: expected >= 0 (m^2 Hz); received {self.weights.cn0_c_m2hz}")
        unsupported = [s for s in self.systems if s not in SYSTEM_LETTERS]
        if unsupported or len(set(self.systems)) != len(self.systems):
            raise ConfigError(
                f"systems: expected 'all' or distinct letters of {', '.join(SYSTEM_LETTERS)}; received {list(self.systems)}"
            )
        if not self.weights.iono_free_factor >= 1.0:
            raise ConfigError(f"weights.iono_free_factor: expected >= 1; received {self.weights.iono_free_factor}")
        for system, codes in self.signals_second.items():
            if system not in SYSTEM_LETTERS:
                raise ConfigError(f"signals.second: unknown system {system!r}; expected {', '.join(SYSTEM_LETTERS)}")
            bad_codes = [c for c in codes if signal_of(system, c) not in IONO_FREE_SIGNALS[system]]
            if bad_codes:
                raise ConfigError(
                    f"signals.second.{system}: codes {bad_codes} are not on a signal with a broadcast group delay; "
                    f"expected codes of {', '.join(IONO_FREE_SIGNALS[system])}"
                )
        if self.orbit_sigma_m < 0:
            raise ConfigError(f"orbit_sigma_m: expected >= 0; received {self.orbit_sigma_m}")
        if self.wtls_column_scaling not in ("orbit", "none"):
            raise ConfigError(f"wtls.column_scaling: expected 'orbit' or 'none'; received {self.wtls_column_scaling!r}")
        if "wtls" in self.methods and self.wtls_column_scaling == "orbit" and not self.orbit_sigma_m > 0:
            raise ConfigError("wtls.column_scaling = 'orbit' needs stls.orbit_sigma_m > 0 (the geometry-column error it scales by)")
        if self.time_system not in TIME_SYSTEMS:
            raise ConfigError(f"time_system: expected one of {', '.join(TIME_SYSTEMS)}; received {self.time_system!r}")
        self.stls.validated()
        if "smoother" in self.methods:  # --lag sets stls.lag too, which may exceed the quadrature's 3
            self.smoother.validated()
        self._validate_measurements()
        self._validate_integrity()
        return self

    @property
    def multi_epoch_methods(self) -> tuple[str, ...]:
        """The methods of :attr:`methods` that solve several epochs at once: ``stls`` with
        ``stls.lag >= 1`` (the identified Hankel STLS), ``smoother`` and ``kf``."""
        return tuple(m for m in self.methods if m in MULTI_EPOCH_METHOD_KEYS or (m == "stls" and self.stls.lag > 0))

    def uses(self, kind: str, present: bool = True) -> bool:
        """Whether the multi-epoch methods use the measurements ``kind`` (of
        :data:`MEASUREMENT_KINDS`), given whether the observation file has them (``present``)."""
        return present and (not self.measurements or kind in self.measurements)

    def _validate_measurements(self) -> None:
        bad = [k for k in self.measurements if k not in MEASUREMENT_KINDS]
        if bad or len(set(self.measurements)) != len(self.measurements):
            raise ConfigError(f"measurements: expected 'all' or distinct kinds of {', '.join(MEASUREMENT_KINDS)}; "
                              f"received {list(self.measurements)}")
        if self.measurements and "pseudorange" not in self.measurements:
            raise ConfigError(f"measurements: the pseudoranges are always used (they fix the position); "
                              f"received {','.join(self.measurements)}: add pseudorange")
        for name in ("doppler_sigma_m_s", "phase_sigma_m", "phase_slip_m"):
            if not getattr(self, name) > 0:  # also NaN
                raise ConfigError(f"{name}: expected > 0; received {getattr(self, name)!r}")

    def _validate_integrity(self) -> None:
        if self.integrity not in INTEGRITY_OPTIONS:
            raise ConfigError(f"integrity: expected one of {', '.join(INTEGRITY_OPTIONS)}; received {self.integrity!r}")
        for name in ("integrity_pfa",):
            if not 0.0 < getattr(self, name) < 0.5:
                raise ConfigError(f"{name}: expected 0 < value < 0.5; received {getattr(self, name)}")
        if self.environment not in ENVIRONMENTS:
            raise ConfigError(f"environment: expected one of {', '.join(ENVIRONMENTS)}; received {self.environment!r}")
        if not 0.0 < self.urban_variance_factor < float("inf"):
            raise ConfigError(f"urban_variance_factor: expected a finite value > 0; received {self.urban_variance_factor}")
        if self.max_exclusions < 0:
            raise ConfigError(f"max_exclusions: expected >= 0; received {self.max_exclusions}")
        if not 1 <= self.max_simultaneous_faults <= 3:
            raise ConfigError(f"max_simultaneous_faults: expected 1, 2 or 3; received {self.max_simultaneous_faults}")
        if self.fde_min_dof < 2:
            raise ConfigError(f"fde_min_dof: expected >= 2 (one degree of freedom must remain to test the rest); "
                              f"received {self.fde_min_dof}")
        if not self.max_gdop > 0:
            raise ConfigError(f"max_gdop: expected > 0; received {self.max_gdop}")
        if not self.max_segment_misfit > 0:
            raise ConfigError(f"max_segment_misfit: expected > 0 (inf: no test); received {self.max_segment_misfit}")
        for name in ("alert_limit_h_m", "alert_limit_v_m"):
            if not getattr(self, name) > 0:
                raise ConfigError(f"{name}: expected > 0 (inf: no limit); received {getattr(self, name)}")
        for name in ("integrity_risk", "prior_fault_satellite", "prior_fault_constellation"):
            if not 0.0 < getattr(self, name) < 1.0:
                raise ConfigError(f"{name}: expected 0 < value < 1; received {getattr(self, name)}")
        if not 0.0 <= self.nominal_bias_cn0_sigmas < float("inf"):
            raise ConfigError(f"nominal_bias_cn0_sigmas: expected a finite value >= 0; received {self.nominal_bias_cn0_sigmas}")
        bad = [s for s in self.exclude if len(s) != 3 or s[0] not in SYSTEM_LETTERS or not s[1:].isdigit()]
        if bad:
            raise ConfigError(f"exclude: expected satellite ids like G07, C28; received {bad}")
        self.kalman.validated()
        self.nlos.validated()
        self.urban.validated()
        if not 0.0 <= self.snr_mask_dbhz < 100.0:
            raise ConfigError(f"snr_mask_dbhz: expected 0 <= value < 100 (0 = no mask); received {self.snr_mask_dbhz}")
        if self.robust not in ROBUST_OPTIONS:
            raise ConfigError(f"robust: expected one of {', '.join(ROBUST_OPTIONS)}; received {self.robust!r}")
        for name in ("robust_huber_k", "robust_cauchy_c", "robust_tolerance"):
            if not 0.0 < getattr(self, name) < float("inf"):
                raise ConfigError(f"{name}: expected a positive number; received {getattr(self, name)}")
        if self.robust_max_iterations < 1:
            raise ConfigError(f"robust_max_iterations: expected >= 1; received {self.robust_max_iterations}")


def parse_methods(text: str | list[str] | tuple[str, ...]) -> tuple[str, ...]:
    """``"ls,wls"`` / ``"all"`` / a list -> a tuple of method keys (order kept, no duplicates)."""
    items = text.split(",") if isinstance(text, str) else list(text)
    out: list[str] = []
    for item in (i.strip().lower() for i in items):
        if not item:
            continue
        for m in METHOD_KEYS if item == "all" else (item,):
            if m not in ALL_METHOD_KEYS:
                raise ConfigError(f"--method: unknown method {item!r}; expected {', '.join(ALL_METHOD_KEYS)} or all"
                                  f" (all = the single-epoch family {' '.join(METHOD_KEYS)})")
            if m not in out:
                out.append(m)
    if not out:
        raise ConfigError("--method: no method given")
    return tuple(out)


def parse_systems(value: str | list[str] | tuple[str, ...]) -> tuple[str, ...]:
    """``"G,E"`` / ``["G", "E"]`` -> ``("G", "E")``; ``"all"`` -> ``()`` (every system with data)."""
    items = value.split(",") if isinstance(value, str) else [str(v) for v in value]
    letters = tuple(i.strip().upper() for i in items if i.strip())
    if letters == ("ALL",):
        return ()
    if not letters:
        raise ConfigError(f"systems: expected 'all' or letters of {', '.join(SYSTEM_LETTERS)}; received {value!r}")
    return letters


def parse_satellites(value: str | list[str] | tuple[str, ...]) -> tuple[str, ...]:
    """``"G07,C28"`` / ``["G7"]`` -> ``("G07", "C28")`` (upper case, two-digit numbers)."""
    items = value.split(",") if isinstance(value, str) else [str(v) for v in value]
    out = []
    for item in (i.strip().upper() for i in items):
        if item:
            out.append(f"{item[0]}{int(item[1:]):02d}" if item[1:].isdigit() else item)
    return tuple(out)


def parse_alert_limits(value: str) -> tuple[float, float]:
    """``"H,V"`` (m; ``inf`` for none) -> ``(alert_limit_h_m, alert_limit_v_m)``.

    >>> parse_alert_limits("40, inf")
    (40.0, inf)
    """
    parts = [p.strip() for p in str(value).split(",")]
    try:
        if len(parts) != 2:
            raise ValueError
        h, v = float(parts[0]), float(parts[1])
    except ValueError:
        raise ConfigError(f"alert limits: expected H,V in metres (inf: no limit), e.g. 40,60; received {value!r}") from None
    return h, v


RENAMED = {
    "integrity_pmd": "integrity_pmd is gone with the slope-based protection levels: the solution-separation "
                     "levels take integrity_risk, prior_fault_satellite and prior_fault_constellation",
    "[smoothing]": "the section [smoothing] is gone: lag, kernel, order, window, tolerance, max_iterations are "
                   "[stls] keys (the identified Hankel STLS, methods = ['stls'] with stls.lag >= 1); model = 'doppler' "
                   "is methods = ['smoother'] with [smoother] motion and lag; carrier_phase is [processing] "
                   "measurements; phase_sigma_m and phase_slip_m are [processing] keys",
    "kalman.doppler": "kalman.doppler is gone: [processing] measurements = ['pseudorange', 'doppler', 'phase'] "
                      "(or 'all') gives every multi-epoch method the same measurements",
    "kalman.smoother": "kalman.smoother is now kalman.output = 'smoothed' (rts) or 'filtered' (none)",
}
"""Old configuration spellings -> the message that names the new one."""


def parse_measurements(value: str | list[str] | tuple[str, ...]) -> tuple[str, ...]:
    """``"pseudorange,doppler"`` / a list -> a tuple of kinds; ``"all"`` -> ``()`` (every kind in the file).

    >>> parse_measurements("pseudorange, doppler"), parse_measurements("all")
    (('pseudorange', 'doppler'), ())
    """
    items = value.split(",") if isinstance(value, str) else [str(v) for v in value]
    kinds = tuple(i.strip().lower() for i in items if i.strip())
    if kinds == ("all",):
        return ()
    if not kinds:
        raise ConfigError(f"measurements: expected 'all' or some of {', '.join(MEASUREMENT_KINDS)}; received {value!r}")
    return kinds


def _read_toml(path: Path | Traversable) -> dict[str, Any]:
    try:
        with path.open("rb") as f:
            return tomllib.load(f)
    except FileNotFoundError:
        raise InputFileNotFoundError(f"{path}: configuration file not found") from None
    except OSError as exc:
        raise InputError(f"{path}: cannot read configuration file ({exc.strerror or exc})") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: invalid TOML ({exc})") from None


_SECTIONS = ("processing", "weights", "signals", "stls", "wtls", "smoother", "kalman", "nlos", "urban")
_OWN_TABLES = {"weights", "signals", "signals_second", "orbit_sigma_m", "wtls_column_scaling", "stls", "smoother", "kalman",
               "nlos", "urban", "environment_judgement"}
"""ProcessingConfig fields that are not ``[processing]`` keys."""
_FLOATS = ("elevation_mask_deg", "convergence_m", "integrity_pfa", "max_gdop", "alert_limit_h_m",
           "alert_limit_v_m", "integrity_risk", "prior_fault_satellite", "prior_fault_constellation",
           "nominal_bias_cn0_sigmas", "snr_mask_dbhz", "robust_huber_k", "robust_cauchy_c", "robust_tolerance", "doppler_sigma_m_s",
           "phase_sigma_m", "phase_slip_m", "max_segment_misfit", "urban_variance_factor")
_INTS = ("max_iterations", "min_satellites", "max_exclusions", "fde_min_dof", "max_simultaneous_faults", "robust_max_iterations",
         "chunk_epochs", "stream_above_epochs", "processes")


def _apply(cfg: ProcessingConfig, data: Mapping[str, Any], source: str) -> ProcessingConfig:
    if "smoothing" in data:
        raise ConfigError(f"{source}: {RENAMED['[smoothing]']}")
    unknown = set(data) - set(_SECTIONS)
    if unknown:
        raise ConfigError(f"{source}: unknown section(s) {sorted(unknown)}; expected {sorted(_SECTIONS)}")
    proc = dict(data.get("processing", {}))
    if "integrity_pmd" in proc:
        raise ConfigError(f"{source}: {RENAMED['integrity_pmd']}")
    names = {f.name for f in fields(ProcessingConfig)} - _OWN_TABLES
    bad = set(proc) - names
    if bad:
        hint = "; ".join(f"did you mean {near!r}?" for key in sorted(bad) for near in _closest(key, names))
        raise ConfigError(f"{source}: unknown [processing] key(s) {sorted(bad)}" + (f" ({hint})" if hint else ""))
    try:
        if "methods" in proc:
            proc["methods"] = parse_methods(proc["methods"])
        if "systems" in proc:
            proc["systems"] = parse_systems(proc["systems"])
        if "measurements" in proc:
            proc["measurements"] = parse_measurements(proc["measurements"])
        if "time_system" in proc:
            proc["time_system"] = str(proc["time_system"]).lower()
        if "exclude" in proc:
            proc["exclude"] = parse_satellites(proc["exclude"])
        if "robust" in proc:
            proc["robust"] = str(proc["robust"]).lower()
        if "environment" in proc:
            proc["environment"] = str(proc["environment"]).lower()
        for key in _FLOATS:
            if key in proc:
                proc[key] = float(proc[key])
        for key in _INTS:
            if key in proc:
                proc[key] = int(proc[key])
        cfg = replace(cfg, **proc)
        w = dict(data.get("weights", {}))
        wbad = set(w) - {f.name for f in fields(WeightConfig)}
        if wbad:
            raise ConfigError(f"{source}: unknown [weights] key(s) {sorted(wbad)}")
        cfg = replace(cfg, weights=replace(cfg.weights, **{k: (v if k in ("model", "cn0_model") else float(v)) for k, v in w.items()}))
        if "signals" in data:
            table = dict(data["signals"])
            second = table.pop("second", {})
            if not isinstance(second, Mapping):
                raise ConfigError(f"{source}: [signals] second must be a table of code lists per system")
            sig = dict(cfg.signals)
            sig.update({str(k).upper(): tuple(str(c) for c in v) for k, v in table.items()})
            sig2 = dict(cfg.signals_second)
            sig2.update({str(k).upper(): tuple(str(c) for c in v) for k, v in second.items()})
            cfg = replace(cfg, signals=sig, signals_second=sig2)
        if "stls" in data:
            table = dict(data["stls"])
            if "orbit_sigma_m" in table:
                cfg = replace(cfg, orbit_sigma_m=float(table.pop("orbit_sigma_m")))
            cfg = replace(cfg, stls=_apply_table(cfg.stls, table, "stls", source, text=("kernel",),
                                                 floats=("tolerance", "behavior_pfa", "latency_m")))
        if "wtls" in data:
            tbad = set(data["wtls"]) - {"column_scaling"}
            if tbad:
                raise ConfigError(f"{source}: unknown [wtls] key(s) {sorted(tbad)}")
            cfg = replace(cfg, wtls_column_scaling=str(data["wtls"].get("column_scaling", cfg.wtls_column_scaling)))
        if "smoother" in data:
            cfg = replace(cfg, smoother=_apply_table(cfg.smoother, data["smoother"], "smoother", source, text=("motion",)))
        if "kalman" in data:
            for old in ("doppler", "smoother"):
                if old in data["kalman"]:
                    raise ConfigError(f"{source}: {RENAMED['kalman.' + old]}")
            cfg = replace(cfg, kalman=_apply_table(cfg.kalman, data["kalman"], "kalman", source, text=("model", "output"),
                                                   floats=tuple(f.name for f in fields(KalmanConfig)
                                                                if f.name not in ("model", "output"))))
        if "nlos" in data:
            text = ("detector", "failed_epochs", "multi_epoch", "cn0_delay_source")
            counts = ("template_min_count", "cn0_min_epochs", "min_dof", "min_direct_dof", "multi_epoch_rounds",
                      "multi_epoch_min_dof")
            cfg = replace(cfg, nlos=_apply_table(cfg.nlos, data["nlos"], "nlos", source, text=text,
                                                 floats=tuple(f.name for f in fields(NlosConfig)
                                                              if f.name not in text + counts)))
        if "urban" in data:
            cfg = replace(cfg, urban=_apply_table(cfg.urban, data["urban"], "urban", source, text=("nlos_detector",),
                                                  floats=("prior_fault_satellite",)))
    except (TypeError, ValueError) as exc:
        if isinstance(exc, ConfigError):
            raise
        raise ConfigError(f"{source}: bad value ({exc})") from None
    return cfg


def _closest(key: str, names: set[str]) -> list[str]:
    """The valid key nearest to a mistyped one (at most one), for the error message."""
    import difflib

    return difflib.get_close_matches(key, sorted(names), n=1)


def _apply_table(base: Any, table: Mapping[str, Any], section: str, source: str, *, text: tuple[str, ...] = (),
                 floats: tuple[str, ...] = ()) -> Any:
    """The keys of ``[section]`` onto the dataclass ``base``: strings, numbers and integers
    converted (values are checked by its ``validated``)."""
    names = {f.name for f in fields(base)}
    bad = set(table) - names
    if bad:
        raise ConfigError(f"{source}: unknown [{section}] key(s) {sorted(bad)}; expected some of {sorted(names)}")
    values: dict[str, Any] = {}
    for key, value in table.items():
        if key in text:
            values[key] = str(value).lower()
        elif isinstance(value, bool):
            raise ConfigError(f"{source}: {section}.{key}: expected a number; received {value!r}")
        elif key in floats:
            if not isinstance(value, (int, float)):
                raise ConfigError(f"{source}: {section}.{key}: expected a number; received {value!r}")
            values[key] = float(value)
        elif isinstance(value, float) and not value.is_integer():
            raise ConfigError(f"{source}: {section}.{key}: expected an integer; received {value!r}")
        else:
            values[key] = int(value)
    return replace(base, **values)


def _sections(overrides: Mapping[str, Any]) -> dict[str, dict[str, Any]]:
    """Override keys -> TOML tables: ``"section.key"`` goes to ``[section]``, a plain key to ``[processing]``."""
    tables: dict[str, dict[str, Any]] = {}
    for key, value in overrides.items():
        if value is not None:
            section, _, name = key.rpartition(".")
            tables.setdefault(section or "processing", {})[name] = value
    return tables


def packaged_defaults(name: str = "default.toml") -> dict[str, Any]:
    """A packaged configuration file (``default.toml`` or ``simulate.toml``) as TOML tables;
    no validation, no numpy: cheap enough for ``--help``."""
    return _read_toml(DEFAULT_CONFIG_PATH.parent / name)


def load_config(path: str | Path | None = None, overrides: Mapping[str, Any] | None = None) -> ProcessingConfig:
    """Packaged defaults, then ``path`` (TOML), then ``overrides``, validated.

    ``overrides`` keys are ``[processing]`` keys, or ``"section.key"`` for another table
    (``"stls.lag"``); None values are ignored.
    """
    cfg = ProcessingConfig()
    cfg = _apply(cfg, _read_toml(DEFAULT_CONFIG_PATH), str(DEFAULT_CONFIG_PATH))
    if path is not None:
        cfg = _apply(cfg, _read_toml(Path(path)), str(path))
    if overrides:
        cfg = _apply(cfg, _sections(overrides), "command line")
    return cfg.validated()
