"""How the reflections' spans of the multi-epoch methods (``[nlos] multi_epoch``) were chosen: on training data only.

    python benchmarks/choose_multi_epoch_spans.py [--quick]

``smoother``, ``kf`` and ``stls --lag L`` leave out, from their own pseudoranges, the spans over
which a satellite's residual at their own trajectory stays positive (a one-sided CUSUM of
``u = r / sigma`` with slack ``multi_epoch_k`` and threshold ``multi_epoch_h``, sigmas; solved
again, up to ``multi_epoch_rounds`` times; :func:`gnss_cli.pipeline.nlos.multi_epoch_spans`).

Training data (as ``choose_nlos.py``): simulated urban drives with seeds 101-103
(``bench_urban.py`` reports seeds 1-20), both receiver profiles, 300 s at 1 Hz, against the
simulator's truth and its ``faults.csv`` labels; tst2 (against its truth); smartloc-berlin
(availability only). Candidates: ``off`` and a grid of ``(k, h, rounds)``; ``smoother`` and ``kf``
with every other option at its default (``stls`` takes the same setting; it is slower and left
out of the choice). Per case and method: availability, misleading epochs, 3D RMS over every
epoch and over the ``ok`` ones, and on the drives the share of NLOS and of LOS satellite-epochs
the method left out (the WLS exclusions, its gate and the spans).

Rule: the allowed candidates have no more misleading epochs (summed over the cases with a
reference and both methods) than ``off``, leave out at most 5 % of the drives' LOS
satellite-epochs, and keep the availability of tst2 and smartloc-berlin within 2 points of
``off``'s. Each is scored by the mean over cases with a reference and both methods of the 3D RMS
over every epoch against ``off``'s (over every epoch: the spans also change which epochs pass the
test, and the RMS of the ``ok`` ones alone would reward a candidate for failing the hard ones).
Chosen (:func:`choose`), as ``multi_epoch_fair.py`` chooses its settings: of the allowed
candidates whose score is within one standard error of the best allowed one's (the error of
their paired difference over the scored cases), the gentlest, the one that leaves out the fewest
of the drives' LOS satellite-epochs. A plain minimum let a 7 % difference over six training
cases decide, and it moved with the code (k 1.5 / h 5, then k 0.5 / h 10). Prints a table and writes
``benchmarks/results/choose_multi_epoch_spans.json``. About 6 minutes on one core.
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_urban import method_row, nlos_handling, real_cases, simulated_cases  # noqa: E402
from choose_cn0_weights import report_choice, training_run  # noqa: E402

from gnss_cli.config import load_config  # noqa: E402
from gnss_cli.pipeline import process  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "benchmarks" / "results" / "choose_multi_epoch_spans.json"
METHODS = ("smoother", "kf")
GRID = ((0.5, 5.0, 3), (0.5, 10.0, 3), (1.0, 5.0, 1), (1.0, 5.0, 3), (1.0, 10.0, 3), (1.5, 5.0, 3), (1.5, 10.0, 3))
UNTESTED = {"max_segment_misfit": float("inf")}
"""The segments' misfit test was chosen after the spans (choose_segment_misfit.py), so not here."""
CANDIDATES: dict[str, dict[str, object]] = {"off": {"nlos.multi_epoch": "off", **UNTESTED}} | {
    f"k {k:g}, h {h:g}, {r} round{'s' * (r > 1)}": {"nlos.multi_epoch": "cusum", "nlos.multi_epoch_k": k,
                                                   "nlos.multi_epoch_h": h, "nlos.multi_epoch_rounds": r, **UNTESTED}
    for k, h, r in GRID}
REAL = ("tst2", "smartloc-berlin")
MAX_LOS_PCT = 5.0
MAX_AVAILABILITY_LOSS = 0.02


def run_candidates(candidates: dict[str, dict[str, object]], seeds: list[int], duration: float, quick: bool,
                   prog: str) -> dict[str, dict[str, dict[str, dict[str, object]]]]:
    """``smoother`` and ``kf`` with each candidate's settings on the training cases: per candidate,
    case and method ``bench_urban.method_row`` (with the drives' NLOS handling); ``seconds`` per case."""
    t0 = time.perf_counter()
    results: dict[str, dict[str, dict[str, dict[str, object]]]] = {c: {} for c in candidates}
    with tempfile.TemporaryDirectory() as tmp:
        cases = simulated_cases(seeds, duration, Path(tmp)) + real_cases(quick)
        for name, obs, navs, systems, ref_at, keep_at, faults in cases:
            for cand, over in candidates.items():
                cfg = load_config(None, {"methods": ",".join(METHODS), "environment": "open",  # as chosen: open-sky settings
                                         **({"systems": systems} if systems else {}), **over})
                t1 = time.perf_counter()
                res = process(obs, navs, cfg)
                t = res.epochs.time_gps_s
                keep = keep_at(t)
                rows = {}
                for m in METHODS:
                    rows[m] = method_row(res.solutions[m], ref_at(t[keep]), keep)
                    if faults is not None:
                        rows[m]["nlos"] = nlos_handling(res.solutions[m], res.epochs, faults)
                rows["seconds"] = time.perf_counter() - t1  # type: ignore[assignment]
                results[cand][name] = rows
            print(f"{prog}: {name} ({time.perf_counter() - t0:.0f} s)", file=sys.stderr)
    return results


def summarize(results: dict[str, dict[str, dict[str, dict[str, object]]]]) -> dict[str, dict[str, object]]:
    """Per candidate: ``score`` (mean over cases with a reference and both methods of the 3D RMS
    over every epoch against the first candidate's; ``ratios``, those ratios, case by case),
    ``misleading`` (summed), the drives' pooled
    ``nlos`` and ``los`` shares left out (%), and ``allowed`` (no more misleading epochs than the
    first candidate, at most 5 % of the LOS out, the real sets' availability within 2 points)."""
    first = next(iter(results))
    off = results[first]
    names = list(off)
    scored = [(n, m) for n in names for m in METHODS if off[n][m].get("rms_3d_all_m")]

    def pooled(cand: str, kind: str) -> float:
        nl = [results[cand][n][m]["nlos"] for n in names for m in METHODS if "nlos" in results[cand][n][m]]
        total = sum(x[f"{kind}_candidates"] for x in nl)  # type: ignore[index]
        return float(sum(x[f"{kind}_dropped_pct"] * x[f"{kind}_candidates"] for x in nl) / max(total, 1))  # type: ignore[index]

    out: dict[str, dict[str, object]] = {}
    for c, rows in results.items():
        misleading = int(sum(rows[n][m].get("misleading", 0) for n in names for m in METHODS))  # type: ignore[arg-type]
        ratios = [rows[n][m]["rms_3d_all_m"] / off[n][m]["rms_3d_all_m"] for n, m in scored]
        out[c] = {"score": float(np.mean(ratios)), "ratios": [float(r) for r in ratios],  # type: ignore[arg-type]
                  "misleading": misleading, "nlos": pooled(c, "nlos"), "los": pooled(c, "los")}
    for c, rows in results.items():
        out[c]["allowed"] = (out[c]["misleading"] <= out[first]["misleading"] and out[c]["los"] <= MAX_LOS_PCT
                             and all(rows[n][m]["availability"] >= off[n][m]["availability"] - MAX_AVAILABILITY_LOSS
                                     for n in REAL if n in off for m in METHODS))
    return out


def choose(summary: dict[str, dict[str, object]]) -> str:
    """The rule of the module docstring: of the ``allowed`` candidates of :func:`summarize` whose
    mean ratio exceeds the best allowed one's by at most the standard error of their paired
    difference, the one with the smallest ``los`` share left out."""
    allowed = [c for c, s in summary.items() if s["allowed"]]
    best = min(allowed, key=lambda c: float(summary[c]["score"]))  # type: ignore[arg-type]
    ref = np.asarray(summary[best]["ratios"])

    def within(c: str) -> bool:
        d = np.asarray(summary[c]["ratios"]) - ref
        return bool(d.mean() <= (d.std(ddof=1) / np.sqrt(d.size) if d.size > 1 else 0.0))

    return min((c for c in allowed if within(c)), key=lambda c: float(summary[c]["los"]))  # type: ignore[arg-type]


def table(results: dict[str, dict[str, dict[str, dict[str, object]]]], summary: dict[str, dict[str, object]]
          ) -> tuple[list[str], list[list[object]]]:
    """The columns and rows of the choice's table."""
    names = list(next(iter(results.values())))
    columns = ["candidate", *[f"{n} {m}: ok / RMS all / RMS ok" for n in names for m in METHODS],
               "NLOS / LOS out % (drives)", "score (RMS all / first's, mean)", "misleading", "allowed", "seconds"]
    rows: list[list[object]] = []
    for c, res in results.items():
        cells = []
        for n in names:
            for m in METHODS:
                r = res[n][m]
                cells.append(f"{100 * r['availability']:.0f} % / " + " / ".join(  # type: ignore[operator]
                    f"{r[k]:.2f}" if r.get(k) else "–" for k in ("rms_3d_all_m", "rms_3d_m")))
        s = summary[c]
        rows.append([c, *cells, f"{s['nlos']:.1f} / {s['los']:.1f}", round(float(s["score"]), 3), s["misleading"],  # type: ignore[arg-type]
                     "yes" if s["allowed"] else "no", round(sum(float(res[n]["seconds"]) for n in names), 1)])  # type: ignore[arg-type]
    return columns, rows


def main() -> None:
    seeds, duration, quick = training_run(__doc__, "one seed per profile, 120 s, tst2")
    t0 = time.perf_counter()
    results = run_candidates(CANDIDATES, seeds, duration, quick, "choose_multi_epoch_spans")
    summary = summarize(results)
    chosen = choose(summary)
    columns, table_rows = table(results, summary)
    report_choice(OUT, "Choosing the multi-epoch methods' reflection spans on training data",
                  "python benchmarks/choose_multi_epoch_spans.py", columns, table_rows, chosen,
                  f"smoother and kf, defaults otherwise; chosen: {chosen}. Training data only: bench_urban.py "
                  "reports other seeds.", quick, seeds=seeds, duration_s=duration, candidates=CANDIDATES,
                  summary=summary, cases=results, seconds=time.perf_counter() - t0)

if __name__ == "__main__":
    main()
