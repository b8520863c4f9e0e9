"""How ``configs/urban.toml``'s ``[nlos] min_direct_dof`` was set: on training data only.

    python benchmarks/choose_direct_dof.py [--quick]

With the NLOS detector on, an epoch whose direct satellites (those it leaves at full weight) cannot
fix it alone keeps its suspected reflections at a hundredth of their weight; they pull the fix and
are all that test it. ``min_direct_dof = m`` makes an ``ok`` ls/wls epoch ``nlos_dependent`` when
its direct satellites leave fewer than ``m`` redundant measurements (docs/integrity.md, "Fixes that
rest on suspected reflections"). It trades availability for closer ``ok`` fixes, so it is not a
packaged default; this script measures the trade on the training data and applies the rule below.

Training data: the simulated urban drives of seeds 101-110 (``choose_nlos.py``'s; ``bench_urban.py``
reports seeds 1-20), both receiver profiles, 300 s at 1 Hz, against the simulator's truth; tst2
(against its truth) and smartloc-berlin (availability only). Candidates: WLS with ``--integrity
off``, and with ``configs/urban.toml`` at ``min_direct_dof`` 0 (off), 1, 2 and 3. Per profile,
pooled over its drives: the share of ``ok`` epochs, the 3D RMS of the ``ok`` epochs and its ratio
to the integrity-off RMS of the same drives (every epoch with a fix).

Rule: the smallest ``min_direct_dof`` whose ratio is at most 0.5 in both profiles (the issue's
bound for street canyons); none (0) when no candidate reaches it. Prints a table and writes
``benchmarks/results/choose_direct_dof.json``. About 15 minutes on one core (tst2 with the
multi-satellite levels is the slow case).
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from gnss_cli.config import load_config
from gnss_cli.pipeline import process

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_urban import method_row, real_cases, simulated_cases  # noqa: E402
from choose_cn0_weights import training_run  # noqa: E402
from choose_nlos import PROFILES, TRAINING_SEEDS  # noqa: E402
from results_page import results_json  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "benchmarks" / "results" / "choose_direct_dof.json"
URBAN = ROOT / "configs" / "urban.toml"
VALUES = (0, 1, 2, 3)
MAX_RATIO = 0.5
CANDIDATES: dict[str, tuple[Path | None, dict[str, object]]] = {
    "integrity off": (None, {"integrity": "off"}),
    **{f"urban, min_direct_dof {m}": (URBAN, {"urban.nlos_min_direct_dof": m}) for m in VALUES},
}
"""Each candidate's settings file (None: the packaged defaults) and overrides."""


def pooled(rows: list[dict[str, object]]) -> dict[str, float | None]:
    """``ok`` share (%) and 3D RMS (m) of the ``ok`` epochs, pooled over ``rows`` (``method_row``'s)."""
    ok = sum(int(r["ok"]) for r in rows)  # type: ignore[call-overload]
    epochs = sum(int(r["epochs"]) for r in rows)  # type: ignore[call-overload]
    ss = sum(float(r["rms_3d_m"]) ** 2 * int(r["ok"]) for r in rows if r.get("rms_3d_m") is not None)  # type: ignore[arg-type]
    return {"ok_pct": 100.0 * ok / max(epochs, 1), "rms_3d_ok_m": float(np.sqrt(ss / ok)) if ok else None}


def main() -> None:
    seeds, duration, quick = training_run(__doc__, "one seed per profile, 120 s, tst2")
    seeds = seeds if quick else TRAINING_SEEDS
    t0 = time.perf_counter()
    results: dict[str, dict[str, dict[str, object]]] = {c: {} for c in CANDIDATES}
    with tempfile.TemporaryDirectory() as tmp:
        for name, obs, navs, systems, ref_at, keep_at, *_ in simulated_cases(seeds, duration, Path(tmp)) + real_cases(quick):
            for cand, (path, over) in CANDIDATES.items():
                cfg = load_config(path, {"methods": "wls", **({"systems": systems} if systems else {}), **over})
                res = process(obs, navs, cfg)
                t = res.epochs.time_gps_s
                keep = keep_at(t)
                results[cand][name] = method_row(res.solutions["wls"], ref_at(t[keep]), keep)
            print(f"choose_direct_dof: {name} ({time.perf_counter() - t0:.0f} s)", file=sys.stderr)
    summary: dict[str, dict[str, dict[str, float | None]]] = {}
    for cand, by_case in results.items():
        summary[cand] = {p: pooled([r for n, r in by_case.items() if n.startswith(f"sim-{p}-")]) for p in PROFILES}
    off = summary["integrity off"]
    for cand in CANDIDATES:
        for p in PROFILES:
            rms, rms_off = summary[cand][p]["rms_3d_ok_m"], off[p]["rms_3d_ok_m"]
            summary[cand][p]["ratio_to_off"] = rms / rms_off if rms and rms_off else None
    reach = [m for m in VALUES[1:] if all((summary[f"urban, min_direct_dof {m}"][p]["ratio_to_off"] or np.inf)
                                          <= MAX_RATIO for p in PROFILES)]
    chosen = min(reach) if reach else 0
    real = [n for n in results["integrity off"] if not n.startswith("sim-")]
    columns = ["candidate", *[f"drives, {p}: ok / RMS of ok / ratio to off" for p in PROFILES],
               *[f"{n}: ok / RMS of ok" for n in real]]
    rows: list[list[object]] = []
    for cand in CANDIDATES:
        cells = [f"{s['ok_pct']:.1f} % / {s['rms_3d_ok_m']:.2f} m / {s['ratio_to_off']:.2f}"
                 for s in (summary[cand][p] for p in PROFILES)]
        cells += [f"{100 * results[cand][n]['availability']:.1f} % / "  # type: ignore[operator]
                  + (f"{results[cand][n]['rms_3d_m']:.2f} m" if results[cand][n].get("rms_3d_m") else "–") for n in real]
        rows.append([cand, *cells])
    print("| " + " | ".join(columns) + " |\n|" + "---|" * len(columns))
    print("\n".join("| " + " | ".join(str(c) for c in r) + " |" for r in rows))
    print(f"chosen: min_direct_dof {chosen}")
    if not quick:
        OUT.write_text(results_json({
            "title": "Setting min_direct_dof on training data", "command": "python benchmarks/choose_direct_dof.py",
            "table": {"columns": columns, "rows": rows},
            "notes": (f"WLS; configs/urban.toml with each min_direct_dof; chosen: {chosen} (the smallest whose ok "
                      f"epochs' 3D RMS is at most {MAX_RATIO} x integrity off's in both profiles). Training data "
                      "only: bench_urban.py reports other seeds."),
            "seeds": seeds, "duration_s": duration, "summary": summary, "chosen": chosen,
            "cases": {c: {n: {k: v for k, v in r.items() if k != "statuses"} for n, r in by.items()}
                      for c, by in results.items()},
            "seconds": time.perf_counter() - t0}))
        print(f"wrote {OUT}", file=sys.stderr)


if __name__ == "__main__":
    main()
