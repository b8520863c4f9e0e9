"""Benchmark the fast RINEX readers on the 24 h ESBC multi-GNSS file and a RINEX 2 nav file.

Measures, each in a fresh Python process (so that peak memory is the reader's own):

* ``hatanaka``: ``open_bytes`` alone (gzip + ``crx2rnx`` to 33 MB of text: what reading took
  before the Compact RINEX 3 records were decoded directly, and what ``gnss-solve`` still runs
  on its idle core while it imports);
* ``obs_pseudoranges``: ``read_obs3(..., pseudorange_only=True)`` (all systems; the Compact
  RINEX records decoded directly, :mod:`gnss_cli.io.crinex3`);
* ``obs_all``: ``read_obs3(...)`` with every observation code;
* ``nav``: ``read_nav3`` on the mixed navigation file of the same day;
* ``georinex_G_C1C`` (with ``--georinex``): ``georinex.load(obs, use={'G'}, meas=['C1C'])``;
  the unfiltered georinex load takes minutes and is not run;
* ``nav2`` / ``georinex_nav2``: ``read_nav2`` / ``georinex.load`` on the RINEX 2 GPS
  navigation file ``brdc0010.19n`` (413 records);

and RTKLIB's whole single-point run (``rnx2rtkp -k rnx2rtkp-spp.conf -p 0 -e`` with
``pos1-navsys=61``, all systems) on plain decompressed copies in a temporary folder, when
``rnx2rtkp`` is on PATH. Wall-clock times are the median of ``--repeat`` runs; peak memory
is the process's maximum resident set size (``ru_maxrss``), with the RSS after imports
shown for reference.

Prints a table and writes ``benchmarks/results/bench_read.json``.

Usage::

    python benchmarks/bench_read.py [--repeat 3] [--georinex] [--cases nav2,georinex_nav2]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SHARED = REPO / ".." / "shared"
OBS = SHARED / "rinex" / "esbc-2020177" / "ESBC00DNK_R_20201770000_01D_30S_MO.crx.gz"
NAV = SHARED / "rinex" / "esbc-2020177" / "ESBC00DNK_R_20201770000_01D_MN.rnx.gz"
NAV2 = SHARED / "rinex" / "p433-2019" / "brdc0010.19n"
PEER_CONF = SHARED / "peer" / "rnx2rtkp-spp.conf"
RESULTS = REPO / "benchmarks" / "results" / "bench_read.json"

# Each case runs in a child process; it prints one JSON line with time and memory.
_CHILD = r"""
import json, resource, sys, time, warnings
warnings.simplefilter("ignore")
case, obs, nav, nav2 = sys.argv[1], sys.argv[2], sys.argv[3], sys.argv[4]
import numpy, xarray
from gnss_cli.io.compression import open_bytes
from gnss_cli.io.rinex3_obs import read_obs3
from gnss_cli.io.rinex3_nav import read_nav3
from gnss_cli.io.rinex2_nav import read_nav2
if case.startswith("georinex"):
    import georinex
rss_imports = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
t0 = time.perf_counter()
if case == "hatanaka":
    out = open_bytes(obs); info = {"n_bytes": len(out)}
elif case == "obs_pseudoranges":
    out = read_obs3(obs, pseudorange_only=True)
    info = {"n_time": out.sizes["time"], "n_sv": out.sizes["sv"], "n_vars": len(out.data_vars),
            "n_values": int(sum(int(numpy.isfinite(v.values).sum()) for v in out.data_vars.values()))}
elif case == "obs_all":
    out = read_obs3(obs)
    info = {"n_time": out.sizes["time"], "n_sv": out.sizes["sv"], "n_vars": len(out.data_vars),
            "n_values": int(sum(int(numpy.isfinite(v.values).sum()) for v in out.data_vars.values()))}
elif case == "nav":
    out = read_nav3(nav)
    info = {"n_time": out.sizes["time"], "n_sv": out.sizes["sv"]}
elif case == "nav2":
    out = read_nav2(nav2)
    info = {"n_time": out.sizes["time"], "n_sv": out.sizes["sv"]}
elif case == "georinex_nav2":
    out = georinex.load(nav2)
    info = {"n_time": out.sizes["time"], "n_sv": out.sizes["sv"]}
elif case == "georinex_G_C1C":
    out = georinex.load(obs, use={"G"}, meas=["C1C"])
    info = {"n_time": out.sizes["time"], "n_sv": out.sizes["sv"]}
else:
    raise SystemExit(f"unknown case {case}")
elapsed = time.perf_counter() - t0
rss_peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
print(json.dumps({"seconds": elapsed, "rss_imports_mib": rss_imports / 1024,
                  "rss_peak_mib": rss_peak / 1024, **info}))
"""


def run_case(case: str, repeat: int) -> dict[str, object]:
    """Run one reader case ``repeat`` times in fresh processes; median time, max memory."""
    env = dict(os.environ, PYTHONPATH=str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    runs = []
    for _ in range(repeat):
        proc = subprocess.run(
            [sys.executable, "-c", _CHILD, case, str(OBS), str(NAV), str(NAV2)],
            capture_output=True, text=True, env=env, cwd=REPO, check=True,
        )
        runs.append(json.loads(proc.stdout.strip().splitlines()[-1]))
    out = dict(runs[0])
    out["seconds"] = statistics.median(r["seconds"] for r in runs)
    out["seconds_all"] = [r["seconds"] for r in runs]
    out["rss_peak_mib"] = max(r["rss_peak_mib"] for r in runs)
    return out


def run_rtklib(repeat: int) -> dict[str, object] | None:
    """Time RTKLIB's single-point run over all systems on plain copies of the files."""
    exe = shutil.which("rnx2rtkp")
    if exe is None or not PEER_CONF.is_file():
        return None
    sys.path.insert(0, str(REPO))
    from gnss_cli.io.compression import open_bytes

    with tempfile.TemporaryDirectory() as tmp:
        tmpdir = Path(tmp)
        obs_plain = tmpdir / "esbc.obs"
        nav_plain = tmpdir / "esbc.nav"
        obs_plain.write_bytes(open_bytes(OBS))
        nav_plain.write_bytes(open_bytes(NAV))
        conf = tmpdir / "spp-all.conf"
        lines = PEER_CONF.read_text().splitlines()
        lines = [("pos1-navsys        =61" if ln.startswith("pos1-navsys") else ln) for ln in lines]
        conf.write_text("\n".join(lines) + "\n")
        times = []
        n_epochs = 0
        for _ in range(repeat):
            pos = tmpdir / "out.pos"
            t0 = time.perf_counter()
            subprocess.run(
                [exe, "-k", str(conf), "-p", "0", "-e", "-o", str(pos), str(obs_plain), str(nav_plain)],
                capture_output=True, check=True, cwd=tmpdir,
            )
            times.append(time.perf_counter() - t0)
            n_epochs = sum(1 for ln in pos.read_text().splitlines() if ln and not ln.startswith("%"))
    return {"seconds": statistics.median(times), "seconds_all": times, "epochs_solved": n_epochs}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3, help="runs per case (median reported)")
    parser.add_argument("--georinex", action="store_true", help="also time georinex on GPS C1C only (~11 s)")
    parser.add_argument("--cases", default="", help="comma list of cases to run (default: all; e.g. nav2,georinex_nav2)")
    args = parser.parse_args()
    if not OBS.is_file() or not NAV.is_file() or not NAV2.is_file():
        raise SystemExit(f"missing shared data: {OBS} / {NAV} / {NAV2}")

    cases = ["hatanaka", "obs_pseudoranges", "obs_all", "nav", "nav2", "georinex_nav2"]
    if args.georinex:
        cases.append("georinex_G_C1C")
    if args.cases:
        cases = [c for c in args.cases.split(",") if c]
    results: dict[str, object] = {"file_obs": OBS.name, "file_nav": NAV.name, "repeat": args.repeat,
                                  "cpu_count": os.cpu_count()}
    for case in cases:
        results[case] = run_case(case, 1 if case == "georinex_G_C1C" else args.repeat)
    rtk = run_rtklib(args.repeat) if "obs_pseudoranges" in cases else None
    results["rtklib_all_systems"] = rtk

    print(f"{'case':<22}{'time (s)':>10}{'peak RSS (MiB)':>16}{'RSS after imports':>19}")
    for case in cases:
        r = results[case]
        assert isinstance(r, dict)
        print(f"{case:<22}{r['seconds']:>10.3f}{r['rss_peak_mib']:>16.1f}{r['rss_imports_mib']:>19.1f}")
    if "nav2" in cases and "georinex_nav2" in cases:
        ratio2 = float(results["georinex_nav2"]["seconds"]) / float(results["nav2"]["seconds"])  # type: ignore[index]
        results["ratio_georinex_to_nav2"] = ratio2
        print(f"RINEX 2 nav {NAV2.name}: georinex / read_nav2: {ratio2:.1f}")
    if rtk is not None:
        print(f"{'rnx2rtkp (navsys=61)':<22}{rtk['seconds']:>10.3f}{'':>16}{'':>19}   "
              f"({rtk['epochs_solved']} epochs solved)")
        pr = results["obs_pseudoranges"]
        assert isinstance(pr, dict)
        ratio = float(pr["seconds"]) / float(rtk["seconds"])  # type: ignore[arg-type]
        results["ratio_pseudoranges_to_rtklib"] = ratio
        print(f"fast reader (all pseudoranges) / RTKLIB whole run: {ratio:.2f}")
    elif "obs_pseudoranges" in cases:
        print("rnx2rtkp not installed: no RTKLIB comparison")
    if "hatanaka" in cases and "obs_pseudoranges" in cases:
        hat = results["hatanaka"]
        pr = results["obs_pseudoranges"]
        assert isinstance(hat, dict) and isinstance(pr, dict)
        results["hatanaka_share_of_pseudorange_read"] = float(hat["seconds"]) / float(pr["seconds"])  # type: ignore[arg-type]
        print(f"crx2rnx expansion alone / the whole direct pseudorange read: {results['hatanaka_share_of_pseudorange_read']:.2f}")
    if "georinex_G_C1C" in cases and "obs_pseudoranges" in cases:
        pr = results["obs_pseudoranges"]
        assert isinstance(pr, dict)
        g = results["georinex_G_C1C"]
        assert isinstance(g, dict)
        print(f"georinex (GPS C1C only) / fast reader (all pseudoranges): {float(g['seconds']) / float(pr['seconds']):.1f}")  # type: ignore[arg-type]

    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps(results, indent=2) + "\n")
    print(f"wrote {RESULTS.relative_to(REPO)}")


if __name__ == "__main__":
    main()
