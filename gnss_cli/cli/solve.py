"""``gnss-solve OBS NAV [NAV ...] [options]``: RINEX in, positions / errors / DOP tables out.

Data go to stdout (or ``-o FILE`` / ``--out-dir DIR``); progress, warnings and the summary
go to stderr. Exit codes: 0 ok, 1 bug, 2 usage, 3 bad configuration, 4 bad input file,
5 no epoch solved, 6 output not writable, 130 / 143 interrupted.

Only Typer and the configuration defaults are imported at start-up, so that ``--help``
answers at once; the numerical modules are imported when a run starts.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any, Optional

import typer

from gnss_cli.cli.exits import HELP_OPTIONS, run_app, version_callback, write_stdout
from gnss_cli.config import packaged_defaults
from gnss_cli.errors import ConfigError, UsageError

_DEFAULTS = packaged_defaults()
_PROC = _DEFAULTS.get("processing", {})
_SMOOTH = _DEFAULTS.get("smoothing", {})


def _shown(value: Any) -> str:
    """A packaged default as it is written on the command line."""
    if isinstance(value, (list, tuple)):
        return ",".join(str(v) for v in value)
    return str(value)


app = typer.Typer(add_completion=False, help=__doc__, context_settings=HELP_OPTIONS, rich_markup_mode=None)


SMOOTHING_FLAGS = ("--model", "--kernel", "--order", "--window", "--model-out")


@app.command()
def solve(
    files: list[Path] = typer.Argument(..., help="A RINEX observation file and one or more navigation files.", metavar="OBS NAV [NAV]...", show_default=False),
    method: Optional[str] = typer.Option(None, "--method", "-m", help="ls, wls, tls, dls, mtls, stls, wtls, a comma list, or all.", show_default=_shown(_PROC.get("methods"))),
    systems: Optional[str] = typer.Option(None, "--systems", help="Constellations: comma list of RINEX letters G,E,C,J,R, or all (every system in both OBS and NAV).", show_default=_shown(_PROC.get("systems"))),
    iono: Optional[str] = typer.Option(None, "--iono", help="klobuchar | iono-free (dual-frequency combination) | none.", show_default=_shown(_PROC.get("iono"))),
    tropo: Optional[str] = typer.Option(None, "--tropo", help="saastamoinen | none.", show_default=_shown(_PROC.get("tropo"))),
    elevation_mask: Optional[float] = typer.Option(None, "--elevation-mask", help="Elevation mask, degrees.", show_default=_shown(_PROC.get("elevation_mask_deg"))),
    reference: Optional[str] = typer.Option(None, "--reference", help="Reference position X,Y,Z (ECEF, m) for error columns.", show_default="none"),
    reference_sinex: Optional[Path] = typer.Option(None, "--reference-sinex", help="SINEX file; the station is the RINEX marker name.", show_default="none"),
    reference_csv: Optional[Path] = typer.Option(None, "--reference-csv", help="Moving reference: CSV with time, x_m, y_m, z_m (e.g. truth.csv).", show_default="none"),
    config: Optional[Path] = typer.Option(None, "--config", help="TOML file of processing options (any key of the packaged default.toml; flags override it).", show_default="packaged defaults"),
    output: Optional[str] = typer.Option(None, "-o", "--output", help="Write the positions CSV here ('-' = stdout).", show_default="stdout"),
    out_dir: Optional[Path] = typer.Option(None, "--out-dir", help="Write positions.csv, errors.csv, dop.csv, summary.csv, satellites.csv here.", show_default="none"),
    lag: Optional[int] = typer.Option(None, "--lag", help="Behavioral smoothing lag L (with --method stls, L >= 1): stls rows from sliding-window Hankel STLS of the WLS fixes; 0 = single-epoch methods.", show_default=_shown(_SMOOTH.get("lag"))),
    model: Optional[str] = typer.Option(None, "--model", help="identify | pva | static: kernel identified per window or fixed (with --lag).", show_default=_shown(_SMOOTH.get("model"))),
    kernel: Optional[str] = typer.Option(None, "--kernel", help="shared | full: structure of the identified kernel (with --lag).", show_default=_shown(_SMOOTH.get("kernel"))),
    order: Optional[int] = typer.Option(None, "--order", help="Order of the full identified kernel (with --lag --kernel full); 0 = 3 L.", show_default=_shown(_SMOOTH.get("order"))),
    window: Optional[int] = typer.Option(None, "--window", help="Window length, epochs; 0 = whole segments (with --lag).", show_default=_shown(_SMOOTH.get("window"))),
    integrity: Optional[str] = typer.Option(None, "--integrity", help="fde (chi-square test, exclude the worst satellite and solve again) | check (test only) | off.", show_default=_shown(_PROC.get("integrity"))),
    exclude: Optional[str] = typer.Option(None, "--exclude", help="Satellites never used, comma list (G07,C28).", show_default=_shown(_PROC.get("exclude")) or "none"),
    snr_mask: Optional[float] = typer.Option(None, "--snr-mask", help="Signals with C/N0 below this (dB-Hz, the code's S observation) are not used; 0 = none.", show_default=_shown(_PROC.get("snr_mask_dbhz"))),
    model_out: Optional[Path] = typer.Option(None, "--model-out", help="Write the per-window kernels, poles, misfits and statuses here (JSON; with --lag).", show_default="none"),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress, warnings or summary on stderr."),
    debug: bool = typer.Option(False, "--debug", help="Show tracebacks of internal errors."),
    version: bool = typer.Option(False, "--version", callback=version_callback("gnss-solve"), is_eager=True, help="Print the version and exit."),
) -> None:
    """Solve every epoch of OBS with the broadcast orbits of NAV and write CSV tables."""
    if len(files) < 2:
        raise UsageError("expected OBS NAV [NAV ...]: an observation file and at least one navigation file")
    if sum(r is not None for r in (reference, reference_sinex, reference_csv)) > 1:
        raise UsageError("give one of --reference, --reference-sinex, --reference-csv")
    if output not in (None, "-") and out_dir is not None:
        raise UsageError("give -o/--output or --out-dir, not both")
    from gnss_cli.cli.output import OutputSet
    from gnss_cli.cli.progress import Progress

    inputs = [*files, *(p for p in (config, reference_sinex, reference_csv) if p is not None)]
    with OutputSet(inputs) as outputs:
        targets = _register_outputs(outputs, output, out_dir, model_out)
        overrides: dict[str, object] = {
            "methods": method,
            "iono": iono,
            "tropo": tropo,
            "elevation_mask_deg": elevation_mask,
            "systems": systems,
            "integrity": integrity,
            "exclude": exclude,
            "snr_mask_dbhz": snr_mask,
            "smoothing.lag": lag,
            "smoothing.model": model,
            "smoothing.kernel": kernel,
            "smoothing.order": order,
            "smoothing.window": window,
        }
        from gnss_cli.config import load_config

        cfg = load_config(config, overrides)
        given = [flag for flag, v in zip(SMOOTHING_FLAGS, (model, kernel, order, window, model_out)) if v is not None]
        if cfg.smoothing.lag == 0 and given:
            raise UsageError(f"{', '.join(given)}: only with --lag L (L >= 1, behavioral smoothing of the stls rows)")
        if cfg.smoothing.lag > 0 and "stls" not in cfg.methods:
            raise UsageError("--lag: needs --method stls (the smoothed rows are the stls rows)")
        progress = Progress("gnss-solve", enabled=not quiet)
        try:
            tables, models, warnings = _run(files, cfg, progress, reference, reference_sinex, reference_csv)
        finally:
            progress.done()
        _write(outputs, targets, tables, models)
    if not quiet:
        for w in warnings:
            sys.stderr.write(f"gnss-solve: warning: {w}\n")
        _print_summary(tables["summary"], "errors" in tables)


def _register_outputs(outputs: Any, output: Optional[str], out_dir: Optional[Path], model_out: Optional[Path]) -> dict[str, Path]:
    """Check every output path before anything is computed (refuse inputs, unusable folders)."""
    targets: dict[str, Path] = {}
    if out_dir is not None:
        if out_dir.exists() and not out_dir.is_dir():
            from gnss_cli.errors import OutputError

            raise OutputError(f"{out_dir}: cannot write output (not a folder)")
        for name in ("positions", "errors", "dop", "summary", "satellites"):
            targets[name] = outputs.add(out_dir / f"{name}.csv", "--out-dir")
    elif output not in (None, "-"):
        targets["positions"] = outputs.add(Path(output), "-o/--output")
    if model_out is not None:
        targets["models"] = outputs.add(model_out, "--model-out")
    return targets


def _run(files: list[Path], cfg: Any, progress: Any, reference: Optional[str], reference_sinex: Optional[Path],
         reference_csv: Optional[Path]) -> tuple[dict[str, Any], str, list[str]]:
    """Process the files (one library call) and build the tables; heavy imports happen here."""
    from gnss_cli.io.reference import parse_reference, reference_from_csv, reference_from_sinex
    from gnss_cli.pipeline import process
    from gnss_cli.report import dop_table, errors_table, models_json, positions_table, satellites_table, summary_table

    ref = parse_reference(reference) if reference else None
    result = process(files[0], files[1:], cfg, progress=progress)
    if reference_sinex is not None:
        if not result.epochs.marker_name:
            raise ConfigError(f"--reference-sinex: {files[0]} has no MARKER NAME to look up")
        ref = reference_from_sinex(reference_sinex, result.epochs.marker_name)
    if reference_csv is not None:
        ref = reference_from_csv(reference_csv, result.epochs.time_gps_s)
    positions = positions_table(result, ref)
    tables = {"positions": positions, "dop": dop_table(positions), "summary": summary_table(result, ref)}
    tables["satellites"] = lambda: satellites_table(result, cfg)  # built only when written
    if ref is not None:
        tables["errors"] = errors_table(positions)
    return tables, models_json(cfg.smoothing, result.models), list(result.warnings)


def _write(outputs: Any, targets: dict[str, Path], tables: dict[str, Any], models_text: str) -> None:
    """Stage every output (committed together when the ``OutputSet`` closes), or print to stdout."""
    from gnss_cli.report import to_csv_text

    for name, path in targets.items():
        if name == "models":
            outputs.write_text(path, models_text)
        elif name in tables:
            table = tables[name]() if callable(tables[name]) else tables[name]
            outputs.write_text(path, to_csv_text(table))
    if "positions" not in targets:
        write_stdout(to_csv_text(tables["positions"]))


def _print_summary(summary, with_errors: bool) -> None:  # type: ignore[no-untyped-def]
    for _, row in summary.iterrows():
        line = f"gnss-solve: {row['method']}: {row['epochs_solved']}/{row['epochs']} epochs solved"
        if with_errors:
            line += f", 3D RMS {row['rms_3d_m']:.3f} m (E {row['rms_e_m']:.3f} N {row['rms_n_m']:.3f} U {row['rms_u_m']:.3f})"
        line += f", mean GDOP {row['mean_gdop']:.2f}"
        sys.stderr.write(line + "\n")


def main() -> None:
    """Console entry point of ``gnss-solve``."""
    run_app(app, "gnss-solve")


if __name__ == "__main__":
    main()
