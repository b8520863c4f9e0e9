"""Availability and 3D RMS of the wls fixes with ``--integrity off / check / fde`` and
``--robust huber / cauchy``, beside rnx2rtkp, on the shared urban and clean sets.

    python benchmarks/bench_integrity_table.py [--sets tst2,berlin,...]

Availability = share of the epochs (in the truth window where there is one) with status
``ok``; for rnx2rtkp, the share it writes (its chi-square and GDOP tests drop the others).
The 3D RMS is over those epochs, against each set's reference (``../shared/rinex/README.md``):
tst2-2020155-urban-static its ground truth (157 epochs, GPS seconds of week 270149-270305),
rtklib-0759 the RTK station position, p433-2019 the header position, yamatogawa the RTK
trajectory ``rtk_ref_rover.pos``; smartloc-berlin has none (availability only).
rnx2rtkp runs with ``../shared/peer/rnx2rtkp-spp.conf`` (``pos1-navsys`` set to the row's
systems) on plain copies in a temporary folder.

Prints a markdown table (README "Integrity") and writes ``benchmarks/results/integrity_table.json``.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from gnss_cli.config import load_config
from gnss_cli.gnss.time import gps_s2week_tow
from gnss_cli.io.compression import open_bytes
from gnss_cli.io.reference import reference_from_pos
from gnss_cli.pipeline import process

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared"
RINEX = SHARED / "rinex"
PEER_CONF = SHARED / "peer" / "rnx2rtkp-spp.conf"
NAVSYS = {"G": 1, "R": 4, "E": 8, "J": 16, "C": 32}

MODES: dict[str, dict[str, object]] = {
    "off": {"integrity": "off"},
    "check": {"integrity": "check"},
    "fde": {"integrity": "fde"},
    "huber, off": {"robust": "huber", "integrity": "off"},
    "huber + check": {"robust": "huber", "integrity": "check"},
    "huber + fde": {"robust": "huber", "integrity": "fde"},
    "cauchy + fde": {"robust": "cauchy", "integrity": "fde"},
}
"""Settings of each column (every other option at its default; wls)."""


@dataclass(frozen=True)
class Case:
    key: str
    name: str
    systems: str
    obs: Path
    navs: tuple[Path, ...]
    reference: str | tuple[float, float, float] | None  # fixed ECEF (m), a .pos file name, or none
    window_tow_s: tuple[float, float] | None = None


def cases() -> list[Case]:
    tst, ber, yam = RINEX / "tst2-2020155-urban-static", RINEX / "smartloc-berlin-2016158-urban-kinematic", \
        RINEX / "yamatogawa-2010006-kinematic"
    tst_navs = tuple(sorted(tst.glob("hksc155d.20?")))
    truth = (-2418077.2710, 5386069.6872, 2405174.1252)
    berlin = (ber / "Berlin_Potsdamer_Platz.obs.gz", (ber / "BRDC00WRD_U_20161580000_01D_MN.rnx.gz",))
    return [
        Case("tst2_all", "tst2-2020155-urban-static", "G,R,E,J,C", tst / "2020_06_03_TST_03.obs.gz", tst_navs, truth,
             (270149.0, 270305.0)),
        Case("tst2_gps", "tst2-2020155-urban-static", "G", tst / "2020_06_03_TST_03.obs.gz", tst_navs, truth,
             (270149.0, 270305.0)),
        Case("berlin_gps", "smartloc-berlin", "G", *berlin, None),
        Case("berlin_gr", "smartloc-berlin", "G,R", *berlin, None),
        Case("0759", "rtklib-0759", "G", RINEX / "rtklib-0759" / "07590920.05o",
             (RINEX / "rtklib-0759" / "07590920.05n",), (-3976219.1879, 3382371.6041, 3652511.1428)),
        Case("p433", "p433-2019", "G", RINEX / "p433-2019" / "P43300USA_R_20190012056_17M_15S_MO.crx",
             (RINEX / "p433-2019" / "brdc0010.19n",), (-2268682.1122, -3949823.1452, 4451278.8623)),
        Case("yamatogawa", "yamatogawa-2010006-kinematic", "G", yam / "yamatogawa_rover.obs", (yam / "brdc0060.10n",),
             str(yam / "rtk_ref_rover.pos")),
    ]


def _reference(case: Case, time_gps_s: np.ndarray) -> np.ndarray | None:
    if case.reference is None:
        return None
    if isinstance(case.reference, str):
        return reference_from_pos(case.reference, time_gps_s)
    return np.broadcast_to(np.array(case.reference), (time_gps_s.size, 3))


def _stats(ok: np.ndarray, in_window: int, err: np.ndarray | None) -> dict[str, object]:
    row: dict[str, object] = {"epochs": in_window, "ok": int(ok.sum()), "availability": float(ok.sum() / in_window)}
    if err is not None:
        e = err[ok & np.isfinite(err)]
        row["rms_3d_m"] = float(np.sqrt(np.mean(e**2))) if e.size else None
        row["max_3d_m"] = float(e.max()) if e.size else None
        row["compared"] = int(e.size)
    return row


def ours(case: Case, settings: dict[str, object]) -> dict[str, object]:
    """One gnss-solve run (wls) of ``case`` with ``settings``: availability, 3D RMS, exclusions."""
    cfg = load_config(None, {"systems": case.systems, "environment": "open", **settings})  # as measured
    t0 = time.perf_counter()
    res = process(case.obs, list(case.navs), cfg)
    seconds = time.perf_counter() - t0
    sol, t = res.solutions["wls"], res.epochs.time_gps_s
    _, tow = gps_s2week_tow(t)
    w = np.ones(t.size, dtype=bool) if case.window_tow_s is None else \
        (tow >= case.window_tow_s[0] - 0.01) & (tow <= case.window_tow_s[1] + 0.01)
    ref = _reference(case, t[w])
    err = None if ref is None else np.linalg.norm(sol.x_ecef_m[w] - ref, axis=1)
    row = _stats(sol.status[w] == "ok", int(w.sum()), err)
    if err is not None:  # every epoch with a position, whatever its status: what the fit alone does
        row["rms_3d_all_m"] = float(np.sqrt(np.nanmean(err**2)))
    rw = sol.robust_weights[w]
    row["mean_excluded"] = float(sol.excluded[w].sum(axis=1).mean())
    row["mean_downweighted"] = float(np.sum(rw < 0.1, axis=1).mean())
    words, counts = np.unique(sol.status[w], return_counts=True)
    row["statuses"] = dict(zip(words.tolist(), counts.tolist()))
    row["seconds"] = seconds
    return row


def _plain_copy(src: Path, folder: Path) -> Path:
    name = src.name.removesuffix(".gz").replace(".crx", ".rnx")
    target = folder / name
    target.write_bytes(open_bytes(src))
    return target


def peer(case: Case, exe: str, week_from: np.ndarray) -> dict[str, object]:
    """rnx2rtkp single point on ``case`` (its systems as ``pos1-navsys``)."""
    navsys = sum(NAVSYS[s] for s in case.systems.split(","))
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        lines = []
        for line in PEER_CONF.read_text().splitlines():
            lines.append(f"pos1-navsys        ={navsys}" if line.startswith("pos1-navsys") else line)
        conf = folder / "peer.conf"
        conf.write_text("\n".join(lines) + "\n")
        files = [str(_plain_copy(p, folder)) for p in (case.obs, *case.navs)]
        out = folder / "peer.pos"
        subprocess.run([exe, "-k", str(conf), "-p", "0", "-e", "-o", str(out), *files], check=True, capture_output=True,
                       timeout=1200)
        rows = [ln.split() for ln in out.read_text().splitlines() if ln.strip() and not ln.startswith("%")]
    week = np.array([int(r[0]) for r in rows])
    tow = np.array([float(r[1]) for r in rows])
    xyz = np.array([[float(v) for v in r[2:5]] for r in rows]).reshape(-1, 3)
    t_gps = week * 604800.0 + tow
    _, our_tow = gps_s2week_tow(week_from)
    if case.window_tow_s is not None:
        lo, hi = case.window_tow_s
        keep = (tow >= lo - 0.01) & (tow <= hi + 0.01)
        t_gps, xyz = t_gps[keep], xyz[keep]
        in_window = int(((our_tow >= lo - 0.01) & (our_tow <= hi + 0.01)).sum())
    else:
        in_window = int(week_from.size)
    ref = _reference(case, t_gps)
    err = None if ref is None else np.linalg.norm(xyz - ref, axis=1)
    return _stats(np.ones(t_gps.size, dtype=bool), in_window, err)


def _cell(row: dict[str, object] | None) -> str:
    if row is None:
        return ""
    avail = f"{100 * row['availability']:.0f} %"  # type: ignore[operator]
    rms = row.get("rms_3d_m")
    return avail if "rms_3d_m" not in row else f"{avail} / " + (f"{rms:.2f} m" if rms is not None else "–")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--sets", default="", help="comma list of case keys (default: all)")
    args = parser.parse_args()
    if not RINEX.is_dir():
        sys.exit(f"{RINEX} not found: the table needs the shared real data")
    exe = shutil.which("rnx2rtkp")
    chosen = [c for c in cases() if not args.sets or c.key in args.sets.split(",")]
    results: list[dict[str, object]] = []
    for case in chosen:
        entry: dict[str, object] = {"key": case.key, "set": case.name, "systems": case.systems, "modes": {}}
        for mode, settings in MODES.items():
            entry["modes"][mode] = ours(case, settings)  # type: ignore[index]
            print(f"{case.key:11} {mode:14} {json.dumps(entry['modes'][mode])}", file=sys.stderr)  # type: ignore[index]
        if exe is not None and PEER_CONF.is_file():
            cfg = load_config(None, {"systems": case.systems, "integrity": "off", "environment": "open"})
            from gnss_cli.pipeline.epochs import load_epochs

            t = load_epochs(case.obs, list(case.navs), cfg).time_gps_s
            entry["rnx2rtkp"] = peer(case, exe, t)
            print(f"{case.key:11} rnx2rtkp       {json.dumps(entry['rnx2rtkp'])}", file=sys.stderr)
        results.append(entry)
    print("| data | systems | " + " | ".join(f"`{m}`" for m in MODES) + " | rnx2rtkp |")
    print("|---|---|" + "---|" * (len(MODES) + 1))
    for e in results:
        cells = [_cell(e["modes"][m]) for m in MODES]  # type: ignore[index]
        print(f"| {e['set']} | {e['systems']} | " + " | ".join(cells) + f" | {_cell(e.get('rnx2rtkp'))} |")  # type: ignore[arg-type]
    out = ROOT / "benchmarks" / "results" / "integrity_table.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    previous = json.loads(out.read_text()) if out.is_file() and args.sets else []
    keys = {e["key"] for e in results}
    merged = [e for e in previous if e.get("key") not in keys] + results
    out.write_text(json.dumps(merged, indent=1) + "\n")
    print(f"\nwrote {out}", file=sys.stderr)


if __name__ == "__main__":
    main()
