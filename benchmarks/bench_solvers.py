"""Monte Carlo study and timing of the single-epoch solver family.

Run from the repository root::

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 python -m benchmarks.bench_solvers [--trials 10000] [--seed 1]

(The script sets both variables itself when they are unset: the stacked small products
are faster with one BLAS thread.)

Study. Random realistic skies: 4-12 satellites, azimuth uniform, elevation uniform in
sin(el) above 10°; rows ``[-e_enu, 1]``. Truth ``x = [δu, δb]`` with the linearization point
off by N(0, ``--offset`` m) per axis (the first Gauss-Newton step of a receiver started
far away), clock N(0, 100 m). Pseudorange noise ``σ_i² = a² + b²/sin²(el_i)`` (a = 0.5 m,
b = 2 m). Two scenarios:

* ``noise-only``: the geometry rows are exact;
* ``geometry``: each line-of-sight component is perturbed by N(0, ``--sigma-a``) (an
  errors-in-variables model for orbit / linearization errors), so TLS-type methods have
  something to correct.

Every method sees the same epochs (padded to 12 rows with a mask): ``wls`` / ``wtls``
get ``weights = 1/σ_i²``; ``mtls`` / ``stls`` treat the clock column as exact; ``stls``
gets the true row covariance ``diag(σ_A², σ_A², σ_A², σ_i²)``. Per method: RMS 3-D position
error, mean GDOP ``sqrt(tr(J Jᵀ))`` (unitless, from the gain), success rate, and the
``solve_batch`` time per epoch. Writes ``benchmarks/results/bench_solvers.json``.
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

if __package__ in (None, ""):  # run as a script from a checkout without installation
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from gnss_cli.solvers import METHODS, solve_batch  # noqa: E402

N_MAX = 12
A_SIGMA_M = 0.5
B_SIGMA_M = 2.0


def simulate(rng: np.random.Generator, T: int, offset_m: float, sigma_a: float) -> dict[str, np.ndarray]:
    """Stacked epochs ``A (T, 12, 4)``, ``q``, ``mask``, variances and the truth."""
    n = rng.integers(4, N_MAX + 1, T)
    mask = np.arange(N_MAX)[None, :] < n[:, None]
    az = rng.uniform(0.0, 2.0 * np.pi, (T, N_MAX))
    el = np.arcsin(rng.uniform(np.sin(np.deg2rad(10.0)), 1.0, (T, N_MAX)))
    e = np.stack([np.cos(el) * np.sin(az), np.cos(el) * np.cos(az), np.sin(el)], axis=-1)
    A_true = np.concatenate([-e, np.ones((T, N_MAX, 1))], axis=-1)
    x_true = np.concatenate([rng.normal(0.0, offset_m, (T, 3)), rng.normal(0.0, 100.0, (T, 1))], axis=1)
    var_q = A_SIGMA_M**2 + B_SIGMA_M**2 / np.sin(el) ** 2
    q = np.einsum("tnm,tm->tn", A_true, x_true) + rng.normal(size=(T, N_MAX)) * np.sqrt(var_q)
    A = A_true.copy()
    A[:, :, :3] += rng.normal(0.0, sigma_a, (T, N_MAX, 3)) if sigma_a > 0 else 0.0
    row_cov = np.zeros((T, N_MAX, 4, 4))
    row_cov[:, :, 0, 0] = row_cov[:, :, 1, 1] = row_cov[:, :, 2, 2] = sigma_a**2
    row_cov[:, :, 3, 3] = var_q
    return {"A": A, "q": q, "mask": mask, "var_q": var_q, "row_cov": row_cov, "x_true": x_true}


def method_kwargs(method: str, data: dict[str, np.ndarray]) -> dict:
    """The options each method is run with in the study."""
    if method in ("wls", "wtls"):
        return {"weights": 1.0 / data["var_q"]}
    if method == "mtls":
        return {"exact_columns": [3]}
    if method == "stls":
        return {"exact_columns": [3], "row_cov": data["row_cov"]}
    return {}


def timed(fn, repeat: int) -> tuple[float, object]:
    """Best wall time of ``repeat`` calls, and the last result."""
    best, out = np.inf, None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


def study(data: dict[str, np.ndarray], repeat: int) -> dict[str, dict[str, float]]:
    rows: dict[str, dict[str, float]] = {}
    T = data["q"].shape[0]
    for method in METHODS:
        kw = method_kwargs(method, data)
        seconds, res = timed(lambda: solve_batch(method, data["A"], data["q"], data["mask"], **kw), repeat)
        ok = res.success
        err = np.linalg.norm(res.x[:, :3] - data["x_true"][:, :3], axis=1)
        gdop = np.sqrt(np.trace(res.gain @ np.swapaxes(res.gain, -1, -2), axis1=1, axis2=2))
        six = ok & (data["mask"].sum(axis=1) >= 6)
        rows[method] = {
            "rms_3d_m": float(np.sqrt(np.mean(err[ok] ** 2))),
            "rms_3d_n6_m": float(np.sqrt(np.mean(err[six] ** 2))),
            "median_3d_m": float(np.median(err[ok])),
            "mean_gdop": float(np.mean(gdop[ok])),
            "median_gdop": float(np.median(gdop[ok])),
            "success_rate": float(ok.mean()),
            "mean_iterations": float(res.iterations[ok].mean()),
            "seconds": seconds,
            "us_per_epoch": 1e6 * seconds / T,
        }
    return rows


def print_table(title: str, rows: dict[str, dict[str, float]]) -> None:
    print(f"\n{title}")
    print(
        f"{'method':<6} {'RMS 3D m':>9} {'RMS n>=6':>9} {'median m':>9} {'mean GDOP':>10} "
        f"{'med GDOP':>9} {'ok %':>6} {'iter':>5} {'µs/epoch':>9}"
    )
    best = min(r["rms_3d_n6_m"] for r in rows.values())
    for m, r in rows.items():
        flag = " <- best (n>=6)" if r["rms_3d_n6_m"] == best else ""
        print(
            f"{m:<6} {r['rms_3d_m']:9.2f} {r['rms_3d_n6_m']:9.3f} {r['median_3d_m']:9.3f} {r['mean_gdop']:10.2f} "
            f"{r['median_gdop']:9.3f} {100 * r['success_rate']:6.2f} {r['mean_iterations']:5.2f} "
            f"{r['us_per_epoch']:9.1f}{flag}"
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=10_000)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--offset", type=float, default=300.0, help="linearization offset σ per axis, m")
    parser.add_argument("--sigma-a", type=float, default=0.005, help="line-of-sight perturbation σ (unitless)")
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    rng = np.random.default_rng(args.seed)
    out: dict[str, object] = {"trials": args.trials, "seed": args.seed, "offset_m": args.offset, "sigma_a": args.sigma_a}

    for name, sigma_a in (("noise-only", 0.0), ("geometry", args.sigma_a)):
        data = simulate(rng, args.trials, args.offset, sigma_a)
        rows = study(data, args.repeat)
        total = sum(r["seconds"] for r in rows.values())
        print_table(f"scenario {name}: {args.trials} epochs, σ_A = {sigma_a}", rows)
        print(f"all seven methods: {total:.3f} s for {args.trials} epochs = {args.trials / total:,.0f} epochs/s")
        out[name] = {"methods": rows, "all_methods_epochs_per_s": args.trials / total}

    # LS / WLS throughput at the pipeline's size
    data = simulate(rng, 3000, args.offset, 0.0)
    speed = {}
    for method in ("ls", "wls"):
        kw = method_kwargs(method, data)
        sec, _ = timed(lambda: solve_batch(method, data["A"], data["q"], data["mask"], **kw), 5)
        speed[method] = 3000 / sec
    print(f"\nT=3000, n=12, m=4: ls {speed['ls']:,.0f} epochs/s, wls {speed['wls']:,.0f} epochs/s (target >= 10,000)")
    out["ls_wls_T3000_epochs_per_s"] = speed

    # vectorized Newton STLS vs the per-epoch scipy.optimize.least_squares reference
    sub = simulate(rng, 300, args.offset, args.sigma_a)
    kw = method_kwargs("stls", sub)
    t_newton, r_newton = timed(lambda: solve_batch("stls", sub["A"], sub["q"], sub["mask"], **kw), 3)
    t_scipy, r_scipy = timed(
        lambda: solve_batch("stls", sub["A"], sub["q"], sub["mask"], optimizer="scipy", **kw), 1
    )
    both = r_newton.success & r_scipy.success
    dx = float(np.max(np.abs(r_newton.x[both] - r_scipy.x[both])))
    print(
        f"STLS on 300 epochs: vectorized Newton {t_newton * 1e3:.1f} ms, scipy loop {t_scipy * 1e3:.1f} ms "
        f"(ratio {t_scipy / t_newton:.0f}x), max |Δx| = {dx:.2e} m"
    )
    out["stls_newton_vs_scipy"] = {"newton_s": t_newton, "scipy_s": t_scipy, "ratio": t_scipy / t_newton, "max_dx_m": dx}

    path = Path(__file__).resolve().parent / "results" / "bench_solvers.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(out, indent=2))
    print(f"\nwrote {path}")


if __name__ == "__main__":
    main()
