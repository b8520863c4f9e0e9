"""The paper's kinematic experiment: every estimator on one simulated flight, one table.

A 10 min, 1 Hz simulated flight (GPS only, 1 m zenith white pseudorange noise growing as
1/sin(el), no other error source, seed 3) is solved by ``gnss-solve`` as a user would, five
times, each row labelled with what ran and the measurements it used (from ``summary.csv``):

1. ``--method ls,wls,tls,dls,mtls,stls``: the single-epoch estimators (``stls`` here is the
   single-epoch structured TLS, ``--lag 0``); pseudoranges;
2. ``--method stls --lag 3 --measurements pseudorange``: the paper's method, a shared lag-3
   kernel *identified* from the data in the default whole segments (split where the behavior test
   rejects them), the trajectory solved in its
   behavior from the pseudoranges;
3. ``--method smoother --measurements pseudorange``: a batch smoother with a *fixed* motion model
   (the lag-3 velocity quadrature), nothing identified -- the standard alternative on the same
   information as row 2;
4. ``--method stls --lag 3`` and ``--method smoother`` with their default measurements,
   pseudoranges *and Doppler*: the same pair on more information than rows 1-3.

Two DOP columns, never mixed: ``mean_gdop`` is geometry (single epoch: ``(A^T A)^-1``-type noise
gains; multi-epoch rows: the unit-weight pseudorange geometry of the 15-epoch window under the
row's motion model, Doppler not included); ``mean_gdop_paper`` is the paper's own formula for the
row's method -- TLS rows: its ``(A^T A - s^2 I)^-1 A^T A (A^T A - s^2 I)^-1``, unitless; the
``stls --lag 3`` rows: its STLS GDOP on ``H_{l+1}(w)`` (``gnss_cli/behavior/paper_gdop.py``), a
gain of the identified kernel in 1/m, not a position DOP; empty elsewhere.

All runs use ``--iono none --tropo none`` (the simulated data have neither) and
``--reference-csv truth.csv``. The table is printed and written, with the title, the command and
notes that ``benchmarks/results_page.py`` renders, to ``benchmarks/results/paper_kinematic.json``.

Usage: ``nice python benchmarks/paper_kinematic.py [--seed 3] [--duration 600]`` (about 30 s)
"""

from __future__ import annotations

import argparse
import io
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import pandas as pd

REPO = Path(__file__).resolve().parents[1]
SINGLE_EPOCH = "ls,wls,tls,dls,mtls,stls"
COLUMNS = ("estimator", "measurements", "epochs_solved", "mean_e_m", "mean_n_m", "mean_u_m", "cov_ee_m2", "cov_nn_m2",
           "cov_uu_m2", "rms_e_m", "rms_n_m", "rms_u_m", "rms_3d_m", "mean_gdop", "mean_gdop_paper", "median_gdop_paper")
RUNS: tuple[tuple[str, tuple[str, ...], dict[str, str]], ...] = (
    ("single epoch", ("--method", SINGLE_EPOCH), {"stls": "stls --lag 0"}),
    ("identified", ("--method", "stls", "--lag", "3", "--measurements", "pseudorange"),
     {"stls": "stls --lag 3 --measurements pseudorange"}),
    ("fixed model", ("--method", "smoother", "--measurements", "pseudorange"),
     {"smoother": "smoother --measurements pseudorange"}),
    ("identified, Doppler", ("--method", "stls", "--lag", "3"), {"stls": "stls --lag 3 (pseudorange+doppler)"}),
    ("fixed model, Doppler", ("--method", "smoother"), {"smoother": "smoother (pseudorange+doppler)"}),
)
"""Each ``gnss-solve`` run: its flags and the row label of each method it writes."""


def simulate(out: Path, seed: int, duration_s: int) -> None:
    """Write the flight's obs.rnx, nav.rnx and truth.csv into ``out``."""
    cmd = [sys.executable, "-m", "gnss_cli.cli.simulate", "--trajectory", "standard-flight", "--duration", str(duration_s),
           "--interval", "1", "--systems", "G", "--seed", str(seed), "--errors", "noise", "--noise-sigma", "1",
           "--out-dir", str(out), "--quiet"]
    subprocess.run(cmd, check=True, capture_output=True, cwd=REPO)


def summary(d: Path, *args: str) -> pd.DataFrame:
    """``gnss-solve`` on the flight with ``args``; its summary table."""
    out = d / ("out" + "_".join(a.strip("-").replace(",", "") for a in args))
    cmd = [sys.executable, "-m", "gnss_cli.cli.solve", str(d / "obs.rnx"), str(d / "nav.rnx"), *args,
           "--iono", "none", "--tropo", "none", "--reference-csv", str(d / "truth.csv"), "--out-dir", str(out), "-q"]
    subprocess.run(cmd, check=True, capture_output=True, cwd=REPO)
    table = pd.read_csv(out / "summary.csv")
    positions = pd.read_csv(out / "positions.csv")
    if "gdop_paper" in positions:  # the median beside summary.csv's mean: a few near-degenerate windows dominate the mean
        table["median_gdop_paper"] = table["method"].map(positions.groupby("method")["gdop_paper"].median())
    return table


def _cell(v: object) -> object:
    if isinstance(v, float):
        return None if v != v else float(f"{v:.4g}")
    return v


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=3, help="simulation seed")
    ap.add_argument("--duration", type=int, default=600, help="flight length, s")
    args = ap.parse_args()
    parts = []
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        simulate(d, args.seed, args.duration)
        for _, flags, labels in RUNS:
            part = summary(d, *flags)
            part["method"] = part["method"].map(lambda m, labels=labels: labels.get(m, m))
            parts.append(part)
    table = pd.concat(parts, ignore_index=True).set_index("method")
    for col in ("mean_gdop_paper", "median_gdop_paper", "estimator", "model"):
        if col not in table:
            table[col] = None
    table["estimator"] = [e if not isinstance(m, str) or not m else f"{e}, {m}"
                          for e, m in zip(table["estimator"], table["model"])]
    table = table[list(COLUMNS)]
    table["rms_3d_over_ls"] = table["rms_3d_m"] / float(table.loc["ls", "rms_3d_m"])
    buf = io.StringIO()
    table.drop(columns="estimator").to_string(buf, float_format=lambda v: f"{v:.4g}")
    print(buf.getvalue())
    rows = table.reset_index()
    command = (f"nice python benchmarks/paper_kinematic.py --seed {args.seed} --duration {args.duration}  # "
               + "; ".join("gnss-solve obs.rnx nav.rnx " + " ".join(f) for _, f, _ in RUNS))
    notes = ("Simulated flight, 1 Hz, GPS, 1 m zenith white pseudorange noise and nothing else, "
             "--iono none --tropo none, errors against the simulator's truth. mean_gdop is geometry "
             "(multi-epoch rows: the pseudorange geometry of the 15-epoch window under the row's motion model, "
             "Doppler not included). mean_gdop_paper is the paper's formula for the row's method: TLS rows its "
             "TLS GDOP (unitless); the stls --lag 3 row its STLS GDOP on H_{l+1}(w), the gain of the identified "
             "kernel in 1/m, not a position DOP (median_gdop_paper its median over the epochs: a few near-degenerate windows "
             "dominate the mean). Only the last two rows use Doppler. tls, dls, mtls: no epoch ok "
             "(their fixes fail the residual test at their own estimate, or are nongeneric).")
    res = REPO / "benchmarks" / "results" / "paper_kinematic.json"
    res.parent.mkdir(parents=True, exist_ok=True)
    res.write_text(json.dumps({
        "title": "The paper's kinematic experiment (simulated flight)", "command": command, "notes": notes,
        "seed": args.seed, "duration_s": args.duration,
        "table": {"columns": list(rows.columns), "rows": [[_cell(v) for v in r] for r in rows.itertuples(index=False)]},
    }, indent=1) + "\n")


if __name__ == "__main__":
    main()
