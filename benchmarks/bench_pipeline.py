"""Pipeline benchmark: time per stage (read, orbits, solve, write), epochs/s and peak memory.

Runs each data set in a fresh process (so the peak RSS is that run's own) on the real files
in ``../shared/rinex``, with LS and WLS (GPS), and — when ``rnx2rtkp`` is installed — times
RTKLIB's whole single-point run on the same file in the same session for a ratio. The
whole all-system run against RTKLIB is ``benchmarks/bench_full_run.py``.

Usage: ``python benchmarks/bench_pipeline.py`` (prints a table, writes
``benchmarks/results/bench_pipeline.json``).
"""

from __future__ import annotations

import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
RINEX = (REPO / ".." / "shared" / "rinex").resolve()
PEER_CONF = (REPO / ".." / "shared" / "peer" / "rnx2rtkp-spp.conf").resolve()
CASES = {
    "rtklib-0759": ("rtklib-0759/07590920.05o", ["rtklib-0759/07590920.05n"]),
    "esbc-2020177 GPS 24 h": (
        "esbc-2020177/ESBC00DNK_R_20201770000_01D_30S_MO.crx.gz",
        ["esbc-2020177/ESBC00DNK_R_20201770000_01D_MN.rnx.gz"],
    ),
}


def one(obs: str, navs: list[str]) -> dict[str, float]:
    """Run in the child process: time every stage of one gnss-solve run."""
    sys.path.insert(0, str(REPO))
    from gnss_cli.config import load_config
    from gnss_cli.pipeline import RunResult, load_epochs, solve_method
    from gnss_cli.report import positions_table, to_csv_text

    cfg = load_config(overrides={"methods": "ls,wls", "systems": ["G"]})  # the GPS-only rows of the table
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    data = load_epochs(obs, navs, cfg, timings=timings)
    solutions = {}
    for m in ("ls", "wls"):
        solve_method(data, m, cfg)  # warm-up (first-call overheads)
        t = time.perf_counter()
        solutions[m] = solve_method(data, m, cfg)
        timings[f"solve_{m}"] = time.perf_counter() - t
    t = time.perf_counter()
    text = to_csv_text(positions_table(RunResult(data, solutions)))
    timings["write"] = time.perf_counter() - t
    timings["total"] = time.perf_counter() - t0
    timings["epochs"] = float(data.time_gps_s.size)
    timings["csv_bytes"] = float(len(text))
    timings["peak_rss_mib"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    return timings


def rtklib_time(obs: Path, navs: list[Path]) -> float | None:
    exe = shutil.which("rnx2rtkp")
    if exe is None or not PEER_CONF.is_file():
        return None
    sys.path.insert(0, str(REPO))
    from gnss_cli.io.rinex import _open_lines  # decompression for the peer (it cannot read .crx/.gz)

    with tempfile.TemporaryDirectory() as tmp:
        plain = []
        for p in [obs, *navs]:
            name = Path(p).name
            for suffix in (".gz", ".Z", ".crx"):
                name = name.removesuffix(suffix)
            target = Path(tmp) / (name if name.endswith((".rnx", "o", "n")) else name + ".rnx")
            target.write_text("\n".join(_open_lines(Path(p))) + "\n")
            plain.append(str(target))
        t = time.perf_counter()
        subprocess.run([exe, "-k", str(PEER_CONF), "-p", "0", "-e", "-o", str(Path(tmp) / "o.pos"), *plain],
                       check=True, capture_output=True)
        return time.perf_counter() - t


def main() -> None:
    if len(sys.argv) > 1 and sys.argv[1] == "--one":
        print(json.dumps(one(sys.argv[2], sys.argv[3:])))
        return
    if not RINEX.is_dir():
        sys.exit(f"bench_pipeline: {RINEX} is missing")
    env = {**os.environ, "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"}
    results = {}
    for label, (obs, navs) in CASES.items():
        args = [str(RINEX / obs), *(str(RINEX / n) for n in navs)]
        out = subprocess.run([sys.executable, __file__, "--one", *args], check=True, capture_output=True, text=True, env=env)
        r = json.loads(out.stdout.strip().splitlines()[-1])
        r["rtklib_s"] = rtklib_time(RINEX / obs, [RINEX / n for n in navs])
        results[label] = r
    header = f"{'data':<24}{'epochs':>7}{'read s':>8}{'orbits s':>9}{'LS s':>8}{'LS ep/s':>10}{'WLS ep/s':>10}{'write s':>8}{'total s':>8}{'peak MiB':>9}{'RTKLIB s':>9}"
    print(header)
    for label, r in results.items():
        n = r["epochs"]
        rtk = f"{r['rtklib_s']:.2f}" if r["rtklib_s"] is not None else "-"
        print(f"{label:<24}{n:>7.0f}{r['read']:>8.2f}{r['orbits']:>9.2f}{r['solve_ls']:>8.3f}{n / r['solve_ls']:>10.0f}"
              f"{n / r['solve_wls']:>10.0f}{r['write']:>8.2f}{r['total']:>8.2f}{r['peak_rss_mib']:>9.0f}{rtk:>9}")
    out_path = REPO / "benchmarks" / "results" / "bench_pipeline.json"
    out_path.parent.mkdir(parents=True, exist_ok=True)
    out_path.write_text(json.dumps(results, indent=2))
    print(f"wrote {out_path.relative_to(REPO)}")


if __name__ == "__main__":
    main()
