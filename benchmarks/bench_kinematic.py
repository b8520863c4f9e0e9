"""The identified Hankel STLS (``stls --lag 3``): window-length trade-off and the cost of a day of epochs.

1. Simulated 1 Hz flight (600 s, GPS, 1 m white pseudorange noise, seed 3): 3D RMS over the
   LS fixes of the position-domain smoothing of the fixes (no measurement rows and no behavior
   test: what ``--kernel full`` runs) with the shared and the full identified kernel (lag 3),
   against the window length.
2. A simulated day (86,400 epochs at 1 s, static or flight): wall time and peak memory of
   ``gnss-solve --method stls --lag 3`` (read, WLS, smoothing, clock re-estimation,
   multi-epoch DOP, CSV; the packaged defaults) over ``gnss-solve --method ls`` on the same
   files, each command in its own process; and the position-domain smoothing of the fixes alone
   in windows of :data:`DAY_WINDOW` epochs, timed in process.

Usage: ``python benchmarks/bench_kinematic.py [--hours 24] [--trajectory static]``
(prints tables, writes ``benchmarks/results/bench_kinematic.json``: the trade-off, and the day's
timing under ``day_timing.<trajectory>``, keeping the other trajectory's timing of an earlier run).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from gnss_cli.config import ProcessingConfig, load_config  # noqa: E402
from gnss_cli.io.reference import reference_from_csv  # noqa: E402
from gnss_cli.pipeline import load_epochs, smooth, solve_method  # noqa: E402

WINDOWS = (8, 10, 12, 15, 20, 25, 30, 40)
VARIANTS = {"shared": dict(kernel="shared"), "full": dict(kernel="full")}


def simulate(out: Path, trajectory: str, duration_s: int) -> Path:
    cmd = [sys.executable, "-m", "gnss_cli.cli.simulate", "--trajectory", trajectory, "--duration", str(duration_s),
           "--interval", "1", "--systems", "G", "--seed", "3", "--errors", "noise", "--noise-sigma", "1",
           "--out-dir", str(out)]
    subprocess.run(cmd, check=True, capture_output=True, cwd=REPO)
    return out


def with_smoothing(cfg: ProcessingConfig, **options: object) -> ProcessingConfig:
    return replace(cfg, stls=replace(cfg.stls, **options))


def rms_3d(x: np.ndarray, ref: np.ndarray) -> float:
    e = x - ref
    ok = np.all(np.isfinite(e), axis=1)
    return float(np.sqrt(np.mean(np.sum(e[ok] ** 2, axis=1))))


def tradeoff(d: Path) -> list[dict[str, object]]:
    cfg = load_config(None, {"iono": "none", "tropo": "none", "methods": "ls,wls"})
    data = load_epochs(d / "obs.rnx", [d / "nav.rnx"], cfg)
    ref = np.asarray(reference_from_csv(d / "truth.csv", data.time_gps_s))
    ls = solve_method(data, "ls", cfg)
    wls = solve_method(data, "wls", cfg)
    rms_ls = rms_3d(ls.x_ecef_m, ref)
    rows: list[dict[str, object]] = []
    for name, kw in VARIANTS.items():
        for window in WINDOWS:
            if name == "full" and window < 13:
                continue
            t0 = time.perf_counter()
            sol, models = smooth(data, wls, with_smoothing(cfg, lag=3, window=window, **kw))
            dt = time.perf_counter() - t0
            statuses = sorted({m.status for m in models})
            rows.append({"variant": name, "window": window, "rms_3d_m": rms_3d(sol.x_ecef_m, ref),
                         "ratio_to_ls": rms_3d(sol.x_ecef_m, ref) / rms_ls, "mean_gdop": float(np.nanmean(sol.gdop)),
                         "time_s": dt, "windows": len(models), "window_statuses": statuses})
    rows.append({"variant": "ls", "window": 1, "rms_3d_m": rms_ls, "ratio_to_ls": 1.0,
                 "mean_gdop": float(np.nanmean(ls.gdop))})
    return rows


def run_cli(args: list[str]) -> tuple[float, float]:
    """Wall time (s) and peak resident memory (MB) of one ``gnss-solve`` run in a child process."""
    cmd = [sys.executable, "-m", "gnss_cli.cli.solve", *args]
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    _, status, usage = os.wait4(proc.pid, 0)
    elapsed = time.perf_counter() - t0
    stderr = proc.stderr.read().decode() if proc.stderr else ""
    if os.waitstatus_to_exitcode(status) != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed: {stderr}")
    return elapsed, usage.ru_maxrss / 1024.0  # ru_maxrss is in kB on Linux


DAY_WINDOW = 15
"""Window (epochs) of the position-domain smoothing timed in process: nothing tests its windows'
behavior there, so whole segments (the command line's default) would be one kernel a day long."""


def day_timing(d: Path) -> dict[str, float]:
    """``gnss-solve --method ls`` against ``--method stls --lag 3`` on the same files (each its own process)."""
    files = [str(d / "obs.rnx"), str(d / "nav.rnx"), "--iono", "none", "--tropo", "none", "-q"]
    out = {}
    for name, extra in (("ls", ["--method", "ls"]), ("stls_lag3", ["--method", "stls", "--lag", "3"])):
        with tempfile.TemporaryDirectory() as tmp:
            out[f"{name}_s"], out[f"{name}_peak_mb"] = run_cli([*files, *extra, "-o", str(Path(tmp) / "out.csv")])
    # the smoothing alone, in process (after reading and WLS)
    cfg = load_config(None, {"iono": "none", "tropo": "none", "methods": "wls"})
    data = load_epochs(d / "obs.rnx", [d / "nav.rnx"], cfg)
    wls = solve_method(data, "wls", cfg)
    t0 = time.perf_counter()
    sol, models = smooth(data, wls, with_smoothing(cfg, lag=3, window=DAY_WINDOW))
    out["smoothing_s"] = time.perf_counter() - t0
    return {"epochs": int(data.time_gps_s.size), **out, "ratio": out["stls_lag3_s"] / out["ls_s"],
            "windows": len(models), "window": DAY_WINDOW, "smoothed_epochs": int((sol.status == "ok").sum())}


RESULTS = REPO / "benchmarks" / "results" / "bench_kinematic.json"


def earlier_timings() -> dict[str, dict[str, float]]:
    """The day timings of :data:`RESULTS` by trajectory (an older file's single timing under its
    ``trajectory``); empty without the file."""
    if not RESULTS.is_file():
        return {}
    timings = json.loads(RESULTS.read_text()).get("day_timing", {})
    if "trajectory" in timings:
        return {timings.pop("trajectory"): timings}
    return dict(timings)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--hours", type=float, default=24.0, help="length of the timed simulated day, h")
    ap.add_argument("--trajectory", default="static", choices=("static", "flight"))
    args = ap.parse_args()
    out: dict[str, object] = {}
    with tempfile.TemporaryDirectory() as tmp:
        flight = simulate(Path(tmp) / "flight", "standard-flight", 600)
        rows = tradeoff(flight)
        out["tradeoff_flight_600s"] = rows
        print("variant  window  3D RMS (m)  ratio to LS  mean GDOP  time (s)")
        for r in rows:
            print(f"{r['variant']:<8} {r['window']:>6}  {r['rms_3d_m']:10.3f}  {r['ratio_to_ls']:11.3f}"
                  f"  {r['mean_gdop']:9.2f}  {r.get('time_s', float('nan')):8.2f}")
        day = simulate(Path(tmp) / "day", args.trajectory, int(round(args.hours * 3600)))
        timing = day_timing(day)
        out["day_timing"] = {**earlier_timings(), args.trajectory: timing}
        print(f"{timing['epochs']} epochs ({args.trajectory}): gnss-solve --method ls {timing['ls_s']:.1f} s "
              f"(peak {timing['ls_peak_mb']:.0f} MB), --method stls --lag 3 {timing['stls_lag3_s']:.1f} s "
              f"(peak {timing['stls_lag3_peak_mb']:.0f} MB; smoothing {timing['smoothing_s']:.1f} s for "
              f"{timing['windows']} windows), ratio {timing['ratio']:.2f}")
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps(out, indent=1) + "\n")


if __name__ == "__main__":
    main()
