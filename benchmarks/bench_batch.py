"""Benchmark ``gnss-batch`` against one ``gnss-solve`` process per file.

The network: ``--files`` (default 8) copies of the 24 h ESBC observation file
(``../shared/rinex/esbc-2020177``, RINEX 3.05, 2880 epochs, all systems) under different
station names (``ST0100DNK_R_...``) in a temporary folder, plus one corrupt copy (an epoch
line garbled in the middle) for the failure case. ``--epochs N`` cuts each copy to its
first N epochs (decompressed; ``TIME OF LAST OBS`` adjusted) when whole days are too slow
for the machine at hand.

Measured, each as wall-clock time of whole processes:

* ``sequential``: ``gnss-solve OBS NAV -o positions.csv`` once per file, one after the other
  (what a shell loop does today);
* ``batch_jobs2``: ``gnss-batch OBS... --nav NAV --out DIR --jobs 2``; the ratio
  ``batch_jobs2 / sequential`` is the figure of merit (issue 16's target: <= 0.6);
* ``batch_dask``: the same files through a ``dask.distributed`` scheduler with two worker
  processes started here (``LocalCluster(n_workers=2, processes=True)``), whose positions
  must equal those of ``batch_jobs2`` exactly;
* ``batch_corrupt``: ``--jobs 2`` with the corrupt copy among the files: it must be the one
  failed row of ``files.csv`` (exit 4) while every other file has all its epochs.

The positions of ``batch_jobs2`` are also compared with the sequential gnss-solve CSVs
(largest coordinate difference; the CSV has 4 decimals). Prints a table and writes
``benchmarks/results/bench_batch.json``. The machine's load average is recorded before
each case: on a shared machine the ratio carries that noise.

Usage::

    python benchmarks/bench_batch.py [--files 8] [--epochs 0] [--skip-dask]
"""

from __future__ import annotations

import argparse
import gzip
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
ESBC = REPO / ".." / "shared" / "rinex" / "esbc-2020177"
OBS = ESBC / "ESBC00DNK_R_20201770000_01D_30S_MO.crx.gz"
NAV = ESBC / "ESBC00DNK_R_20201770000_01D_MN.rnx.gz"
RESULTS = REPO / "benchmarks" / "results" / "bench_batch.json"


def _cut(text: bytes, epochs: int) -> bytes:
    """The first ``epochs`` epochs of plain RINEX 3 ``text`` (header kept, TIME OF LAST OBS dropped)."""
    head_end = text.index(b"END OF HEADER")
    head_end = text.index(b"\n", head_end) + 1
    header = b"".join(ln for ln in text[:head_end].splitlines(keepends=True) if b"TIME OF LAST OBS" not in ln)
    body = text[head_end:]
    starts = [m.start() for m in re.finditer(rb"^>", body, re.M)][: epochs + 1]
    return header + (body[: starts[epochs]] if len(starts) > epochs else body)


def make_network(folder: Path, n_files: int, epochs: int) -> tuple[list[Path], Path]:
    """``n_files`` station copies of the ESBC file (cut to ``epochs`` when > 0) and a corrupt one."""
    from gnss_cli.io.compression import open_bytes

    if epochs > 0:
        plain = _cut(open_bytes(OBS), epochs)
        raw, suffix = gzip.compress(plain, compresslevel=1), ".rnx.gz"
    else:
        raw, suffix = OBS.read_bytes(), ".crx.gz"
    files = []
    for k in range(1, n_files + 1):
        path = folder / f"ST{k:02d}00DNK_R_20201770000_01D_30S_MO{suffix}"
        path.write_bytes(raw)
        files.append(path)
    text = open_bytes(files[0]).splitlines(keepends=True)
    epoch_lines = [i for i, ln in enumerate(text) if ln.startswith(b">")]
    text[epoch_lines[len(epoch_lines) // 2]] = b"> 2020 06 25 xx 00  0.0000000  0 30\n"
    corrupt = folder / "BAD100DNK_R_20201770000_01D_30S_MO.rnx.gz"
    corrupt.write_bytes(gzip.compress(b"".join(text), compresslevel=1))
    return files, corrupt


def _load() -> float:
    return os.getloadavg()[0]


def _timed(cmd: list[str], cwd: Path) -> tuple[float, subprocess.CompletedProcess[str]]:
    env = {**os.environ, "PYTHONWARNINGS": "ignore"}
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True, env=env)
    return time.perf_counter() - t0, proc


def _sequential(files: list[Path], work: Path) -> tuple[float, list[Path]]:
    outs, total = [], 0.0
    for k, obs in enumerate(files):
        out = work / f"seq{k:02d}.csv"
        dt, proc = _timed([sys.executable, "-m", "gnss_cli.cli.solve", str(obs), str(NAV), "-o", str(out), "-q"], work)
        if proc.returncode != 0:
            raise SystemExit(f"gnss-solve failed on {obs}: {proc.stderr}")
        total += dt
        outs.append(out)
        print(f"  gnss-solve {obs.name}: {dt:.1f} s", flush=True)
    return total, outs


def _batch(files: list[Path], out: Path, work: Path, *extra: str) -> tuple[float, subprocess.CompletedProcess[str]]:
    return _timed([sys.executable, "-m", "gnss_cli.cli.batch", *map(str, files), "--nav", str(NAV), "--out", str(out),
                   *extra], work)


def _positions(out: Path):  # type: ignore[no-untyped-def]
    import pandas as pd

    df = pd.read_parquet(out / "positions")
    return df.sort_values(["obs_file", "method", "time"]).reset_index(drop=True)


def _max_csv_difference(out: Path, csvs: list[Path], files: list[Path]) -> float:
    import numpy as np
    import pandas as pd

    data = _positions(out)
    worst = 0.0
    for obs, csv in zip(files, csvs):
        mine = data[data["obs_file"] == obs.name].reset_index(drop=True)
        ref = pd.read_csv(csv).sort_values(["method", "time"]).reset_index(drop=True)
        if len(mine) != len(ref):
            return float("inf")
        both = np.isfinite(ref["x_m"].to_numpy())
        d = np.abs(mine[["x_m", "y_m", "z_m"]].to_numpy()[both] - ref[["x_m", "y_m", "z_m"]].to_numpy()[both])
        worst = max(worst, float(d.max()) if d.size else 0.0)
    return worst


def _dask_case(files: list[Path], work: Path) -> tuple[float, subprocess.CompletedProcess[str]]:
    from distributed import LocalCluster

    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        return _batch(files, work / "out-dask", work, "--scheduler", cluster.scheduler_address)


def _pairs(files: list[Path], work: Path, repeat: int) -> dict[str, object]:
    """``repeat`` interleaved (sequential, batch --jobs 2) pairs: the ratio of each pair, so that a
    change of the machine's load between the two halves of a pair is the only noise."""
    import statistics

    seq, bat, ratios, loads = [], [], [], []
    csvs: list[Path] = []
    for r in range(repeat):
        loads.append(_load())
        seq_s, csvs = _sequential(files, work)
        batch_s, proc = _batch(files, work / "out-local", work, "--jobs", "2")
        if proc.returncode != 0:
            raise SystemExit(f"gnss-batch failed: {proc.stderr}")
        seq.append(seq_s)
        bat.append(batch_s)
        ratios.append(batch_s / seq_s)
        print(f"[{r + 1}/{repeat}] sequential gnss-solve x{len(files)}: {seq_s:.1f} s; gnss-batch --jobs 2: {batch_s:.1f} s; "
              f"ratio {batch_s / seq_s:.3f} (load {loads[-1]:.1f})", flush=True)
    return {"sequential_s": seq, "batch_jobs2_s": bat, "ratios": ratios, "load_averages": loads,
            "sequential_median_s": statistics.median(seq), "batch_jobs2_median_s": statistics.median(bat),
            "ratio_batch_jobs2_to_sequential_median": statistics.median(ratios),
            "max_position_difference_vs_gnss_solve_csv_m": _max_csv_difference(work / "out-local", csvs, files)}


def _corrupt_case(files: list[Path], corrupt: Path, work: Path) -> dict[str, object]:
    import pandas as pd

    bad_s, proc = _batch([*files[:3], corrupt, *files[3:]], work / "out-bad", work, "--jobs", "2")
    table = pd.read_csv(work / "out-bad" / "files.csv")
    ok = table[table["status"] == "ok"]
    failed = table[table["status"] != "ok"]
    out = {"batch_corrupt_s": bad_s, "batch_corrupt_exit_code": proc.returncode,
           "corrupt_reported": failed["obs_path"].tolist() == [str(corrupt)],
           "corrupt_error": str(failed["error"].iloc[0]) if len(failed) else "",
           "others_complete": bool(len(ok) == len(files) and (ok["solved"] == ok["epochs"]).all())}
    print(f"with a corrupt file: exit {proc.returncode}, failed {[Path(p).name for p in failed['obs_path']]}, "
          f"others complete: {out['others_complete']}", flush=True)
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--files", type=int, default=8, help="station copies (default 8)")
    parser.add_argument("--epochs", type=int, default=0, help="epochs per file, 0 = the whole day (2880)")
    parser.add_argument("--repeat", type=int, default=3, help="interleaved sequential/batch pairs (median ratio)")
    parser.add_argument("--skip-dask", action="store_true", help="leave out the Dask scheduler case")
    args = parser.parse_args(argv)
    if not OBS.is_file():
        print(f"bench_batch: {OBS} is missing (../shared/rinex beside the repository)", file=sys.stderr)
        return 1
    result: dict[str, object] = {"files": args.files, "epochs_per_file": args.epochs or 2880, "cores": os.cpu_count()}
    with tempfile.TemporaryDirectory(prefix="bench-batch-") as tmp:
        work = Path(tmp)
        files, corrupt = make_network(work, args.files, args.epochs)
        result.update(_pairs(files, work, args.repeat))
        if not args.skip_dask:
            result["load_before_dask"] = _load()
            dask_s, dproc = _dask_case(files, work)
            same = dproc.returncode == 0 and _positions(work / "out-dask").equals(_positions(work / "out-local"))
            ratio = dask_s / float(result["sequential_median_s"])  # type: ignore[arg-type]
            result.update({"batch_dask_s": dask_s, "ratio_batch_dask_to_sequential_median": ratio,
                           "dask_positions_identical": bool(same)})
            print(f"gnss-batch --scheduler (2 local Dask worker processes): {dask_s:.1f} s, ratio {ratio:.3f} "
                  f"(to the median sequential time), positions identical: {same}", flush=True)
        result.update(_corrupt_case(files, corrupt, work))
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps(result, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
