"""What each part of stls's tied solve with range rates costs or gains: its velocity link, its kernels, its exactness.

    python benchmarks/stls_structure.py [--quick]

With range rates, ``stls`` solves each run of spans at once (:mod:`gnss_cli.pipeline.tied`):
inside each span the trajectory lies exactly in the behavior of its identified kernel, the
spans meet through one soft row, and the velocities the range rates observe are tied to the
positions (:func:`gnss_cli.behavior.piecewise.piecewise_terms`). Three parts of that model can
hold its error above the peers', which let every step deviate a little (process noise):

* **the velocity link**: the quadrature rule of ``smoother`` (as it ships), or the derivative of
  each kernel's modes (exact in the behavior; what ``stls`` used before);
* **the kernels**: each span's kernel is identified from its window's noisy data (on short
  windows, roots such as -27 or 3.3 appear where the behavior test cut a manoeuvre into
  8-epoch windows);
* **the exactness**: the kernel rows hold exactly, also of spans whose behavior passed the test
  only without the range rates.

This script changes one part at a time inside the tied solve, with the spans, gates and
variance factors of the method as it ships, on the training runs of ``multi_epoch_fair.py``
(flights seeds 1-3, drives 1001-1003, 300 s at 1 Hz, GPS, 1 m code noise, pseudoranges and
range rates; 3D RMS pooled):

* ``as it ships``;
* ``velocities from the modes' derivatives``: ``v_t = log(A_k) / dt`` applied to ``l`` positions of
  the span (a kernel without a real logarithm: the central difference);
* ``kernel rows in every span (also rejected or untested)``: the spans that passed the behavior
  test only with the pseudoranges alone, and those whose result stayed in the position domain,
  keep their kernel rows (they ship without);
* ``(z - 1)^3 in the same spans``: every span's kernel replaced by ``(z - 1)^3`` (exact
  quadratics), the spans unchanged: what a kernel known in advance would give in this structure;
* ``latency S m``: each span's kernel rows as soft rows of standard deviation ``S`` m
  (``stls.latency_m``: the behavior driven by a latent input beside the measurement misfit),
  its velocity and switch rows as shipped;

each for whole segments (``window`` 0, halved where the behavior test rejects) and for
20-epoch windows, both at ``behavior_pfa`` 1e-12 and at the ``latency_m`` the training of
``multi_epoch_fair.py`` chose with range rates; beside them ``smoother`` (quadrature) and ``kf
ca`` with the settings that training chose for them (all read from its committed results).
Nothing is chosen here (``multi_epoch_fair.py`` chooses the settings). Prints a table and writes
``benchmarks/results/stls_structure.json``. About 10 minutes
(``--quick``: one flight and one drive, 120 s).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from multi_epoch_fair import OUT as FAIR  # noqa: E402
from multi_epoch_fair import SEED_OFFSET, SETS, TRAIN_SEEDS, pooled, simulate, solve_variants, stats, variants_for  # noqa: E402

from gnss_cli.behavior.kinematic_solve import MotionTerms  # noqa: E402
from gnss_cli.behavior.piecewise import piecewise_terms  # noqa: E402
from gnss_cli.pipeline import tied  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "benchmarks" / "results" / "stls_structure.json"
WINDOWS = {"whole segments": {"stls.window": 0, "stls.behavior_pfa": 1e-12},
           "20-epoch windows": {"stls.window": 20, "stls.behavior_pfa": 1e-12}}
PEERS = ("smoother quadrature", "kf ca")
"""The peers, with the settings ``multi_epoch_fair.py``'s training chose for them with range rates
(read from its committed results)."""
LATENCIES_M = (0.0, 0.01, 0.1, 1.0)
"""The ``stls.latency_m`` rows (the shipped choice among them is the ``as it ships`` row)."""
CUBE = np.array([-1.0, 3.0, -3.0, 1.0])
"""``(z - 1)^3``, ascending and monic, as the identified shared kernels are written."""


def cube_kernels(kernels: np.ndarray, *args: Any, **kwargs: Any) -> MotionTerms:
    """:func:`piecewise_terms` with every span's kernel replaced by ``(z - 1)^3``."""
    return piecewise_terms(np.broadcast_to(CUBE, kernels.shape).copy(), *args, **kwargs)


def mode_velocities(kernels: np.ndarray, starts: np.ndarray, n: int, dt_s: np.ndarray, switch_sigma_m: float,
                    range_rates: bool = False, windows: np.ndarray | None = None,
                    free: np.ndarray | None = None, latency_sigma_m: float = 0.0) -> MotionTerms:
    """:func:`piecewise_terms` with the velocities tied to the positions by the kernels' modes'
    derivatives (its form without range rates; a kernel without a real logarithm, the central
    difference) in place of the quadrature rule."""
    return piecewise_terms(kernels, starts, n, dt_s, switch_sigma_m, False, windows, free, latency_sigma_m)


def rejected_kernels(kernels: np.ndarray, starts: np.ndarray, n: int, dt_s: np.ndarray, switch_sigma_m: float,
                     range_rates: bool = False, windows: np.ndarray | None = None,
                     free: np.ndarray | None = None, latency_sigma_m: float = 0.0) -> MotionTerms:
    """:func:`piecewise_terms` with the kernel rows of every span, also of those whose behavior the
    range rates rejected or whose result stayed in the position domain (which ship without them)."""
    return piecewise_terms(kernels, starts, n, dt_s, switch_sigma_m, range_rates, windows, None, latency_sigma_m)


def _settings_text(settings: dict[str, Any]) -> str:
    """``{"smoother.lag": 3}`` as ``lag 3``."""
    return ", ".join(f"{key.rsplit('.', 1)[1]} {value}" for key, value in settings.items())


@contextmanager
def terms_of(build: Callable[..., MotionTerms] | None) -> Iterator[None]:
    """The tied solve with its piecewise terms from ``build`` (None: as it ships)."""
    if build is None:
        yield
        return
    tied.piecewise_terms = build  # type: ignore[attr-defined]
    try:
        yield
    finally:
        tied.piecewise_terms = piecewise_terms  # type: ignore[attr-defined]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="one flight and one drive of 120 s")
    args = parser.parse_args()
    t0 = time.perf_counter()
    seeds, duration_s = (TRAIN_SEEDS[:1], 120.0) if args.quick else (TRAIN_SEEDS, 300.0)
    common = {"measurements": SETS["pr+doppler"], "iono": "none", "tropo": "none"}
    chosen = json.loads(FAIR.read_text())["settings_chosen"]["pr+doppler"]["choice"]
    shipped = {"stls.latency_m": chosen.get("stls latency_m", 0.0)}
    variants: dict[str, tuple[Callable[..., MotionTerms] | None, dict[str, float]]] = {
        "as it ships": (None, shipped), "velocities from the modes' derivatives": (mode_velocities, shipped),
        "kernel rows in every span (also rejected or untested)": (rejected_kernels, shipped),
        "(z - 1)^3 in the same spans": (cube_kernels, shipped)}
    variants |= {f"latency {v:g} m": (None, {"stls.latency_m": v}) for v in LATENCIES_M if v != shipped["stls.latency_m"]}
    rows: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        files = [simulate(tmp / f"{kind}-{seed}", kind, seed + SEED_OFFSET[kind], duration_s, "noise")
                 for kind in ("flight", "drive") for seed in seeds]

        def rms(method_settings: dict[str, dict[str, Any]]) -> tuple[float, list[float]]:
            runs = [solve_variants(d / "obs.rnx", [d / "nav.rnx"], d / "truth.csv", method_settings, common) for d in files]
            name = next(iter(method_settings))
            return stats(pooled(runs, name))["rms_3d_m"], [stats(r[name]["enu_m"])["rms_3d_m"] for r in runs]

        for peer, settings in variants_for(chosen, PEERS).items():
            label = f"{peer} ({_settings_text(settings)})"
            total, each = rms({peer: settings})
            rows.append({"method": label, "windows": "", "rms_3d_m": total, "per_run_m": each})
            print(f"{label:60s} {total:.3f} m", file=sys.stderr)
        for wname, wset in WINDOWS.items():
            for vname, (build, extra) in variants.items():
                with terms_of(build):
                    total, each = rms({"stls": {"stls.lag": 3, **wset, **extra}})
                rows.append({"method": f"stls, {vname}", "windows": wname, "rms_3d_m": total, "per_run_m": each})
                print(f"stls, {vname:48s} {wname:17s} {total:.3f} m", file=sys.stderr)
    best_peer = min(r["rms_3d_m"] for r in rows if not r["windows"])
    for r in rows:
        r["ratio_best_peer"] = r["rms_3d_m"] / best_peer
    data = {"title": "stls with range rates, one part changed at a time (training runs)",
            "command": "python benchmarks/stls_structure.py",
            "notes": "3D RMS pooled over flights 1-3 and drives 1001-1003 (300 s, 1 Hz, GPS, 1 m code noise, "
                     "pseudoranges and range rates); x best peer: against the better of the two peers.",
            "description": __doc__.splitlines()[0], "quick": args.quick, "seconds": time.perf_counter() - t0,
            "runs": [f"{kind} seed {seed + SEED_OFFSET[kind]}" for kind in ("flight", "drive") for seed in seeds],
            "table": {"columns": ["method", "windows", "3D RMS (m)", "x best peer"],
                      "rows": [[r["method"], r["windows"], round(r["rms_3d_m"], 3), round(r["ratio_best_peer"], 2)]
                               for r in rows]},
            "rows": rows}
    if not args.quick:
        OUT.write_text(json.dumps(data, indent=1) + "\n")
    print(f"{'method':60s} {'windows':18s} {'3D RMS':>7s} {'x peer':>7s}")
    for r in rows:
        print(f"{r['method']:60s} {r['windows']:18s} {r['rms_3d_m']:7.3f} {r['ratio_best_peer']:7.2f}")
    print(f"{data['seconds']:.0f} s" + ("" if args.quick else f"; wrote {OUT.relative_to(ROOT)}"))


if __name__ == "__main__":
    main()
