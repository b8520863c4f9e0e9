"""The fixed-model batch smoother by motion and measurement set, against the position-domain models.

Rows (3D RMS, horizontal RMS, 95th percentile and max of the 3D error, m, over the ``ok``
epochs, and how many there are):

- :func:`~gnss_cli.pipeline.smoother.smooth_segments` for every motion
  (``quadrature`` lag 3, ``cv``, ``ca``, ``static``) and measurement set (pseudorange;
  pseudorange + Doppler; + phase, and pseudorange + phase, where the file has phase), and
  quadrature lag 1 (the trapezoid) with pseudoranges and Doppler. Column ``WLS-ok``: the 3D RMS
  over the epochs where both it and WLS are ``ok`` (the position-domain models smooth only those).

Data: the Yamatogawa walk against its RTK trajectory; tst2 (urban, static) on its 157 truth
epochs; simulated 1 Hz flights (600 s, GPS, ``--seeds``) with ``--errors noise`` (solved with
``--iono none --tropo none``) and ``--errors all``; the seed draws the path, the start time and
the errors.

The position-domain models this smoother replaced (``stls --lag 3 --model pva|static|kinematic``
before the method vocabulary of ``smoother``) were measured on the same data with the code of
commit 6b48f15; their numbers are in ``docs/results.md``.

Usage: ``python benchmarks/bench_smoother.py [--seeds 11,12,13]`` (prints tables, writes
``benchmarks/results/bench_smoother.json``).
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from gnss_cli.config import load_config
from gnss_cli.gnss.frames import ecef2enu_rotation, ecef2geodetic
from gnss_cli.gnss.time import gps_s2week_tow
from gnss_cli.io.reference import reference_from_csv, reference_from_pos
from gnss_cli.pipeline import load_epochs, solve_method
from gnss_cli.sim.error_sources import parse_error_list
from gnss_cli.sim.scenario import ScenarioConfig, run_scenario, write_scenario

HERE = Path(__file__).resolve().parent
RINEX = HERE.parents[1] / "shared" / "rinex"
if not RINEX.is_dir():
    RINEX = Path("/work/shared/rinex")
TST_TRUTH = np.array([-2418077.2710, 5386069.6872, 2405174.1252])
TST_TOW = (270149.0, 270305.0)
MOTIONS = ("quadrature", "cv", "ca", "static")


def stats(x: np.ndarray, ref: np.ndarray) -> dict[str, float]:
    """3D RMS, horizontal RMS, 95th percentile and max of the 3D error (m) where both are finite."""
    ok = np.isfinite(x).all(axis=1) & np.isfinite(ref).all(axis=1)
    if not ok.any():
        return {"rms_3d_m": float("nan"), "rms_h_m": float("nan"), "p95_3d_m": float("nan"),
                "max_3d_m": float("nan"), "epochs": 0}
    lat, lon, _ = ecef2geodetic(ref[ok])
    enu = np.einsum("tij,tj->ti", ecef2enu_rotation(lat, lon), x[ok] - ref[ok])
    e3 = np.linalg.norm(enu, axis=1)
    return {"rms_3d_m": float(np.sqrt(np.mean(e3**2))), "rms_h_m": float(np.sqrt(np.mean(np.sum(enu[:, :2] ** 2, axis=1)))),
            "p95_3d_m": float(np.percentile(e3, 95)), "max_3d_m": float(e3.max()), "epochs": int(ok.sum())}


def simulate(out: Path, errors: str, seed: int, duration_s: float = 600.0) -> Path:
    base = ScenarioConfig()
    cfg = replace(base, trajectory="standard-flight", duration_s=duration_s, interval_s=1.0, seed=seed,
                  errors=base.errors.with_sources(parse_error_list(errors)))
    write_scenario(run_scenario(cfg), out)
    return out


def data_sets(tmp: Path, seeds: list[int]) -> list[tuple[str, Path, list[Path], dict[str, object], object]]:
    """``(name, obs, navs, base options, reference(t, tow) -> (T, 3) with NaN outside the scored epochs)``."""
    out = []
    d = RINEX / "yamatogawa-2010006-kinematic"
    out.append(("yamatogawa", d / "yamatogawa_rover.obs", [d / "brdc0060.10n"], {},
                lambda t, tow, d=d: reference_from_pos(d / "rtk_ref_rover.pos", t, np.zeros_like(t))))
    d = RINEX / "tst2-2020155-urban-static"

    def tst_ref(t: np.ndarray, tow: np.ndarray) -> np.ndarray:
        inside = (tow >= TST_TOW[0] - 0.01) & (tow <= TST_TOW[1] + 0.01)
        return np.where(inside[:, None], TST_TRUTH, np.nan)

    out.append(("tst2", d / "2020_06_03_TST_03.obs.gz", sorted(d.glob("hksc155d.20?")), {}, tst_ref))
    for errors in ("noise", "all"):
        for seed in seeds:
            f = simulate(tmp / f"{errors}{seed}", errors, seed)
            base = {"iono": "none", "tropo": "none"} if errors == "noise" else {}
            out.append((f"flight {errors} seed {seed}", f / "obs.rnx", [f / "nav.rnx"], base,
                        lambda t, tow, f=f: reference_from_csv(f / "truth.csv", t)))
    return out


def _scored(sol, ref: np.ndarray, wls=None) -> dict[str, float]:  # type: ignore[no-untyped-def]
    """Statistics over the ``ok`` epochs; with ``wls`` also the 3D RMS over the epochs both have ``ok``
    (the position-domain models smooth only the WLS fixes)."""
    out = stats(np.where((sol.status == "ok")[:, None], sol.x_ecef_m, np.nan), ref)
    if wls is not None:
        both = (sol.status == "ok") & (wls.status == "ok")
        out["rms_3d_wls_ok_m"] = stats(np.where(both[:, None], sol.x_ecef_m, np.nan), ref)["rms_3d_m"]
    return out


def measurement_sets(data) -> list[frozenset[str]]:  # type: ignore[no-untyped-def]
    sets = [frozenset({"pseudorange"})]
    if data.range_rate_m_s is not None:
        sets.append(frozenset({"pseudorange", "doppler"}))
    if data.phase_m is not None:
        sets.append(frozenset({"pseudorange", "phase"}))
        if data.range_rate_m_s is not None:
            sets.append(frozenset({"pseudorange", "doppler", "phase"}))
    return sets


def new_rows(obs: Path, navs: list[Path], base: dict[str, object], ref_of) -> dict[str, dict]:  # type: ignore[no-untyped-def]
    from gnss_cli.pipeline.smoother import smooth_segments

    config = load_config(None, {**base, "methods": "wls,smoother", "environment": "open"})  # as measured
    data = load_epochs(obs, navs, config)  # the epochs of a smoothing run: with carrier phase where the file has it
    wls = solve_method(data, "wls", config)
    t = data.time_gps_s
    ref = ref_of(t, gps_s2week_tow(t)[1])
    rows: dict[str, dict] = {"wls": _scored(wls, ref)}
    for kinds in measurement_sets(data):
        label = "+".join(k for k in ("pseudorange", "doppler", "phase") if k in kinds)
        runs = [(m, 3) for m in MOTIONS] + ([("quadrature", 1)] if kinds == {"pseudorange", "doppler"} else [])
        for motion, lag in runs:
            t0 = time.perf_counter()
            sol, models = smooth_segments(data, wls, config, motion=motion, lag=lag, measurements=kinds)
            name = f"smoother {motion}{' lag 1' if lag == 1 else ''} {label}"
            rows[name] = _scored(sol, ref, wls)
            rows[name]["seconds"] = time.perf_counter() - t0
            rows[name]["failed_segments"] = sum(m.status == "failed" for m in models)
    return rows


def mean_rows(table: dict[str, dict[str, dict]], prefix: str) -> dict[str, dict]:
    sets = [v for k, v in table.items() if k.startswith(prefix)]
    return {n: {k: (int(sum(s[n][k] for s in sets)) if k == "epochs" else float(np.mean([s[n][k] for s in sets])))
                for k in ("rms_3d_m", "rms_h_m", "p95_3d_m", "max_3d_m", "epochs")} for n in sets[0]}


def print_table(title: str, rows: dict[str, dict]) -> None:
    print(f"\n{title}\n{'method':<48} {'3D RMS':>8} {'H RMS':>8} {'p95':>8} {'max':>8} {'epochs':>7} {'WLS-ok':>8}")
    for name, r in rows.items():
        print(f"{name:<48} {r['rms_3d_m']:8.3f} {r['rms_h_m']:8.3f} {r['p95_3d_m']:8.3f} {r['max_3d_m']:8.3f} {r['epochs']:7d}"
              + (f" {r['rms_3d_wls_ok_m']:8.3f}" if "rms_3d_wls_ok_m" in r else "") + (f"  {r['error']}" if "error" in r else ""))


def summary_table(results: dict[str, object], seeds: list[int]) -> dict[str, object]:
    """The results page's fields (``title``, ``command``, ``table``): one row per data set and run,
    the simulated flights as their mean over the seeds."""
    sets: dict[str, dict[str, dict]] = results["sets"]  # type: ignore[assignment]
    shown = {**{k: v for k, v in sets.items() if not k.startswith("flight")},
             **{k.removeprefix("mean "): v for k, v in results.items() if k.startswith("mean ")}}  # type: ignore[misc]
    rows = [[name, method, *(round(r[k], 3) for k in ("rms_3d_m", "rms_h_m", "p95_3d_m", "max_3d_m")), r["epochs"]]
            for name, table in shown.items() for method, r in table.items() if "error" not in r]
    return {"title": "The smoother's motions by measurement set",
            "command": f"python benchmarks/bench_smoother.py --seeds {','.join(map(str, seeds))}",
            "notes": "3D RMS, horizontal RMS, 95th percentile and largest 3D error (m) over each run's ok epochs; "
                     "simulated flights: mean over the seeds (each seed draws its path, start time and errors).",
            "table": {"columns": ["data", "run", "3D RMS", "H RMS", "p95", "max", "epochs"], "rows": rows}}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seeds", default="11,12,13")
    parser.add_argument("--sets", default="", help="comma list of data set name prefixes (default: all)")
    args = parser.parse_args()
    seeds = [int(s) for s in args.seeds.split(",")]
    table: dict[str, dict[str, dict]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for name, obs, navs, base, ref_of in data_sets(Path(tmp), seeds):
            if args.sets and not any(name.startswith(p) for p in args.sets.split(",")):
                continue
            table[name] = new_rows(obs, navs, base, ref_of)
            print_table(name, table[name])
    results: dict[str, object] = {"sets": table}
    for prefix in ("flight noise", "flight all"):
        if any(k.startswith(prefix) for k in table):
            results[f"mean {prefix}"] = rows = mean_rows(table, prefix)
            print_table(f"{prefix}, mean over seeds {seeds}", rows)
    results.update(summary_table(results, seeds))
    path = HERE / "results" / "bench_smoother.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(results, indent=1) + "\n")


if __name__ == "__main__":
    main()
