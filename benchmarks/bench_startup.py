"""Start-up time of the command-line programs (a measurement; it exits 0 whatever it finds).

Runs each command as a subprocess of the current interpreter (``python -m gnss_cli.cli.solve
--help`` is what the ``gnss-solve --help`` console script does) several times and reports
the median, min and max wall time beside two baselines, ``python -c pass`` and
``python -c "import numpy"``. Writes ``benchmarks/results/bench_startup.json`` and says
whether the target "gnss-solve --help median <= 0.3 s" holds.

    python benchmarks/bench_startup.py [--runs 15]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import time
from pathlib import Path

TARGET_COMMAND = "gnss-solve --help"
TARGET_MEDIAN_S = 0.3
COMMANDS = {
    "python -c pass": ["-c", "pass"],
    'python -c "import numpy"': ["-c", "import numpy"],
    "gnss-solve --help": ["-m", "gnss_cli.cli.solve", "--help"],
    "gnss-solve --version": ["-m", "gnss_cli.cli.solve", "--version"],
    "gnss-simulate --help": ["-m", "gnss_cli.cli.simulate", "--help"],
    "gnss-identify --help": ["-m", "gnss_cli.cli.identify", "--help"],
}


def time_command(args: list[str], runs: int, cwd: Path) -> dict[str, object]:
    times, codes = [], set()
    for _ in range(runs):
        t0 = time.perf_counter()
        proc = subprocess.run([sys.executable, *args], cwd=cwd, capture_output=True)
        times.append(time.perf_counter() - t0)
        codes.add(proc.returncode)
    return {
        "median_s": statistics.median(times), "min_s": min(times), "max_s": max(times), "runs": runs,
        "exit_codes": sorted(codes), "ok": codes == {0},
        "stderr_tail": "" if codes == {0} else proc.stderr.decode(errors="replace").strip().splitlines()[-1:],
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=15)
    args = parser.parse_args()
    root = Path(__file__).resolve().parents[1]
    results = {}
    print(f"{'command':28s} {'median s':>9s} {'min s':>7s} {'max s':>7s}  exit")
    for name, cmd in COMMANDS.items():
        r = time_command(cmd, args.runs, root)
        results[name] = r
        mark = "" if r["ok"] else f"  FAILED (exit {r['exit_codes']}: {' '.join(r['stderr_tail'])})"
        print(f"{name:28s} {r['median_s']:9.3f} {r['min_s']:7.3f} {r['max_s']:7.3f}  {r['exit_codes']}{mark}")
    target = results[TARGET_COMMAND]
    holds = bool(target["ok"]) and float(target["median_s"]) <= TARGET_MEDIAN_S  # type: ignore[arg-type]
    verdict = "holds" if holds else "does NOT hold"
    print(f"target: {TARGET_COMMAND} median <= {TARGET_MEDIAN_S} s {verdict} ({float(target['median_s']):.3f} s)")
    out = root / "benchmarks" / "results" / "bench_startup.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({
        "python": sys.version.split()[0], "executable": sys.executable, "machine": platform.machine(),
        "cpus": os.cpu_count(), "target": {"command": TARGET_COMMAND, "median_le_s": TARGET_MEDIAN_S, "holds": holds},
        "commands": results,
    }, indent=2) + "\n")
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
