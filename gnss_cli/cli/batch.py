"""``gnss-batch OBS... --nav NAV... --out DIR [--jobs N | --scheduler tcp://HOST:PORT] [options]``.

Many observation files in one run, one task per file, each solved exactly as ``gnss-solve``
solves it (every processing and reference option of gnss-solve applies to each file).
Navigation files are matched to each observation file by time (the records' toc span
against the file's first and last epoch; several may match). Results: ``DIR/positions/``,
a Parquet dataset partitioned by station and GPS day, ``DIR/files.csv`` (one row per input:
status, epochs, solved, 3D RMS with a reference, seconds, error) and ``DIR/summary.csv``,
written together or not at all; ``--plots DIR`` / ``--report FILE.html`` add the network's
figures and one page with a row per station. A failing file never stops the others; the exit code is 0
when every file was solved, else the code of the first failed file in the order given.
Progress: one line per finished file on stderr (with ``-q`` only the failed files' lines and
the closing count of failures: quiet silences progress, never errors).
"""

from __future__ import annotations

import glob
import os
import sys
import time
from dataclasses import replace
from pathlib import Path
from typing import Any, Optional

import typer

from gnss_cli.cli.exits import HELP_OPTIONS, run_app, single_blas_thread, version_callback, without_dask
from gnss_cli.cli.help import PanelCommand
from gnss_cli.cli.options import (
    AlertLimit, Config, Debug, ElevationMask, Environment, Exclude, Integrity, Iono, Kernel, KfModel, KfOutput, Lag, Measurements, Method, Motion,
    OldModel, OldSmoother, Order, Quiet, Reference, ReferenceCsv, ReferencePos, ReferenceSinex, Robust, SnrMask, Systems,
    TimeSystem, Tropo, Window, check_method_flags, check_old_spellings, check_reference_options, reference_inputs,
    run_config,
)
from gnss_cli.errors import ConfigError, GnssError, InputFileNotFoundError, RinexFormatError, UsageError

PROG = "gnss-batch"

EXAMPLES = """\
Examples:
  Every obs.rnx one folder down, each with the nav.rnx files that cover it:
    gnss-batch '*/obs.rnx' --nav '*/nav.rnx' --out network

  Two files on two local workers, each solved by WLS and the smoother:
    gnss-batch static/obs.rnx flight/obs.rnx --nav static/nav.rnx \\
        --nav flight/nav.rnx --out smoothed -j 2 --method wls,smoother
"""
"""The epilog of ``gnss-batch --help`` (``tests/cli/test_help.py`` runs every example)."""

app = typer.Typer(add_completion=False, help=__doc__, context_settings=HELP_OPTIONS, rich_markup_mode=None)


@app.command(cls=PanelCommand, epilog=EXAMPLES)
def batch(
    files: Optional[list[str]] = typer.Argument(None, help="RINEX observation files or quoted glob patterns ('obs/*.crx.gz'); navigation files among them count as --nav.", metavar="OBS...", show_default=False, rich_help_panel="Inputs"),
    nav: Optional[list[str]] = typer.Option(None, "--nav", metavar="FILE", rich_help_panel="Inputs", help="Navigation file or quoted glob pattern; repeat --nav for more. Each OBS gets the ones whose records cover its epochs.", show_default="none"),
    out: Optional[Path] = typer.Option(None, "--out", metavar="DIR", rich_help_panel="Output", show_default=False, help="Output folder: positions/ (Parquet, partitioned by station and day), files.csv, summary.csv."),
    jobs: Optional[int] = typer.Option(None, "--jobs", "-j", metavar="N", rich_help_panel="Run", help="Local worker processes (one file per task).", show_default="all cores"),
    scheduler: Optional[str] = typer.Option(None, "--scheduler", metavar="URL", rich_help_panel="Run", help="Run the tasks on this Dask distributed scheduler (tcp://HOST:PORT) instead; needs pip install 'gnss-solve[cluster]'.", show_default="none"),
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
    time_system: TimeSystem = None,
    lag: Lag = None,
    kernel: Kernel = None,
    order: Order = None,
    window: Window = None,
    motion: Motion = None,
    measurements: Measurements = None,
    kf_model: KfModel = None,
    kf_output: KfOutput = None,
    model: OldModel = None,
    smoother: OldSmoother = None,
    integrity: Integrity = None,
    environment: Environment = None,
    alert_limit: AlertLimit = None,
    robust: Robust = None,
    exclude: Exclude = None,
    snr_mask: SnrMask = None,
    plots: Optional[Path] = typer.Option(None, "--plots", metavar="DIR", rich_help_panel="Output", help="Write the network's figures (PNG: per-station RMS and mean GDOP, station map) into this folder; needs matplotlib (pip install 'gnss-solve[plot]').", show_default="none"),
    report: Optional[Path] = typer.Option(None, "--report", metavar="FILE", rich_help_panel="Output", help="Write one self-contained HTML page for the network: settings, a row per station, figures; needs matplotlib.", show_default="none"),
    print_config: bool = typer.Option(False, "--print-config", rich_help_panel="Run", help="Print the effective configuration (packaged defaults < --config < flags) as TOML and exit."),
    quiet: Quiet = False,
    debug: Debug = False,
    version: bool = typer.Option(False, "--version", callback=version_callback(PROG), is_eager=True, rich_help_panel="Run", help="Print the version and exit."),
) -> int:
    """Solve every observation file with the navigation files that cover it; write one dataset."""
    values = dict(locals())
    check_old_spellings(values)
    if print_config:
        from gnss_cli.config.toml import config_toml

        sys.stdout.write(config_toml(run_config(config, values)))
        return 0
    if not files:
        raise UsageError("expected OBS...: one or more observation files or quoted glob patterns")
    if out is None:
        raise UsageError("--out DIR: the output folder is required")
    if scheduler is None:
        without_dask()  # (before xarray is imported; the Dask runner needs dask)
    check_reference_options(values)
    if jobs is not None and scheduler is not None:
        raise UsageError("give --jobs or --scheduler, not both (the cluster decides how many tasks run at once)")
    cfg = run_config(config, values)
    check_method_flags(cfg, values)
    if jobs is not None and jobs < 1:
        raise ConfigError(f"--jobs: expected an integer >= 1; received {jobs}")
    _check_references(values)
    obs_paths, nav_paths = collect_inputs(files, nav or [])
    from gnss_cli.cli.batch_output import PositionsDataset
    from gnss_cli.cli.batch_task import BatchSettings
    from gnss_cli.cli.output import OutputSet

    with OutputSet([*obs_paths, *nav_paths, *reference_inputs(values)]) as outputs:
        if out.exists() and not out.is_dir():
            from gnss_cli.errors import OutputError

            raise OutputError(f"{out}: cannot write output (not a folder)")
        csv_targets = {name: outputs.add(out / f"{name}.csv", "--out") for name in ("files", "summary")}
        from gnss_cli.cli.figures import register_figures
        from gnss_cli.plots import NETWORK_FIGURES

        figure_targets = register_figures(outputs, plots, report, list(NETWORK_FIGURES))
        dataset = PositionsDataset(outputs.stage_folder(out / "positions", "--out"))
        from gnss_cli.cli.batch_runner import forks_workers, open_runner
        from gnss_cli.parallel import cores

        # forked workers start with what the parent has loaded: the navigation reader first;
        # spawned ones (elsewhere) import while the parent reads the navigation files
        navs = nav_spans(nav_paths, quiet) if scheduler is None and forks_workers() else None
        runner = open_runner(jobs if jobs is not None else cores(), scheduler, len(obs_paths))
        finished = False
        try:
            navs = navs if navs is not None else nav_spans(nav_paths, quiet)
            if runner.parallel:  # the files are the parallelism: a worker solves its file in one process
                cfg = replace(cfg, processes=1)  # (a forked helper of a worker would outlive its SIGTERM)
            settings = BatchSettings(cfg, reference, reference_sinex, reference_csv, reference_pos, navs)
            results = _run_all(runner.results([str(p) for p in obs_paths], settings), len(obs_paths), dataset, quiet)
            finished = True
        finally:
            runner.close(finished)
        dataset.finish()
        written = _write_outputs(outputs, {**csv_targets, **figure_targets}, dataset, results, settings, obs_paths, nav_paths)
    return _finish(results, out, quiet, written)


def _write_outputs(outputs: Any, targets: dict[str, Path], dataset: Any, results: list[Any], batch: Any,
                   obs_paths: list[Path], nav_paths: list[Path]) -> list[tuple[Path, str]]:
    """Stage files.csv, summary.csv and the network's figures and page; what was written (the
    dataset, already staged, first)."""
    from gnss_cli.cli.exits import command_line
    from gnss_cli.cli.tables import run_settings

    given = [v for v in (batch.reference, batch.reference_sinex, batch.reference_csv, batch.reference_pos) if v is not None]
    settings = run_settings(batch.config, str(given[0]) if given else "none")
    written = [(dataset.folder.parent / "positions", dataset.description())]
    written += _write_tables(outputs, targets, results, command_line(), settings)
    figures = {k: v for k, v in targets.items() if k not in ("files", "summary")}
    if figures:
        written += _stage_network(outputs, figures, results, command_line(), settings, obs_paths, nav_paths)
    return written


def _check_references(values: dict[str, Any]) -> None:
    """The reference options are the same for every file: check them once, before any work."""
    if values.get("reference") is not None:
        from gnss_cli.io.reference import parse_reference

        parse_reference(values["reference"])
    for name in ("reference_sinex", "reference_csv", "reference_pos"):
        path = values.get(name)
        if path is not None and not Path(path).is_file():
            flag = "--" + name.replace("_", "-")
            raise InputFileNotFoundError(f"{flag}: {path}: {'not a regular file' if Path(path).exists() else 'no such file'}")


def _expand(patterns: list[str], what: str) -> list[Path]:
    """Paths and glob patterns (``*``, ``?``, ``[...]``, ``**``) -> paths, in order, each once."""
    out: list[Path] = []
    for pattern in patterns:
        if any(c in pattern for c in "*?[") and not Path(pattern).exists():
            matches = sorted(glob.glob(os.path.expanduser(pattern), recursive=True))
            if not matches:
                raise InputFileNotFoundError(f"{pattern}: no {what} file matches this pattern")
            out += [Path(m) for m in matches]
        else:
            out.append(Path(pattern))
    seen: set[str] = set()
    unique = []
    for p in out:
        key = os.path.realpath(p)
        if key not in seen:
            seen.add(key)
            unique.append(p)
    return unique


def collect_inputs(files: list[str], navs: list[str]) -> tuple[list[Path], list[Path]]:
    """Observation and navigation files from the arguments.

    Globs are expanded here too (quoted patterns). A navigation file among the OBS arguments
    is used as a navigation file (``--nav nav/*.rnx`` unquoted leaves all but the first of
    them among the OBS). An OBS argument that cannot be read stays an observation file and
    fails as its task. A missing navigation file is an error before anything starts.

    Raises
    ------
    InputFileNotFoundError
        A pattern matches nothing, or a ``--nav`` file does not exist.
    UsageError
        No observation file, or no navigation file at all.
    """
    from gnss_cli.io.rinex import rinex_info

    obs_paths, nav_paths = [], _expand(navs, "navigation")
    for p in nav_paths:
        if not p.is_file():
            raise InputFileNotFoundError(f"--nav: {p}: {'not a regular file' if p.exists() else 'no such file'}")
    for p in _expand(files, "observation"):
        try:
            is_nav = rinex_info(p).kind == "nav"
        except GnssError:
            is_nav = False
        (nav_paths if is_nav else obs_paths).append(p)
    if not obs_paths:
        raise UsageError("expected at least one observation file (OBS...)")
    if not nav_paths:
        raise UsageError("expected navigation files: give --nav NAV (a file or a quoted glob pattern)")
    return obs_paths, nav_paths


def nav_spans(nav_paths: list[Path], quiet: bool) -> tuple[tuple[str, float, float], ...]:
    """``(path, first toc, last toc)`` of every readable navigation file; a warning for the others.

    Raises
    ------
    RinexFormatError
        Not one navigation file can be read (the first one's error).
    """
    from gnss_cli.io.catalog import nav_toc_span

    spans, errors = [], []
    for p in nav_paths:
        try:
            spans.append((str(p), *nav_toc_span(p)))
        except GnssError as exc:
            errors.append(exc)
            if not quiet:
                sys.stderr.write(f"{PROG}: warning: navigation file not used: {' '.join(str(exc).split())}\n")
    if not spans:
        raise RinexFormatError(f"no usable navigation file ({errors[0]})")
    return tuple(spans)


def _run_all(stream: Any, total: int, dataset: Any, quiet: bool) -> list[Any]:
    """Store each result as it arrives (its rows into the dataset) and report it on stderr (with
    ``quiet``, only a failed one)."""
    t0 = time.perf_counter()
    results = []
    try:
        for result in stream:
            dataset.add(result)
            results.append(result)
            if not quiet or result.status != "ok":
                sys.stderr.write(_progress_line(result, len(results), total, time.perf_counter() - t0))
                sys.stderr.flush()
    finally:
        stream.close()
    return results


def _progress_line(result: Any, done: int, total: int, elapsed_s: float) -> str:
    head = f"{PROG}: [{elapsed_s:6.1f} s] {done}/{total} {Path(result.obs_path).name}:"
    if result.status != "ok":
        return f"{head} failed (exit {result.exit_code}): {result.error}\n"
    line = f"{head} ok, {result.solved}/{result.epochs} epochs solved ({result.method})"
    if result.rms_3d_m == result.rms_3d_m:  # not NaN: a reference was given
        line += f", 3D RMS {result.rms_3d_m:.3f} m"
    if result.warnings:
        line += f", {len(result.warnings)} warning(s) in files.csv"
    # a reference that misses the epochs voids the file's errors: said here too, not only in files.csv
    notes = "".join(f"{PROG}: warning: {Path(result.obs_path).name}: {w}\n" for w in result.warnings
                    if w.startswith("reference "))
    return f"{line}, {result.seconds:.1f} s\n{notes}"


def _write_tables(outputs: Any, targets: dict[str, Path], results: list[Any], command: str,
                  settings: dict[str, str]) -> list[tuple[Path, str]]:
    """Stage ``files.csv`` and ``summary.csv`` (the command line and the settings first); what was written."""
    from gnss_cli.cli.batch_output import files_table, summary_table
    from gnss_cli.cli.tables import count, with_run_columns
    from gnss_cli.report import to_csv_text

    files, summary = files_table(results), summary_table(results)
    outputs.write_text(targets["files"], to_csv_text(files))
    outputs.write_text(targets["summary"], to_csv_text(with_run_columns(summary, command, settings)))
    return [(targets["files"], count(len(files), "row") + ", one per observation file"),
            (targets["summary"], count(len(summary), "row") + ", one per file and method")]


def _stage_network(outputs: Any, targets: dict[str, Path], results: list[Any], command: str, settings: dict[str, str],
                   obs_paths: list[Path], nav_paths: list[Path]) -> list[tuple[Path, str]]:
    """Draw the network's figures (``--plots``) and its page (``--report``: a row per station
    and method first, every summary row folded) and stage them."""
    from gnss_cli.cli.batch_output import network_table, summary_table
    from gnss_cli.cli.figures import stage_figures
    from gnss_cli.plots import NETWORK_FIGURES
    from gnss_cli.plots.html import html_report
    from gnss_cli.plots.network import network_figures

    summary = summary_table(results)
    table = network_table(summary)
    ok = sum(r.status == "ok" for r in results)
    page = {"command": command, "observation files": f"{len(obs_paths)} ({ok} solved)",
            "navigation files": ", ".join(str(p) for p in nav_paths), "stations": str(len(set(table["station"]))),
            **settings}
    return stage_figures(outputs, targets, network_figures(table), NETWORK_FIGURES,
                         lambda figs: html_report(f"{PROG}: {len(set(table['station']))} stations", figs, summary, page,
                                                  key=table))


def _finish(results: list[Any], out: Path, quiet: bool, written: list[tuple[Path, str]]) -> int:
    """The closing lines (the files solved, then the outputs written) and the exit code: 0, or
    that of the first failed file in input order. With ``quiet`` only the count line, and only
    when a file failed."""
    from gnss_cli.cli.tables import written_lines

    failures = sorted((r for r in results if r.status != "ok"), key=lambda r: r.index)
    if not quiet or failures:
        ok = len(results) - len(failures)
        tail = f", {len(failures)} failed (errors in {out / 'files.csv'})" if failures else ""
        sys.stderr.write(f"{PROG}: {ok} of {len(results)} files solved{tail}; results in {out}\n")
    if not quiet:
        sys.stderr.write("".join(f"{line}\n" for line in written_lines(written, PROG)))
    return failures[0].exit_code if failures else 0


def main() -> None:
    """Console entry point of ``gnss-batch``."""
    single_blas_thread()
    run_app(app, PROG)


if __name__ == "__main__":
    main()
