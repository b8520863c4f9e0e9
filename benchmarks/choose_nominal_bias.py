"""How the default of ``nominal_bias_cn0_sigmas`` was chosen: on training data only.

    python benchmarks/choose_nominal_bias.py [--quick]

The protection levels give every used pseudorange a nominal bias bound ``b_i = beta x`` the C/N0
part of its sigma (docs/integrity.md, "Nominal biases"): reflections last, so a weak signal's
extra error is a bias as much as noise, and several of them at once are what the single-fault
hypotheses miss. ``beta`` changes the levels only (positions, tests and exclusions stay).

Training data (as ``choose_integrity_priors.py``, with more drives): simulated urban drives with
seeds 101-110 (``bench_urban.py`` reports seeds 1-20), both receiver profiles, 300 s at 1 Hz; tst2 (against its truth);
smartloc-berlin, ESBC and rtklib-0759 (levels only). Candidates ``beta`` in {0, 0.5, 1, 1.5, 2,
3, 4}: ``wls`` with every other option at its default. Per case: availability, misleading epochs
(``ok`` with the horizontal error above HPL or the vertical above VPL) and the median HPL / VPL of
the ``ok`` epochs.

Rule: the smallest ``beta`` whose misleading epochs on the drives are at most 0.1 % of their ``ok``
epochs and none on tst2; if none reaches it, the one with the fewest misleading epochs (drives
and tst2), ties to the smaller ``beta``. The price is the levels' size, reported beside it.

Why ten seeds: the first choice was made on seeds 101-103, about 1,750 ``ok`` epochs, in which
0.1 % is under two epochs -- a rate three seeds cannot measure. It chose 3 (one misleading
epoch), which left 0.83 % of the WLS ``ok`` epochs misleading on the dual-profile evaluation
drives. Ten seeds per profile (about 5,800 ``ok`` epochs) make the 0.1 % measurable; the
evaluation seeds stay unseen.
Prints a table and writes ``benchmarks/results/choose_nominal_bias.json``.
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from choose_cn0_weights import report_choice, score_candidates, training_run  # noqa: E402
from choose_integrity_priors import training_cases  # noqa: E402
from gnss_cli.pipeline.results import RunResult  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "benchmarks" / "results" / "choose_nominal_bias.json"
BETAS = (0.0, 0.5, 1.0, 1.5, 2.0, 3.0, 4.0)
CANDIDATES: dict[str, dict[str, object]] = {f"beta {b:g}": {"nominal_bias_cn0_sigmas": b} for b in BETAS}
MAX_DRIVE_MISLEADING_PCT = 0.1
TRAINING_SEEDS = list(range(101, 111))
"""Ten drives per profile (module docstring: why not three)."""


def _levels(name: str, res: RunResult) -> dict[str, object]:
    """Median HPL and VPL (m) of the WLS ``ok`` epochs with finite levels."""
    sol = res.solutions["wls"]
    ok = (sol.status == "ok") & np.isfinite(sol.hpl_m) & np.isfinite(sol.vpl_m)
    if not ok.any():
        return {"median_hpl_m": None, "median_vpl_m": None}
    return {"median_hpl_m": float(np.median(sol.hpl_m[ok])), "median_vpl_m": float(np.median(sol.vpl_m[ok]))}


def main() -> None:
    seeds, duration, quick = training_run(__doc__, "one seed per profile, 120 s, tst2, rtklib-0759")
    seeds = seeds if quick else TRAINING_SEEDS
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        results, seconds = score_candidates(CANDIDATES, training_cases(Path(tmp), seeds, duration, quick),
                                            "choose_nominal_bias", extra=_levels)
    names = list(next(iter(results.values())))
    drives = [n for n in names if n.startswith("sim-")]
    summary: dict[str, dict[str, object]] = {}
    for cand, rows in results.items():
        with_pl = sum(rows[n]["ok"] - rows[n]["ok_without_pl"] for n in drives)
        mis_drives = sum(rows[n].get("misleading", 0) for n in drives)
        summary[cand] = {
            "drive_misleading": mis_drives,
            "drive_misleading_pct": 100 * mis_drives / max(with_pl, 1),
            "tst2_misleading": rows.get("tst2", {}).get("misleading", 0),
            "misleading": int(sum(rows[n].get("misleading", 0) for n in names)),
            "drive_median_vpl_m": float(np.median([rows[n]["median_vpl_m"] for n in drives
                                                   if rows[n]["median_vpl_m"] is not None])),
        }
    meeting = [c for c in CANDIDATES if summary[c]["drive_misleading_pct"] <= MAX_DRIVE_MISLEADING_PCT
               and summary[c]["tst2_misleading"] == 0]
    chosen = meeting[0] if meeting else min(CANDIDATES, key=lambda c: summary[c]["misleading"])
    others = [n for n in names if not n.startswith("sim-")]
    columns = ["candidate", "drives misleading (% of ok)", "drives median VPL, m",
               *[f"{n}: misleading / median HPL, VPL m" for n in others]]
    table_rows: list[list[object]] = []
    for cand, rows in results.items():
        s = summary[cand]
        cells = []
        for n in others:
            r = rows[n]
            lv = ("–" if r["median_hpl_m"] is None else f"{r['median_hpl_m']:.1f}, {r['median_vpl_m']:.1f}")
            cells.append(f"{r.get('misleading', '–')} / {lv}")
        table_rows.append([cand, f"{s['drive_misleading']} ({s['drive_misleading_pct']:.2f})",
                           round(s["drive_median_vpl_m"], 1), *cells])
    report_choice(OUT, "Choosing the nominal bias of the protection levels on training data",
                  "python benchmarks/choose_nominal_bias.py", columns, table_rows, chosen,
                  (f"WLS, every other option at its default; rule: the smallest beta with drive misleading "
                   f"<= {MAX_DRIVE_MISLEADING_PCT} % of ok and none on tst2; chosen: {chosen}. Training data "
                   "only: bench_urban.py reports seeds 1-N."), quick,
                  seeds=seeds, duration_s=duration, candidates=CANDIDATES, summary=summary, cases=results,
                  seconds=seconds, total_seconds=time.perf_counter() - t0)


if __name__ == "__main__":
    main()
