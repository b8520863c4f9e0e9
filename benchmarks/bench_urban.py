"""Integrity in street canyons: every method with integrity off and at its default, on simulated
urban drives (both receiver profiles, fixed seeds), on tst2 and on smartloc-berlin, beside rnx2rtkp.

    python benchmarks/bench_urban.py [--quick] [--seeds N] [--duration S] [--out PATH]

Cases:

- **Simulated urban drives** (``gnss-simulate --environment urban --trajectory drive``), ``--seeds``
  seeds (default 20, so 40 drives) for each receiver profile: ``single`` (single-frequency
  GPS + BeiDou) and ``dual`` (dual-frequency multi-GNSS), ``--duration`` s at 1 Hz (default 300).
  The truth is the simulator's ``truth.csv``; ``faults.csv`` labels every satellite-epoch LOS or
  NLOS, which gives the share of NLOS (and LOS) satellite-epochs that WLS excluded or down-weighted
  below 10 % of their nominal weight.
- **tst2-2020155-urban-static** (u-blox F9P, all systems) against its ground truth (157 epochs).
- **smartloc-berlin** (5 Hz urban vehicle, GPS): no reference trajectory in the shared data, so
  availability only, and the distance to rnx2rtkp on the epochs both write.

Methods: ``wls``, ``smoother``, ``kf`` and ``stls --lag 3`` in one run, each file with
``--integrity off`` (no residual gate, no per-epoch test; stls's behavior test still chooses its
spans), with
``--environment open`` (``fde`` and the multi-epoch gates, no street-canyon settings), with the
defaults (``--environment auto``: the street-canyon settings when the file's WLS variance factor
says so; the run's judgement is recorded per case) and with
``configs/urban.toml`` (``--environment urban``: the NLOS detector, nlos_dependent fixes and
protection levels that monitor several reflected satellites at once). Per method and
setting: availability (share of the epochs with status ``ok``), misleading epochs (``ok`` with the
horizontal error above HPL or the vertical above VPL), ``ok`` epochs that carry no protection level,
and the 3D RMS / 95th percentile / max of the ``ok`` epochs. rnx2rtkp (``../shared/peer/
rnx2rtkp-spp.conf`` with the file's systems) writes no protection levels: availability and errors.

Nothing here chooses a setting: every run uses the packaged defaults but for the settings above.
Prints a table and writes ``benchmarks/results/urban.json``. The full run (40 drives of 300 s, tst2,
Berlin) takes about 35 minutes on one core; ``--quick`` (2 drives of 120 s, tst2) about 4 minutes.
"""

from __future__ import annotations

from dataclasses import replace

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

from gnss_cli.config import load_config
from gnss_cli.gnss.frames import ecef2enu_rotation, ecef2geodetic
from gnss_cli.gnss.time import gps_s2week_tow
from gnss_cli.io.compression import open_bytes
from gnss_cli.io.reference import reference_from_csv
from gnss_cli.pipeline import load_epochs, process, solve_method
from gnss_cli.sim.scenario import los_grid
from results_page import results_json  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared"
RINEX = SHARED / "rinex"
PEER_CONF = SHARED / "peer" / "rnx2rtkp-spp.conf"
OUT = ROOT / "benchmarks" / "results" / "urban.json"
NAVSYS = {"G": 1, "R": 4, "E": 8, "J": 16, "C": 32}
METHODS = ("wls", "smoother", "kf", "stls")
SETTINGS: dict[str, dict[str, object]] = {"off": {"integrity": "off"},
                                           "open": {"environment": "open"}, "default": {},
                                           "urban": {"config": "configs/urban.toml"}}
"""Integrity settings of each run (every other option at its packaged default): integrity off (stls
in its default whole segments: the behavior test, which chooses its spans, runs whatever
``integrity`` says), the open-sky settings (``environment = "open"``: the packaged
settings without the street-canyon ones), the defaults (``environment = "auto"``: the street-canyon
settings when the file's WLS variance factor says so) and ``configs/urban.toml`` (``environment =
"urban"``: the NLOS detector, nlos_dependent fixes and the levels' multi-satellite faults, always;
``config`` names a settings file, relative to the repository, that the run loads under the flags)."""
SETTING_NAMES = {"open": "environment open", "default": "defaults (environment auto)", "urban": "configs/urban.toml"}
"""The judged settings (every one but ``off``) as the tables name them."""
TST_TRUTH = np.array([-2418077.2710, 5386069.6872, 2405174.1252])
TST_TOW = (270149.0, 270305.0)


def _enu_errors(x_m: np.ndarray, ref_m: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Horizontal, vertical and 3D error (m) of ``x_m`` against ``ref_m`` (both (T, 3) ECEF)."""
    lat, lon, _ = ecef2geodetic(ref_m)
    rot = ecef2enu_rotation(lat, lon)  # (T, 3, 3)
    enu = np.einsum("tij,tj->ti", rot, x_m - ref_m)
    return np.hypot(enu[:, 0], enu[:, 1]), np.abs(enu[:, 2]), np.linalg.norm(enu, axis=1)


def _error_stats(e: np.ndarray) -> dict[str, float | None]:
    e = e[np.isfinite(e)]
    if not e.size:
        return {"rms_3d_m": None, "p95_3d_m": None, "max_3d_m": None}
    return {"rms_3d_m": float(np.sqrt(np.mean(e**2))), "p95_3d_m": float(np.percentile(e, 95)), "max_3d_m": float(e.max())}


def method_row(sol, ref_m: np.ndarray | None, keep: np.ndarray) -> dict[str, object]:  # noqa: ANN001 - MethodSolution
    """Availability, misleading epochs and errors of one method's rows ``keep`` against ``ref_m``."""
    status = sol.status[keep]
    ok = status == "ok"
    row: dict[str, object] = {"epochs": int(keep.sum()), "ok": int(ok.sum()), "availability": float(ok.mean())}
    hpl = sol.hpl_m[keep] if sol.hpl_m is not None else np.full(ok.size, np.nan)
    vpl = sol.vpl_m[keep] if sol.vpl_m is not None else np.full(ok.size, np.nan)
    with_pl = ok & np.isfinite(hpl) & np.isfinite(vpl)
    row["ok_without_pl"] = int((ok & ~with_pl).sum())
    if ref_m is not None:
        h, v, e3 = _enu_errors(sol.x_ecef_m[keep], ref_m)
        mis = with_pl & ((h > hpl) | (v > vpl))
        row["misleading"] = int(mis.sum())
        row["misleading_pct"] = float(100 * mis.sum() / max(with_pl.sum(), 1))
        row.update(_error_stats(e3[ok]))
        row["rms_3d_all_m"] = _error_stats(e3)["rms_3d_m"]
    words, counts = np.unique(status, return_counts=True)
    row["statuses"] = dict(zip(words.tolist(), counts.tolist()))
    return row


def nlos_handling(sol, epochs, faults: pd.DataFrame) -> dict[str, object]:  # noqa: ANN001
    """Share of NLOS and of LOS satellite-epochs (observed and used as candidates) that ``sol``
    excluded or down-weighted below 10 % of the nominal weight."""
    labels = los_grid(faults, epochs.time_gps_s, epochs.sv)
    excluded = sol.excluded if sol.excluded is not None else np.zeros(labels.shape, bool)
    weights = sol.robust_weights if sol.robust_weights is not None else np.ones(excluded.shape)
    if sol.variance_scale is not None:  # the NLOS detector's down-weighted reflections
        weights = weights / np.nan_to_num(sol.variance_scale, nan=1.0)
    used = np.isfinite(sol.residuals_m) | excluded
    dropped = excluded | (np.nan_to_num(weights, nan=1.0) < 0.1)
    out: dict[str, object] = {}
    for name, los in (("nlos", 0), ("los", 1)):
        cand = used & (labels == los)
        out[f"{name}_candidates"] = int(cand.sum())
        out[f"{name}_dropped_pct"] = float(100 * (dropped & cand).sum() / max(cand.sum(), 1))
    return out


def los_only_rows(obs: Path, navs: list[Path], faults: pd.DataFrame, ref_at) -> dict[str, object]:  # noqa: ANN001
    """WLS with every NLOS satellite-epoch of the simulator's labels removed before the fix, with
    integrity off and with the open-sky settings (``environment = "open"``: FDE, no NLOS detector):
    what a perfect detector would leave (a bound, not a method)."""
    out: dict[str, object] = {}
    for label, over in (("off", {"integrity": "off"}), ("default", {"environment": "open"})):
        cfg = load_config(None, {"methods": "wls", **over})
        data = load_epochs(obs, navs, cfg)
        nlos = los_grid(faults, data.time_gps_s, data.sv) == 0
        sol = solve_method(replace(data, usable=data.usable & ~nlos), "wls", cfg)
        out[label] = method_row(sol, ref_at(data.time_gps_s), np.ones(data.time_gps_s.size, dtype=bool))
    return out


CASE_COLUMNS = ["case", "setting", "method", "epochs", "ok", "ok_without_pl", "misleading", "rms_3d_m", "p95_3d_m",
                "max_3d_m", "rms_3d_all_m", "statuses", "nlos_dropped_pct", "los_dropped_pct"]
"""The per-case table of the JSON: one row per case, setting and method (``los_only off`` /
``los_only default``: WLS with the labelled NLOS removed, :func:`los_only_rows`)."""


def _r(v: object) -> object:
    return round(v, 3) if isinstance(v, float) else v


def case_table(entries: list[dict[str, object]]) -> dict[str, object]:
    """The cases as one table (columns named once; metres and percent to 3 decimals), the rnx2rtkp
    rows per case and the resolved settings (one entry when every case ran the same)."""
    rows: list[list[object]] = []
    for e in entries:
        runs = [(label, m, r) for label, by in e["settings"].items() for m, r in by.items() if m != "seconds"]  # type: ignore[union-attr]
        runs += [(f"los_only {label}", "wls", r) for label, r in e.get("wls_los_only", {}).items()]  # type: ignore[union-attr]
        for label, m, r in runs:
            nl = r.get("nlos", {})
            statuses = ",".join(f"{k}:{v}" for k, v in sorted(r.get("statuses", {}).items()))
            rows.append([e["case"], label, m, *(_r(r.get(c)) for c in CASE_COLUMNS[3:11]), statuses,
                         _r(nl.get("nlos_dropped_pct")), _r(nl.get("los_dropped_pct"))])
    resolved = {str(e["case"]): e.get("resolved", {}) for e in entries}
    same = len({json.dumps(v, sort_keys=True) for v in resolved.values()}) == 1
    return {"columns": CASE_COLUMNS, "rows": rows,
            "rnx2rtkp": {str(e["case"]): {k: (_r(v) if not isinstance(v, dict) else {a: _r(b) for a, b in v.items()})
                                          for k, v in e["rnx2rtkp"].items()}  # type: ignore[union-attr]
                         for e in entries if e.get("rnx2rtkp")},
            "resolved": next(iter(resolved.values())) if same else resolved}


def _plain_copy(src: Path, folder: Path) -> Path:
    target = folder / src.name.removesuffix(".gz").replace(".crx", ".rnx")
    target.write_bytes(open_bytes(src))
    return target


def peer(obs: Path, navs: list[Path], systems: str) -> tuple[np.ndarray, np.ndarray] | None:
    """rnx2rtkp single point (the peer settings, ``pos1-navsys`` = ``systems``): GPS seconds and ECEF."""
    exe = shutil.which("rnx2rtkp")
    if exe is None or not PEER_CONF.is_file():
        return None
    navsys = sum(NAVSYS[s] for s in systems.split(",") if s in NAVSYS)
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        conf = folder / "peer.conf"
        conf.write_text("\n".join(f"pos1-navsys        ={navsys}" if ln.startswith("pos1-navsys") else ln
                                  for ln in PEER_CONF.read_text().splitlines()) + "\n")
        files = [str(_plain_copy(p, folder)) for p in (obs, *navs)]
        out = folder / "peer.pos"
        subprocess.run([exe, "-k", str(conf), "-p", "0", "-e", "-o", str(out), *files], check=True,
                       capture_output=True, timeout=1200)
        rows = [ln.split() for ln in out.read_text().splitlines() if ln.strip() and not ln.startswith("%")]
    if not rows:
        return np.zeros(0), np.zeros((0, 3))
    t = np.array([int(r[0]) * 604800.0 + float(r[1]) for r in rows])
    return t, np.array([[float(v) for v in r[2:5]] for r in rows])


def peer_row(obs: Path, navs: list[Path], systems: str, t_all: np.ndarray, keep: np.ndarray,
             ref_at) -> dict[str, object] | None:  # noqa: ANN001 - times -> (T, 3) ECEF or None
    """rnx2rtkp's fixes in the epochs ``keep`` of ``t_all``: the share it writes and its errors."""
    got = peer(obs, navs, systems)
    if got is None:
        return None
    t, xyz = got
    w = (t >= t_all[keep].min() - 0.01) & (t <= t_all[keep].max() + 0.01)
    row: dict[str, object] = {"epochs": int(keep.sum()), "written": int(w.sum()),
                              "availability": float(w.sum() / keep.sum())}
    ref = ref_at(t[w]) if w.any() else None
    if ref is not None:
        row.update(_error_stats(_enu_errors(xyz[w], ref)[2]))
    row["t_gps_s"], row["xyz_m"] = t[w], xyz[w]  # for the distance to our fixes; dropped before JSON
    return row


def run_case(name: str, obs: Path, navs: list[Path], systems: str | None, ref_at, keep_at,  # noqa: ANN001
             faults: pd.DataFrame | None) -> dict[str, object]:
    """Every method with each integrity setting on one file, and rnx2rtkp."""
    entry: dict[str, object] = {"case": name, "settings": {}}
    t_all = keep = ref = None
    wls_of: dict[str, object] = {}  # each judged setting's WLS solution, for the distance to rnx2rtkp
    for label, overrides in SETTINGS.items():
        over = {"methods": ",".join(METHODS), "stls.lag": 3, **overrides}
        config = over.pop("config", None)
        if systems:
            over["systems"] = systems
        cfg = load_config(ROOT / str(config) if config else None, over)
        t0 = time.perf_counter()
        res = process(obs, navs, cfg)
        seconds = time.perf_counter() - t0
        t_all = res.epochs.time_gps_s
        keep = keep_at(t_all)
        ref = ref_at(t_all[keep])
        rows = {m: method_row(res.solutions[m], ref, keep) for m in METHODS}
        if faults is not None:
            rows["wls"]["nlos"] = nlos_handling(res.solutions["wls"], res.epochs, faults)
        rows["seconds"] = seconds
        entry["settings"][label] = rows  # type: ignore[index]
        if label in SETTING_NAMES:
            wls_of[label] = res.solutions["wls"]
        entry["resolved"] = {m: s.to_dict() for m, s in res.settings.items()} if res.settings else {}
    assert t_all is not None and keep is not None
    if faults is not None:
        entry["wls_los_only"] = los_only_rows(obs, navs, faults, ref_at)
    sys_list = systems or ",".join(sorted({s[0] for s in res.epochs.sv.astype(str)}))
    pr = peer_row(obs, navs, sys_list, t_all, keep, ref_at)
    if pr is not None:
        t_p, x_p = pr.pop("t_gps_s"), pr.pop("xyz_m")
        idx = np.clip(np.searchsorted(t_all, t_p), 0, t_all.size - 1)
        pr["wls_ok_vs_peer_rms_m"] = {}
        for label, wls in wls_of.items():  # RMS distance (m) of WLS's ok fixes to rnx2rtkp's, per setting
            both = (np.abs(t_all[idx] - t_p) < 0.01) & (wls.status[idx] == "ok")  # type: ignore[attr-defined]
            d = np.linalg.norm(wls.x_ecef_m[idx[both]] - x_p[both], axis=1)  # type: ignore[attr-defined]
            pr["wls_ok_vs_peer_rms_m"][label] = float(np.sqrt(np.mean(d**2))) if d.size else None
        entry["rnx2rtkp"] = pr
    return entry


def simulated_cases(seeds: list[int], duration_s: float, work: Path) -> list[tuple]:
    cases = []
    for receiver in ("single", "dual"):
        for seed in seeds:
            folder = work / f"{receiver}-{seed}"
            subprocess.run([sys.executable, "-m", "gnss_cli.cli.simulate", "--environment", "urban", "--receiver",
                            receiver, "--trajectory", "drive", "--duration", str(duration_s), "--interval", "1",
                            "--seed", str(seed), "--out-dir", str(folder), "-q"], check=True)
            truth = pd.read_csv(folder / "truth.csv")
            t_truth = truth["gps_week"].to_numpy() * 604800.0 + truth["tow_s"].to_numpy()
            xyz = truth[["x_m", "y_m", "z_m"]].to_numpy()

            def ref_at(t: np.ndarray, t_truth: np.ndarray = t_truth, xyz: np.ndarray = xyz) -> np.ndarray:
                idx = np.clip(np.searchsorted(t_truth, t), 0, t_truth.size - 1)
                return xyz[idx]

            cases.append((f"sim-{receiver}-{seed}", folder / "obs.rnx", [folder / "nav.rnx"], None, ref_at,
                          lambda t: np.ones(t.size, bool), pd.read_csv(folder / "faults.csv")))
    return cases


def real_cases(quick: bool) -> list[tuple]:
    cases = []
    tst = RINEX / "tst2-2020155-urban-static"
    if tst.is_dir():
        def tst_keep(t: np.ndarray) -> np.ndarray:
            tow = gps_s2week_tow(t)[1]
            return (tow >= TST_TOW[0] - 0.01) & (tow <= TST_TOW[1] + 0.01)

        cases.append(("tst2", tst / "2020_06_03_TST_03.obs.gz", sorted(tst.glob("hksc155d.20?")), None,
                      lambda t: np.broadcast_to(TST_TRUTH, (t.size, 3)), tst_keep, None))
    ber = RINEX / "smartloc-berlin-2016158-urban-kinematic"
    if ber.is_dir() and not quick:
        cases.append(("smartloc-berlin", ber / "Berlin_Potsdamer_Platz.obs.gz",
                      [ber / "BRDC00WRD_U_20161580000_01D_MN.rnx.gz"], "G", lambda t: None,
                      lambda t: np.ones(t.size, bool), None))
    return cases


def _fmt(x: object, spec: str = ".1f") -> str:
    return "–" if x is None else format(x, spec)


def table(entries: list[dict[str, object]]) -> str:
    lines = ["| case | method | integrity | ok % | misleading (%) | ok without PL | RMS / 95 % / max of ok, m | RMS all, m |",
             "|---|---|---|---|---|---|---|---|"]
    for e in entries:
        for label, rows in e["settings"].items():  # type: ignore[union-attr]
            for m in METHODS:
                r = rows[m]
                mis = f"{r['misleading']} ({r['misleading_pct']:.1f})" if "misleading" in r else "–"
                err = f"{_fmt(r.get('rms_3d_m'))} / {_fmt(r.get('p95_3d_m'))} / {_fmt(r.get('max_3d_m'))}"
                lines.append(f"| {e['case']} | {m} | {label} | {100 * r['availability']:.0f} | {mis} | "
                             f"{r['ok_without_pl']} | {err} | {_fmt(r.get('rms_3d_all_m'))} |")
        p = e.get("rnx2rtkp")
        if p:
            err = f"{_fmt(p.get('rms_3d_m'))} / {_fmt(p.get('p95_3d_m'))} / {_fmt(p.get('max_3d_m'))}"
            lines.append(f"| {e['case']} | rnx2rtkp | its χ² | {100 * p['availability']:.0f} | – | – | {err} | |")
    return "\n".join(lines)


def aggregate(entries: list[dict[str, object]], prefix: str, label: str) -> dict[str, object]:
    """Pooled over the simulated drives of one profile, setting ``label`` against ``off``."""
    out: dict[str, object] = {}
    chosen = [e for e in entries if str(e["case"]).startswith(prefix)]
    if not chosen:
        return out
    for m in METHODS:
        ok = mis = with_pl = 0
        rms_on, rms_off = [], []
        for e in chosen:
            r, r_off = e["settings"][label][m], e["settings"]["off"][m]  # type: ignore[index]
            ok += r["ok"]
            mis += r.get("misleading", 0)
            with_pl += r["ok"] - r["ok_without_pl"]
            if r.get("rms_3d_m") is not None:
                rms_on.append(r["rms_3d_m"] ** 2 * r["ok"])
            if r_off.get("rms_3d_m") is not None:
                rms_off.append(r_off["rms_3d_m"] ** 2 * r_off["ok"])
        n_ok = sum(e["settings"][label][m]["ok"] for e in chosen)  # type: ignore[index]
        n_off = sum(e["settings"]["off"][m]["ok"] for e in chosen)  # type: ignore[index]
        rms = float(np.sqrt(sum(rms_on) / n_ok)) if n_ok else None
        rms_o = float(np.sqrt(sum(rms_off) / n_off)) if n_off else None
        out[m] = {"ok": ok, "epochs": sum(e["settings"][label][m]["epochs"] for e in chosen),  # type: ignore[index]
                  "misleading": mis, "misleading_pct_of_ok_with_pl": 100 * mis / max(with_pl, 1),
                  "ok_without_pl": ok - with_pl, "rms_3d_ok_m": rms, "rms_3d_ok_integrity_off_m": rms_o,
                  "rms_ratio_to_off": (rms / rms_o) if rms and rms_o else None}
    bound = [e["wls_los_only"] for e in chosen if "wls_los_only" in e]
    if bound:  # WLS without the labelled NLOS, against the full data's integrity-off run
        b = [x["default"] for x in bound]
        n_b = sum(x["ok"] for x in b)
        rms_b = float(np.sqrt(sum(x["rms_3d_m"] ** 2 * x["ok"] for x in b if x.get("rms_3d_m") is not None) / max(n_b, 1)))
        off = out["wls"]["rms_3d_ok_integrity_off_m"]  # type: ignore[index]
        out["wls_los_only"] = {"ok": n_b, "epochs": sum(x["epochs"] for x in b), "rms_3d_ok_m": rms_b,
                               "misleading": sum(x.get("misleading", 0) for x in b),
                               "rms_ratio_to_off": rms_b / off if off else None}
    nl = [e["settings"][label]["wls"].get("nlos") for e in chosen]  # type: ignore[index]
    nl = [x for x in nl if x]
    if nl:
        out["wls_nlos_dropped_pct"] = float(np.sum([x["nlos_dropped_pct"] * x["nlos_candidates"] for x in nl])
                                            / max(sum(x["nlos_candidates"] for x in nl), 1))
        out["wls_los_dropped_pct"] = float(np.sum([x["los_dropped_pct"] * x["los_candidates"] for x in nl])
                                           / max(sum(x["los_candidates"] for x in nl), 1))
    return out


def summary_table(entries: list[dict[str, object]], pooled: dict[str, dict[str, dict[str, object]]]) -> dict[str, object]:
    """The results page's table: the drives pooled per receiver profile, then each real set, per
    method and judged setting (``pooled[label][profile]`` from :func:`aggregate`)."""
    rows: list[list[object]] = []
    for profile in ("single", "dual"):
        for m in METHODS:
            for label, name in SETTING_NAMES.items():
                agg = pooled[label].get(profile, {})
                if m not in agg:
                    continue
                a = agg[m]
                out = (None if m != "wls" or "wls_nlos_dropped_pct" not in agg else
                       f"{agg['wls_nlos_dropped_pct']:.1f} / {agg['wls_los_dropped_pct']:.2f}")
                rows.append([f"simulated drives, {profile} profile", m, name,
                             round(100 * a["ok"] / max(a["epochs"], 1), 1), a["misleading"],
                             round(a["misleading_pct_of_ok_with_pl"], 2), a["ok_without_pl"],
                             None if a["rms_3d_ok_m"] is None else round(a["rms_3d_ok_m"], 2),
                             None if a["rms_ratio_to_off"] is None else round(a["rms_ratio_to_off"], 2), out])
        bound = pooled["default"].get(profile, {}).get("wls_los_only")
        if bound:
            rows.append([f"simulated drives, {profile} profile", "wls", "environment open, NLOS removed by the labels (bound)",
                         round(100 * bound["ok"] / max(bound["epochs"], 1), 1), bound["misleading"], None, None,
                         round(bound["rms_3d_ok_m"], 2),
                         None if bound["rms_ratio_to_off"] is None else round(bound["rms_ratio_to_off"], 2), "100 / 0"])
    for e in entries:
        if str(e["case"]).startswith("sim-"):
            continue
        for m in METHODS:
            for label, name in SETTING_NAMES.items():
                r, off = e["settings"][label][m], e["settings"]["off"][m]  # type: ignore[index]
                rms, rms_off = r.get("rms_3d_m"), off.get("rms_3d_m")
                rows.append([e["case"], m, name, round(100 * r["availability"], 1), r.get("misleading"),
                             None if "misleading_pct" not in r else round(r["misleading_pct"], 2),
                             r["ok_without_pl"], None if rms is None else round(rms, 2),
                             None if not (rms and rms_off) else round(rms / rms_off, 2), None])
        p = e.get("rnx2rtkp")
        if p:
            rows.append([e["case"], "rnx2rtkp", "its χ²", round(100 * p["availability"], 1), None, None, None,
                         None if p.get("rms_3d_m") is None else round(p["rms_3d_m"], 2), None, None])
    return {"columns": ["data", "method", "integrity", "ok %", "misleading", "misleading % of ok with PL",
                        "ok without PL", "3D RMS of ok, m", "RMS / RMS integrity off",
                        "NLOS / LOS sat-epochs out, %"], "rows": rows}


def notes(n_seeds: int, duration: float) -> str:
    """The result file's notes: what each setting and column is."""
    return (f"{2 * n_seeds} simulated urban drives of {duration:g} s (seeds 1-{n_seeds}, both receiver "
            "profiles, pooled), tst2 in its truth window, smartloc-berlin (no reference: availability). "
            "'environment open': the packaged settings without the street-canyon ones (NLOS detector off, "
            "single-fault levels); 'defaults (environment auto)': the packaged defaults, which judge each "
            "file (its WLS variance factor) and took the urban settings on every file here; "
            "'configs/urban.toml': environment urban, always (the NLOS detector, protection levels over "
            "faults of up to three satellites at a prior of 1e-2, and ls/wls epochs whose fix rests on "
            "suspected reflections nlos_dependent: min_direct_dof 1). 'RMS / RMS integrity off' "
            "compares with the same run with --integrity off. 'NLOS / LOS sat-epochs out': the "
            "share of the drives' NLOS and LOS satellite-epochs WLS excluded or down-weighted "
            "below 10 %. 'NLOS removed by the labels (bound)': WLS with the open-sky settings after the "
            "simulator's NLOS satellite-epochs are taken out before the fix, against the full data's "
            "integrity-off run: what a perfect detector would leave. "
            "The multi-epoch methods' levels are those of their own positions from the WLS epoch's "
            "fault-free subsets (docs/integrity.md, 'In the multi-epoch methods').")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="2 drives of 120 s and tst2 only")
    parser.add_argument("--seeds", type=int, default=20, help="simulated drives per receiver profile (seeds 1..N)")
    parser.add_argument("--duration", type=float, default=300.0, help="length of each drive, s")
    parser.add_argument("--out", type=Path, default=OUT, help="JSON to write (default benchmarks/results/urban.json)")
    args = parser.parse_args()
    n_seeds, duration = (1, 120.0) if args.quick else (args.seeds, args.duration)
    t0 = time.perf_counter()
    entries: list[dict[str, object]] = []
    with tempfile.TemporaryDirectory() as tmp:
        for case in simulated_cases(list(range(1, n_seeds + 1)), duration, Path(tmp)) + real_cases(args.quick):
            entry = run_case(*case)
            entries.append(entry)
            print(f"bench_urban: {entry['case']} done ({time.perf_counter() - t0:.0f} s)", file=sys.stderr)
    summary = {label: {p: aggregate(entries, f"sim-{p}-", label) for p in ("single", "dual")}
               for label in SETTING_NAMES}
    print(table(entries))
    print()
    for label, by_profile in summary.items():
        for p, agg in by_profile.items():
            print(f"simulated {p}-profile drives, {SETTING_NAMES[label]}, pooled: {json.dumps(agg, indent=None)}")
    if not args.quick:
        args.out.write_text(results_json({
            "title": "Integrity in street canyons",
            "command": "python benchmarks/bench_urban.py",
            "table": summary_table(entries, summary),
            "notes": notes(n_seeds, duration),
            "seeds": n_seeds, "duration_s": duration, "methods": METHODS, "settings": SETTINGS,
            "pooled": summary, "cases": case_table(entries), "seconds": time.perf_counter() - t0,
        }))
        print(f"wrote {args.out}", file=sys.stderr)


if __name__ == "__main__":
    main()
