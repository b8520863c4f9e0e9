"""Timing of the behavioral STLS: one misfit evaluation and a whole identification.

Run with one BLAS thread (tall-skinny products are faster that way on a 2-core machine)::

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 python -m benchmarks.bench_stls

Prints a table and writes ``benchmarks/results/bench_stls.json``. Problems: the anchor arc
of ``../shared/slra-anchor`` re-generated at T = 1e3..1e5 (lag 1, order 3) and the same arc
with the lag-3 order-9 model; ``slra``'s anchor-README times are quoted for comparison.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from gnss_cli.behavior import misfit, stls

SLRA_TIME_S = {10000: 0.20, 100000: 3.48}


def anchor_arc(n_t: int, rng: np.random.Generator) -> np.ndarray:
    """``c + rho (u cos wt + v sin wt) + noise`` as in the anchor README (w = 2 pi / 150, sigma 0.05)."""
    t = np.arange(n_t, dtype=float)
    omega = 2 * np.pi / 150
    u = np.array([1.0, 0.3, -0.2])
    u /= np.linalg.norm(u)
    v = np.cross(u, [0.2, -0.1, 1.0])
    v /= np.linalg.norm(v)
    y0 = np.array([0.5, -0.3, 0.2]) + np.outer(np.cos(omega * t), u) + np.outer(np.sin(omega * t), v)
    return y0 + 0.05 * rng.normal(size=y0.shape)


def best_of(fn, repeat: int) -> float:  # type: ignore[no-untyped-def]
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def main() -> None:
    rng = np.random.default_rng(0)
    rows = []
    for lag, order in ((1, 3), (3, 9)):
        for n_t in (1000, 10000, 100000):
            y = anchor_arc(n_t, rng)
            res = stls(y, lag=lag, order=order)
            t_misfit = best_of(lambda: misfit(y, res.kernel), 3)
            t_stls = best_of(lambda: stls(y, lag=lag, order=order), 1 if n_t == 100000 else 2)
            rows.append({"lag": lag, "order": order, "T": n_t, "misfit_s": t_misfit, "stls_s": t_stls,
                         "iterations": res.iterations, "status": res.status.name, "misfit": res.misfit,
                         "slra_s": SLRA_TIME_S.get(n_t) if lag == 1 else None})
    print(f"{'lag':>3} {'order':>5} {'T':>7} {'misfit [s]':>11} {'stls [s]':>9} {'iter':>5} {'status':>20} {'slra [s]':>8}")
    for r in rows:
        slra = f"{r['slra_s']:.2f}" if r["slra_s"] else "-"
        print(f"{r['lag']:>3} {r['order']:>5} {r['T']:>7} {r['misfit_s']:>11.4f} {r['stls_s']:>9.3f} {r['iterations']:>5} {r['status']:>20} {slra:>8}")
    for lag in (1, 3):
        sub = [r for r in rows if r["lag"] == lag]
        ratios = [b["stls_s"] / a["stls_s"] for a, b in zip(sub, sub[1:])]
        mratios = [b["misfit_s"] / a["misfit_s"] for a, b in zip(sub, sub[1:])]
        print(f"lag {lag}: stls time ratio per decade {['%.1f' % x for x in ratios]}, misfit {['%.1f' % x for x in mratios]}")
    out = Path(__file__).resolve().parent / "results"
    out.mkdir(exist_ok=True)
    (out / "bench_stls.json").write_text(json.dumps(rows, indent=2) + "\n")


if __name__ == "__main__":
    main()
