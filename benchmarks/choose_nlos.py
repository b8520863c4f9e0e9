"""How the settings of ``[nlos]`` (the detector of persistent reflections) were chosen: on training data only.

    python benchmarks/choose_nlos.py [--quick]

Training data: simulated urban drives with seeds 101-110 (``bench_urban.py`` reports seeds 1-20),
both receiver profiles, 300 s at 1 Hz (against the simulator's truth, and its ``faults.csv``
labels); tst2 (against its truth); smartloc-berlin (availability only: no reference); ESBC, a
clean station (24 h at 30 s), which must not change. For each candidate -- ``off``, and ``arcs``
with a few C/N0 thresholds (enter/exit, dB), redundancies (``min_dof``), ``failed_epochs``
"keep" or "retry", the delay test of the C/N0 spans, the residual CUSUM
(``residual_k``/``residual_h``) and the down-weighting of the spans an epoch's redundancy keeps
(``variance_factor`` 1, 10, 100) -- ``wls`` with the default integrity (``fde``) and every other
option at its default. Per case: availability, misleading epochs, 3D RMS of the ``ok`` epochs,
satellite-epochs excluded; on the drives the share of NLOS and of LOS satellite-epochs excluded
or down-weighted below 10 % (``bench_urban.nlos_handling``).

Rule: the allowed candidates have no more misleading epochs (summed over the cases with a
reference) than ``off``, exclude at most 5 % of the LOS satellite-epochs of the drives, keep the
availability of tst2 and smartloc-berlin within 2 points of ``off``'s, and on ESBC exclude no
more satellite-epochs than ``off`` (clean signals: nothing to flag) with its RMS within 1 cm;
among them, the one with the lowest score (the mean RMS over ``off``'s) of those that surely take at
least 90 % of the drives' NLOS satellite-epochs out or below a tenth of their weight (the share the
issue asks of the canyons): in each receiver profile, the lower end of a 90 % bootstrap interval
over the drives (``scipy.stats.bootstrap``, each drive one sample) of the mean share per drive is
at least 90 % -- a one-sided 95 % bound on what an unseen drive of that profile gets. When none
does, the one with the largest such bound. ``off`` is
chosen when no ``arcs`` candidate is allowed. The candidates with a delay test
(``cn0_min_delay_m``: a C/N0 span stays out only when the fix without it predicts the
satellite's pseudoranges short by at least that much, so that an attenuated direct signal is
kept) were added when the detector was made the default: the rule before, the largest NLOS
share, took the C/N0 spans without it (99.2 %), which cost the pedestrian Yamatogawa walk
(not a canyon) 7-11 cm of horizontal RMS in ``smoother`` and ``kf``. The candidates with
``cn0_delay_source = "doppler"`` measure that delay against the satellite's own range rates
instead of a fix (the span's code-minus-Doppler level over that of the direct epochs beside it).
The candidates with ``cn0_delay_sigmas`` keep a span in only when it is surely early (its delay
plus that many of its standard deviations below the threshold) and down-weight the spans that
are neither surely late nor surely early: where the satellites left are few and on one side, the
fix's prediction is uncertain by more than a reflection's delay.
The chosen candidate's
values are the packaged ``[nlos]`` settings (``gnss_cli/configs/default.toml`` says what the
detector costs away from street canyons). Prints a table and writes
``benchmarks/results/choose_nlos.json``.
About 8 minutes on one core.

Why ten seeds and a bound: the choice was first made on seeds 101-103, where the chosen candidate
took 92.0 % of the drives' reflections out (pooled; each drive 90-96 %) and then 85.5-86.3 % of
the evaluation drives': three drives per profile hold too few reflection spans to tell a share
near the 90 % bound from one below it (as ``choose_nominal_bias.py`` found for its misleading
rate). On seeds 101-110 the rule took the pooled share (the candidate "7/4 dB, dof 2, delay 0 m":
91.0 %, each drive 76-98 %) and the evaluation drives then got 89.4 % / 90.6 %: a pooled share
just over the bar says nothing about the next drive, whose share spreads by 5-10 points. The
bound over the drives asks the training data for what the bar means. The evaluation seeds stay
unseen.
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.stats import bootstrap

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_urban import nlos_handling  # noqa: E402
from choose_cn0_weights import score_candidates, training_cases, training_run  # noqa: E402
from results_page import results_json  # noqa: E402

from gnss_cli.pipeline import RunResult  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "benchmarks" / "results" / "choose_nlos.json"
ARCS = {"nlos.detector": "arcs", "nlos.cn0_enter_db": 7.0, "nlos.cn0_exit_db": 4.0, "nlos.min_dof": 2,
        "nlos.failed_epochs": "retry", "nlos.variance_factor": 100.0, "nlos.cn0_min_delay_m": -np.inf,
        "nlos.cn0_delay_source": "fix", "nlos.cn0_delay_sigmas": 0.0}
"""The base of every ``arcs`` candidate: each key a candidate varies is set here, so that a run
does not depend on the packaged values it chooses (the kept spans at a hundredth of their weight,
no delay test, unless the
candidate says so)."""
CANDIDATES: dict[str, dict[str, object]] = {
    "off": {"nlos.detector": "off"},
    "C/N0 7/4 dB, dof 3, keep": {**ARCS, "nlos.min_dof": 3, "nlos.failed_epochs": "keep"},
    "C/N0 7/4 dB, dof 3": {**ARCS, "nlos.min_dof": 3},
    "C/N0 7/4 dB, dof 2": ARCS,
    "C/N0 7/4 dB, dof 1": {**ARCS, "nlos.min_dof": 1},
    "C/N0 6/3 dB, dof 2": {**ARCS, "nlos.cn0_enter_db": 6.0, "nlos.cn0_exit_db": 3.0},
    "C/N0 9/5 dB, dof 2": {**ARCS, "nlos.cn0_enter_db": 9.0, "nlos.cn0_exit_db": 5.0},
    "C/N0 9/5 dB, dof 1": {**ARCS, "nlos.cn0_enter_db": 9.0, "nlos.cn0_exit_db": 5.0, "nlos.min_dof": 1},
    "C/N0 11/6 dB, dof 1": {**ARCS, "nlos.cn0_enter_db": 11.0, "nlos.cn0_exit_db": 6.0, "nlos.min_dof": 1},
    "C/N0 7/4 dB, dof 2, delay 0 m": {**ARCS, "nlos.cn0_min_delay_m": 0.0},
    "C/N0 7/4 dB, dof 2, CUSUM 2/10": {**ARCS, "nlos.residual_k": 2.0, "nlos.residual_h": 10.0},
    "C/N0 9/5 dB, dof 1, kept x10": {**ARCS, "nlos.cn0_enter_db": 9.0, "nlos.cn0_exit_db": 5.0, "nlos.min_dof": 1,
                                     "nlos.variance_factor": 10.0},
    "C/N0 9/5 dB, dof 1, kept x100": {**ARCS, "nlos.cn0_enter_db": 9.0, "nlos.cn0_exit_db": 5.0, "nlos.min_dof": 1,
                                      "nlos.variance_factor": 100.0},
}
KEPT = CANDIDATES["C/N0 9/5 dB, dof 1, kept x100"]
CANDIDATES.update({f"C/N0 9/5 dB, dof 1, kept x100, delay {d:g} m": {**KEPT, "nlos.cn0_min_delay_m": d}
                   for d in (-2.0, -1.0, 0.0, 1.0)})
CANDIDATES.update({f"C/N0 9/5 dB, dof 1, kept x100, Doppler delay {d:g} m":
                   {**KEPT, "nlos.cn0_delay_source": "doppler", "nlos.cn0_min_delay_m": d} for d in (0.0, 1.0, 2.0, 3.0)})
CANDIDATES.update({f"C/N0 7/4 dB, dof 2, delay 0 m, {z:g} sigma": {**ARCS, "nlos.cn0_min_delay_m": 0.0,
                                                                  "nlos.cn0_delay_sigmas": z} for z in (1.0, 2.0)})
CANDIDATES.update({f"C/N0 9/5 dB, dof 1, kept x100, delay 0 m, {z:g} sigma":
                   {**KEPT, "nlos.cn0_min_delay_m": 0.0, "nlos.cn0_delay_sigmas": z} for z in (1.0, 2.0)})
"""Every ``arcs`` candidate keeps the ``[nlos]`` keys neither it nor :data:`ARCS` sets at their packaged values."""
TRAINING_SEEDS = list(range(101, 111))
REAL = ("tst2", "smartloc-berlin")
MAX_LOS_PCT = 5.0
MIN_NLOS_PCT = 90.0
SHARE_CONFIDENCE = 0.90
"""Two-sided level of the bootstrap interval of a profile's mean NLOS share; its lower end is a
one-sided 95 % bound."""
PROFILES = ("single", "dual")
MAX_AVAILABILITY_LOSS = 0.02
MAX_ESBC_RMS_INCREASE_M = 0.01


def _extra(faults: dict[str, pd.DataFrame]):  # noqa: ANN202 - the score_candidates hook
    def extra(name: str, res: RunResult) -> dict[str, object]:
        sol = res.solutions["wls"]
        out: dict[str, object] = {"excluded": int(sol.excluded.sum()) if sol.excluded is not None else 0}
        if name in faults:
            out["nlos"] = nlos_handling(sol, res.epochs, faults[name])
        return out
    return extra


CASE_COLUMNS = ["candidate", "case", "epochs", "ok", "misleading", "rms_3d_m", "p95_3d_m", "max_3d_m", "excluded",
                "nlos_dropped_pct", "los_dropped_pct"]


def case_table(results: dict[str, dict[str, dict[str, object]]]) -> dict[str, object]:
    """Every candidate's cases as one table (columns named once; metres and percent to 3 decimals)."""
    def r(v: object) -> object:
        return round(v, 3) if isinstance(v, float) else v

    rows = [[cand, name, *(r(row.get(c)) for c in CASE_COLUMNS[2:9]),
             *(r(row.get("nlos", {}).get(c)) for c in CASE_COLUMNS[9:])]  # type: ignore[union-attr]
            for cand, by_case in results.items() for name, row in by_case.items()]
    return {"columns": CASE_COLUMNS, "rows": rows}


def _pooled(rows: dict[str, dict[str, object]], key: str) -> float:
    """The ``key`` share (%) of the drives' NLOS or LOS satellite-epochs, pooled over the drives."""
    nl = [r["nlos"] for r in rows.values() if "nlos" in r]
    kind = key.split("_")[0]
    n = sum(x[f"{kind}_candidates"] for x in nl)
    return float(sum(x[key] * x[f"{kind}_candidates"] for x in nl) / max(n, 1))


def share_lower_bound(rows: dict[str, dict[str, object]], profile: str) -> float:
    """A one-sided 95 % lower bound (%) on the mean NLOS share per drive of ``profile``'s drives.

    The lower end of a :data:`SHARE_CONFIDENCE` percentile bootstrap over the drives (each drive one
    sample: its reflections come in spans, so its satellite-epochs are not independent); with a
    single drive, that drive's share."""
    shares = np.array([r["nlos"]["nlos_dropped_pct"] for n, r in rows.items()  # type: ignore[index]
                       if n.startswith(f"sim-{profile}-") and "nlos" in r], dtype=float)
    if shares.size < 2 or np.ptp(shares) == 0.0:
        return float(shares.min()) if shares.size else float("nan")
    res = bootstrap((shares,), np.mean, confidence_level=SHARE_CONFIDENCE, method="percentile",
                    n_resamples=4000, random_state=0)
    return float(res.confidence_interval.low)


def main() -> None:
    seeds, duration, quick = training_run(__doc__, "one seed per profile, 120 s, tst2")
    seeds = seeds if quick else TRAINING_SEEDS
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        cases = training_cases(Path(tmp), seeds, duration, quick)
        faults = {c[0]: pd.read_csv(Path(c[1]).parent / "faults.csv") for c in cases if str(c[0]).startswith("sim-")}
        results, _ = score_candidates(CANDIDATES, cases, "choose_nlos", extra=_extra(faults))
    off = results["off"]
    names = list(off)
    scores, misleading, nlos_pct, los_pct, nlos_low = {}, {}, {}, {}, {}
    for cand, rows in results.items():
        ratios = [rows[n]["rms_3d_m"] / off[n]["rms_3d_m"] for n in names if rows[n].get("rms_3d_m") and off[n].get("rms_3d_m")]
        scores[cand] = float(np.mean(ratios))
        misleading[cand] = int(sum(rows[n].get("misleading", 0) for n in names))
        nlos_pct[cand], los_pct[cand] = _pooled(rows, "nlos_dropped_pct"), _pooled(rows, "los_dropped_pct")
        nlos_low[cand] = {p: share_lower_bound(rows, p) for p in PROFILES}

    def allowed(cand: str) -> bool:
        rows = results[cand]
        esbc = rows.get("esbc", {}).get("rms_3d_m")
        return (misleading[cand] <= misleading["off"] and los_pct[cand] <= MAX_LOS_PCT
                and all(rows[n]["availability"] >= off[n]["availability"] - MAX_AVAILABILITY_LOSS for n in REAL if n in rows)
                and (esbc is None or (esbc <= off["esbc"]["rms_3d_m"] + MAX_ESBC_RMS_INCREASE_M
                                      and rows["esbc"]["excluded"] <= off["esbc"]["excluded"])))

    arcs = [c for c in CANDIDATES if c != "off" and allowed(c)]
    def surely(cand: str) -> float:  # the lower of the two profiles' bounds
        return min(nlos_low[cand].values())

    enough = [c for c in arcs if surely(c) >= MIN_NLOS_PCT]
    chosen = (min(enough, key=lambda c: scores[c]) if enough
              else max(arcs, key=lambda c: (round(surely(c), 1), -scores[c])) if arcs else "off")
    lines = ["| candidate | " + " | ".join(names) + " | NLOS / LOS out % | NLOS out, 95 % lower bound per drive, "
             "single / dual % | score | misleading | allowed |",
             "|---|" + "---|" * (len(names) + 5)]
    table_rows: list[list[object]] = []
    for cand, rows in results.items():
        cells = [f"{100 * rows[n]['availability']:.0f} % / " + (f"{rows[n]['rms_3d_m']:.2f} m" if rows[n].get("rms_3d_m")
                 else "–") + f" / {rows[n]['excluded']}" for n in names]
        ok = "yes" if cand == "off" or allowed(cand) else "no"
        low = " / ".join(f"{nlos_low[cand][p]:.1f}" for p in PROFILES)
        lines.append(f"| {cand} | " + " | ".join(cells) + f" | {nlos_pct[cand]:.1f} / {los_pct[cand]:.1f} | {low} | "
                     f"{scores[cand]:.3f} | {misleading[cand]} | {ok} |")
        table_rows.append([cand, *cells, f"{nlos_pct[cand]:.1f} / {los_pct[cand]:.1f}", low, round(scores[cand], 3),
                           misleading[cand], ok])
    print("\n".join(lines))
    print(f"chosen: {chosen} (NLOS {nlos_pct[chosen]:.1f} %, at least {surely(chosen):.1f} % per drive (95 %), "
          f"LOS {los_pct[chosen]:.1f} %, score {scores[chosen]:.3f})")
    if not quick:
        OUT.write_text(results_json({"title": "Choosing the NLOS detector on training data",
                                   "command": "python benchmarks/choose_nlos.py",
                                   "table": {"columns": ["candidate", *[f"{n}: ok / RMS / excluded" for n in names],
                                                         "NLOS / LOS satellite-epochs out, % (drives)",
                                                         "NLOS out, 95 % lower bound per drive, single / dual %",
                                                         "score (RMS / off's, mean)", "misleading epochs", "allowed"],
                                             "rows": table_rows},
                                   "notes": f"WLS, default integrity; chosen: {chosen}. Training data only: "
                                            "bench_urban.py reports other seeds.",
                                   "seeds": seeds, "duration_s": duration, "candidates": CANDIDATES,
                                   "scores": scores, "misleading": misleading, "nlos_dropped_pct": nlos_pct,
                                   "los_dropped_pct": los_pct, "nlos_dropped_low_pct": nlos_low, "chosen": chosen, "cases": case_table(results),
                                   "seconds": time.perf_counter() - t0}))


if __name__ == "__main__":
    main()
