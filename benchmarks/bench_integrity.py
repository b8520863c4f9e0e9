"""Integrity monitoring (FDE) measured: simulated random outliers, rtklib-0759 with injected
biases, clean rtklib-0759, and the urban static set tst2-2020155 against its truth.

    python benchmarks/bench_integrity.py [--quick]

Prints one table per experiment and writes ``benchmarks/results/integrity.json``. The real-data
rows need ``../shared/rinex`` (skipped with a note when it is missing).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np

from gnss_cli.config import load_config
from gnss_cli.gnss.time import gps_s2week_tow
from gnss_cli.pipeline import process
from gnss_cli.pipeline.epochs import load_epochs
from gnss_cli.pipeline.snapshot import solve_method
from gnss_cli.sim.scenario import ScenarioConfig, config_from_mapping, run_scenario, write_scenario

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "rinex"
D0759 = SHARED / "rtklib-0759"
REF_0759 = np.array([-3976219.1879, 3382371.6041, 3652511.1428])
TST = SHARED / "tst2-2020155-urban-static"
TST_TRUTH = np.array([-2418077.2710, 5386069.6872, 2405174.1252])
TST_TOW = (270149.0, 270305.0)


def _rms(err: np.ndarray) -> float:
    err = err[np.isfinite(err)]
    return float(np.sqrt(np.mean(err**2))) if err.size else float("nan")


def simulated(trajectory: str, seed: int, duration: float, systems: str) -> dict[str, object]:
    """Clean and random-outlier runs of one scenario, solved with the default settings (FDE)."""
    base = config_from_mapping({"simulate": {"trajectory": trajectory, "duration_s": duration, "seed": seed,
                                             "systems": systems, "errors": "all"}}, ScenarioConfig())
    faulty = replace(base, errors=replace(base.errors, outlier_rate=0.05, outlier_range_m=(50.0, 500.0)))
    cfg = load_config()
    out: dict[str, object] = {"trajectory": trajectory, "seed": seed, "systems": systems}
    with tempfile.TemporaryDirectory() as tmp:
        for name, scen_cfg in (("clean", base), ("faulty", faulty)):
            scen = run_scenario(scen_cfg)
            folder = Path(tmp) / name
            write_scenario(scen, folder)
            res = process(folder / "obs.rnx", [folder / "nav.rnx"], cfg)
            sol, data = res.solutions["wls"], res.epochs
            truth = scen.observations.rx_pos_ecef_m
            idx = np.searchsorted(scen.observations.t_gps_s, data.time_gps_s)
            ok = sol.status == "ok"
            err = np.linalg.norm(sol.x_ecef_m - truth[idx], axis=1)
            excluded = sol.excluded
            row = {"epochs": int(ok.size), "ok": int(ok.sum()), "rms_3d_m": _rms(err[ok]),
                   "epochs_with_exclusion": int(excluded.any(axis=1).sum())}
            bias = scen.observations.outlier_bias_m
            if bias is not None:
                bias = bias[idx]
                col = {sv: i for i, sv in enumerate(scen.observations.sv)}
                cols = np.array([col[s] for s in data.sv])
                b = bias[:, cols]  # (T, n) in the solution's satellite order
                faulty_t = (b != 0).any(axis=1)
                hit = (excluded & (b != 0)).any(axis=1)
                clean_t = ~faulty_t
                row.update({
                    "faulty_epochs": int(faulty_t.sum()),
                    "faulty_excluded": int(hit[faulty_t].sum()),
                    "faulty_excluded_share": float(hit[faulty_t].mean()) if faulty_t.any() else float("nan"),
                    "clean_epochs_losing_a_satellite_share": float(excluded[clean_t].any(axis=1).mean()),
                    "faulty_not_ok": int((~ok & faulty_t).sum()),
                })
            else:
                row["clean_epochs_losing_a_satellite_share"] = float(excluded.any(axis=1).mean())
            out[name] = row
    out["rms_ratio"] = out["faulty"]["rms_3d_m"] / out["clean"]["rms_3d_m"]  # type: ignore[index]
    return out


def injected_0759(biases: tuple[float, ...] = (50.0, 100.0, 200.0, 500.0)) -> list[dict[str, object]]:
    """rtklib-0759 with a bias on one satellite in 20 epochs, solved with and without FDE."""
    cfg = load_config()
    data = load_epochs(D0759 / "07590920.05o", [D0759 / "07590920.05n"], cfg)
    clean = solve_method(data, "wls", cfg)
    err_clean = np.linalg.norm(clean.x_ecef_m - REF_0759, axis=1)
    j = int(np.argmax(np.isfinite(clean.residuals_m).sum(axis=0)))  # a satellite used throughout
    rows = np.arange(40, 60)
    out = []
    for b in biases:
        pr = data.pr_corrected_m.copy()
        pr[rows, j] += b
        bad = replace(data, pr_corrected_m=pr)
        row: dict[str, object] = {"bias_m": b, "satellite": str(data.sv[j]), "epochs": int(rows.size)}
        for mode in ("off", "fde"):
            sol = solve_method(bad, "wls", replace(cfg, integrity=mode))
            err = np.linalg.norm(sol.x_ecef_m - REF_0759, axis=1)[rows]
            row[f"{mode}_rms_3d_m"] = _rms(err)
            if mode == "fde":
                row["excluded"] = int(sol.excluded[rows, j].sum())
                row["other_exclusions"] = int(sol.excluded.sum() - sol.excluded[rows, j].sum())
                row["ok"] = int((sol.status[rows] == "ok").sum())
        row["clean_rms_3d_m"] = _rms(err_clean[rows])
        out.append(row)
    return out


def clean_0759() -> dict[str, object]:
    cfg = load_config(None, {"methods": "all"})
    res = process(D0759 / "07590920.05o", [D0759 / "07590920.05n"], cfg)
    return {m: {"excluded": int(s.excluded.sum()) if s.excluded is not None else 0,
                "ok": int((s.status == "ok").sum()), "epochs": int(s.status.size)} for m, s in res.solutions.items()}


def urban_tst(settings: dict[str, object]) -> dict[str, object]:
    cfg = load_config(None, {"environment": "open", **settings})  # as measured: the open-sky settings
    navs = sorted(TST.glob("hksc155d.20?"))
    res = process(TST / "2020_06_03_TST_03.obs.gz", navs, cfg)
    sol = res.solutions["wls"]
    _, tow = gps_s2week_tow(res.epochs.time_gps_s)
    w = (tow >= TST_TOW[0] - 0.01) & (tow <= TST_TOW[1] + 0.01)
    ok = w & (sol.status == "ok")
    err = np.linalg.norm(sol.x_ecef_m - TST_TRUTH, axis=1)
    words, counts = np.unique(sol.status[w], return_counts=True)
    return {"settings": settings, "epochs": int(w.sum()), "ok": int(ok.sum()), "ok_share": float(ok.sum() / w.sum()),
            "rms_3d_ok_m": _rms(err[ok]), "rms_3d_all_m": _rms(err[w]),
            "mean_excluded": float(sol.excluded[w].sum(axis=1).mean()), "statuses": dict(zip(words.tolist(), counts.tolist()))}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--quick", action="store_true", help="one seed, 600 s")
    args = parser.parse_args()
    seeds, duration = ((1,), 600.0) if args.quick else ((1, 2, 3), 1800.0)
    results: dict[str, object] = {"simulated": []}
    print("simulated, random outliers 50-500 m in 5 % of epochs (errors: all; default settings)")
    print(f"{'traj':8} {'sys':4} {'seed':>4} {'faulty':>6} {'excl %':>7} {'clean lose %':>12} {'rms clean':>9} {'rms faulty':>10} {'ratio':>6}")
    for traj in ("static", "standard-flight"):
        for systems in ("G", "G,E"):
            for seed in seeds:
                r = simulated(traj, seed, duration, systems)
                results["simulated"].append(r)  # type: ignore[union-attr]
                f, c = r["faulty"], r["clean"]
                print(f"{traj:8} {systems:4} {seed:4d} {f['faulty_epochs']:6d} {100 * f['faulty_excluded_share']:7.2f} "
                      f"{100 * f['clean_epochs_losing_a_satellite_share']:12.2f} {c['rms_3d_m']:9.3f} {f['rms_3d_m']:10.3f} {r['rms_ratio']:6.3f}")
    if SHARED.is_dir():
        results["rtklib_0759_injected"] = injected_0759()
        print("\nrtklib-0759, bias on one satellite in epochs 40-59 (wls)")
        print(f"{'bias m':>6} {'sat':4} {'excluded':>8} {'other':>5} {'rms off':>8} {'rms fde':>8} {'rms clean':>9}")
        for r in results["rtklib_0759_injected"]:  # type: ignore[union-attr]
            print(f"{r['bias_m']:6.0f} {r['satellite']:4} {r['excluded']:5d}/20 {r['other_exclusions']:5d} {r['off_rms_3d_m']:8.2f} "
                  f"{r['fde_rms_3d_m']:8.2f} {r['clean_rms_3d_m']:9.2f}")
        results["rtklib_0759_clean"] = clean_0759()
        print("\nclean rtklib-0759, all methods:", json.dumps(results["rtklib_0759_clean"]))
        results["tst_urban"] = [urban_tst(s) for s in ({}, {"max_exclusions": 1000}, {"integrity": "check"},
                                                        {"integrity": "off"}, {"snr_mask_dbhz": 30.0})]
        print("\ntst2-2020155-urban-static, truth window (157 epochs), all systems")
        for r in results["tst_urban"]:  # type: ignore[union-attr]
            print(f"  {json.dumps(r['settings']):32} ok {r['ok']}/{r['epochs']} ({100 * r['ok_share']:.1f} %), "
                  f"3D RMS ok {r['rms_3d_ok_m']:.2f} m, all {r['rms_3d_all_m']:.2f} m, mean excluded {r['mean_excluded']:.2f}")
    else:
        print(f"\n{SHARED} not found: real-data rows skipped", file=sys.stderr)
    out = ROOT / "benchmarks" / "results" / "integrity.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(results, indent=1) + "\n")
    print(f"\nwrote {out}")


if __name__ == "__main__":
    main()
