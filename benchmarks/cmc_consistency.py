"""Does code-minus-carrier consistency per arc tell reflections apart? Measured on training data.

    python benchmarks/cmc_consistency.py [--quick]

Within an unbroken carrier arc (no slip or loss of lock, consecutive epochs), the pseudorange less
the carrier phase ``P - lambda phi`` is the ambiguity, twice the ionosphere (slow) and the code's
errors that the carrier does not share -- multipath of a direct signal mixed with a reflection, or
a code fault. Per arc, the detrended level (a line fitted with two rounds of 3-sigma trimming) over
the pseudorange's a-priori sigma, ``u``, is what a code-minus-carrier test would watch; the one-sided
CUSUM of the NLOS detector's residual stage (``cusum_spans``, k / h in sigmas) is the test.

Training data only: the simulated urban drives of seeds 101-110 (``choose_nlos.py``'s), both
receiver profiles, against the simulator's LOS / NLOS labels, and tst2 (no labels). Per case: the
share of the used satellite-epochs with a carrier arc long enough (10 epochs), the spread of the
detrended level (m), that of ``u`` of LOS and NLOS satellite-epochs, and the share the CUSUM flags. Prints a table and writes
``benchmarks/results/cmc_consistency.json``. About 4 minutes on one core.
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from gnss_cli.config import load_config
from gnss_cli.pipeline import load_epochs, solve_method
from gnss_cli.pipeline.nlos import cusum_spans
from gnss_cli.sim.scenario import los_grid

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_urban import real_cases, simulated_cases  # noqa: E402
from choose_cn0_weights import training_run  # noqa: E402
from choose_nlos import TRAINING_SEEDS  # noqa: E402
from results_page import results_json  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "benchmarks" / "results" / "cmc_consistency.json"
MIN_ARC = 10
TESTS = ((1.0, 5.0), (2.0, 10.0))
"""The CUSUM's (k, h), sigmas: the NLOS detector's multi-epoch spans use 1.5 / 5."""


def cmc_sigmas(data, sigma_m: np.ndarray) -> np.ndarray:  # noqa: ANN001 - EpochData
    """``(T, n)``: per unbroken carrier arc of at least :data:`MIN_ARC` epochs, the code-minus-carrier
    level less a line fitted to it (two rounds, residuals beyond 3 robust sigmas left out), over
    ``sigma_m``; NaN elsewhere."""
    cmc = data.pr_corrected_m - data.phase_m
    t = data.time_gps_s
    have = np.isfinite(cmc)
    linked = have[1:] & have[:-1] & (np.diff(t)[:, None] <= 1.5 * np.median(np.diff(t))) & ~data.phase_slip[1:]
    arc = np.cumsum(np.vstack([np.ones((1, cmc.shape[1]), dtype=bool), ~linked]), axis=0)
    u = np.full(cmc.shape, np.nan)
    for j in range(cmc.shape[1]):
        for a in np.unique(arc[have[:, j], j]):
            m = have[:, j] & (arc[:, j] == a)
            if m.sum() < MIN_ARC:
                continue
            x, y = t[m] - t[m].mean(), cmc[m, j]
            keep = np.ones(x.size, dtype=bool)
            for _ in range(2):
                r = y - np.polyval(np.polyfit(x[keep], y[keep], 1), x)
                spread = 1.4826 * np.median(np.abs(r[keep] - np.median(r[keep])))
                keep = np.abs(r) < 3.0 * max(spread, 1e-3)
            u[m, j] = r / sigma_m[m, j]
    return u


def main() -> None:
    seeds, duration, quick = training_run(__doc__, "one seed per profile, 120 s, tst2")
    seeds = seeds if quick else TRAINING_SEEDS
    t0 = time.perf_counter()
    cfg = load_config(None, {"methods": "wls,smoother", "environment": "open"})  # a multi-epoch method: the carrier phase is read
    rows: list[list[object]] = []
    with tempfile.TemporaryDirectory() as tmp:
        for name, obs, navs, systems, _, _, faults in simulated_cases(seeds, duration, Path(tmp)) + real_cases(True):
            data = load_epochs(obs, navs, cfg)
            if data.phase_m is None or data.phase_slip is None:
                continue
            sol = solve_method(data, "wls", cfg)
            u = cmc_sigmas(data, sol.sigma_m)
            used = np.isfinite(sol.residuals_m)
            lab = los_grid(faults, data.time_gps_s, data.sv) if faults is not None else np.full(u.shape, -1)
            have = np.isfinite(u) & used
            row: list[object] = [name, round(100 * have.sum() / max(used.sum(), 1), 1),
                                 round(float(np.std((u * sol.sigma_m)[have])), 2)]
            for v in (1, 0):
                sel = have & (lab == v)
                row.append(round(float(np.std(u[sel])), 2) if sel.any() else None)
            for k, h in TESTS:
                flagged = cusum_spans(np.where(used, u, np.nan), k, h)
                row.append(" / ".join(f"{100 * flagged[have & (lab == v)].mean():.2f}" if (have & (lab == v)).any()
                                      else "–" for v in (0, 1)) if faults is not None
                           else f"{100 * flagged[have].mean():.2f}")
            rows.append(row)
            print(f"cmc_consistency: {name} ({time.perf_counter() - t0:.0f} s)", file=sys.stderr)
    columns = ["case", "used satellite-epochs in an arc, %", "std of the detrended level, m", "std of u, LOS",
               "std of u, NLOS",
               *[f"flagged, CUSUM {k:g}/{h:g}: NLOS / LOS % (tst2: all)" for k, h in TESTS]]
    print("| " + " | ".join(columns) + " |\n|" + "---|" * len(columns))
    print("\n".join("| " + " | ".join("–" if c is None else str(c) for c in r) + " |" for r in rows))
    if not quick:
        OUT.write_text(results_json({
            "title": "Code-minus-carrier consistency per arc on training data",
            "command": "python benchmarks/cmc_consistency.py", "table": {"columns": columns, "rows": rows},
            "notes": "u: the detrended code-minus-carrier over the pseudorange's a-priori sigma, per unbroken "
                     "carrier arc; the CUSUM is the NLOS detector's one-sided test on u.",
            "seeds": seeds, "duration_s": duration, "seconds": time.perf_counter() - t0}))
        print(f"wrote {OUT}", file=sys.stderr)


if __name__ == "__main__":
    main()
