"""``gnss-identify``: identify a kernel (behavioral model) from a trajectory and predict it.

Reads the positions CSV written by ``gnss-solve`` (or any CSV with a ``time`` column and ECEF
``x_m, y_m, z_m`` or ``x, y, z`` in metres), converts the positions to local East-North-Up
with the origin at the **first sample**, identifies a lag-``L`` kernel by STLS or WTLS on the
first ``--train`` samples, and writes CSV rows ``kind = fit`` (the corrected trajectory) and
``kind = predicted`` (the continuation by the kernel) to stdout or ``-o``. The model goes to
``--model-out`` as JSON (coefficients, order, poles, misfit, iterations, status, origin).

Everything here is a thin shell over :mod:`gnss_cli.io.trajectory`,
:mod:`gnss_cli.pipeline.identification` and :func:`gnss_cli.report.identification_table`; exit codes follow
:mod:`gnss_cli.errors` (2 usage, 3 bad option value, 4 bad input file, 5 no solution, 6 output not writable).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Optional

import typer

from gnss_cli.cli.exits import HELP_OPTIONS, run_app, version_callback, write_stdout
from gnss_cli.cli.help import PanelCommand
from gnss_cli.errors import ConfigError

EXAMPLES = """\
Examples:
  A lag-3 kernel shared by East, North and Up (--structure shared: it fits
  flights where a full kernel is singular) from the first 200 stls fixes of
  gnss-solve's flight.csv example, then the next 60 epochs predicted:
    gnss-identify flight.csv --source-method stls --lag 3 --structure shared \\
        --train 200 --predict 60 -o predicted.csv --model-out model.json
"""
"""The epilog of ``gnss-identify --help`` (``tests/cli/test_help.py`` runs every example)."""

app = typer.Typer(add_completion=False, context_settings=HELP_OPTIONS, rich_markup_mode=None, help=__doc__.split("\n\n")[0])


@app.command(cls=PanelCommand, epilog=EXAMPLES)
def identify(
    trajectory: Path = typer.Argument(..., metavar="TRAJECTORY", rich_help_panel="Inputs", help="Positions CSV (gnss-solve output or time,x_m,y_m,z_m).", show_default=False),
    lag: int = typer.Option(3, "--lag", metavar="L", rich_help_panel="Model", help="Kernel lag L (>= 1)."),
    order: Optional[int] = typer.Option(None, "--order", metavar="N", rich_help_panel="Model", help="Hankel rank (full structure).", show_default="3 L"),
    method: str = typer.Option("stls", "--method", metavar="METHOD", rich_help_panel="Model", help="stls (structured) or wtls (unstructured SVD)."),
    structure: str = typer.Option("full", "--structure", metavar="KIND", rich_help_panel="Model", help="full (general kernel) or shared (r(z) I_3)."),
    train: Optional[int] = typer.Option(None, "--train", metavar="K", rich_help_panel="Model", help="Identify on the first K samples.", show_default="all"),
    predict: Optional[int] = typer.Option(None, "--predict", metavar="N", rich_help_panel="Model", help="Predict N epochs after the training samples.", show_default="the rest of the file"),
    source_method: Optional[str] = typer.Option(None, "--source-method", metavar="METHOD", rich_help_panel="Inputs", help="Method rows to use when the CSV holds several.", show_default="the only one"),
    model_out: Optional[Path] = typer.Option(None, "--model-out", metavar="FILE", rich_help_panel="Output", help="Write the model as JSON.", show_default="none"),
    output: str = typer.Option("-", "-o", "--output", metavar="FILE", rich_help_panel="Output", help="Output CSV ('-' = stdout).", show_default="stdout"),
    plots: Optional[Path] = typer.Option(None, "--plots", metavar="DIR", rich_help_panel="Output", help="Write identification.png (fit and prediction against the data, E/N/U and track) into this folder; needs matplotlib (pip install 'gnss-solve[plot]').", show_default="none"),
    quiet: bool = typer.Option(False, "--quiet", "-q", rich_help_panel="Run", help="No summary on stderr."),
    debug: bool = typer.Option(False, "--debug", rich_help_panel="Run", help="Tracebacks for internal errors."),
    version: bool = typer.Option(False, "--version", callback=version_callback("gnss-identify"), is_eager=True,
                                 rich_help_panel="Run", help="Print the version and exit."),
) -> None:
    """Identify a lag-L kernel in local ENU (origin: the first sample), write fit and prediction CSV."""
    if method not in ("stls", "wtls"):
        raise ConfigError(f"--method: expected stls or wtls, received {method!r}")
    if structure not in ("full", "shared"):
        raise ConfigError(f"--structure: expected full or shared, received {structure!r}")
    if lag < 1:
        raise ConfigError(f"--lag: expected an integer >= 1, received {lag}")
    from gnss_cli.cli.output import OutputSet
    from gnss_cli.io.trajectory import read_trajectory
    from gnss_cli.pipeline.identification import identify_trajectory
    from gnss_cli.report import identification_table, to_csv_text

    with OutputSet([trajectory]) as outputs:
        if model_out is not None:
            outputs.add(model_out, "--model-out")
        if output != "-":
            outputs.add(Path(output), "-o/--output")
        from gnss_cli.cli.figures import register_figures
        from gnss_cli.plots import IDENTIFY_FIGURES

        figure_targets = register_figures(outputs, plots, None, list(IDENTIFY_FIGURES))
        traj = read_trajectory(trajectory, source_method)
        ident = identify_trajectory(traj, lag, order, method, structure, train, predict)
        if figure_targets:
            from gnss_cli.cli.figures import stage_figures
            from gnss_cli.plots.track import figure_identification

            figure = figure_identification(ident, traj.t_s, traj.xyz_m)
            stage_figures(outputs, figure_targets, {"identification": figure}, IDENTIFY_FIGURES)
        res = ident.result
        text = to_csv_text(identification_table(ident))
        if model_out is not None:
            outputs.write_text(model_out, json.dumps(ident.model_record(), indent=2) + "\n")
        if output != "-":
            outputs.write_text(Path(output), text)
    if output == "-":
        write_stdout(text)
    if not quiet:
        sys.stderr.write(f"gnss-identify: {method} lag {lag}: misfit {res.misfit:.6g} m^2, {res.iterations} iterations, {res.message}\n")


def main(argv: list[str] | None = None) -> None:
    """Console entry point of ``gnss-identify``."""
    run_app(app, "gnss-identify", argv)


if __name__ == "__main__":  # pragma: no cover
    main()
