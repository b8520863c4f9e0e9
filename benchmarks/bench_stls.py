"""Timing of the behavioral STLS: one misfit evaluation and a whole identification.

Run with one BLAS thread (tall-skinny products are faster that way on a 2-core machine)::

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 python -m benchmarks.bench_stls

Prints a table and writes ``benchmarks/results/bench_stls.json``. Problems: the anchor arc of
``../shared/slra-anchor`` (its files for T = 1e3 and 1e4, the same recipe for T = 1e5) with
the anchor's model (lag 1, order 3) and with the lag-3 order-9 model; ``slra``'s
anchor-README times are quoted for comparison. The time ratio per decade of T is printed
for both the misfit and the whole ``stls`` (the issue asks for at most 12).
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from gnss_cli.behavior import misfit, stls

SLRA_TIME_S = {10000: 0.20, 100000: 3.48}
ANCHOR_DIR = Path(__file__).resolve().parents[2] / "shared" / "slra-anchor"
ANCHOR_MISFIT = {1000: 7.61286, 10000: 75.9692}


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


def anchor_data(n_t: int, rng: np.random.Generator) -> tuple[np.ndarray, str]:
    """The anchor file for ``n_t`` samples when it exists, else the same recipe."""
    path = ANCHOR_DIR / f"y_{n_t}.txt"
    if path.is_file():
        return np.loadtxt(path, delimiter=","), "anchor file"
    return anchor_arc(n_t, rng), "anchor recipe"


def best_of(fn, repeat: int) -> float:  # type: ignore[no-untyped-def]
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def main() -> None:
    rng = np.random.default_rng(0)
    sizes = (1000, 10000, 100000)
    data = {n_t: anchor_data(n_t, rng) for n_t in sizes}
    rows = []
    for lag, order in ((1, 3), (3, 9)):
        for n_t in sizes:
            y, source = data[n_t]
            res = stls(y, lag=lag, order=order)
            # best of several runs: the machine is shared, and one misfit call at T = 1e5 takes ~40 ms
            t_misfit = best_of(lambda: misfit(y, res.kernel), 15)
            t_stls = best_of(lambda: stls(y, lag=lag, order=order), 3)
            rows.append({"lag": lag, "order": order, "T": n_t, "data": source, "misfit_s": t_misfit,
                         "stls_s": t_stls, "iterations": res.iterations, "evaluations": res.n_evaluations,
                         "status": res.status.name, "misfit": res.misfit,
                         "anchor_misfit": ANCHOR_MISFIT.get(n_t) if lag == 1 and source == "anchor file" else None,
                         "slra_s": SLRA_TIME_S.get(n_t) if lag == 1 else None})
    print(f"{'lag':>3} {'order':>5} {'T':>7} {'misfit [s]':>11} {'stls [s]':>9} {'iter':>5} {'evals':>6} "
          f"{'status':>20} {'misfit':>10} {'anchor':>10} {'slra [s]':>8}")
    for r in rows:
        slra = f"{r['slra_s']:.2f}" if r["slra_s"] else "-"
        anchor = f"{r['anchor_misfit']:.6g}" if r["anchor_misfit"] else "-"
        print(f"{r['lag']:>3} {r['order']:>5} {r['T']:>7} {r['misfit_s']:>11.4f} {r['stls_s']:>9.3f} "
              f"{r['iterations']:>5} {r['evaluations']:>6} {r['status']:>20} {r['misfit']:>10.6g} {anchor:>10} {slra:>8}")
    ratios = {}
    for lag in (1, 3):
        sub = [r for r in rows if r["lag"] == lag]
        ratios[f"lag{lag}"] = {
            "stls": [b["stls_s"] / a["stls_s"] for a, b in zip(sub, sub[1:])],
            "misfit": [b["misfit_s"] / a["misfit_s"] for a, b in zip(sub, sub[1:])],
        }
        print(f"lag {lag}: time ratio per decade of T: stls {['%.1f' % x for x in ratios[f'lag{lag}']['stls']]}, "
              f"misfit {['%.1f' % x for x in ratios[f'lag{lag}']['misfit']]}")
    out = Path(__file__).resolve().parent / "results"
    out.mkdir(exist_ok=True)
    (out / "bench_stls.json").write_text(json.dumps({"rows": rows, "ratios_per_decade": ratios}, indent=2) + "\n")


if __name__ == "__main__":
    main()
