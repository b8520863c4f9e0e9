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
(flights seeds 1-3, drives 1001-1003, the first three of its training seeds, 300 s at 1 Hz, GPS, 1 m code noise, pseudoranges and
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
* ``kernels re-fitted to the tied track``: the alternation of the joint problem (DESIGN.md
  section 6) on the whole run, with the kernel rows soft (latency :data:`ALTERNATION_LATENCY_M`):
  the tied trajectory, then each span's monic kernel (root at ``z = 1``) fitted by weighted least
  squares to that trajectory's kernel and switch rows, then the trajectory again, :data:`ROUNDS` times.
  Each step minimizes the run's cost (measurement misfit plus the soft rows) over its own
  unknowns; the residual gate may change between solves, so the cost is reported, not assumed;
* ``kernels of the true track``: each span's kernel replaced by the monic kernel that best
  predicts the *true* positions on the window it was identified on (least squares of its rows):
  the identification made perfect in this structure, a bound for any better way to find the
  kernels (variable projection included) -- a diagnostic that reads the truth, never a method;
* ``lag 2``, ``lag 4``: the order of the behavior;

each for whole segments (``window`` 0, halved where the behavior test rejects) and for
20-epoch windows, both at ``behavior_pfa`` 1e-12 and at the ``latency_m`` the training of
``multi_epoch_fair.py`` chose with range rates; beside them ``smoother`` (quadrature) and ``kf
ca`` with the settings that training chose for them (all read from its committed results).
Nothing is chosen here (``multi_epoch_fair.py`` chooses the settings). With range rates the behavior
test accepts a lag-3 behavior only over short spans on these tracks; each ``as it ships`` row gives
the mean span (epochs) of its tied runs. Prints a table and writes
``benchmarks/results/stls_structure.json``. About 20 minutes
(``--quick``: one flight and one drive, 120 s).
"""

from __future__ import annotations

import argparse
import inspect
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
from multi_epoch_fair import SEED_OFFSET, SETS, pooled, simulate, solve_variants, stats, variants_for  # noqa: E402

from gnss_cli.behavior.kinematic_solve import MotionTerms  # noqa: E402
from gnss_cli.behavior.piecewise import piecewise_terms  # noqa: E402
from gnss_cli.pipeline import tied  # noqa: E402
from gnss_cli.pipeline.smoother import SegmentRun, solve_segments  # noqa: E402

SEEDS = (1, 2, 3)
"""Flight seeds of the runs (drives: :data:`SEED_OFFSET` more), the first of ``multi_epoch_fair.py``'s
training seeds; the committed results were measured on these."""
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
ALTERNATION_LATENCY_M = 0.03
"""The soft kernel rows' standard deviation (m) of the run-level alternation (with exact rows the
tied track lies in its kernels' behavior and re-fitting returns them unchanged)."""
ROUNDS = 10
"""Kernel re-fits of the run-level alternation."""


def cube_kernels(kernels: np.ndarray, *args: Any, **kwargs: Any) -> MotionTerms:
    """:func:`piecewise_terms` with every span's kernel replaced by ``(z - 1)^3``."""
    return piecewise_terms(np.broadcast_to(CUBE, kernels.shape).copy(), *args, **kwargs)


def mode_velocities(kernels: np.ndarray, starts: np.ndarray, n: int, dt_s: np.ndarray, switch_sigma_m: float,
                    range_rates: bool = False, windows: np.ndarray | None = None,
                    free: np.ndarray | None = None, latency_sigma_m: float = 0.0, **more: Any) -> MotionTerms:
    """:func:`piecewise_terms` with the velocities tied to the positions by the kernels' modes'
    derivatives (its form without range rates; a kernel without a real logarithm, the central
    difference) in place of the quadrature rule."""
    return piecewise_terms(kernels, starts, n, dt_s, switch_sigma_m, False, windows, free, latency_sigma_m, **more)


def rejected_kernels(kernels: np.ndarray, starts: np.ndarray, n: int, dt_s: np.ndarray, switch_sigma_m: float,
                     range_rates: bool = False, windows: np.ndarray | None = None,
                     free: np.ndarray | None = None, latency_sigma_m: float = 0.0, **more: Any) -> MotionTerms:
    """:func:`piecewise_terms` with the kernel rows of every span, also of those whose behavior the
    range rates rejected or whose result stayed in the position domain (which ship without them)."""
    return piecewise_terms(kernels, starts, n, dt_s, switch_sigma_m, range_rates, windows, None, latency_sigma_m, **more)


_SIGNATURE = inspect.signature(piecewise_terms)
_TIE: dict[str, Any] = {"calls": [], "truth": None, "spans": [], "costs": []}
"""The hooks' state: ``calls`` the piecewise terms' arguments of each run of the current tie (in
plan order), ``truth`` the current file's true track (GPS seconds of week, ECEF m), ``spans``
``(epochs, spans)`` of every tied run, ``costs`` each alternation's run costs."""


def recorded_terms(*args: Any, **kwargs: Any) -> MotionTerms:
    """:func:`piecewise_terms`, its arguments kept for the hooks below and its run's size counted."""
    bound = _SIGNATURE.bind(*args, **kwargs)
    bound.apply_defaults()
    _TIE["calls"].append(dict(bound.arguments))
    _TIE["spans"].append((int(bound.arguments["n"]), len(bound.arguments["starts"])))
    return piecewise_terms(**bound.arguments)


def monic_kernel(x_m: np.ndarray, shifts: np.ndarray, weights: np.ndarray, lag: int) -> np.ndarray | None:
    """The monic kernel ``r(z) = (z - 1) q(z)`` of degree ``lag`` (ascending) whose rows
    ``sum_i r_i x_{t+i}`` at the ``shifts`` ``t`` have the least weighted square sum on the positions
    ``x_m`` ((N, 3), m); None without a row. The rows are ``q`` on the position differences."""
    if shifts.size == 0:
        return None
    d = np.diff(x_m, axis=0)
    blocks = np.stack([d[t : t + lag] for t in shifts])                  # (R, lag, 3): d_t .. d_{t+lag-1}
    a = np.concatenate(blocks[:, :-1, :].transpose(0, 2, 1))             # (3R, lag - 1)
    b = -np.concatenate(blocks[:, -1, :])                                # (3R,)
    w = np.sqrt(np.repeat(weights, 3))
    q = np.append(np.linalg.lstsq(a * w[:, None], b * w, rcond=None)[0], 1.0)
    return np.append(0.0, q) - np.append(q, 0.0)


def true_track_kernels(args: dict[str, Any], data: Any, epochs: np.ndarray) -> np.ndarray:
    """Each span's kernel fitted to the true track on its window (equal weights; a free span, or a
    window the truth does not cover, keeps its kernel)."""
    kernels = np.array(args["kernels"], dtype=np.float64)
    lag = kernels.shape[1] - 1
    tow0 = float(np.mod(data.time_gps_s[epochs[0]], 604800.0))
    truth = _TIE["truth"]
    for k, (a, b) in enumerate(args["windows"]):
        t = tow0 + np.arange(a, b) * float(args["dt_s"][k])
        i = np.searchsorted(truth[:, 0], t - 1e-6)
        if args["free"][k] or i.max() >= len(truth) or not np.allclose(truth[i, 0], t, atol=1e-3):
            continue
        r = monic_kernel(truth[i, 1:], np.arange(b - a - lag), np.ones(max(b - a - lag, 0)), lag)
        kernels[k] = kernels[k] if r is None else r
    return kernels


def refitted_kernels(args: dict[str, Any], x_m: np.ndarray) -> np.ndarray:
    """Each span's kernel fitted to the run's trajectory ``x_m`` on its own kernel rows (weight
    ``1 / latency^2``) and its switch row (``1 / switch_sigma^2``): the kernel step of the
    alternation, exact for the run's cost."""
    kernels = np.array(args["kernels"], dtype=np.float64)
    lag = kernels.shape[1] - 1
    starts, n = args["starts"], int(args["n"])
    for k, (p, q) in enumerate(zip(starts, np.append(starts[1:], n))):
        shifts = np.arange(p, max(q - lag, p))
        weights = np.full(shifts.size, args["latency_sigma_m"] ** -2.0)
        if q < n and q - lag >= p:
            shifts, weights = np.append(shifts, q - lag), np.append(weights, args["switch_sigma_m"] ** -2.0)
        r = None if args["free"][k] else monic_kernel(x_m, shifts, weights, lag)
        kernels[k] = kernels[k] if r is None else r
    return kernels


def _run_cost(res: SegmentRun) -> float:
    return float(np.nansum(res.misfit))


def true_kernel_solve(data: Any, *args: Any, plan: Any = None, **kwargs: Any) -> SegmentRun | None:
    """The tied solve with :func:`true_track_kernels` in every run."""
    calls, _TIE["calls"] = _TIE["calls"][-len(plan):], []  # this tie's runs (a tie may end before its solve)
    plan = [(epochs, piecewise_terms(**{**a, "kernels": true_track_kernels(a, data, epochs)}))
            for (epochs, _), a in zip(plan, calls)]
    return solve_segments(data, *args, plan=plan, **kwargs)


def alternating_solve(data: Any, *args: Any, plan: Any = None, **kwargs: Any) -> SegmentRun | None:
    """The tied solve, then :data:`ROUNDS` rounds of :func:`refitted_kernels` and the tied solve again."""
    calls, _TIE["calls"] = _TIE["calls"][-len(plan):], []  # this tie's runs (a tie may end before its solve)
    res = solve_segments(data, *args, plan=plan, **kwargs)
    costs = []
    for _ in range(ROUNDS):
        if res is None or not np.isfinite(res.x_ecef_m[np.concatenate([e for e, _ in plan])]).all():
            break
        costs.append(_run_cost(res))
        for a, (epochs, _) in zip(calls, plan):
            a["kernels"] = refitted_kernels(a, res.x_ecef_m[epochs])
        plan = [(epochs, piecewise_terms(**a)) for (epochs, _), a in zip(plan, calls)]
        res = solve_segments(data, *args, plan=plan, **kwargs)
    if res is not None:
        costs.append(_run_cost(res))
    _TIE["costs"].append(costs)
    return res


@contextmanager
def tie_hooks(solve: Callable[..., SegmentRun | None] | None) -> Iterator[None]:
    """The tied solve with its arguments recorded and, with ``solve``, solved by it."""
    tied.piecewise_terms = recorded_terms  # type: ignore[attr-defined]
    if solve is not None:
        tied.solve_segments = solve  # type: ignore[attr-defined]
    try:
        yield
    finally:
        tied.piecewise_terms = piecewise_terms  # type: ignore[attr-defined]
        tied.solve_segments = solve_segments  # type: ignore[attr-defined]


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


def notes_of(rows: list[dict[str, Any]]) -> str:
    """The table's notes, with how often the alternation's run cost rose (it should not)."""
    rises = sum(r.get("cost_rises", 0) for r in rows)
    return ("3D RMS pooled over flights 1-3 and drives 1001-1003 (300 s, 1 Hz, GPS, 1 m code noise, pseudoranges and "
            "range rates); x best peer: against the better of the two peers; mean span: epochs per span of the tied "
            "runs. The re-fitted kernels' run cost (measurement misfit plus soft rows) "
            + ("fell at every round of every run." if rises == 0 else f"rose {rises} times (a residual gate changed)."))


def table_of(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """The printed table of the rows."""
    return {"columns": ["method", "windows", "3D RMS (m)", "x best peer", "mean span (epochs)"],
            "rows": [[r["method"], r["windows"], round(r["rms_3d_m"], 3), round(r["ratio_best_peer"], 2),
                      round(r["mean_span_epochs"], 1) if "mean_span_epochs" in r else ""] for r in rows]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="one flight and one drive of 120 s")
    args = parser.parse_args()
    t0 = time.perf_counter()
    seeds, duration_s = (SEEDS[:1], 120.0) if args.quick else (SEEDS, 300.0)
    common = {"measurements": SETS["pr+doppler"], "iono": "none", "tropo": "none"}
    chosen = json.loads(FAIR.read_text())["settings_chosen"]["pr+doppler"]["choice"]
    shipped = {"stls.latency_m": chosen.get("stls latency_m", 0.0)}
    variants: dict[str, tuple[Callable[..., Any] | None, dict[str, float]]] = {
        "as it ships": (None, shipped), "velocities from the modes' derivatives": (mode_velocities, shipped),
        "kernel rows in every span (also rejected or untested)": (rejected_kernels, shipped),
        "(z - 1)^3 in the same spans": (cube_kernels, shipped)}
    variants |= {f"latency {v:g} m": (None, {"stls.latency_m": v}) for v in LATENCIES_M if v != shipped["stls.latency_m"]}
    variants |= {
        f"kernels re-fitted to the tied track ({ROUNDS} rounds, latency {ALTERNATION_LATENCY_M:g} m)":
            (alternating_solve, {"stls.latency_m": ALTERNATION_LATENCY_M}),
        "kernels of the true track (a bound, reads the truth)": (true_kernel_solve, shipped),
        "lag 2": (None, {**shipped, "stls.lag": 2}), "lag 4": (None, {**shipped, "stls.lag": 4})}
    rows: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        files = [simulate(tmp / f"{kind}-{seed}", kind, seed + SEED_OFFSET[kind], duration_s, "noise")
                 for kind in ("flight", "drive") for seed in seeds]

        def rms(method_settings: dict[str, dict[str, Any]]) -> tuple[float, list[float]]:
            runs = []
            for d in files:
                _TIE["truth"] = np.loadtxt(d / "truth.csv", delimiter=",", skiprows=1, usecols=(2, 3, 4, 5))
                runs.append(solve_variants(d / "obs.rnx", [d / "nav.rnx"], d / "truth.csv", method_settings, common))
            name = next(iter(method_settings))
            return stats(pooled(runs, name))["rms_3d_m"], [stats(r[name]["enu_m"])["rms_3d_m"] for r in runs]

        for peer, settings in variants_for(chosen, PEERS).items():
            label = f"{peer} ({_settings_text(settings)})"
            total, each = rms({peer: settings})
            rows.append({"method": label, "windows": "", "rms_3d_m": total, "per_run_m": each})
            print(f"{label:60s} {total:.3f} m", file=sys.stderr)
        for wname, wset in WINDOWS.items():
            for vname, (hook, extra) in variants.items():
                _TIE.update(calls=[], spans=[], costs=[])
                solve = hook if hook in (alternating_solve, true_kernel_solve) else None
                with tie_hooks(solve) if hook is solve else terms_of(hook):
                    total, each = rms({"stls": {"stls.lag": 3, **wset, **extra}})
                row = {"method": f"stls, {vname}", "windows": wname, "rms_3d_m": total, "per_run_m": each}
                if vname == "as it ships":
                    row["mean_span_epochs"] = sum(n for n, _ in _TIE["spans"]) / max(sum(k for _, k in _TIE["spans"]), 1)
                if solve is alternating_solve:
                    row["run_costs"] = _TIE["costs"]
                    row["cost_rises"] = sum(int(b > a * (1 + 1e-9)) for c in _TIE["costs"] for a, b in zip(c, c[1:]))
                rows.append(row)
                print(f"stls, {vname:48s} {wname:17s} {total:.3f} m {row.get('mean_span_epochs', '')}", file=sys.stderr)
    best_peer = min(r["rms_3d_m"] for r in rows if not r["windows"])
    for r in rows:
        r["ratio_best_peer"] = r["rms_3d_m"] / best_peer
    data = {"title": "stls with range rates, one part changed at a time (training runs)",
            "command": "python benchmarks/stls_structure.py",
            "notes": notes_of(rows),
            "description": __doc__.splitlines()[0], "quick": args.quick, "seconds": time.perf_counter() - t0,
            "runs": [f"{kind} seed {seed + SEED_OFFSET[kind]}" for kind in ("flight", "drive") for seed in seeds],
            "table": table_of(rows), "rows": rows}
    if not args.quick:
        OUT.write_text(json.dumps(data, indent=1) + "\n")
    print(f"{'method':72s} {'windows':18s} {'3D RMS':>7s} {'x peer':>7s}")
    for r in rows:
        print(f"{r['method']:72s} {r['windows']:18s} {r['rms_3d_m']:7.3f} {r['ratio_best_peer']:7.2f}")
    print(f"{data['seconds']:.0f} s" + ("" if args.quick else f"; wrote {OUT.relative_to(ROOT)}"))


if __name__ == "__main__":
    main()
