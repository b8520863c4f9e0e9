"""Where the identified stls loses to the peers with range rates: its kernels or its exact behavior.

    python benchmarks/stls_structure.py [--quick]

``multi_epoch_fair.py`` measures the identified ``stls`` at 1.5-1.8 x the best peer's 3D RMS on
the simulated flights and drives with pseudoranges and range rates. Two parts of the method
could hold that gap:

* **the kernels**: each span's kernel is identified from its window's noisy data (on short
  windows, roots such as -27 or 3.3 appear where the behavior test cut a manoeuvre into
  8-epoch windows);
* **the structure**: inside each span the trajectory lies exactly in the behavior of its kernel
  (``l`` free values per coordinate), the spans meet through one soft row
  (:mod:`gnss_cli.pipeline.tied`), and the velocities are the modes' derivatives. A peer lets
  every step deviate a little (process noise), and the smoother integrates the measured
  velocities with no model of the position at all.

This script separates them on the training runs of ``multi_epoch_fair.py`` (flights seeds
1-3, drives 1001-1003, 300 s at 1 Hz, GPS, 1 m code noise, pseudoranges and range rates; 3D
RMS pooled) by changing one thing at a time inside the tied solve, with the spans, gates and
variance factors of the method as it ships:

* ``identified``: ``stls`` as it ships;
* ``(z - 1)^3 in the same spans``: every span's kernel replaced by ``(z - 1)^3`` (exact
  quadratics), the spans unchanged: what a kernel known in advance would give in this structure;
* ``kernel rows soft, sigma S m``: each span's kernel rows as soft rows of standard deviation
  ``S`` m (the behavior with an equation error, "latency", beside the measurement misfit),
  its velocity and switch rows as shipped;

each for the 20-epoch windows at ``behavior_pfa`` 1e-12 that ``multi_epoch_fair.py``'s training
chose, and for whole segments (``window`` 0, halved where the behavior test rejects); beside
them ``smoother`` (quadrature, lag 3) and ``kf ca`` (jerk PSD 0.1 m^2/s^5), the peers' training
choices. Nothing is chosen here. Prints a table and writes
``benchmarks/results/stls_structure.json``. About 3 minutes (``--quick``: one flight and one
drive, 120 s).
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
import scipy.sparse as sp

sys.path.insert(0, str(Path(__file__).resolve().parent))
from multi_epoch_fair import SEED_OFFSET, SETS, TRAIN_SEEDS, pooled, simulate, solve_variants, stats  # noqa: E402

from gnss_cli.behavior.kinematic_solve import MotionTerms  # noqa: E402
from gnss_cli.behavior.piecewise import piecewise_terms  # noqa: E402
from gnss_cli.pipeline import tied  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "benchmarks" / "results" / "stls_structure.json"
WINDOWS = {"20-epoch windows": {"stls.window": 20, "stls.behavior_pfa": 1e-12},
           "whole segments": {"stls.window": 0, "stls.behavior_pfa": 1e-12}}
PEERS = {"smoother quadrature, lag 3": {"smoother.motion": "quadrature", "smoother.lag": 3},
         "kf ca, jerk PSD 0.1": {"kalman.model": "ca", "kalman.jerk_psd_m2_s5": 0.1}}
SOFT_SIGMAS_M = (0.03, 0.1, 0.3, 1.0)
CUBE = np.array([-1.0, 3.0, -3.0, 1.0])
"""``(z - 1)^3``, ascending and monic, as the identified shared kernels are written."""


def cube_kernels(kernels: np.ndarray, *args: Any, **kwargs: Any) -> MotionTerms:
    """:func:`piecewise_terms` with every span's kernel replaced by ``(z - 1)^3``."""
    return piecewise_terms(np.broadcast_to(CUBE, kernels.shape).copy(), *args, **kwargs)


def soft_kernel_rows(sigma_m: float) -> Callable[..., MotionTerms]:
    """:func:`piecewise_terms` with the kernel rows (the hard rows on positions only) moved to the
    soft rows with standard deviation ``sigma_m``; velocity and switch rows unchanged."""

    def terms(*args: Any, **kwargs: Any) -> MotionTerms:
        t = piecewise_terms(*args, **kwargs)
        n = t.hard.shape[1] // 2
        kernel = np.asarray(abs(t.hard[:, n:]).sum(axis=1)).ravel() == 0
        k = int(kernel.sum())
        return MotionTerms(t.hard[~kernel], t.hard_step[~kernel], sp.vstack([t.hard[kernel], t.soft], format="csr"),
                           sp.vstack([t.hard_step[kernel], t.soft_step], format="csr"),
                           sp.block_diag([sp.eye(k) / sigma_m**2, t.soft_weight], format="csr"), True)

    return terms


def cube_velocities(sigma_m: float | None) -> Callable[..., MotionTerms]:
    """:func:`piecewise_terms` with the velocity rows of ``(z - 1)^3`` (the derivative of the quadratic
    through ``l`` positions) in place of the identified modes' derivatives; the identified kernel rows
    hard (``sigma_m`` None) or soft with standard deviation ``sigma_m``."""

    def terms(kernels: np.ndarray, *args: Any, **kwargs: Any) -> MotionTerms:
        t = piecewise_terms(kernels, *args, **kwargs)
        c = cube_kernels(kernels, *args, **kwargs)
        n = t.hard.shape[1] // 2
        kernel = np.asarray(abs(t.hard[:, n:]).sum(axis=1)).ravel() == 0
        velocity = np.asarray(abs(c.hard[:, n:]).sum(axis=1)).ravel() != 0
        if sigma_m is None:
            return MotionTerms(sp.vstack([t.hard[kernel], c.hard[velocity]], format="csr"),
                               sp.vstack([t.hard_step[kernel], c.hard_step[velocity]], format="csr"),
                               t.soft, t.soft_step, t.soft_weight, True)
        k = int(kernel.sum())
        return MotionTerms(c.hard[velocity], c.hard_step[velocity], sp.vstack([t.hard[kernel], t.soft], format="csr"),
                           sp.vstack([t.hard_step[kernel], t.soft_step], format="csr"),
                           sp.block_diag([sp.eye(k) / sigma_m**2, t.soft_weight], format="csr"), True)

    return terms


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
    variants: dict[str, Callable[..., MotionTerms] | None] = {"identified": None, "(z - 1)^3 in the same spans": cube_kernels}
    variants |= {f"kernel rows soft, sigma {s:g} m": soft_kernel_rows(s) for s in SOFT_SIGMAS_M}
    variants["velocities of (z - 1)^3"] = cube_velocities(None)
    variants |= {f"velocities of (z - 1)^3, kernel rows soft, sigma {s:g} m": cube_velocities(s) for s in SOFT_SIGMAS_M}
    rows: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        files = [simulate(tmp / f"{kind}-{seed}", kind, seed + SEED_OFFSET[kind], duration_s, "noise")
                 for kind in ("flight", "drive") for seed in seeds]

        def rms(method_settings: dict[str, dict[str, Any]]) -> tuple[float, list[float]]:
            runs = [solve_variants(d / "obs.rnx", [d / "nav.rnx"], d / "truth.csv", method_settings, common) for d in files]
            name = next(iter(method_settings))
            return stats(pooled(runs, name))["rms_3d_m"], [stats(r[name]["enu_m"])["rms_3d_m"] for r in runs]

        for peer, settings in PEERS.items():
            total, each = rms({peer.split(",")[0]: settings})
            rows.append({"method": peer, "windows": "", "rms_3d_m": total, "per_run_m": each})
            print(f"{peer:42s} {total:.3f} m", file=sys.stderr)
        for wname, wset in WINDOWS.items():
            for vname, build in variants.items():
                with terms_of(build):
                    total, each = rms({"stls": {"stls.lag": 3, **wset}})
                rows.append({"method": f"stls, {vname}", "windows": wname, "rms_3d_m": total, "per_run_m": each})
                print(f"stls, {vname:58s} {wname:17s} {total:.3f} m", file=sys.stderr)
    best_peer = min(r["rms_3d_m"] for r in rows if not r["windows"])
    for r in rows:
        r["ratio_best_peer"] = r["rms_3d_m"] / best_peer
    data = {"description": __doc__.splitlines()[0], "quick": args.quick, "seconds": time.perf_counter() - t0,
            "runs": [f"{kind} seed {seed + SEED_OFFSET[kind]}" for kind in ("flight", "drive") for seed in seeds],
            "table": {"columns": ["method", "windows", "3D RMS (m)", "x best peer"],
                      "rows": [[r["method"], r["windows"], round(r["rms_3d_m"], 3), round(r["ratio_best_peer"], 2)]
                               for r in rows]},
            "rows": rows}
    if not args.quick:
        OUT.write_text(json.dumps(data, indent=1) + "\n")
    print(f"{'method':70s} {'windows':18s} {'3D RMS':>7s} {'x peer':>7s}")
    for r in rows:
        print(f"{r['method']:70s} {r['windows']:18s} {r['rms_3d_m']:7.3f} {r['ratio_best_peer']:7.2f}")
    print(f"{data['seconds']:.0f} s" + ("" if args.quick else f"; wrote {OUT.relative_to(ROOT)}"))


if __name__ == "__main__":
    main()
