"""The processing options that ``gnss-solve`` and ``gnss-batch`` share, defined once.

Each option is an ``Annotated`` type (Typer reads the ``typer.Option`` inside it), so a
command lists it as ``method: Method = None`` and both commands show the same flag, help
text and packaged default. A flag that sets a configuration key has no default of its own
(None): the ``--config`` file and the packaged ``default.toml`` decide, and ``--help``
shows the packaged value. :data:`CONFIG_KEYS` maps the parameter names to the
configuration keys, :func:`run_config` builds the configuration from a command's
parameters, and :func:`check_reference_options` / :func:`check_smoothing_flags` are the
usage checks both commands make.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Annotated, Any, Optional

import typer

from gnss_cli.config import packaged_defaults
from gnss_cli.errors import UsageError

_DEFAULTS = packaged_defaults()
_PROC = _DEFAULTS.get("processing", {})
_SMOOTH = _DEFAULTS.get("smoothing", {})
_KALMAN = _DEFAULTS.get("kalman", {})


def shown(value: Any) -> str:
    """A packaged default as it is written on the command line.

    >>> shown(["ls", "wls"]), shown(10.0)
    ('ls,wls', '10.0')
    """
    if isinstance(value, (list, tuple)):
        return ",".join(str(v) for v in value)
    return str(value)


Method = Annotated[Optional[str], typer.Option("--method", "-m", help="ls, wls, tls, dls, mtls, stls, wtls, kf (Kalman filter), a comma list, or all (= ls ... wtls).", show_default=shown(_PROC.get("methods")))]
Systems = Annotated[Optional[str], typer.Option("--systems", help="Constellations: comma list of RINEX letters G,E,C,J,R, or all (every system in both OBS and NAV).", show_default=shown(_PROC.get("systems")))]
Iono = Annotated[Optional[str], typer.Option("--iono", help="klobuchar | iono-free (dual-frequency combination) | none.", show_default=shown(_PROC.get("iono")))]
Tropo = Annotated[Optional[str], typer.Option("--tropo", help="saastamoinen | none.", show_default=shown(_PROC.get("tropo")))]
ElevationMask = Annotated[Optional[float], typer.Option("--elevation-mask", help="Elevation mask, degrees.", show_default=shown(_PROC.get("elevation_mask_deg")))]
Reference = Annotated[Optional[str], typer.Option("--reference", help="Reference position X,Y,Z (ECEF, m) for error columns.", show_default="none")]
ReferenceSinex = Annotated[Optional[Path], typer.Option("--reference-sinex", help="SINEX file; the station is the RINEX marker name.", show_default="none")]
ReferenceCsv = Annotated[Optional[Path], typer.Option("--reference-csv", help="Moving reference: CSV with time, x_m, y_m, z_m (e.g. truth.csv).", show_default="none")]
ReferencePos = Annotated[Optional[Path], typer.Option("--reference-pos", help="Moving reference: an RTKLIB .pos solution file (ECEF or lat/lon/height; GPST or UTC).", show_default="none")]
Config = Annotated[Optional[Path], typer.Option("--config", help="TOML file of processing options (any key of the packaged default.toml; flags override it).", show_default="packaged defaults")]
TimeSystem = Annotated[Optional[str], typer.Option("--time-system", help="gpst | utc: time scale of the time stamps (UTC = GPST - leap seconds; gps_week and tow_s stay GPS).", show_default=shown(_PROC.get("time_system")))]
Lag = Annotated[Optional[int], typer.Option("--lag", help="Behavioral smoothing lag L (with --method stls, L >= 1): stls rows from sliding-window Hankel STLS of the WLS fixes; 0 = single-epoch methods.", show_default=shown(_SMOOTH.get("lag")))]
Model = Annotated[Optional[str], typer.Option("--model", help="auto | doppler | identify | pva | static | kinematic: auto = doppler with Doppler in the file, else identify; doppler = pseudoranges and range rates in the measurement domain, positions and velocities tied by the lag-L kinematic kernel; a kernel identified per window, fixed, or fixes tied to Doppler velocities (with --lag).", show_default=shown(_SMOOTH.get("model")))]
Kernel = Annotated[Optional[str], typer.Option("--kernel", help="shared | full: structure of the identified kernel (with --lag).", show_default=shown(_SMOOTH.get("kernel")))]
Order = Annotated[Optional[int], typer.Option("--order", help="Order of the full identified kernel (with --lag --kernel full); 0 = 3 L.", show_default=shown(_SMOOTH.get("order")))]
Window = Annotated[Optional[str], typer.Option("--window", metavar="N|auto", help="Window length, epochs; 0 = whole segments; auto = with --model static the longest window around each epoch whose misfit passes the chi-square test, else 15 (with --lag).", show_default=shown(_SMOOTH.get("window")))]
KfModel = Annotated[Optional[str], typer.Option("--kf-model", help="cv | ca: constant-velocity or constant-acceleration motion model of --method kf.", show_default=shown(_KALMAN.get("model")))]
Smoother = Annotated[Optional[str], typer.Option("--smoother", help="rts | none: Rauch-Tung-Striebel smoothed or filtered kf rows.", show_default=shown(_KALMAN.get("smoother")))]
Robust = Annotated[Optional[str], typer.Option("--robust", help="huber | cauchy: M-estimate of the ls/wls fixes (IRLS, residuals scaled by the a-priori sigmas); the chi-square test and fde still apply | off.", show_default=shown(_PROC.get("robust")))]
Integrity = Annotated[Optional[str], typer.Option("--integrity", help="fde (chi-square test, exclude the worst satellite and solve again) | check (test only) | off.", show_default=shown(_PROC.get("integrity")))]
Exclude = Annotated[Optional[str], typer.Option("--exclude", help="Satellites never used, comma list (G07,C28).", show_default=shown(_PROC.get("exclude")) or "none")]
SnrMask = Annotated[Optional[float], typer.Option("--snr-mask", help="Signals with C/N0 below this (dB-Hz, the code's S observation) are not used; 0 = none.", show_default=shown(_PROC.get("snr_mask_dbhz")))]
Processes = Annotated[Optional[int], typer.Option("--processes", metavar="N", help="Processes that read and solve the parts of a day file at once (snapshot methods, CSV); 0 = one per core, 1 = this one only.", show_default=shown(_PROC.get("processes")))]
Quiet = Annotated[bool, typer.Option("--quiet", "-q", help="No progress, warnings or summary on stderr.")]
Debug = Annotated[bool, typer.Option("--debug", help="Show tracebacks of internal errors.")]

CONFIG_KEYS = {
    "method": "methods", "iono": "iono", "tropo": "tropo", "elevation_mask": "elevation_mask_deg", "systems": "systems",
    "integrity": "integrity", "exclude": "exclude", "snr_mask": "snr_mask_dbhz", "lag": "smoothing.lag",
    "model": "smoothing.model", "kernel": "smoothing.kernel", "order": "smoothing.order", "window": "smoothing.window",
    "kf_model": "kalman.model", "smoother": "kalman.smoother", "robust": "robust", "time_system": "time_system",
    "processes": "processes",
}
"""Command parameter name -> :func:`~gnss_cli.config.load_config` override key."""

REFERENCE_NAMES = ("reference", "reference_sinex", "reference_csv", "reference_pos")
"""The parameters of the four reference options, in the order :func:`solve_tables` takes them."""

SMOOTHING_FLAGS = {"model": "--model", "kernel": "--kernel", "order": "--order", "window": "--window",
                   "model_out": "--model-out"}
"""Parameters (-> flags) that only make sense with ``--lag`` >= 1."""


def run_config(config: Optional[Path], values: Mapping[str, Any]) -> Any:
    """The :class:`~gnss_cli.config.ProcessingConfig` of a command's parameters ``values``
    (flags > ``config`` TOML > packaged defaults); only the names of :data:`CONFIG_KEYS` are used."""
    from gnss_cli.config import load_config

    return load_config(config, {key: values.get(name) for name, key in CONFIG_KEYS.items()})


def check_reference_options(values: Mapping[str, Any]) -> None:
    """At most one of the four reference options (:class:`UsageError` otherwise)."""
    if sum(values.get(name) is not None for name in REFERENCE_NAMES) > 1:
        raise UsageError("give one of --reference, --reference-sinex, --reference-csv, --reference-pos")


def check_smoothing_flags(cfg: Any, values: Mapping[str, Any]) -> None:
    """The smoothing flags need ``--lag`` >= 1, ``--lag`` needs ``stls``, the Kalman flags need ``kf`` (:class:`UsageError`)."""
    given = [flag for name, flag in SMOOTHING_FLAGS.items() if values.get(name) is not None]
    if cfg.smoothing.lag == 0 and given:
        raise UsageError(f"{', '.join(given)}: only with --lag L (L >= 1, behavioral smoothing of the stls rows)")
    if cfg.smoothing.lag > 0 and "stls" not in cfg.methods:
        raise UsageError("--lag: needs --method stls (the smoothed rows are the stls rows)")
    kf_given = [flag for name, flag in (("kf_model", "--kf-model"), ("smoother", "--smoother")) if values.get(name) is not None]
    if kf_given and "kf" not in cfg.methods:
        raise UsageError(f"{', '.join(kf_given)}: only with --method kf")


def reference_inputs(values: Mapping[str, Any]) -> list[Path]:
    """The files that ``--config`` and the reference options name (inputs no output may overwrite)."""
    return [p for p in (values.get("config"), *(values.get(n) for n in REFERENCE_NAMES[1:])) if isinstance(p, Path)]
