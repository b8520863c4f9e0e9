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
_KALMAN = _DEFAULTS.get("kalman", {})


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
    method: Optional[str] = typer.Option(None, "--method", "-m", help="ls, wls, tls, dls, mtls, stls, wtls, kf (Kalman filter), a comma list, or all (= ls ... wtls).", show_default=_shown(_PROC.get("methods"))),
    systems: Optional[str] = typer.Option(None, "--systems", help="Constellations: comma list of RINEX letters G,E,C,J,R, or all (every system in both OBS and NAV).", show_default=_shown(_PROC.get("systems"))),
    iono: Optional[str] = typer.Option(None, "--iono", help="klobuchar | iono-free (dual-frequency combination) | none.", show_default=_shown(_PROC.get("iono"))),
    tropo: Optional[str] = typer.Option(None, "--tropo", help="saastamoinen | none.", show_default=_shown(_PROC.get("tropo"))),
    elevation_mask: Optional[float] = typer.Option(None, "--elevation-mask", help="Elevation mask, degrees.", show_default=_shown(_PROC.get("elevation_mask_deg"))),
    reference: Optional[str] = typer.Option(None, "--reference", help="Reference position X,Y,Z (ECEF, m) for error columns.", show_default="none"),
    reference_sinex: Optional[Path] = typer.Option(None, "--reference-sinex", help="SINEX file; the station is the RINEX marker name.", show_default="none"),
    reference_csv: Optional[Path] = typer.Option(None, "--reference-csv", help="Moving reference: CSV with time, x_m, y_m, z_m (e.g. truth.csv).", show_default="none"),
    reference_pos: Optional[Path] = typer.Option(None, "--reference-pos", help="Moving reference: an RTKLIB .pos solution file (ECEF or lat/lon/height; GPST or UTC).", show_default="none"),
    config: Optional[Path] = typer.Option(None, "--config", help="TOML file of processing options (any key of the packaged default.toml; flags override it).", show_default="packaged defaults"),
    output: Optional[str] = typer.Option(None, "-o", "--output", help="Write the positions here ('-' = stdout); pos and nmea with several methods: FILE.<method>.pos / .nmea.", show_default="stdout"),
    out_dir: Optional[Path] = typer.Option(None, "--out-dir", help="Write positions (in --format), errors.csv, dop.csv, summary.csv, satellites.csv here.", show_default="none"),
    fmt: Optional[str] = typer.Option(None, "--format", help="csv | pos | geojson | kml | nmea | parquet: format of the positions (default: from the -o extension, else csv).", show_default="csv"),
    time_system: Optional[str] = typer.Option(None, "--time-system", help="gpst | utc: time scale of the time stamps (UTC = GPST - leap seconds; gps_week and tow_s stay GPS).", show_default=_shown(_PROC.get("time_system"))),
    lag: Optional[int] = typer.Option(None, "--lag", help="Behavioral smoothing lag L (with --method stls, L >= 1): stls rows from sliding-window Hankel STLS of the WLS fixes; 0 = single-epoch methods.", show_default=_shown(_SMOOTH.get("lag"))),
    model: Optional[str] = typer.Option(None, "--model", help="identify | pva | static | kinematic: kernel identified per window, fixed, or positions tied to Doppler velocities (with --lag).", show_default=_shown(_SMOOTH.get("model"))),
    kernel: Optional[str] = typer.Option(None, "--kernel", help="shared | full: structure of the identified kernel (with --lag).", show_default=_shown(_SMOOTH.get("kernel"))),
    order: Optional[int] = typer.Option(None, "--order", help="Order of the full identified kernel (with --lag --kernel full); 0 = 3 L.", show_default=_shown(_SMOOTH.get("order"))),
    window: Optional[int] = typer.Option(None, "--window", help="Window length, epochs; 0 = whole segments (with --lag).", show_default=_shown(_SMOOTH.get("window"))),
    kf_model: Optional[str] = typer.Option(None, "--kf-model", help="cv | ca: constant-velocity or constant-acceleration motion model of --method kf.", show_default=_shown(_KALMAN.get("model"))),
    smoother: Optional[str] = typer.Option(None, "--smoother", help="rts | none: Rauch-Tung-Striebel smoothed or filtered kf rows.", show_default=_shown(_KALMAN.get("smoother"))),
    integrity: Optional[str] = typer.Option(None, "--integrity", help="fde (chi-square test, exclude the worst satellite and solve again) | check (test only) | off.", show_default=_shown(_PROC.get("integrity"))),
    robust: Optional[str] = typer.Option(None, "--robust", help="huber | cauchy: M-estimate of the ls/wls fixes (IRLS, residuals scaled by the a-priori sigmas); the chi-square test and fde still apply | off.", show_default=_shown(_PROC.get("robust"))),
    exclude: Optional[str] = typer.Option(None, "--exclude", help="Satellites never used, comma list (G07,C28).", show_default=_shown(_PROC.get("exclude")) or "none"),
    snr_mask: Optional[float] = typer.Option(None, "--snr-mask", help="Signals with C/N0 below this (dB-Hz, the code's S observation) are not used; 0 = none.", show_default=_shown(_PROC.get("snr_mask_dbhz"))),
    model_out: Optional[Path] = typer.Option(None, "--model-out", help="Write the per-window kernels, poles, misfits and statuses here (JSON; with --lag).", show_default="none"),
    plots: Optional[Path] = typer.Option(None, "--plots", help="Write the figures (PNG: errors, ellipses, GDOP, track, sky plot, satellites, residuals) into this folder; needs matplotlib (pip install 'gnss-solve[plot]').", show_default="none"),
    report: Optional[Path] = typer.Option(None, "--report", help="Write one self-contained HTML page: settings, summary table, figures; needs matplotlib.", show_default="none"),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress, warnings or summary on stderr."),
    debug: bool = typer.Option(False, "--debug", help="Show tracebacks of internal errors."),
    version: bool = typer.Option(False, "--version", callback=version_callback("gnss-solve"), is_eager=True, help="Print the version and exit."),
) -> None:
    """Solve every epoch of OBS with the broadcast orbits of NAV and write CSV tables."""
    if len(files) < 2:
        raise UsageError("expected OBS NAV [NAV ...]: an observation file and at least one navigation file")
    if sum(r is not None for r in (reference, reference_sinex, reference_csv, reference_pos)) > 1:
        raise UsageError("give one of --reference, --reference-sinex, --reference-csv, --reference-pos")
    if output not in (None, "-") and out_dir is not None:
        raise UsageError("give -o/--output or --out-dir, not both")
    from gnss_cli.cli.output import OutputSet
    from gnss_cli.cli.progress import Progress

    inputs = [*files, *(p for p in (config, reference_sinex, reference_csv, reference_pos) if p is not None)]
    with OutputSet(inputs) as outputs:
        overrides: dict[str, object] = {
            "methods": method,
            "iono": iono,
            "tropo": tropo,
            "elevation_mask_deg": elevation_mask,
            "systems": systems,
            "integrity": integrity,
            "robust": robust,
            "exclude": exclude,
            "snr_mask_dbhz": snr_mask,
            "smoothing.lag": lag,
            "smoothing.model": model,
            "smoothing.kernel": kernel,
            "smoothing.order": order,
            "smoothing.window": window,
            "kalman.model": kf_model,
            "kalman.smoother": smoother,
            "time_system": time_system,
        }
        from gnss_cli.config import load_config

        cfg = load_config(config, overrides)
        fmt = _output_format(fmt, output, out_dir, cfg.methods)
        targets = _register_outputs(outputs, output, out_dir, model_out, fmt, cfg.methods)
        from gnss_cli.cli.figures import register_figures
        from gnss_cli.plots import RUN_FIGURES

        figure_targets = register_figures(outputs, plots, report, list(RUN_FIGURES))
        given = [flag for flag, v in zip(SMOOTHING_FLAGS, (model, kernel, order, window, model_out)) if v is not None]
        if cfg.smoothing.lag == 0 and given:
            raise UsageError(f"{', '.join(given)}: only with --lag L (L >= 1, behavioral smoothing of the stls rows)")
        if cfg.smoothing.lag > 0 and "stls" not in cfg.methods:
            raise UsageError("--lag: needs --method stls (the smoothed rows are the stls rows)")
        kf_given = [flag for flag, v in (("--kf-model", kf_model), ("--smoother", smoother)) if v is not None]
        if kf_given and "kf" not in cfg.methods:
            raise UsageError(f"{', '.join(kf_given)}: only with --method kf")
        progress = Progress("gnss-solve", enabled=not quiet)
        try:
            tables, models, warnings, (result, ref) = _run(files, cfg, progress, reference, reference_sinex, reference_csv,
                                                           reference_pos)
            if figure_targets:
                progress("figures", 0.0)
                _stage_figures(outputs, figure_targets, files, cfg, result, ref, tables["summary"],
                               reference or reference_sinex or reference_csv or reference_pos)
        finally:
            progress.done()
        _write(outputs, targets, tables, models, fmt, cfg.time_system, [str(f) for f in files])
    if not quiet:
        for w in warnings:
            sys.stderr.write(f"gnss-solve: warning: {w}\n")
        _print_summary(tables["summary"], "errors" in tables)


FORMAT_NAMES = ("csv", "pos", "geojson", "kml", "nmea", "parquet")
"""``--format`` values (the writers are in :mod:`gnss_cli.formats`)."""
_SUFFIXES = {".csv": "csv", ".pos": "pos", ".geojson": "geojson", ".json": "geojson", ".kml": "kml", ".nmea": "nmea",
             ".parquet": "parquet"}


def _output_format(fmt: Optional[str], output: Optional[str], out_dir: Optional[Path], methods: tuple[str, ...]) -> str:
    """``--format``, else the one the ``-o`` extension implies, else csv; refuses what stdout cannot take."""
    if fmt is None:
        fmt = _SUFFIXES.get(Path(output).suffix.lower(), "csv") if output not in (None, "-") else "csv"
    fmt = fmt.lower()
    if fmt not in FORMAT_NAMES:
        raise UsageError(f"--format: expected one of {', '.join(FORMAT_NAMES)}; received {fmt!r}")
    if output in (None, "-") and out_dir is None:
        if fmt == "parquet":
            raise UsageError("--format parquet: binary output needs -o FILE or --out-dir (not stdout)")
        if fmt in ("pos", "nmea") and len(methods) > 1:
            raise UsageError(f"--format {fmt}: one method per file; give one --method or -o FILE "
                             f"(FILE.<method>.{fmt} per method)")
    return fmt


def _positions_paths(base: Path, fmt: str, methods: tuple[str, ...]) -> dict[str, Path]:
    """Positions target(s): ``base``, or ``base`` with ``.<method>`` before the suffix per method
    for the one-method formats (pos, nmea) with several methods."""
    if fmt in ("pos", "nmea") and len(methods) > 1:
        return {f"positions:{m}": base.with_name(f"{base.stem}.{m}{base.suffix}") for m in methods}
    return {"positions": base}


def _register_outputs(outputs: Any, output: Optional[str], out_dir: Optional[Path], model_out: Optional[Path],
                      fmt: str = "csv", methods: tuple[str, ...] = ()) -> dict[str, Path]:
    """Check every output path before anything is computed (refuse inputs, unusable folders)."""
    targets: dict[str, Path] = {}
    if out_dir is not None:
        if out_dir.exists() and not out_dir.is_dir():
            from gnss_cli.errors import OutputError

            raise OutputError(f"{out_dir}: cannot write output (not a folder)")
        positions = _positions_paths(out_dir / f"positions.{fmt}", fmt, methods)
        targets.update({k: outputs.add(p, "--out-dir") for k, p in positions.items()})
        for name in ("errors", "dop", "summary", "satellites"):
            targets[name] = outputs.add(out_dir / f"{name}.csv", "--out-dir")
    elif output not in (None, "-"):
        positions = _positions_paths(Path(output), fmt, methods)
        targets.update({k: outputs.add(p, "-o/--output") for k, p in positions.items()})
    if model_out is not None:
        targets["models"] = outputs.add(model_out, "--model-out")
    return targets


def _run(files: list[Path], cfg: Any, progress: Any, reference: Optional[str], reference_sinex: Optional[Path],
         reference_csv: Optional[Path], reference_pos: Optional[Path] = None
         ) -> tuple[dict[str, Any], str, list[str], tuple[Any, Any]]:
    """Process the files (one library call) and build the tables; heavy imports happen here."""
    from gnss_cli.io.reference import parse_reference, reference_from_csv, reference_from_pos, reference_from_sinex
    from gnss_cli.pipeline import process
    from gnss_cli.formats import pos_options
    from gnss_cli.report import dop_table, errors_table, models_json, positions_table, satellites_table, summary_table, utc_offset_s

    ref = parse_reference(reference) if reference else None
    result = process(files[0], files[1:], cfg, progress=progress)
    if reference_sinex is not None:
        if not result.epochs.marker_name:
            raise ConfigError(f"--reference-sinex: {files[0]} has no MARKER NAME to look up")
        ref = reference_from_sinex(reference_sinex, result.epochs.marker_name)
    if reference_csv is not None:
        ref = reference_from_csv(reference_csv, result.epochs.time_gps_s)
    if reference_pos is not None:
        ref = reference_from_pos(reference_pos, result.epochs.time_gps_s, utc_offset_s(result))
    positions = positions_table(result, ref, cfg.time_system)
    tables = {"positions": positions, "dop": dop_table(positions), "summary": summary_table(result, ref),
              "pos_options": pos_options(cfg.elevation_mask_deg, cfg.iono, cfg.tropo, result.epochs.systems)}
    tables["satellites"] = lambda: satellites_table(result, cfg)  # built only when written
    if ref is not None:
        tables["errors"] = errors_table(positions)
    return tables, models_json(cfg.smoothing, result.models), list(result.warnings), (result, ref)


def _stage_figures(outputs: Any, targets: dict[str, Path], files: list[Path], cfg: Any, result: Any, ref: Any,
                   summary: Any, reference: Any) -> None:
    """Draw the run's figures (``--plots``) and the HTML page (``--report``) and stage them."""
    from gnss_cli.cli.figures import solve_settings, stage_figures
    from gnss_cli.plots import RUN_FIGURES
    from gnss_cli.plots.html import html_report
    from gnss_cli.plots.run import run_figures

    settings = solve_settings(files, cfg, result, str(reference) if reference is not None else "none")
    title = f"gnss-solve: {Path(files[0]).name}"
    stage_figures(outputs, targets, run_figures(result, ref, cfg.elevation_mask_deg), RUN_FIGURES,
                  lambda figs: html_report(title, figs, summary, settings))


def _write(outputs: Any, targets: dict[str, Path], tables: dict[str, Any], models_text: str, fmt: str = "csv",
           time_system: str = "gpst", inputs: Optional[list[str]] = None) -> None:
    """Stage every output (committed together when the ``OutputSet`` closes), or print to stdout.

    The positions go in ``fmt`` (one file per method for pos / nmea with several methods,
    targets ``positions:<method>``); the other tables are CSV."""
    from gnss_cli.formats import render
    from gnss_cli.report import to_csv_text

    positions = tables["positions"]
    for name, path in targets.items():
        if name == "models":
            outputs.write_text(path, models_text)
        elif name.startswith("positions"):
            _, _, method = name.partition(":")
            table = positions[positions["method"] == method] if method else positions
            data = render(fmt, table, time_system, inputs or (), tables.get("pos_options", ()))
            if isinstance(data, bytes):
                outputs.write_with(path, lambda tmp, data=data: tmp.write_bytes(data))
            else:
                outputs.write_text(path, data)
        elif name in tables:
            table = tables[name]() if callable(tables[name]) else tables[name]
            outputs.write_text(path, to_csv_text(table))
    if not any(name.startswith("positions") for name in targets):
        text = render(fmt, positions, time_system, inputs or (), tables.get("pos_options", ()))
        write_stdout(text if isinstance(text, str) else text.decode())


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
