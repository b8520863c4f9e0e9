"""The kf with each set of measurements: pseudoranges; + range rates; + time-differenced carrier phase.

Sets: the Yamatogawa walk against its RTK trajectory, tst2 urban static over its 157 truth
epochs (GPS seconds of week 270149-270305), and a simulated 1 Hz flight (600 s, GPS, seed 3,
``--errors all``, as ``gnss-simulate --trajectory flight --duration 600 --seed 3``; the
simulator writes no phase, so the third set equals the second there). Both motion models
(``cv``, ``ca``), the packaged defaults otherwise. The phase is read as the smoother reads it
(the kf method makes the reader keep the phase columns). Prints horizontal and
3D RMS (m) and the variance factors (pseudoranges, range rates, phase pairs).

Usage: ``python benchmarks/bench_kf_measurements.py [--rinex DIR]`` (default ``../shared/rinex``; writes
``benchmarks/results/bench_kf_measurements.json``).
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

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from gnss_cli.config import load_config  # noqa: E402
from gnss_cli.gnss.frames import ecef2enu_rotation, ecef2geodetic  # noqa: E402
from gnss_cli.io.reference import reference_from_csv, reference_from_pos  # noqa: E402
from gnss_cli.pipeline import load_epochs, solve_method  # noqa: E402
from gnss_cli.pipeline.kalman import run_kalman  # noqa: E402
from gnss_cli.pipeline.kalman_rows import variance_factors  # noqa: E402
from gnss_cli.sim.scenario import ScenarioConfig, run_scenario, write_scenario  # noqa: E402

RINEX = REPO.parent / "shared" / "rinex"
KINDS = {"pr": ("pseudorange",), "pr+doppler": ("pseudorange", "doppler"),
         "pr+doppler+phase": ("pseudorange", "doppler", "phase")}
TST2_TRUTH = np.array([-2418077.2710, 5386069.6872, 2405174.1252])


def rms(x: np.ndarray, ref: np.ndarray, sel: np.ndarray) -> dict[str, float]:
    ok = sel & np.isfinite(x).all(axis=1) & np.isfinite(ref).all(axis=1)
    lat, lon, _ = ecef2geodetic(ref[ok])
    enu = np.einsum("tij,tj->ti", ecef2enu_rotation(lat, lon), x[ok] - ref[ok])
    return {"rms_h_m": float(np.sqrt(np.mean(np.sum(enu[:, :2] ** 2, axis=1)))),
            "rms_3d_m": float(np.sqrt(np.mean(np.sum(enu**2, axis=1)))), "epochs": int(ok.sum())}


def sets(tmp: Path, rinex: Path) -> dict[str, tuple[Path, list[Path], object]]:
    out: dict[str, tuple[Path, list[Path], object]] = {}
    y = rinex / "yamatogawa-2010006-kinematic"
    if y.is_dir():
        out["yamatogawa"] = (y / "yamatogawa_rover.obs", [y / "brdc0060.10n"],
                             lambda t: (reference_from_pos(y / "rtk_ref_rover.pos", t, np.zeros_like(t)), np.ones(t.size, bool)))
    s = rinex / "tst2-2020155-urban-static"
    if s.is_dir():
        def tst2(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            tow = np.mod(t, 604800.0)
            return np.tile(TST2_TRUTH, (t.size, 1)), (tow >= 270149) & (tow <= 270305)
        out["tst2"] = (s / "2020_06_03_TST_03.obs.gz", sorted(s.glob("hksc155d.20?")), tst2)
    d = tmp / "flight"
    write_scenario(run_scenario(replace(ScenarioConfig(), trajectory="standard-flight", duration_s=600.0, interval_s=1.0, seed=3)), d)
    out["flight"] = (d / "obs.rnx", [d / "nav.rnx"],
                     lambda t: (reference_from_csv(d / "truth.csv", t), np.ones(t.size, bool)))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rinex", type=Path, default=RINEX, help="the real-data folder (default ../shared/rinex)")
    args = parser.parse_args()
    results: dict[str, dict] = {}
    with tempfile.TemporaryDirectory() as tmp_name:
        for name, (obs, navs, ref_of) in sets(Path(tmp_name), args.rinex).items():
            cfg = load_config(None, {"methods": "wls,kf", "environment": "open"})  # as measured: open-sky settings
            data = load_epochs(obs, navs, cfg)
            wls = solve_method(data, "wls", cfg)
            ref, sel = ref_of(data.time_gps_s)  # type: ignore[operator]
            factors = variance_factors(data, wls, cfg)
            results[name] = {"phase_in_file": data.phase_m is not None, "factors": factors, "wls": rms(wls.x_ecef_m, ref, sel)}
            print(f"{name}: phase {'yes' if data.phase_m is not None else 'no'}, variance factors "
                  + " / ".join(f"{f:.4g}" for f in factors) + f"; wls {results[name]['wls']['rms_3d_m']:.3f} m 3D")
            for model in ("cv", "ca"):
                c = replace(cfg, kalman=replace(cfg.kalman, model=model))
                for label, kinds in KINDS.items():
                    t0 = time.perf_counter()
                    row = rms(run_kalman(data, wls, c, measurements=frozenset(kinds)).x_ecef_m, ref, sel)
                    row["seconds"] = time.perf_counter() - t0
                    results[name][f"kf {model} {label}"] = row
                    print(f"  kf {model} {label:<17} {row['epochs']:4d} epochs  H {row['rms_h_m']:6.3f}  3D {row['rms_3d_m']:6.3f}"
                          f"  ({row['seconds']:.1f} s)")
    out = REPO / "benchmarks" / "results" / "bench_kf_measurements.json"
    out.parent.mkdir(exist_ok=True)
    out.write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
