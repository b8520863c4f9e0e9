"""The paper's identification experiment: STLS against WTLS on a semicircular flight.

A receiver flies a constant-speed half circle (radius 2 km, 100 m/s, 1 s epochs, ENU,
horizontal). Noisy positions (white, sigma per coordinate) are observed; a lag-3 model is
identified from the first ``train`` epochs (7, as in the paper) with

* STLS: weighted Hankel structured low-rank approximation (``gnss_cli.behavior.stls``),
* WTLS: the unstructured SVD kernel of the Hankel matrix (``gnss_cli.behavior.wtls``),

both with the shared structure ``R(z) = r(z) I_3`` (a full lag-3 kernel of order 9 is not
identifiable from 7 epochs: it needs at least 13), then the rest of the trajectory is
predicted from the fitted last ``lag`` samples. Over 100 noise seeds, the prediction RMS
error per method and horizon is reported, and the rate at which each method wins.

Usage: ``python benchmarks/paper_identification.py [--sigma 0.5] [--seeds 100]`` —
prints a table and writes ``benchmarks/results/paper_identification.json``.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from gnss_cli.behavior import stls, wtls  # noqa: E402
from gnss_cli.errors import GnssError  # noqa: E402


def semicircle(n: int, radius_m: float = 2000.0, speed_m_s: float = 100.0, dt_s: float = 1.0) -> np.ndarray:
    """ENU positions (m) of a constant-speed half circle, shape ``(n, 3)``."""
    omega = speed_m_s / radius_m
    t = np.arange(n) * dt_s
    return np.stack([radius_m * np.cos(omega * t), radius_m * np.sin(omega * t), np.full(n, 500.0)], axis=1)


def predict(result, w_hat: np.ndarray, lag: int, steps: int) -> np.ndarray:
    return result.kernel.predict(w_hat[-lag:], steps)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sigma", type=float, default=0.5, help="noise std per coordinate, m")
    ap.add_argument("--seeds", type=int, default=100)
    ap.add_argument("--train", type=int, default=7)
    ap.add_argument("--total", type=int, default=60)
    ap.add_argument("--lag", type=int, default=3)
    args = ap.parse_args()
    truth = semicircle(args.total)
    horizons = [1, 5, 10, 20, 30, args.total - args.train]
    steps = args.total - args.train
    errors = {"stls": [], "wtls": []}
    failures = {"stls": 0, "wtls": 0}
    fit_err = {"stls": [], "wtls": []}
    for seed in range(args.seeds):
        rng = np.random.default_rng(seed)
        w = truth + rng.normal(0.0, args.sigma, truth.shape)
        train = w[: args.train]
        for name, fn in (("stls", stls), ("wtls", wtls)):
            try:
                res = fn(train, args.lag, structure="shared", fixed_roots=(1.0,))
                pred = predict(res, res.w_hat, args.lag, steps)
            except GnssError:
                failures[name] += 1
                continue
            if not np.all(np.isfinite(pred)):
                failures[name] += 1
                continue
            errors[name].append(np.linalg.norm(pred - truth[args.train :], axis=1))
            fit_err[name].append(np.sqrt(np.mean(np.sum((res.w_hat - truth[: args.train]) ** 2, axis=1))))
    table = {}
    for name in errors:
        e = np.array(errors[name])
        table[name] = {
            "runs": int(e.shape[0]),
            "failures": failures[name],
            "fit_rms_m": float(np.mean(fit_err[name])) if fit_err[name] else None,
            "rms_by_horizon_m": {str(h): float(np.sqrt(np.mean(e[:, h - 1] ** 2))) for h in horizons} if e.size else {},
            "median_by_horizon_m": {str(h): float(np.median(e[:, h - 1])) for h in horizons} if e.size else {},
        }
    both = min(len(errors["stls"]), len(errors["wtls"]))
    if both and len(errors["stls"]) == len(errors["wtls"]):
        s, w = np.array(errors["stls"]), np.array(errors["wtls"])
        table["stls_better_fraction_by_horizon"] = {str(h): float(np.mean(s[:, h - 1] < w[:, h - 1])) for h in horizons}
    print(f"semicircle r=2 km, 100 m/s, 1 s; sigma {args.sigma} m; lag {args.lag}; train {args.train}; {args.seeds} seeds")
    print(f"{'method':<8}{'fails':>6}{'fit RMS':>9}" + "".join(f"{'h=' + str(h):>10}" for h in horizons) + "   (prediction RMS error, m)")
    for name in ("stls", "wtls"):
        r = table[name]
        print(f"{name:<8}{r['failures']:>6}{(r['fit_rms_m'] or float('nan')):>9.3f}" + "".join(f"{r['rms_by_horizon_m'].get(str(h), float('nan')):>10.2f}" for h in horizons))
    for name in ("stls", "wtls"):
        r = table[name]
        print(f"{name + ' med':<8}{'':>6}{'':>9}" + "".join(f"{r['median_by_horizon_m'].get(str(h), float('nan')):>10.2f}" for h in horizons) + "   (median)")
    if "stls_better_fraction_by_horizon" in table:
        print("STLS better than WTLS in " + ", ".join(f"h={h}: {100 * v:.0f} %" for h, v in table["stls_better_fraction_by_horizon"].items()))
    out = REPO / "benchmarks" / "results" / "paper_identification.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"settings": vars(args), "results": table}, indent=2))
    print(f"wrote {out.relative_to(REPO)}")


if __name__ == "__main__":
    main()
