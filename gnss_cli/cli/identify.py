"""``gnss-identify``: identify a kernel (behavioral model) from a trajectory and predict it.

Reads the positions CSV written by ``gnss-solve`` (or any CSV with a ``time`` column and ECEF
``x_m, y_m, z_m`` or ``x, y, z`` in metres), converts the positions to local East-North-Up
with the origin at the **first sample**, identifies a lag-``L`` kernel by STLS or WTLS on the
first ``--train`` samples, and writes CSV rows ``kind = fit`` (the corrected trajectory) and
``kind = predicted`` (the continuation by the kernel) to stdout or ``-o``. The model goes to
``--model-out`` as JSON (coefficients, order, poles, misfit, iterations, status, origin).

Everything here is a thin shell over :mod:`gnss_cli.behavior`; exit codes follow
:mod:`gnss_cli.errors` (2 usage, 4 bad input file, 5 no solution).
"""

from __future__ import annotations

import json
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import numpy as np
import pandas as pd
import typer
from numpy.typing import NDArray

from gnss_cli.behavior import StlsResult, stls, wtls
from gnss_cli.cli.exits import HELP_OPTIONS, run_app, version_callback, write_stdout
from gnss_cli.errors import ConfigError, InputError, InputFileNotFoundError, NoSolutionError, UsageError
from gnss_cli.gnss.frames import ecef2enu, enu2ecef
from gnss_cli.gnss.time import datetime2gps_s, gps_s2datetime, gps_s2week_tow

app = typer.Typer(add_completion=False, context_settings=HELP_OPTIONS, rich_markup_mode=None, help=__doc__.split("\n\n")[0])

#: Relative tolerance on the sampling interval (uniform sampling is required).
STEP_RTOL = 1e-6
CSV_COLUMNS = ["time", "gps_week", "tow_s", "x_m", "y_m", "z_m", "e_m", "n_m", "u_m", "kind"]


@dataclass(frozen=True, slots=True)
class Trajectory:
    """A uniformly sampled ECEF trajectory read from CSV.

    Attributes
    ----------
    t_s : ndarray (T,)
        Seconds since the GPS epoch (ISO input) or the input's own seconds (numeric input).
    is_gps_time : bool
        Whether ``t_s`` came from ISO-8601 GPS time stamps.
    xyz_m : ndarray (T, 3)
        ECEF positions, metres.
    dt_s : float
        Sampling interval, seconds.
    """

    t_s: NDArray[np.float64]
    is_gps_time: bool
    xyz_m: NDArray[np.float64]
    dt_s: float


def read_trajectory(path: Path, source_method: str | None = None) -> Trajectory:
    """Read and validate a trajectory CSV.

    Raises
    ------
    InputFileNotFoundError
        The file does not exist.
    InputError
        Missing columns, several methods without ``source_method``, NaN positions,
        fewer than 2 samples, non-increasing or non-uniform time steps.
    """
    if not path.is_file():
        raise InputFileNotFoundError(f"{path}: no such file")
    try:
        frame = pd.read_csv(path)
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: not a readable CSV file ({exc})") from None
    cols = {c.strip(): c for c in frame.columns}
    if "time" not in cols:
        raise InputError(f"{path}: expected a 'time' column, found {list(frame.columns)}")
    names = next((n for n in (["x_m", "y_m", "z_m"], ["x", "y", "z"]) if all(c in cols for c in n)), None)
    if names is None:
        raise InputError(f"{path}: expected ECEF columns x_m,y_m,z_m (or x,y,z), found {list(frame.columns)}")
    if "method" in cols:
        methods = sorted(str(m) for m in frame[cols["method"]].dropna().unique())
        if source_method is not None:
            if source_method not in methods:
                raise InputError(f"{path}: --source-method {source_method!r} not in the file's methods {methods}")
            frame = frame[frame[cols["method"]] == source_method]
        elif len(methods) > 1:
            raise InputError(f"{path}: holds several methods {methods}; choose one with --source-method")
    xyz = frame[[cols[n] for n in names]].to_numpy(dtype=np.float64, na_value=np.nan)
    if xyz.shape[0] < 2:
        raise InputError(f"{path}: expected at least 2 samples, found {xyz.shape[0]}")
    bad = ~np.all(np.isfinite(xyz), axis=1)
    if np.any(bad):
        raise InputError(f"{path}: {int(bad.sum())} rows have missing or NaN positions (first at data row {int(np.argmax(bad)) + 1}); split the trajectory at gaps")
    raw_t = frame[cols["time"]]
    numeric = pd.to_numeric(raw_t, errors="coerce")
    if numeric.notna().all():
        t_s, is_gps = numeric.to_numpy(dtype=np.float64), False
    else:
        try:
            stamps = pd.to_datetime(raw_t, format="ISO8601").to_numpy(dtype="datetime64[ns]")
        except (ValueError, TypeError):
            raise InputError(f"{path}: column 'time' is neither seconds nor ISO-8601 time stamps") from None
        t_s, is_gps = datetime2gps_s(stamps), True
    steps = np.diff(t_s)
    dt = float(np.median(steps))
    if not dt > 0 or np.any(steps <= 0):
        raise InputError(f"{path}: time stamps must increase strictly")
    worst = float(np.max(np.abs(steps - dt)))
    if worst > STEP_RTOL * dt + 1e-6:
        raise InputError(f"{path}: non-uniform time steps (median {dt:g} s, off by up to {worst:g} s); split the trajectory at gaps")
    return Trajectory(t_s, is_gps, xyz, dt)


def identify_trajectory(
    traj: Trajectory, lag: int, order: int | None, method: str, structure: str, train: int | None,
    predict: int | None,
) -> tuple[pd.DataFrame, dict[str, object], StlsResult]:
    """Identify a kernel on the first ``train`` samples (ENU, origin = first sample) and predict.

    Returns
    -------
    table, model, result
        The CSV rows, the JSON model and the identification result.
    """
    n_t = traj.xyz_m.shape[0]
    k = n_t if train is None else train
    if not 1 <= k <= n_t:
        raise UsageError(f"--train: expected 1..{n_t} samples, received {train}")
    if k < lag + 2:
        raise InputError(f"too few samples for lag {lag}: {k} training samples, at least lag + 2 = {lag + 2} needed")
    n_pred = (n_t - k) if predict is None else predict
    if n_pred < 0:
        raise UsageError(f"--predict: expected a non-negative number of epochs, received {predict}")
    origin = traj.xyz_m[0]
    enu = ecef2enu(traj.xyz_m[:k], origin)
    solver = stls if method == "stls" else wtls
    res = solver(enu, lag, order, structure=structure)
    if not np.isfinite(res.misfit):
        raise NoSolutionError(f"{method}: {res.message}")
    fit = res.w_hat
    rows_enu = [fit]
    kinds = ["fit"] * k
    if n_pred > 0:
        try:
            rows_enu.append(res.kernel.predict(fit[-lag:], n_pred))
        except UsageError as exc:
            raise NoSolutionError(f"cannot predict with the identified kernel: {exc}") from None
        kinds += ["predicted"] * n_pred
    all_enu = np.vstack(rows_enu)
    times = traj.t_s[0] + traj.dt_s * np.arange(k + n_pred)
    times[:k] = traj.t_s[:k]
    xyz = enu2ecef(all_enu, origin)
    table = pd.DataFrame({"x_m": xyz[:, 0], "y_m": xyz[:, 1], "z_m": xyz[:, 2],
                          "e_m": all_enu[:, 0], "n_m": all_enu[:, 1], "u_m": all_enu[:, 2], "kind": kinds})
    if traj.is_gps_time:
        week, tow = gps_s2week_tow(times)
        iso = np.datetime_as_string(gps_s2datetime(times), unit="ms")
        table.insert(0, "tow_s", np.round(tow, 3))
        table.insert(0, "gps_week", week)
        table.insert(0, "time", iso)
    else:
        table.insert(0, "tow_s", np.nan)
        table.insert(0, "gps_week", pd.array([None] * len(times), dtype="Int64"))
        table.insert(0, "time", times)
    try:
        poles = [[float(p.real), float(p.imag)] for p in res.kernel.poles()]
    except UsageError:
        poles = []
    model = {
        "method": method,
        "structure": structure,
        "lag": res.kernel.lag,
        "order": res.kernel.order,
        "rows": res.kernel.p,
        "variables": ["e_m", "n_m", "u_m"],
        "coefficients": res.kernel.R.tolist(),
        "coefficients_layout": "R = [R_0 R_1 ... R_lag], rows x 3(lag+1); sum_k R_k w(t+k) = 0",
        "poles": poles,
        "misfit_m2": res.misfit,
        "iterations": res.iterations,
        "status": res.status.name.lower(),
        "message": res.message,
        "train_samples": k,
        "predicted_samples": n_pred,
        "dt_s": traj.dt_s,
        "enu_origin_ecef_m": origin.tolist(),
        "enu_origin": "first sample of the trajectory",
    }
    return table, model, res


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
    version: bool = typer.Option(False, "--version", callback=version_callback("gnss-identify"), is_eager=True,
                                 help="Print the version and exit."),
) -> None:
    """Identify a lag-L kernel in local ENU (origin: the first sample), write fit and prediction CSV."""
    if method not in ("stls", "wtls"):
        raise ConfigError(f"--method: expected stls or wtls, received {method!r}")
    if structure not in ("full", "shared"):
        raise ConfigError(f"--structure: expected full or shared, received {structure!r}")
    if lag < 1:
        raise ConfigError(f"--lag: expected an integer >= 1, received {lag}")
    from gnss_cli.cli.output import OutputSet

    with OutputSet([trajectory]) as outputs:
        if model_out is not None:
            outputs.add(model_out, "--model-out")
        if output != "-":
            outputs.add(Path(output), "-o/--output")
        traj = read_trajectory(trajectory, source_method)
        table, model, res = identify_trajectory(traj, lag, order, method, structure, train, predict)
        text = table.to_csv(index=False, float_format="%.4f", lineterminator="\n")
        if model_out is not None:
            outputs.write_text(model_out, json.dumps(model, indent=2) + "\n")
        if output != "-":
            outputs.write_text(Path(output), text)
    if output == "-":
        write_stdout(text)
    sys.stderr.write(f"gnss-identify: {method} lag {lag}: misfit {res.misfit:.6g} m^2, {res.iterations} iterations, {res.message}\n")


def main(argv: list[str] | None = None) -> None:
    """Console entry point of ``gnss-identify``."""
    run_app(app, "gnss-identify", argv)


if __name__ == "__main__":  # pragma: no cover
    main()
