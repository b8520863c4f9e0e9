"""The kf method against WLS: simulated flights, the Yamatogawa walk, and the cost of a day.

1. Simulated 1 Hz flights (600 s, GPS, seeds 11-15) with ``--errors noise`` (processed with
   ``--iono none --tropo none``) and ``--errors all`` (default corrections): 3D RMS, horizontal
   RMS, 95th percentile and max of the 3D error for WLS, kf (RTS smoothed), kf without the
   smoother and kf without Doppler, all with the packaged defaults (``[kalman]``,
   ``doppler_sigma_m_s``: chosen from the literature, not on these sets); the ratio of the kf's
   predicted 3D sd to its actual 3D error; velocity RMS error (m/s) against the truth.
2. Yamatogawa walk (``../shared/rinex``, skipped when missing) against its RTK trajectory.
3. A simulated 1 Hz day (``--hours``, flight): epochs per second of the filter and smoother.

Usage: ``python benchmarks/bench_kf.py [--hours 24]`` (prints tables, writes
``benchmarks/results/bench_kf.json``).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from gnss_cli.config import load_config  # noqa: E402
from gnss_cli.gnss.frames import ecef2enu_rotation, ecef2geodetic  # noqa: E402
from gnss_cli.io.reference import reference_from_csv, reference_from_pos  # noqa: E402
from gnss_cli.pipeline import load_epochs, process, solve_method  # noqa: E402
from gnss_cli.pipeline.kalman import run_kalman  # noqa: E402
from gnss_cli.sim.error_sources import parse_error_list  # noqa: E402
from gnss_cli.sim.scenario import ScenarioConfig, run_scenario, write_scenario  # noqa: E402

SEEDS = (11, 12, 13, 14, 15)
RINEX = REPO.parent / "shared" / "rinex"
VARIANTS = {"kf": {}, "kf (filtered)": {"kalman.output": "filtered"}, "kf (no Doppler)": {"measurements": "pseudorange"}}


def simulate(out: Path, errors: str, seed: int, duration_s: float = 600.0) -> Path:
    base = ScenarioConfig()
    cfg = replace(base, trajectory="standard-flight", duration_s=duration_s, interval_s=1.0, seed=seed,
                  errors=base.errors.with_sources(parse_error_list(errors)))
    write_scenario(run_scenario(cfg), out)
    return out


def stats(x: np.ndarray, ref: np.ndarray) -> dict[str, float]:
    """3D RMS, horizontal RMS, 95th percentile and max of the 3D error (m)."""
    ok = np.isfinite(x).all(axis=1) & np.isfinite(ref).all(axis=1)
    lat, lon, _ = ecef2geodetic(ref[ok])
    enu = np.einsum("tij,tj->ti", ecef2enu_rotation(lat, lon), x[ok] - ref[ok])
    e3 = np.linalg.norm(enu, axis=1)
    return {"rms_3d_m": float(np.sqrt(np.mean(e3**2))), "rms_h_m": float(np.sqrt(np.mean(np.sum(enu[:, :2] ** 2, axis=1)))),
            "p95_3d_m": float(np.percentile(e3, 95)), "max_3d_m": float(e3.max()), "epochs": int(ok.sum())}


def run_set(obs: Path, nav: list[Path], ref_of, base: dict[str, object], truth_v: np.ndarray | None) -> dict[str, dict]:  # type: ignore[no-untyped-def]
    out: dict[str, dict] = {}
    for name, extra in VARIANTS.items():
        result = process(obs, nav, load_config(None, {"methods": "wls,kf", "environment": "open", **base, **extra}))
        ref = ref_of(result.epochs.time_gps_s)
        for method, s in result.solutions.items():
            key = "wls" if method == "wls" else name
            if key in out:
                continue
            row = stats(s.x_ecef_m, ref)
            if method == "kf":
                sd = np.sqrt(np.trace(s.cov_m2[:, :3, :3], axis1=1, axis2=2))
                row["sd_over_error"] = float(np.sqrt(np.nanmean(sd**2)) / row["rms_3d_m"])
            if truth_v is not None and s.vel_ecef_m_s is not None:
                row["vel_rms_m_s"] = float(np.sqrt(np.nanmean(np.sum((s.vel_ecef_m_s - truth_v) ** 2, axis=1))))
            out[key] = row
    return out


def simulated_flights(tmp: Path) -> dict[str, dict]:
    table: dict[str, dict] = {}
    for errors in ("noise", "all"):
        base = {"iono": "none", "tropo": "none"} if errors == "noise" else {}
        for seed in SEEDS:
            d = simulate(tmp / f"{errors}{seed}", errors, seed)
            truth_v = pd.read_csv(d / "truth.csv")[["vx_m_s", "vy_m_s", "vz_m_s"]].to_numpy()
            table[f"{errors} seed {seed}"] = run_set(d / "obs.rnx", [d / "nav.rnx"],
                                                     lambda t, d=d: reference_from_csv(d / "truth.csv", t), base, truth_v)
    return table


def yamatogawa() -> dict[str, dict] | None:
    d = RINEX / "yamatogawa-2010006-kinematic"
    if not d.is_dir():
        return None
    return run_set(d / "yamatogawa_rover.obs", [d / "brdc0060.10n"],
                   lambda t: reference_from_pos(d / "rtk_ref_rover.pos", t, np.zeros_like(t)), {}, None)


def day_speed(tmp: Path, hours: float) -> dict[str, float]:
    d = simulate(tmp / "day", "noise", 5, duration_s=hours * 3600.0)
    cfg = load_config(None, {"methods": "wls,kf", "iono": "none", "tropo": "none"})
    data = load_epochs(d / "obs.rnx", [d / "nav.rnx"], cfg)
    wls = solve_method(data, "wls", cfg)
    out = {"epochs": float(data.time_gps_s.size)}
    for smoother, output in (("rts", "smoothed"), ("none", "filtered")):
        c = replace(cfg, kalman=replace(cfg.kalman, output=output))
        t0 = time.perf_counter()
        run_kalman(data, wls, c)
        out[f"seconds_{smoother}"] = time.perf_counter() - t0
        out[f"epochs_per_s_{smoother}"] = data.time_gps_s.size / out[f"seconds_{smoother}"]
    return out


def print_table(title: str, rows: dict[str, dict]) -> None:
    print(f"\n{title}")
    print(f"{'set':<16} {'method':<18} {'3D RMS':>8} {'H RMS':>8} {'p95':>8} {'max':>8} {'sd/err':>7} {'v RMS':>7}")
    for name, methods in rows.items():
        for m, r in methods.items():
            print(f"{name:<16} {m:<18} {r['rms_3d_m']:8.3f} {r['rms_h_m']:8.3f} {r['p95_3d_m']:8.3f} {r['max_3d_m']:8.3f} "
                  f"{r.get('sd_over_error', float('nan')):7.2f} {r.get('vel_rms_m_s', float('nan')):7.3f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--hours", type=float, default=24.0, help="length of the simulated day, hours (0: skip)")
    args = parser.parse_args()
    results: dict[str, object] = {}
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        flights = simulated_flights(tmp)
        print_table("Simulated flights (600 s, 1 Hz, GPS)", flights)
        for errors in ("noise", "all"):
            sets = [v for k, v in flights.items() if k.startswith(errors)]
            mean = {m: float(np.mean([s[m]["rms_3d_m"] for s in sets])) for m in sets[0]}
            ratio = {m: float(np.mean([s[m]["rms_3d_m"] / s["wls"]["rms_3d_m"] for s in sets])) for m in sets[0]}
            print(f"mean 3D RMS, --errors {errors}: " + ", ".join(f"{m} {mean[m]:.3f} m ({ratio[m]:.3f} x WLS)" for m in mean))
            results[f"mean_{errors}"] = {"rms_3d_m": mean, "ratio_to_wls": ratio}
        results["flights"] = flights
        walk = yamatogawa()
        if walk is not None:
            print_table("Yamatogawa walk against its RTK trajectory", {"yamatogawa": walk})
            results["yamatogawa"] = walk
        if args.hours > 0:
            speed = day_speed(tmp, args.hours)
            print(f"\nA simulated {args.hours:g} h at 1 Hz ({speed['epochs']:.0f} epochs): filter + RTS "
                  f"{speed['seconds_rts']:.1f} s ({speed['epochs_per_s_rts']:.0f} epochs/s), filter alone "
                  f"{speed['seconds_none']:.1f} s ({speed['epochs_per_s_none']:.0f} epochs/s)")
            results["day"] = speed
    out = REPO / "benchmarks" / "results" / "bench_kf.json"
    out.parent.mkdir(exist_ok=True)
    out.write_text(json.dumps(results, indent=2))


if __name__ == "__main__":
    main()
