"""``gnss-solve OBS NAV [NAV ...] [options]``: RINEX in, positions / errors / DOP tables out.

Data go to stdout (or ``-o FILE`` / ``--out-dir DIR``); progress, warnings and the summary
go to stderr. Exit codes: 0 ok, 1 bug, 2 usage, 3 bad configuration, 4 bad input file,
5 no epoch solved.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path
from typing import Optional

import typer

from gnss_cli.cli.exits import run_app
from gnss_cli.config import load_config
from gnss_cli.errors import ConfigError, UsageError
from gnss_cli.io.reference import parse_reference, reference_from_csv, reference_from_sinex
from gnss_cli.pipeline import process
from gnss_cli.report import (
    dop_table,
    errors_table,
    models_json,
    positions_table,
    summary_table,
    to_csv_text,
    write_atomic,
)

app = typer.Typer(add_completion=False, help=__doc__)


class _Progress:
    """Progress lines on stderr, only when stderr is a terminal and not ``--quiet``."""

    def __init__(self, enabled: bool) -> None:
        self.enabled = enabled and sys.stderr.isatty()
        self.t0 = time.perf_counter()

    def __call__(self, stage: str, fraction: float) -> None:
        if self.enabled:
            sys.stderr.write(f"\r[{time.perf_counter() - self.t0:6.1f} s] {stage:<32} {100 * fraction:5.1f} %")
            sys.stderr.flush()

    def done(self) -> None:
        if self.enabled:
            sys.stderr.write("\n")


@app.command()
def solve(
    files: list[Path] = typer.Argument(..., help="OBS NAV [NAV ...]: a RINEX observation file and one or more navigation files."),
    method: Optional[str] = typer.Option(None, "--method", "-m", help="ls, wls, tls, dls, mtls, stls, wtls, a comma list, or all [config: wls]."),
    systems: Optional[str] = typer.Option(None, "--systems", help="Constellations: comma list of RINEX letters G,E,C,J,R, or all (every system in both OBS and NAV) [config: all]."),
    iono: Optional[str] = typer.Option(None, "--iono", help="klobuchar | iono-free (dual-frequency combination) | none [config: klobuchar]."),
    tropo: Optional[str] = typer.Option(None, "--tropo", help="saastamoinen | none [config: saastamoinen]."),
    elevation_mask: Optional[float] = typer.Option(None, "--elevation-mask", help="Elevation mask, degrees [config: 10]."),
    reference: Optional[str] = typer.Option(None, "--reference", help="Reference position X,Y,Z (ECEF, m) for error columns."),
    reference_sinex: Optional[Path] = typer.Option(None, "--reference-sinex", help="SINEX file; the station is the RINEX marker name."),
    reference_csv: Optional[Path] = typer.Option(None, "--reference-csv", help="Moving reference: CSV with time, x_m, y_m, z_m (e.g. truth.csv)."),
    config: Optional[Path] = typer.Option(None, "--config", help="TOML file of processing options (see configs/default.toml)."),
    output: Optional[str] = typer.Option(None, "-o", "--output", help="Write the positions CSV here ('-' = stdout, the default)."),
    out_dir: Optional[Path] = typer.Option(None, "--out-dir", help="Write positions.csv, errors.csv, dop.csv, summary.csv here."),
    lag: int = typer.Option(0, "--lag", help="Behavioral smoothing lag L (with --method stls, L >= 1): stls rows from sliding-window Hankel STLS of the WLS fixes; 0 = single-epoch methods."),
    model: str = typer.Option("identify", "--model", help="identify | pva | static: kernel identified per window or fixed (with --lag)."),
    kernel: str = typer.Option("shared", "--kernel", help="shared | full: structure of the identified kernel (with --lag)."),
    order: Optional[int] = typer.Option(None, "--order", help="Order of the full identified kernel [3 L]."),
    window: Optional[int] = typer.Option(None, "--window", help="Window length, epochs; 0 = whole segments [15]."),
    model_out: Optional[Path] = typer.Option(None, "--model-out", help="Write the per-window kernels, poles, misfits and statuses here (JSON)."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress, warnings or summary on stderr."),
    debug: bool = typer.Option(False, "--debug", help="Show tracebacks of internal errors."),
) -> None:
    """Solve every epoch of OBS with the broadcast orbits of NAV and write CSV tables."""
    if len(files) < 2:
        raise UsageError("expected OBS NAV [NAV ...]: an observation file and at least one navigation file")
    if sum(r is not None for r in (reference, reference_sinex, reference_csv)) > 1:
        raise UsageError("give one of --reference, --reference-sinex, --reference-csv")
    if output not in (None, "-") and out_dir is not None:
        raise UsageError("give -o/--output or --out-dir, not both")
    overrides: dict[str, object] = {
        "methods": method,
        "iono": iono,
        "tropo": tropo,
        "elevation_mask_deg": elevation_mask,
        "systems": [s.strip().upper() for s in systems.split(",") if s.strip()] if systems else None,
        **_given_on_command_line("smoothing", lag=lag, model=model, kernel=kernel, order=order, window=window),
    }
    cfg = load_config(config, overrides)
    ref = parse_reference(reference) if reference else None
    progress = _Progress(not quiet)
    if cfg.smoothing.lag > 0 and "stls" not in cfg.methods:
        raise UsageError("--lag: needs --method stls (the smoothed rows are the stls rows)")
    result = process(files[0], files[1:], cfg, progress=progress)
    if model_out is not None and cfg.smoothing.lag > 0:
        write_atomic(model_out, models_json(cfg.smoothing, result.models))
    progress.done()
    if reference_sinex is not None:
        if not result.epochs.marker_name:
            raise ConfigError(f"--reference-sinex: {files[0]} has no MARKER NAME to look up")
        ref = reference_from_sinex(reference_sinex, result.epochs.marker_name)
    if reference_csv is not None:
        ref = reference_from_csv(reference_csv, result.epochs.time_gps_s)
    positions = positions_table(result, ref)
    if not quiet:
        for w in result.warnings:
            sys.stderr.write(f"gnss-solve: warning: {w}\n")
    summary = summary_table(result, ref)
    if out_dir is not None:
        write_atomic(out_dir / "positions.csv", to_csv_text(positions))
        if ref is not None:
            write_atomic(out_dir / "errors.csv", to_csv_text(errors_table(positions)))
        write_atomic(out_dir / "dop.csv", to_csv_text(dop_table(positions)))
        write_atomic(out_dir / "summary.csv", to_csv_text(summary))
    elif output not in (None, "-"):
        write_atomic(output, to_csv_text(positions))
    else:
        sys.stdout.write(to_csv_text(positions))
        sys.stdout.flush()
    if not quiet:
        _print_summary(summary, ref is not None)


_SMOOTHING_FLAG_DEFAULTS = {"lag": 0, "model": "identify", "kernel": "shared", "order": None, "window": None}
"""The declared defaults of the smoothing flags: a flag at its default is left to ``--config``."""


def _given_on_command_line(section: str, **values: object) -> dict[str, object]:
    """``{"section.name": value}`` of the flags not at their declared default, so that ``--config``
    and the packaged defaults apply to the others (a flag given as its default value is not
    told apart from an absent one)."""
    return {f"{section}.{k}": v for k, v in values.items() if v != _SMOOTHING_FLAG_DEFAULTS.get(k)}


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
