"""``gnss-solve OBS NAV [NAV ...] [options]``: RINEX in, positions / errors / DOP tables out.

Data go to stdout (or ``-o FILE`` / ``--out-dir DIR``); progress, warnings and the summary
go to stderr. Exit codes: 0 ok, 1 bug, 2 usage, 3 bad configuration, 4 bad input file,
5 no epoch solved, 6 output not writable, 130 / 143 interrupted.

Only Typer and the configuration defaults are imported at start-up, so that ``--help``
answers at once; the numerical modules are imported when a run starts.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import Any, NoReturn, Optional

import typer

from gnss_cli.cli.exits import HELP_OPTIONS, mark_missing, run_app, single_blas_thread, version_callback, without_dask
from gnss_cli.cli.help import PanelCommand
from gnss_cli.cli.options import (
    AlertLimit, Config, Debug, ElevationMask, Environment, Exclude, Integrity, Iono, Kernel, KfModel, KfOutput, Lag, Measurements, Method,
    Motion, OldModel, OldSmoother, Order, Processes, Quiet, Reference, ReferenceCsv, ReferencePos, ReferenceSinex,
    Robust, SnrMask, Systems, TimeSystem, Tropo, Window, check_method_flags, check_old_spellings,
    check_reference_options, reference_inputs, run_config,
)
from gnss_cli.errors import UsageError

EXAMPLES = """\
Examples:
  A static station against its SINEX coordinates; every table in a folder:
    gnss-solve site.rnx nav.rnx --method ls,wls --reference-sinex site.snx \\
        --out-dir site

  A kinematic file: the fixed-model smoother and the identified Hankel STLS:
    gnss-solve flight/obs.rnx flight/nav.rnx --method smoother,stls --lag 3 \\
        --reference-csv flight/truth.csv -o flight.csv

  An RTKLIB .pos file (for pos2kml, rtkplot); epochs whose protection levels
  exceed 30 m horizontally or 50 m vertically are not ok:
    gnss-solve site.rnx nav.rnx --alert-limit 30,50 -o site.pos
"""
"""The epilog of ``gnss-solve --help`` (``tests/cli/test_help.py`` runs every example)."""

app = typer.Typer(add_completion=False, help=__doc__, context_settings=HELP_OPTIONS, rich_markup_mode=None)


@app.command(cls=PanelCommand, epilog=EXAMPLES)
def solve(
    files: Optional[list[Path]] = typer.Argument(None, help="A RINEX observation file and one or more navigation files.", metavar="OBS NAV...", show_default=False, rich_help_panel="Inputs"),
    method: Method = None,
    systems: Systems = None,
    iono: Iono = None,
    tropo: Tropo = None,
    elevation_mask: ElevationMask = None,
    reference: Reference = None,
    reference_sinex: ReferenceSinex = None,
    reference_csv: ReferenceCsv = None,
    reference_pos: ReferencePos = None,
    config: Config = None,
    output: Optional[str] = typer.Option(None, "-o", "--output", metavar="FILE", rich_help_panel="Output", help="Write the positions here ('-' = stdout); pos and nmea with several methods: one file per method, FILE.METHOD.pos / .nmea.", show_default="stdout"),
    out_dir: Optional[Path] = typer.Option(None, "--out-dir", metavar="DIR", rich_help_panel="Output", help="Write positions (in --format), errors.csv, dop.csv, summary.csv, satellites.csv here.", show_default="none"),
    fmt: Optional[str] = typer.Option(None, "--format", metavar="FORMAT", rich_help_panel="Output", help="csv | pos | geojson | kml | nmea | parquet: format of the positions (default: from the -o extension, else csv).", show_default="csv"),
    time_system: TimeSystem = None,
    lag: Lag = None,
    kernel: Kernel = None,
    order: Order = None,
    window: Window = None,
    motion: Motion = None,
    measurements: Measurements = None,
    kf_model: KfModel = None,
    kf_output: KfOutput = None,
    integrity: Integrity = None,
    environment: Environment = None,
    alert_limit: AlertLimit = None,
    robust: Robust = None,
    exclude: Exclude = None,
    snr_mask: SnrMask = None,
    processes: Processes = None,
    model_out: Optional[Path] = typer.Option(None, "--model-out", metavar="FILE", rich_help_panel="Output", help="Write what each multi-epoch method ran and its window models (kernels, poles, misfits, statuses) here (JSON).", show_default="none"),
    plots: Optional[Path] = typer.Option(None, "--plots", metavar="DIR", rich_help_panel="Output", help="Write the figures (PNG: errors, ellipses, GDOP, track, sky plot, satellites, residuals) into this folder; needs matplotlib (pip install 'gnss-solve[plot]').", show_default="none"),
    report: Optional[Path] = typer.Option(None, "--report", metavar="FILE", rich_help_panel="Output", help="Write one self-contained HTML page: settings, summary table, figures; needs matplotlib.", show_default="none"),
    print_config: bool = typer.Option(False, "--print-config", rich_help_panel="Run", help="Print the effective configuration (packaged defaults < --config < flags) as TOML and exit."),
    model: OldModel = None,
    smoother: OldSmoother = None,
    quiet: Quiet = False,
    debug: Debug = False,
    version: bool = typer.Option(False, "--version", callback=version_callback("gnss-solve"), is_eager=True, rich_help_panel="Run", help="Print the version and exit."),
) -> None:
    """Solve every epoch of OBS with the broadcast orbits of NAV and write CSV tables."""
    values = dict(locals())
    check_old_spellings(values)
    if print_config:
        from gnss_cli.config.toml import config_toml

        sys.stdout.write(config_toml(run_config(config, values)))
        return
    if not files or len(files) < 2:
        raise UsageError("expected OBS NAV [NAV ...]: an observation file and at least one navigation file")
    from gnss_cli.io.compression import prefetch

    prefetch(*files)  # decompression (crx2rnx, gzip) on another core while the numerical modules import
    if not _writes_parquet(fmt, output):
        mark_missing("pyarrow")  # pandas imports it (~50 ms) for its string storage; only Parquet needs it
    check_reference_options(values)
    if output not in (None, "-") and out_dir is not None:
        raise UsageError("give -o/--output or --out-dir, not both")
    from gnss_cli.cli.output import OutputSet
    from gnss_cli.cli.progress import Progress

    with OutputSet([*files, *reference_inputs(values)]) as outputs:
        cfg = run_config(config, values)
        check_method_flags(cfg, values)
        fmt = _output_format(fmt, output, out_dir, cfg.methods)
        targets = _register_outputs(outputs, output, out_dir, model_out, fmt, cfg.methods)
        from gnss_cli.cli.figures import register_figures
        from gnss_cli.plots import RUN_FIGURES

        figure_targets = register_figures(outputs, plots, report, list(RUN_FIGURES))
        progress = Progress("gnss-solve", enabled=not quiet)
        from gnss_cli.cli.exits import command_line
        from gnss_cli.cli.tables import closing_lines, solve_files, stage, written_lines
        from gnss_cli.io.reference import Reference

        ref = Reference.from_options(reference, reference_sinex, reference_csv, reference_pos)
        try:
            run = solve_files(files, cfg, progress, ref, tables=tuple(n for n in targets if ":" not in n),
                              models="models" in targets, keep_positions=fmt != "csv", keep_result=bool(figure_targets),
                              command=command_line())
        except BaseException:
            progress.done()
            raise
        try:
            written = []
            if figure_targets:  # the figures report their own progress; the line ends when they are done
                written = _stage_figures(outputs, figure_targets, files, cfg, run, ref.source, progress)
            progress.done()
            from gnss_cli.formats import pos_options

            written = stage(outputs, targets, run, fmt, cfg.time_system,
                            tuple(pos_options(cfg.elevation_mask_deg, cfg.iono, cfg.tropo, run.systems))) + written
        finally:
            progress.done()
            run.close()
    if not quiet:
        lines = [f"gnss-solve: warning: {w}" for w in run.warnings] + closing_lines(run)
        sys.stderr.write("".join(f"{line}\n" for line in lines + written_lines(written) + _split_note(targets, output, out_dir, fmt)))


def _split_note(targets: dict[str, Path], output: Optional[str], out_dir: Optional[Path], fmt: str) -> list[str]:
    """The line that says a one-method format went to one file per method (and not to the name given)."""
    split = [p for name, p in targets.items() if name.startswith("positions:")]
    if not split:
        return []
    asked = Path(output) if out_dir is None and output not in (None, "-") else (out_dir or Path()) / f"positions.{fmt}"
    return [f"gnss-solve: {fmt} holds one method: {len(split)} files, one per method ({', '.join(p.name for p in split)}); "
            f"{asked} itself is not written"]


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


def _stage_figures(outputs: Any, targets: dict[str, Path], files: list[Path], cfg: Any, run: Any,
                   reference: str, progress: Any = None) -> list[tuple[Path, str]]:
    """Draw the run's figures (``--plots``) and the HTML page (``--report``) and stage them;
    ``progress("figures", fraction)`` as each figure is done."""
    from gnss_cli.cli.figures import solve_settings, stage_figures
    from gnss_cli.plots import RUN_FIGURES
    from gnss_cli.plots.html import html_report
    from gnss_cli.plots.run import run_figures

    settings = solve_settings(files, cfg, run.result, reference, run.command)
    title = f"gnss-solve: {Path(files[0]).name}"
    figures = run_figures(run.result, run.reference_ecef_m, cfg.elevation_mask_deg,
                          (cfg.alert_limit_h_m, cfg.alert_limit_v_m), progress)
    return stage_figures(outputs, targets, figures, RUN_FIGURES, lambda figs: html_report(title, figs, run.summary, settings),
                         progress)


def main() -> None:
    """Console entry point of ``gnss-solve``."""
    single_blas_thread()
    without_dask()
    try:
        run_app(app, "gnss-solve")
    except SystemExit as done:
        _exit_now(done.code)


def _exit_now(code: object) -> NoReturn:
    """End the process with exit status ``code``, skipping the interpreter's teardown.

    What it buys, measured (2-core machine, load 2-3, medians of 9 runs): the teardown of the
    imported libraries (numpy, pandas, xarray, scipy.special, typer) and of the run's objects
    takes 0.30 s of wall time after the 24 h ESBC run and 0.34 s after the 120-epoch rtklib-0759
    run. On ESBC that is 0.07 of the whole-run ratio to rnx2rtkp (``benchmarks/bench_full_run.py``,
    target <= 0.6): 0.56 with this exit, 0.65 with the normal one (lowest of 10 interleaved pairs).

    By now every output is written, renamed into place and closed (or, after an error,
    removed). The standard streams are flushed first (a reader that closed the pipe is not an
    error).
    """
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):
            pass
    os._exit(code if isinstance(code, int) else (0 if code is None else 1))


def _writes_parquet(fmt: Optional[str], output: Optional[str]) -> bool:
    """Whether the positions may be written as Parquet (``--format parquet`` or ``-o *.parquet``)."""
    if fmt is not None:
        return fmt.lower() == "parquet"
    return output not in (None, "-") and Path(str(output)).suffix.lower() == ".parquet"


if __name__ == "__main__":
    main()
