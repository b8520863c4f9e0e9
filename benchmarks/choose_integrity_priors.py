"""How the defaults of ``max_simultaneous_faults`` and ``prior_fault_satellite`` were chosen: on
training data only.

    python benchmarks/choose_integrity_priors.py [--quick]

Training data: simulated urban drives with seeds 101-103 (``bench_urban.py`` reports seeds 1-N),
both receiver profiles, 300 s at 1 Hz (against the simulator's truth); tst2 (against its truth);
smartloc-berlin (availability only: no reference); and two clean sets whose availability must
stay: rtklib-0759 and ESBC (24 h). For each candidate of the grid ``max_simultaneous_faults`` in
{1, 2, 3} x ``prior_fault_satellite`` in {1e-3, 1e-2, 3e-2}: ``wls`` with the default integrity
(``fde``) and every other option at its default. Per case: availability (``ok`` share), misleading
epochs (``ok`` with the horizontal error above HPL or the vertical above VPL), ``ok`` epochs without
a finite protection level.

Rule: among the candidates whose pooled availability on the simulated drives is at least 70 %
and whose availability on each clean set (rtklib-0759, ESBC) is at least 99 % with finite levels
on every ``ok`` epoch, the one with the fewest misleading epochs summed over the cases with a
reference (drives and tst2); ties go to the higher drive availability. Prints a table and writes
``benchmarks/results/choose_integrity_priors.json``.
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_urban import RINEX  # noqa: E402
from choose_cn0_weights import report_choice, score_candidates, training_run  # noqa: E402
from choose_cn0_weights import training_cases as cn0_training_cases  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "benchmarks" / "results" / "choose_integrity_priors.json"
CANDIDATES: dict[str, dict[str, object]] = {
    f"max {k}, p {p:g}": {"max_simultaneous_faults": k, "prior_fault_satellite": p}
    for k in (1, 2, 3) for p in (1e-3, 1e-2, 3e-2)}
CLEAN = ("rtklib-0759", "esbc")
MIN_DRIVE_AVAILABILITY = 0.70
MIN_CLEAN_AVAILABILITY = 0.99


def training_cases(work: Path, seeds: list[int], duration_s: float, quick: bool) -> list[tuple]:
    """(name, obs, navs, systems, ref_at, keep_at) of the drives, tst2, Berlin, ESBC (the C/N0
    choice's training cases) and rtklib-0759."""
    cases = cn0_training_cases(work, seeds, duration_s, quick)
    r0759 = RINEX / "rtklib-0759"
    if r0759.is_dir():
        cases.append(("rtklib-0759", r0759 / "07590920.05o", [r0759 / "07590920.05n"], None, lambda t: None,
                      lambda t: np.ones(t.size, bool)))
    return cases


def main() -> None:
    seeds, duration, quick = training_run(__doc__, "one seed per profile, 120 s, tst2, rtklib-0759")
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        results, seconds = score_candidates(CANDIDATES, training_cases(Path(tmp), seeds, duration, quick),
                                            "choose_integrity_priors")
    names = list(next(iter(results.values())))
    drives = [n for n in names if n.startswith("sim-")]
    summary: dict[str, dict[str, object]] = {}
    for cand, rows in results.items():
        ok = sum(rows[n]["ok"] for n in drives)
        epochs = sum(rows[n]["epochs"] for n in drives)
        with_pl = sum(rows[n]["ok"] - rows[n]["ok_without_pl"] for n in drives)
        mis_drives = sum(rows[n].get("misleading", 0) for n in drives)
        summary[cand] = {
            "drive_availability": ok / max(epochs, 1),
            "drive_misleading": mis_drives,
            "drive_misleading_pct": 100 * mis_drives / max(with_pl, 1),
            "misleading": int(sum(rows[n].get("misleading", 0) for n in names)),
            "clean_ok": all(rows[c]["availability"] >= MIN_CLEAN_AVAILABILITY and rows[c]["ok_without_pl"] == 0
                            for c in CLEAN if c in rows),
        }
    allowed = [c for c in CANDIDATES if summary[c]["drive_availability"] >= MIN_DRIVE_AVAILABILITY
               and summary[c]["clean_ok"]]
    chosen = min(allowed, key=lambda c: (summary[c]["misleading"], -summary[c]["drive_availability"])) if allowed else None
    columns = ["candidate", "drives ok %", "drives misleading (% of ok)", *[f"{n}: ok % / misleading" for n in names
               if not n.startswith("sim-")], "misleading (drives + tst2)", "allowed", "seconds (esbc)"]
    table_rows: list[list[object]] = []
    for cand, rows in results.items():
        s = summary[cand]
        cells = [f"{100 * rows[n]['availability']:.1f} / " + (str(rows[n]["misleading"]) if "misleading" in rows[n]
                 else "–") + (f" ({rows[n]['ok_without_pl']} without PL)" if rows[n]["ok_without_pl"] else "")
                 for n in names if not n.startswith("sim-")]
        table_rows.append([cand, round(100 * s["drive_availability"], 1),
                           f"{s['drive_misleading']} ({s['drive_misleading_pct']:.2f})", *cells, s["misleading"],
                           cand in allowed, round(seconds[cand].get("esbc", float("nan")), 1)])
    report_choice(OUT, "Choosing the multi-fault integrity priors on training data",
                  "python benchmarks/choose_integrity_priors.py", columns, table_rows, chosen,
                  (f"WLS, default integrity (fde); rule: fewest misleading epochs (drives + tst2) among the "
                   f"candidates with pooled drive availability >= {MIN_DRIVE_AVAILABILITY:.0%} and clean-set "
                   f"availability >= {MIN_CLEAN_AVAILABILITY:.0%} with finite levels; chosen: {chosen}. "
                   "Training data only: bench_urban.py reports seeds 1-N."), quick,
                  seeds=seeds, duration_s=duration, candidates=CANDIDATES, summary=summary, cases=results,
                  seconds=seconds, total_seconds=time.perf_counter() - t0)


if __name__ == "__main__":
    main()
