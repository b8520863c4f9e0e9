"""How the default of ``[weights] cn0_model`` (and its reference C/N0) was chosen: on training data only.

    python benchmarks/choose_cn0_weights.py [--quick]

Training data: simulated urban drives with seeds 101-103 (``bench_urban.py`` reports seeds 1-20),
both receiver profiles, 300 s at 1 Hz; the shared urban sets tst2 (against its truth) and
smartloc-berlin (availability only: no reference); and ESBC, a clean station, which must not get
worse. For each candidate -- ``off``, and ``sigma-epsilon`` with ``cn0_ref_dbhz`` 40, 45, 50 --
``wls`` with the default integrity (``fde``) and every other option at its default. Per case:
availability, misleading epochs, 3D RMS of the ``ok`` epochs. The score of a candidate is the mean
over the cases with a reference of its RMS over the ``off`` RMS; the chosen default is the lowest
score among the candidates whose misleading epochs (summed) are no more than ``off``'s and whose
ESBC RMS is within 2 % of ``off``'s. Prints a table and writes
``benchmarks/results/choose_cn0_weights.json``. About 6 minutes on one core.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from gnss_cli.config import load_config
from gnss_cli.pipeline import RunResult, process

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_urban import RINEX, method_row, real_cases, simulated_cases  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "benchmarks" / "results" / "choose_cn0_weights.json"
CANDIDATES: dict[str, dict[str, object]] = {
    "off": {"weights.cn0_model": "off"},
    "sigma-epsilon 40": {"weights.cn0_model": "sigma-epsilon", "weights.cn0_ref_dbhz": 40.0},
    "sigma-epsilon 45": {"weights.cn0_model": "sigma-epsilon", "weights.cn0_ref_dbhz": 45.0},
    "sigma-epsilon 50": {"weights.cn0_model": "sigma-epsilon", "weights.cn0_ref_dbhz": 50.0},
}
ESBC_REF = np.array([3582104.922, 532590.196, 5232755.366])  # ../shared/rinex/README.md (PPP, ARP)


def training_cases(work: Path, seeds: list[int], duration_s: float, quick: bool) -> list[tuple]:
    """bench_urban's drives (other seeds) and real sets, and ESBC: (name, obs, navs, systems, ref_at, keep_at)."""
    cases = [c[:6] for c in simulated_cases(seeds, duration_s, work) + real_cases(quick)]
    esbc = RINEX / "esbc-2020177"
    if esbc.is_dir() and not quick:
        cases.append(("esbc", esbc / "ESBC00DNK_R_20201770000_01D_30S_MO.crx.gz",
                      [esbc / "ESBC00DNK_R_20201770000_01D_MN.rnx.gz"], None,
                      lambda t: np.broadcast_to(ESBC_REF, (t.size, 3)), lambda t: np.ones(t.size, bool)))
    return cases


def training_run(doc: str | None, quick_help: str) -> tuple[list[int], float, bool]:
    """The command line every choice script takes (``--quick``): the training seeds, the drives'
    duration (s) and whether it is the quick run (one seed per profile, 120 s)."""
    parser = argparse.ArgumentParser(description=doc, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help=quick_help)
    args = parser.parse_args()
    seeds, duration = ([101], 120.0) if args.quick else ([101, 102, 103], 300.0)
    return seeds, duration, bool(args.quick)


def report_choice(out: Path, title: str, command: str, columns: list[str], table_rows: list[list[object]],
                  chosen: str | None, notes: str, quick: bool, **extra: object) -> None:
    """Print a choice's table and its choice; unless ``quick``, write them with ``extra`` to ``out`` (JSON)."""
    print("| " + " | ".join(columns) + " |\n|" + "---|" * len(columns))
    for r in table_rows:
        print("| " + " | ".join(str(v) for v in r) + " |")
    print(f"chosen: {chosen}")
    if not quick:
        out.write_text(json.dumps({"title": title, "command": command, "table": {"columns": columns, "rows": table_rows},
                                   "notes": notes, **extra, "chosen": chosen},
                                  indent=1, default=lambda o: o.tolist() if hasattr(o, "tolist") else str(o)) + "\n")


def score_candidates(candidates: dict[str, dict[str, object]], cases: list[tuple], prog: str,
                     extra: Callable[[str, RunResult], dict[str, object]] | None = None,
                     ) -> tuple[dict[str, dict[str, object]], dict[str, dict[str, float]]]:
    """WLS with each candidate's settings on each training case (``training_cases``'s tuples):
    ``bench_urban.method_row`` of every candidate and case (with ``extra(case name, run)``'s
    entries when given), and the seconds each run took."""
    t0 = time.perf_counter()
    results: dict[str, dict[str, object]] = {c: {} for c in candidates}
    seconds: dict[str, dict[str, float]] = {c: {} for c in candidates}
    for name, obs, navs, systems, ref_at, keep_at in cases:
        for cand, over in candidates.items():
            # the open-sky settings the choices were made with, unless a candidate names an environment
            cfg = load_config(None, {"methods": "wls", "environment": "open", **({"systems": systems} if systems else {}),
                                     **over})
            t1 = time.perf_counter()
            res = process(obs, navs, cfg)
            seconds[cand][name] = time.perf_counter() - t1
            t = res.epochs.time_gps_s
            keep = keep_at(t)
            results[cand][name] = method_row(res.solutions["wls"], ref_at(t[keep]), keep)
            if extra is not None:
                results[cand][name].update(extra(name, res))
        print(f"{prog}: {name} ({time.perf_counter() - t0:.0f} s)", file=sys.stderr)
    return results, seconds


def main() -> None:
    seeds, duration, quick = training_run(__doc__, "one seed per profile, 120 s, tst2")
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        results, _ = score_candidates(CANDIDATES, training_cases(Path(tmp), seeds, duration, quick),
                                      "choose_cn0_weights")
    names = list(results["off"])
    lines = ["| candidate | " + " | ".join(names) + " | score | misleading |", "|---|" + "---|" * (len(names) + 2)]
    table_rows: list[list[object]] = []
    scores: dict[str, float] = {}
    misleading: dict[str, int] = {}
    for cand, rows in results.items():
        ratios = [rows[n]["rms_3d_m"] / results["off"][n]["rms_3d_m"] for n in names
                  if rows[n].get("rms_3d_m") and results["off"][n].get("rms_3d_m")]
        scores[cand] = float(np.mean(ratios))
        misleading[cand] = int(sum(rows[n].get("misleading", 0) for n in names))
        cells = [f"{100 * rows[n]['availability']:.0f} % / " + (f"{rows[n]['rms_3d_m']:.2f} m" if rows[n].get("rms_3d_m")
                 else "–") for n in names]
        lines.append(f"| {cand} | " + " | ".join(cells) + f" | {scores[cand]:.3f} | {misleading[cand]} |")
        table_rows.append([cand, *cells, round(scores[cand], 3), misleading[cand]])
    esbc = results["off"].get("esbc", {}).get("rms_3d_m")
    allowed = [c for c in CANDIDATES if misleading[c] <= misleading["off"]
               and (esbc is None or results[c]["esbc"]["rms_3d_m"] <= 1.02 * esbc)]
    chosen = min(allowed, key=lambda c: scores[c])
    print("\n".join(lines))
    print(f"chosen: {chosen} (score {scores[chosen]:.3f}; off 1.000)")
    if not quick:
        OUT.write_text(json.dumps({"title": "Choosing the C/N0 weights on training data",
                                   "command": "python benchmarks/choose_cn0_weights.py",
                                   "table": {"columns": ["candidate", *[f"{n}: ok / RMS" for n in names],
                                                         "score (RMS / off's, mean)", "misleading epochs"],
                                             "rows": table_rows},
                                   "notes": f"WLS, default integrity; chosen: {chosen}. Training data only: "
                                            "bench_urban.py reports other seeds.",
                                   "seeds": seeds,
                                   "duration_s": duration, "candidates": CANDIDATES, "scores": scores,
                                   "misleading": misleading, "chosen": chosen, "cases": results,
                                   "seconds": time.perf_counter() - t0}, indent=1) + "\n")


if __name__ == "__main__":
    main()
