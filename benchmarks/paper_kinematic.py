"""The paper's kinematic experiment: every estimator on one simulated flight, one table.

A 10 min, 1 Hz simulated flight (GPS only, 1 m zenith white pseudorange noise growing as
1/sin(el), no other error source, seed 3) is solved by ``gnss-solve`` twice, as a user would:

1. ``--method ls,wls,tls,dls,mtls,stls`` (single-epoch estimators; ``stls`` is the
   single-epoch structured TLS, i.e. ``--lag 0``);
2. ``--method stls --lag 3``: the paper's identified Hankel STLS (the shared kernel identified
   from the WLS fixes in the default 15-epoch windows);
3. ``--method smoother --measurements pseudorange``: the fixed-model batch smoother (lag-3
   velocity quadrature) given the same pseudoranges, nothing identified -- the standard
   alternative, on equal information (the simulated file has Doppler; it is not used here).

Both runs use ``--iono none --tropo none`` (the simulated data have neither) and
``--reference-csv truth.csv``. The summary rows (mean error E/N/U, error covariance, RMS,
mean GDOP: the paper's figures 4-6) are printed as one table and written to
``benchmarks/results/paper_kinematic.json``.

Usage: ``python benchmarks/paper_kinematic.py [--seed 3] [--duration 600]``
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
COLUMNS = ("epochs_solved", "mean_e_m", "mean_n_m", "mean_u_m", "cov_ee_m2", "cov_nn_m2", "cov_uu_m2",
           "rms_e_m", "rms_n_m", "rms_u_m", "rms_3d_m", "mean_gdop")


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
    return pd.read_csv(out / "summary.csv")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=3, help="simulation seed")
    ap.add_argument("--duration", type=int, default=600, help="flight length, s")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        simulate(d, args.seed, args.duration)
        single = summary(d, "--method", SINGLE_EPOCH)
        single.loc[single["method"] == "stls", "method"] = "stls (lag 0)"
        identified = summary(d, "--method", "stls", "--lag", "3")
        identified["method"] = "stls --lag 3 (identified)"
        fixed = summary(d, "--method", "smoother", "--measurements", "pseudorange")
        fixed["method"] = "smoother (fixed model, pseudoranges)"
    table = pd.concat([single, identified, fixed], ignore_index=True).set_index("method")[list(COLUMNS)]
    ls_rms = float(table.loc["ls", "rms_3d_m"])
    table["rms_3d_over_ls"] = table["rms_3d_m"] / ls_rms
    buf = io.StringIO()
    table.to_string(buf, float_format=lambda v: f"{v:.4g}")
    print(buf.getvalue())
    res = REPO / "benchmarks" / "results" / "paper_kinematic.json"
    res.parent.mkdir(parents=True, exist_ok=True)
    res.write_text(json.dumps({"seed": args.seed, "duration_s": args.duration,
                               "rows": table.reset_index().to_dict(orient="records")}, indent=1) + "\n")


if __name__ == "__main__":
    main()
