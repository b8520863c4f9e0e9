"""``gnss-simulate``: write simulated RINEX observation and navigation files with their truth.

A thin shell over :mod:`gnss_cli.sim.scenario`: options -> :class:`ScenarioConfig`
(flags > ``--config`` TOML > built-in defaults, which equal ``gnss_cli/configs/simulate.toml``),
then ``run_scenario`` and ``write_scenario``. The list of files written goes to stderr
unless ``--quiet``.
"""

from __future__ import annotations

import contextlib
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Annotated, Optional

import typer

from gnss_cli.cli.exits import HELP_OPTIONS, run_app, version_callback
from gnss_cli.cli.help import PanelCommand
from gnss_cli.config import packaged_defaults
from gnss_cli.errors import ConfigError, UsageError

_SIM = packaged_defaults("simulate.toml")


def _default(table: str, key: str) -> str:
    """A packaged ``simulate.toml`` default as shown by ``--help``."""
    value = _SIM.get(table, {}).get(key)
    if isinstance(value, list):
        return ",".join(str(v) for v in value) or "none"
    if isinstance(value, bool):
        return "yes" if value else "no"
    return str(value)


EXAMPLES = """\
Examples:
  One hour of a static GPS + Galileo receiver, an epoch every 30 s:
    gnss-simulate --systems G,E --duration 3600 --interval 30 --out-dir static

  The first five minutes of the standard flight (take-off roll, climb) at 1 Hz
  (--trajectory flight draws its path and start from --seed):
    gnss-simulate --trajectory standard-flight --duration 300 --interval 1 \\
        --out-dir flight
"""
"""The epilog of ``gnss-simulate --help`` (``tests/cli/test_help.py`` runs every example)."""

app = typer.Typer(add_completion=False, context_settings=HELP_OPTIONS, rich_markup_mode=None, help="Simulate GNSS pseudoranges and broadcast ephemerides as RINEX files.")

_RINEX_VERSIONS = {"3": "3.04", "3.04": "3.04", "3.05": "3.05", "2": "2.11", "2.11": "2.11"}


@contextlib.contextmanager
def _values_are_configuration() -> Iterator[None]:
    """A bad option value is a configuration error (exit 3), as in gnss-solve; Click keeps
    the usage mistakes (missing or unknown options, wrong types: exit 2)."""
    try:
        yield
    except UsageError as exc:
        raise ConfigError(str(exc)) from None


@app.command(cls=PanelCommand, epilog=EXAMPLES)
def simulate(
    out_dir: Annotated[Path, typer.Option("--out-dir", metavar="DIR", rich_help_panel="Output", help="Folder for obs.rnx, nav.rnx, truth.csv.")],
    trajectory: Annotated[Optional[str], typer.Option(metavar="KIND", rich_help_panel="Scenario", show_default=_default("simulate", "trajectory"), help="static | flight | standard-flight | drive | semicircle | csv:FILE (flight and drive: path and start time drawn from --seed)")] = None,
    start: Annotated[Optional[str], typer.Option(metavar="TIME", rich_help_panel="Scenario", show_default=_default("simulate", "start"), help="Start, ISO 8601 GPS time (2024-03-01T00:00:00).")] = None,
    duration: Annotated[Optional[float], typer.Option(metavar="S", rich_help_panel="Scenario", show_default=_default("simulate", "duration_s"), help="Duration, s.")] = None,
    interval: Annotated[Optional[float], typer.Option(metavar="S", rich_help_panel="Scenario", show_default=_default("simulate", "interval_s"), help="Epoch interval, s.")] = None,
    systems: Annotated[Optional[str], typer.Option(metavar="LIST", rich_help_panel="Scenario", show_default=_default("simulate", "systems"), help="Systems, comma list of G, E, C, J.")] = None,
    seed: Annotated[Optional[int], typer.Option(metavar="N", rich_help_panel="Scenario", show_default=_default("simulate", "seed"), help="Seed of the random generator.")] = None,
    errors: Annotated[
        Optional[str],
        typer.Option(metavar="LIST", rich_help_panel="Errors", show_default=_default("simulate", "errors"), help="none | all | comma list of clock,noise,iono,tropo,orbit,multipath,outliers."),
    ] = None,
    noise_sigma: Annotated[Optional[float], typer.Option(metavar="M", rich_help_panel="Errors", show_default=_default("errors", "noise_sigma_m"), help="Zenith std of the white pseudorange noise, m.")] = None,
    noise_model: Annotated[
        Optional[str], typer.Option(metavar="MODEL", rich_help_panel="Errors", show_default="elevation" if _SIM.get("errors", {}).get("noise_elevation_dependent", True) else "constant", help="elevation (sigma grows as 1/sin el) | constant.")
    ] = None,
    orbit_rms: Annotated[Optional[float], typer.Option(metavar="M", rich_help_panel="Errors", show_default=_default("errors", "orbit_rms_m"), help="3-D RMS of the broadcast orbit error, m.")] = None,
    iono_factor: Annotated[Optional[float], typer.Option(metavar="FACTOR", rich_help_panel="Errors", show_default=_default("errors", "iono_factor"), help="True ionosphere / Klobuchar.")] = None,
    outlier_sats: Annotated[Optional[str], typer.Option(metavar="LIST", rich_help_panel="Errors", show_default=_default("errors", "outlier_sats"), help="Satellites with injected outliers, e.g. G05,G07.")] = None,
    outlier_m: Annotated[Optional[str], typer.Option(metavar="M", rich_help_panel="Errors", show_default=_default("errors", "outlier_m"), help="Outlier size, m (with --outlier-sats); LOW,HIGH: the range of the random outliers' sizes (with --outlier-rate).")] = None,
    outlier_rate: Annotated[Optional[float], typer.Option(metavar="SHARE", rich_help_panel="Errors", show_default=_default("errors", "outlier_rate"), help="Share of epochs with a random outlier on one random satellite (writes faults.csv).")] = None,
    environment: Annotated[Optional[str], typer.Option(metavar="KIND", rich_help_panel="Scenario", show_default=_default("simulate", "environment"), help="open | urban (a street canyon: masks, NLOS, C/N0, phase with slips; writes faults.csv).")] = None,
    receiver: Annotated[Optional[str], typer.Option(metavar="KIND", rich_help_panel="Scenario", show_default=_default("simulate", "receiver"), help="With urban: single (GPS+BeiDou L1) | dual (G,E,C,J two frequencies); --systems and --dual-frequency override.")] = None,
    elevation_mask: Annotated[Optional[float], typer.Option(metavar="DEG", rich_help_panel="Scenario", show_default=_default("simulate", "elevation_mask_deg"), help="Elevation mask of what is written, deg.")] = None,
    position: Annotated[
        Optional[str], typer.Option(metavar="LAT,LON,H", rich_help_panel="Scenario", show_default=",".join(_default("simulate", k) for k in ("latitude_deg", "longitude_deg", "height_m")), help="Site / start point LAT_DEG,LON_DEG,HEIGHT_M.")
    ] = None,
    rinex_version: Annotated[Optional[str], typer.Option(metavar="VERSION", rich_help_panel="Output", show_default=_default("simulate", "rinex_version"), help="3 (3.04), 3.05 or 2 (2.11).")] = None,
    dual_frequency: Annotated[
        Optional[bool], typer.Option("--dual-frequency/--single-frequency", rich_help_panel="Scenario", help="Also C2W / C7Q / C7I.", show_default="dual" if _SIM.get("simulate", {}).get("dual_frequency") else "single")
    ] = None,
    phase: Annotated[
        Optional[bool], typer.Option("--phase/--no-phase", rich_help_panel="Scenario", help="Also carrier phases (L1C ...) in open sky: continuous, noise from the C/N0 (the street canyon always writes them, with slips). RINEX 3.", show_default="phase" if _SIM.get("simulate", {}).get("phase") else "no-phase")
    ] = None,
    truth_ranges: Annotated[
        Optional[bool], typer.Option("--truth-ranges/--no-truth-ranges", rich_help_panel="Output", help="Also write truth_ranges.csv.", show_default="truth-ranges" if _SIM.get("simulate", {}).get("truth_ranges") else "no-truth-ranges")
    ] = None,
    config: Annotated[Optional[Path], typer.Option(metavar="FILE", rich_help_panel="Scenario", help="TOML settings (any key of the packaged simulate.toml; flags override it).", show_default="packaged defaults")] = None,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", rich_help_panel="Run", help="No summary on stderr.")] = False,
    debug: Annotated[bool, typer.Option("--debug", rich_help_panel="Run", help="Tracebacks for internal errors.")] = False,
    version: Annotated[bool, typer.Option("--version", rich_help_panel="Run", callback=version_callback("gnss-simulate"), is_eager=True,
                                          help="Print the version and exit.")] = False,
) -> None:
    """Write obs.rnx, nav.rnx and truth.csv for a simulated receiver."""
    from gnss_cli.sim.error_sources import parse_error_list
    from gnss_cli.sim.scenario import ScenarioConfig, config_from_mapping, load_config, parse_systems, run_scenario, write_scenario

    with _values_are_configuration():
        cfg = load_config(config) if config is not None else ScenarioConfig()
        if systems is not None:
            parse_systems(systems)
        if errors is not None:
            parse_error_list(errors)
        if noise_model is not None and noise_model not in ("elevation", "constant"):
            raise UsageError(f"--noise-model: expected elevation or constant, got {noise_model!r}")
        if rinex_version is not None and rinex_version not in _RINEX_VERSIONS:
            raise UsageError(f"--rinex-version: expected 3, 3.05 or 2, got {rinex_version!r}")
        site: dict[str, float] = {}
        if position is not None:
            try:
                lat, lon, h = (float(v) for v in position.split(","))
            except ValueError as exc:
                raise UsageError(f"--position: expected LAT_DEG,LON_DEG,HEIGHT_M, got {position!r}") from exc
            site = {"latitude_deg": lat, "longitude_deg": lon, "height_m": h}
        flags = {
            "simulate": {
                "trajectory": trajectory, "start": start, "duration_s": duration, "interval_s": interval,
                "systems": systems, "seed": seed, "elevation_mask_deg": elevation_mask, **site,
                "rinex_version": _RINEX_VERSIONS.get(rinex_version or ""), "dual_frequency": dual_frequency, "phase": phase,
                "truth_ranges": truth_ranges, "errors": errors, "environment": environment, "receiver": receiver,
            },
            "errors": {
                "noise_sigma_m": noise_sigma, "noise_elevation_dependent": None if noise_model is None else noise_model == "elevation",
                "orbit_rms_m": orbit_rms, "iono_factor": iono_factor, "outlier_rate": outlier_rate, **_outlier_sizes(outlier_m),
                "outlier_sats": None if outlier_sats is None else [s.strip().upper() for s in outlier_sats.split(",") if s.strip()],
            },
        }
        mapping = {table: {k: v for k, v in keys.items() if v is not None} for table, keys in flags.items()}
        cfg = config_from_mapping(mapping, cfg, source="command line")
        scenario = run_scenario(cfg)
    from gnss_cli.cli.output import OutputSet

    with OutputSet() as outputs:
        staging = outputs.staging_dir(out_dir)
        write_scenario(scenario, staging)
        written = outputs.adopt_staged(staging, out_dir)
    if not quiet:
        n_obs = int(scenario.observations.visible.sum())
        sys.stderr.write(
            f"gnss-simulate: {scenario.observations.t_gps_s.size} epochs, {n_obs} satellite observations, "
            f"errors: {','.join(sorted(cfg.errors.enabled)) or 'none'}; wrote {', '.join(str(p) for p in written)}\n"
        )


def _outlier_sizes(text: Optional[str]) -> dict[str, object]:
    """``--outlier-m``: ``M`` -> ``outlier_m``; ``LOW,HIGH`` -> ``outlier_range_m``."""
    if text is None:
        return {}
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError as exc:
        raise UsageError(f"--outlier-m: expected M or LOW,HIGH (m), got {text!r}") from exc
    if len(values) == 1:
        return {"outlier_m": values[0]}
    if len(values) != 2:
        raise UsageError(f"--outlier-m: expected M or LOW,HIGH (m), got {text!r}")
    return {"outlier_range_m": values}


def main() -> None:
    """Console-script entry point."""
    run_app(app, "gnss-simulate")


if __name__ == "__main__":
    main()
