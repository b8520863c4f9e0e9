"""The processing options that ``gnss-solve`` and ``gnss-batch`` share, defined once.

Each option is an ``Annotated`` type (Typer reads the ``typer.Option`` inside it), so a
command lists it as ``method: Method = None`` and both commands show the same flag, help
text, packaged default, placeholder (``metavar``) and help panel (``rich_help_panel``, drawn by
:class:`~gnss_cli.cli.help.PanelCommand`). A flag that sets a configuration key has no default of its own
(None): the ``--config`` file and the packaged ``default.toml`` decide, and ``--help``
shows the packaged value. :data:`CONFIG_KEYS` maps the parameter names to the
configuration keys, :func:`run_config` builds the configuration from a command's
parameters, and :func:`check_old_spellings`, :func:`check_reference_options` and
:func:`check_method_flags` are the usage checks both commands make.
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
_STLS = _DEFAULTS.get("stls", {})
_SMOOTHER = _DEFAULTS.get("smoother", {})
_KALMAN = _DEFAULTS.get("kalman", {})


def shown(value: Any) -> str:
    """A packaged default as it is written on the command line.

    >>> shown(["ls", "wls"]), shown(10.0)
    ('ls,wls', '10.0')
    """
    if isinstance(value, (list, tuple)):
        return ",".join(str(v) for v in value)
    return str(value)


Method = Annotated[Optional[str], typer.Option("--method", "-m", metavar="METHOD[,METHOD...]", rich_help_panel="Processing", help="ls, wls, tls, dls, mtls, stls, wtls (single epoch; stls with --lag L >= 1: the identified Hankel STLS over several epochs), smoother (fixed-model batch smoother), kf (Kalman filter + RTS), a comma list, or all (= ls ... wtls).", show_default=shown(_PROC.get("methods")))]
Systems = Annotated[Optional[str], typer.Option("--systems", metavar="LIST", rich_help_panel="Processing", help="Constellations: comma list of RINEX letters G,E,C,J,R, or all (every system in both OBS and NAV).", show_default=shown(_PROC.get("systems")))]
Iono = Annotated[Optional[str], typer.Option("--iono", metavar="MODEL", rich_help_panel="Processing", help="klobuchar | iono-free (dual-frequency combination) | none.", show_default=shown(_PROC.get("iono")))]
Tropo = Annotated[Optional[str], typer.Option("--tropo", metavar="MODEL", rich_help_panel="Processing", help="saastamoinen | none.", show_default=shown(_PROC.get("tropo")))]
ElevationMask = Annotated[Optional[float], typer.Option("--elevation-mask", metavar="DEG", rich_help_panel="Processing", help="Elevation mask, degrees.", show_default=shown(_PROC.get("elevation_mask_deg")))]
Reference = Annotated[Optional[str], typer.Option("--reference", metavar="POSITION", rich_help_panel="Reference", help="Reference position for error columns: X,Y,Z (ECEF, m) or geodetic:LAT,LON,H (WGS-84 deg, deg, ellipsoidal m).", show_default="none")]
ReferenceSinex = Annotated[Optional[Path], typer.Option("--reference-sinex", metavar="FILE", rich_help_panel="Reference", help="SINEX file; the station is the RINEX marker name.", show_default="none")]
ReferenceCsv = Annotated[Optional[Path], typer.Option("--reference-csv", metavar="FILE", rich_help_panel="Reference", help="Moving reference: CSV with time (or gps_week, tow_s) and x_m, y_m, z_m or lat_deg, lon_deg, height_m; headerless: week,tow,lat,lon,height.", show_default="none")]
ReferencePos = Annotated[Optional[Path], typer.Option("--reference-pos", metavar="FILE", rich_help_panel="Reference", help="Moving reference: an RTKLIB .pos solution file (ECEF or lat/lon/height; GPST or UTC).", show_default="none")]
Config = Annotated[Optional[Path], typer.Option("--config", metavar="FILE", rich_help_panel="Inputs", help="TOML file of processing options (any key of the packaged default.toml; flags override it).", show_default="packaged defaults")]
TimeSystem = Annotated[Optional[str], typer.Option("--time-system", metavar="SCALE", rich_help_panel="Output", help="gpst | utc: time scale of the time stamps (UTC = GPST - leap seconds; gps_week and tow_s stay GPS).", show_default=shown(_PROC.get("time_system")))]
Lag = Annotated[Optional[int], typer.Option("--lag", rich_help_panel="Multi-epoch", metavar="L", help="Lag of the multi-epoch kernel, epochs: stls with L >= 1 identifies a lag-L kernel from the data (0 = single-epoch STLS); smoother --motion quadrature: the lag (1-3) of its velocity rule.", show_default=f"stls {_STLS.get('lag')}, smoother {_SMOOTHER.get('lag')}")]
Kernel = Annotated[Optional[str], typer.Option("--kernel", metavar="KIND", rich_help_panel="Multi-epoch", help="shared | full: structure of the kernel stls --lag L identifies.", show_default=shown(_STLS.get("kernel")))]
Order = Annotated[Optional[int], typer.Option("--order", rich_help_panel="Multi-epoch", metavar="N", help="Order of the full identified kernel (stls --lag L --kernel full); 0 = 3 L.", show_default=shown(_STLS.get("order")))]
Window = Annotated[Optional[int], typer.Option("--window", rich_help_panel="Multi-epoch", metavar="N", help="Window of stls --lag L, epochs: 0 = whole segments, split where the behavior test rejects them; N = sliding windows of N epochs.", show_default=shown(_STLS.get("window")))]
Motion = Annotated[Optional[str], typer.Option("--motion", metavar="MODEL", rich_help_panel="Multi-epoch", help="quadrature | cv | ca | static: the fixed motion model of --method smoother.", show_default=shown(_SMOOTHER.get("motion")))]
Measurements = Annotated[Optional[str], typer.Option("--measurements", rich_help_panel="Multi-epoch", metavar="KINDS", help="pseudorange,doppler,phase (comma list) or all: what every multi-epoch method (smoother, kf, stls --lag L) uses; all = every kind in the file; a kind the file lacks is left out, with a warning.", show_default=shown(_PROC.get("measurements")))]
KfModel = Annotated[Optional[str], typer.Option("--kf-model", metavar="MODEL", rich_help_panel="Multi-epoch", help="cv | ca: constant-velocity or constant-acceleration motion model of --method kf.", show_default=shown(_KALMAN.get("model")))]
KfOutput = Annotated[Optional[str], typer.Option("--kf-output", metavar="KIND", rich_help_panel="Multi-epoch", help="smoothed | filtered: Rauch-Tung-Striebel smoothed or the filter's own kf rows.", show_default=shown(_KALMAN.get("output")))]
OldModel = Annotated[Optional[str], typer.Option("--model", hidden=True, help="Replaced by --method smoother / stls --lag L.")]
OldSmoother = Annotated[Optional[str], typer.Option("--smoother", hidden=True, help="Replaced by --kf-output.")]
Robust = Annotated[Optional[str], typer.Option("--robust", metavar="MODE", rich_help_panel="Integrity", help="huber | cauchy: M-estimate of the ls/wls fixes (IRLS, residuals scaled by the a-priori sigmas); the chi-square test and fde still apply | off.", show_default=shown(_PROC.get("robust")))]
Integrity = Annotated[Optional[str], typer.Option("--integrity", metavar="MODE", rich_help_panel="Integrity", help="fde (chi-square test, exclude the worst satellite and solve again) | check (test only) | off (no test, exclusion or gate; stls --lag L still tests the behavior of its spans).", show_default=shown(_PROC.get("integrity")))]
Environment = Annotated[Optional[str], typer.Option("--environment", metavar="ENV", rich_help_panel="Integrity", help="auto (street-canyon settings when the WLS residuals say so; summary.csv says which ran) | open | urban (the NLOS detector, nlos_dependent fixes, levels over several faulty satellites: configs/urban.toml).", show_default=shown(_PROC.get("environment")))]
AlertLimit = Annotated[Optional[str], typer.Option("--alert-limit", metavar="H,V", rich_help_panel="Integrity", help="Horizontal and vertical alert limits, m (inf: none): an epoch whose protection level exceeds one is hpl_limit / vpl_limit, not ok.", show_default=f"{_PROC.get('alert_limit_h_m')},{_PROC.get('alert_limit_v_m')}")]
Exclude = Annotated[Optional[str], typer.Option("--exclude", metavar="LIST", rich_help_panel="Processing", help="Satellites never used, comma list (G07,C28).", show_default=shown(_PROC.get("exclude")) or "none")]
SnrMask = Annotated[Optional[float], typer.Option("--snr-mask", metavar="DBHZ", rich_help_panel="Processing", help="Signals with C/N0 below this (dB-Hz, the code's S observation) are not used; 0 = none.", show_default=shown(_PROC.get("snr_mask_dbhz")))]
Processes = Annotated[Optional[int], typer.Option("--processes", rich_help_panel="Run", metavar="N", help="Processes that read and solve the parts of a day file at once (snapshot methods, CSV); 0 = one per core, 1 = this one only.", show_default=shown(_PROC.get("processes")))]
Quiet = Annotated[bool, typer.Option("--quiet", "-q", rich_help_panel="Run", help="No progress, warnings or summary on stderr.")]
Debug = Annotated[bool, typer.Option("--debug", rich_help_panel="Run", help="Show tracebacks of internal errors.")]

CONFIG_KEYS = {
    "method": "methods", "iono": "iono", "tropo": "tropo", "elevation_mask": "elevation_mask_deg", "systems": "systems",
    "integrity": "integrity", "environment": "environment", "exclude": "exclude", "snr_mask": "snr_mask_dbhz", "lag": ("stls.lag", "smoother.lag"),
    "kernel": "stls.kernel", "order": "stls.order", "window": "stls.window", "motion": "smoother.motion",
    "measurements": "measurements", "kf_model": "kalman.model", "kf_output": "kalman.output", "robust": "robust",
    "time_system": "time_system", "processes": "processes",
}
"""Command parameter name -> :func:`~gnss_cli.config.load_config` override key(s)."""

REFERENCE_NAMES = ("reference", "reference_sinex", "reference_csv", "reference_pos")
"""The parameters of the four reference options, in the order :func:`solve_tables` takes them."""

OLD_SPELLINGS = {
    ("model", "doppler"): "--method smoother", ("model", "auto"): "--method smoother (or stls --lag L)",
    ("model", "identify"): "--method stls --lag L", ("model", "pva"): "--method smoother --motion ca",
    ("model", "static"): "--method smoother --motion static",
    ("model", "kinematic"): "--method smoother --motion quadrature --lag 1",
    ("smoother", "rts"): "--kf-output smoothed", ("smoother", "none"): "--kf-output filtered",
}
"""Retired flags and values -> their new spelling (:func:`check_old_spellings`)."""


def run_config(config: Optional[Path], values: Mapping[str, Any]) -> Any:
    """The :class:`~gnss_cli.config.ProcessingConfig` of a command's parameters ``values``
    (flags > ``config`` TOML > packaged defaults); only the names of :data:`CONFIG_KEYS` are used."""
    from gnss_cli.config import load_config

    from gnss_cli.config import parse_alert_limits

    overrides: dict[str, Any] = {}
    for name, keys in CONFIG_KEYS.items():
        for key in (keys,) if isinstance(keys, str) else keys:
            overrides[key] = values.get(name)
    if values.get("alert_limit") is not None:  # one flag, two keys
        overrides["alert_limit_h_m"], overrides["alert_limit_v_m"] = parse_alert_limits(values["alert_limit"])
    return load_config(config, overrides)


def check_old_spellings(values: Mapping[str, Any]) -> None:
    """A retired flag (``--model``, ``--smoother``) exits 2 with one line naming the new spelling."""
    for name in ("model", "smoother"):
        value = values.get(name)
        if value is None:
            continue
        new = OLD_SPELLINGS.get((name, str(value).lower()))
        if new is None:
            new = "--method smoother --motion M or --method stls --lag L" if name == "model" else "--kf-output smoothed|filtered"
        raise UsageError(f"--{name} {value} was replaced: use {new}")


def check_reference_options(values: Mapping[str, Any]) -> None:
    """At most one of the four reference options (:class:`UsageError` otherwise)."""
    if sum(values.get(name) is not None for name in REFERENCE_NAMES) > 1:
        raise UsageError("give one of --reference, --reference-sinex, --reference-csv, --reference-pos")


def check_method_flags(cfg: Any, values: Mapping[str, Any]) -> None:
    """Each multi-epoch flag only with the method it configures (:class:`UsageError` otherwise)."""
    methods = cfg.methods
    identified = "stls" in methods and cfg.stls.lag > 0
    need = [
        (("kernel", "order", "window"), identified, "only with --method stls --lag L (L >= 1, the identified Hankel STLS)"),
        (("motion",), "smoother" in methods, "only with --method smoother"),
        (("kf_model", "kf_output"), "kf" in methods, "only with --method kf"),
        (("lag",), "stls" in methods or "smoother" in methods, "only with --method stls or smoother"),
        (("measurements", "model_out"), bool(cfg.multi_epoch_methods),
         "only with a multi-epoch method (stls --lag L, smoother, kf)"),
    ]
    for names, allowed, why in need:
        given = [f"--{n.replace('_', '-')}" for n in names if values.get(n) is not None]
        if given and not allowed:
            raise UsageError(f"{', '.join(given)}: {why}")


def reference_inputs(values: Mapping[str, Any]) -> list[Path]:
    """The files that ``--config`` and the reference options name (inputs no output may overwrite)."""
    return [p for p in (values.get("config"), *(values.get(n) for n in REFERENCE_NAMES[1:])) if isinstance(p, Path)]
