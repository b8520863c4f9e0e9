"""``gnss-identify``: identify a kernel (behavioral model) from a trajectory and predict it.

Reads the positions CSV written by ``gnss-solve`` (or any CSV with a ``time`` column and ECEF
``x_m, y_m, z_m`` or ``x, y, z`` in metres), converts the positions to local East-North-Up
with the origin at the **first sample**, identifies a lag-``L`` kernel by STLS or WTLS on the
first ``--train`` samples, and writes CSV rows ``kind = fit`` (the corrected trajectory) and
``kind = predicted`` (the continuation by the kernel) to stdout or ``-o``. The model goes to
``--model-out`` as JSON (coefficients, order, poles, misfit, iterations, status, origin).

Everything here is a thin shell over :mod:`gnss_cli.io.trajectory`,
:mod:`gnss_cli.pipeline.identification` and :func:`gnss_cli.report.identification_table`; exit codes follow
:mod:`gnss_cli.errors` (2 usage, 4 bad input file, 5 no solution).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Optional

import typer

from gnss_cli.cli.exits import run_app
from gnss_cli.errors import UsageError
from gnss_cli.io.trajectory import read_trajectory
from gnss_cli.pipeline.identification import identify_trajectory
from gnss_cli.report import IDENTIFICATION_COLUMNS, identification_table

app = typer.Typer(add_completion=False, help=__doc__.split("\n\n")[0])

CSV_COLUMNS = IDENTIFICATION_COLUMNS


@app.command()
def identify(
    trajectory: Path = typer.Argument(..., help="Positions CSV (gnss-solve output or time,x_m,y_m,z_m)."),
    lag: int = typer.Option(3, "--lag", help="Kernel lag L (>= 1)."),
    order: Optional[int] = typer.Option(None, "--order", help="Hankel rank (full structure); default 3*lag."),
    method: str = typer.Option("stls", "--method", help="stls (structured) or wtls (unstructured SVD)."),
    structure: str = typer.Option("full", "--structure", help="full (general kernel) or shared (r(z) I_3)."),
    train: Optional[int] = typer.Option(None, "--train", help="Identify on the first K samples (default: all)."),
    predict: Optional[int] = typer.Option(None, "--predict", help="Predict N epochs after the training samples (default: the rest of the file)."),
    source_method: Optional[str] = typer.Option(None, "--source-method", help="Method rows to use when the CSV holds several."),
    model_out: Optional[Path] = typer.Option(None, "--model-out", help="Write the model as JSON."),
    output: str = typer.Option("-", "-o", "--output", help="Output CSV ('-' = stdout)."),
    debug: bool = typer.Option(False, "--debug", help="Tracebacks for internal errors."),
) -> None:
    """Identify a lag-L kernel in local ENU (origin: the first sample), write fit and prediction CSV."""
    if method not in ("stls", "wtls"):
        raise UsageError(f"--method: expected stls or wtls, received {method!r}")
    if structure not in ("full", "shared"):
        raise UsageError(f"--structure: expected full or shared, received {structure!r}")
    if lag < 1:
        raise UsageError(f"--lag: expected an integer >= 1, received {lag}")
    traj = read_trajectory(trajectory, source_method)
    ident = identify_trajectory(traj, lag, order, method, structure, train, predict)
    table, model, res = identification_table(ident), ident.model_record(), ident.result
    if model_out is not None:
        model_out.write_text(json.dumps(model, indent=2) + "\n")
    text = table.to_csv(index=False, float_format="%.4f", lineterminator="\n")
    if output == "-":
        sys.stdout.write(text)
    else:
        Path(output).write_text(text)
    sys.stderr.write(f"gnss-identify: {method} lag {lag}: misfit {res.misfit:.6g} m^2, {res.iterations} iterations, {res.message}\n")


def main(argv: list[str] | None = None) -> None:
    """Console entry point of ``gnss-identify``."""
    run_app(app, "gnss-identify", argv)


if __name__ == "__main__":  # pragma: no cover
    main()
