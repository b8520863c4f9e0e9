"""Peak memory of ``gnss-solve`` on a simulated 1 Hz GPS + Galileo file of 1 h and of 24 h.

The files come from ``gnss-simulate --systems G,E --duration 3600 | 86400`` (static site,
every error source, Doppler and C/N0; plain RINEX 3.04: 3.6 MB and 86 MB) and are cached in
``--cache`` (default ``benchmarks/results/sim-cache``, not committed; generating the day
takes a minute or two). Each case runs ``gnss-solve OBS NAV --method ... --out-dir TMP -q``
(every CSV table written) as a child process and reads the child's peak resident set
size from ``os.wait4`` (``ru_maxrss``); no third-party package is needed.

Cases: ``--method wls``, ``--method stls --lag 3`` (identified Hankel STLS) and ``--method smoother``
(pseudoranges and Doppler), each on the 1 h and the 24 h file,
with the packaged ``chunk_epochs`` / ``stream_above_epochs`` (1200 / 3600: the 1 h file of
3601 epochs is one part, the day 72 parts). ``--chunk-epochs N`` sets both to N. Every run is
given ``--processes 1``: a file of one part is otherwise cut in one part per core, solved in
forked processes, and ``ru_maxrss`` is the peak of the largest single process, not of their
sum; the comparison of lengths is made in one process.
Targets: the 24 h peak <= 1.3 x the 1 h peak, and <= 400 MiB, for every case.
Prints a table and writes ``benchmarks/results/bench_memory.json``.

Usage::

    python benchmarks/bench_memory.py [--cache DIR] [--hours 1 24] [--chunk-epochs N]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "benchmarks" / "results" / "bench_memory.json"
METHODS = {"wls": ["--method", "wls"], "stls_lag3": ["--method", "stls", "--lag", "3"],
           "smoother": ["--method", "smoother"]}
TARGET_RATIO = 1.3
TARGET_MIB = 400.0


def _bin(name: str) -> str:
    """The console script ``name`` next to this Python (the project's virtual environment)."""
    here = Path(sys.executable).parent / name
    return str(here) if here.exists() else name


def simulated(cache: Path, hours: int) -> Path:
    """The folder with ``obs.rnx`` and ``nav.rnx`` of ``hours`` hours at 1 Hz (generated once)."""
    out = cache / f"sim_GE_{hours}h"
    if not (out / "obs.rnx").exists() or not (out / "nav.rnx").exists():
        out.mkdir(parents=True, exist_ok=True)
        subprocess.run([_bin("gnss-simulate"), "--out-dir", str(out), "--duration", str(3600 * hours),
                        "--interval", "1", "--systems", "G,E", "--quiet"], check=True)
    return out


def peak_rss(cmd: list[str], env: dict[str, str]) -> tuple[float, float, int]:
    """``(peak RSS MiB, wall s, exit code)`` of one child process."""
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - t0
    proc.returncode = os.waitstatus_to_exitcode(status)
    if proc.returncode != 0 and proc.stderr is not None:
        sys.stderr.write(proc.stderr.read().decode(errors="replace"))
    if proc.stderr is not None:
        proc.stderr.close()
    return usage.ru_maxrss / 1024.0, wall, proc.returncode  # ru_maxrss is in KiB on Linux


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cache", type=Path, default=REPO / "benchmarks" / "results" / "sim-cache")
    ap.add_argument("--hours", type=int, nargs="+", default=[1, 24])
    ap.add_argument("--chunk-epochs", type=int, default=None,
                    help="[processing] chunk_epochs and stream_above_epochs (default: packaged)")
    args = ap.parse_args()
    env = {**os.environ, "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        extra: list[str] = []
        if args.chunk_epochs is not None:
            cfg = Path(tmp) / "chunk.toml"
            cfg.write_text(f"[processing]\nchunk_epochs = {args.chunk_epochs}\nstream_above_epochs = {args.chunk_epochs}\n")
            extra = ["--config", str(cfg)]
        for hours in args.hours:
            d = simulated(args.cache, hours)
            for name, flags in METHODS.items():
                out = Path(tmp) / f"{name}_{hours}h"
                cmd = [_bin("gnss-solve"), str(d / "obs.rnx"), str(d / "nav.rnx"), *flags, "--out-dir", str(out), "-q", "--processes", "1",
                       *extra]
                mib, wall, code = peak_rss(cmd, env)
                rows.append({"method": name, "hours": hours, "epochs": 3600 * hours + 1, "peak_mib": round(mib, 1),
                             "seconds": round(wall, 1), "exit_code": code})
                print(f"{name:10s} {hours:3d} h  peak {mib:7.1f} MiB  {wall:7.1f} s  exit {code}", flush=True)
    verdicts = {}
    for name in METHODS:
        by_h = {r["hours"]: r["peak_mib"] for r in rows if r["method"] == name}
        if 1 in by_h and 24 in by_h:
            ratio = by_h[24] / by_h[1]
            verdicts[name] = {"ratio_24h_1h": round(ratio, 3), "ratio_ok": ratio <= TARGET_RATIO,
                              "peak_24h_ok": by_h[24] <= TARGET_MIB}
    print()
    print(f"{'method':10s} {'1 h MiB':>9s} {'24 h MiB':>9s} {'24h/1h':>7s}  target <= {TARGET_RATIO} and <= {TARGET_MIB:.0f} MiB")
    for name, v in verdicts.items():
        by_h = {r["hours"]: r["peak_mib"] for r in rows if r["method"] == name}
        ok = "ok" if v["ratio_ok"] and v["peak_24h_ok"] else "MISSED"
        print(f"{name:10s} {by_h[1]:9.1f} {by_h[24]:9.1f} {v['ratio_24h_1h']:7.3f}  {ok}")
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps({"cases": rows, "verdicts": verdicts, "chunk_epochs": args.chunk_epochs,
                                   "targets": {"ratio": TARGET_RATIO, "peak_mib": TARGET_MIB}}, indent=1) + "\n")
    print(f"\nwrote {RESULTS}")


if __name__ == "__main__":
    main()
