"""Several epochs at once against a Kalman smoother (issue "Several epochs at once, the paper's way").

For each data set: 3D RMS, horizontal RMS, 95th percentile and max of the 3D error of

- ``wls``: the snapshot fixes;
- ``kf``: ``--method kf`` (measurement-domain EKF with Doppler, RTS smoother, defaults);
- ``stls lag 3``: ``--method stls --lag 3`` with the defaults (``--model auto``: on these files,
  which have Doppler, the measurement-domain solution of every pseudorange and range rate with
  positions and velocities tied by the lag-3 kinematic kernel, ``--model doppler``);
- ``stls lag 3 identify (fixes)``: ``--model identify``, the shared kernel identified on 15-epoch
  windows of the WLS fixes (the default before ``auto``);
- ``stls kinematic``: ``--method stls --lag 1 --model kinematic`` (fixes and Doppler velocities
  tied by the kinematic kernel, variance factors from the data);
- ``kf+rts on fixes (truth-tuned)``: a constant-velocity Kalman filter with an RTS smoother run
  on the WLS fixes (their covariances as measurement noise), its acceleration PSD the best of
  0.01 ... 100 m^2/s^3 chosen against the truth (an optimistic peer: a user cannot tune on
  the truth). Its numerics are :mod:`gnss_cli.solvers.kalman`.

Data: simulated 1 Hz flights (600 s, GPS, seeds 11-15) with ``--errors noise`` (solved with
``--iono none --tropo none``), ``--errors all`` (default corrections) and ``--errors none``
(each also as the mean over the seeds of every statistic);
the Yamatogawa walk against its RTK trajectory; tst2 (urban static) with ``--model static``
over whole segments, with the default window "auto" (chosen by the chi-square ladder) and in 15-epoch windows, ``stls --lag 3`` with the defaults and ``kf``,
against the snapshot solution, on the 157 truth epochs.

Usage: ``python benchmarks/kinematic_vs_kf.py`` (prints tables, writes
``benchmarks/results/kinematic_vs_kf.json``).
"""

from __future__ import annotations

import json
import sys
import tempfile
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "benchmarks"))

from bench_kf import RINEX, SEEDS, simulate, stats  # noqa: E402

from gnss_cli.config import load_config  # noqa: E402
from gnss_cli.gnss.time import gps_s2week_tow  # noqa: E402
from gnss_cli.io.reference import reference_from_csv, reference_from_pos  # noqa: E402
from gnss_cli.pipeline import process  # noqa: E402
from gnss_cli.solvers.kalman import kalman_filter, rts_smooth  # noqa: E402

Q_GRID = np.logspace(-2, 2, 9)
RUNS = {
    "wls": ({"methods": "wls"}, "wls"),
    "kf": ({"methods": "wls,kf"}, "kf"),
    "stls lag 3": ({"methods": "wls,stls", "smoothing.lag": 3}, "stls"),
    "stls lag 3 identify (fixes)": ({"methods": "wls,stls", "smoothing.lag": 3, "smoothing.model": "identify"}, "stls"),
    "stls kinematic": ({"methods": "wls,stls", "smoothing.lag": 1, "smoothing.model": "kinematic"}, "stls"),
}
TST_TRUTH = np.array([-2418077.2710, 5386069.6872, 2405174.1252])
TST_TOW = (270149.0, 270305.0)


def kf_rts_on_fixes(t_s: np.ndarray, x: np.ndarray, cov: np.ndarray, q: float) -> np.ndarray:
    """Constant-velocity filter + RTS on fixes ``x (T, 3)`` (NaN = none) with covariances ``cov``."""
    T = t_s.size
    F = np.repeat(np.eye(6)[None], T, axis=0)
    Q = np.zeros((T, 6, 6))
    dt = np.diff(t_s, prepend=t_s[0])
    eye = np.eye(3)
    F[:, :3, 3:] = dt[:, None, None] * eye
    Q[:, :3, :3] = (q * dt**3 / 3)[:, None, None] * eye
    Q[:, :3, 3:] = Q[:, 3:, :3] = (q * dt**2 / 2)[:, None, None] * eye
    Q[:, 3:, 3:] = (q * dt)[:, None, None] * eye
    H, y, r = [], [], []
    for k in range(T):
        if np.isfinite(x[k]).all() and np.isfinite(cov[k]).all():
            L_inv = np.linalg.inv(np.linalg.cholesky(cov[k]))
            H.append(np.hstack([L_inv, np.zeros((3, 3))]))
            y.append(L_inv @ x[k])
            r.append(np.ones(3))
        else:
            H.append(np.zeros((0, 6)))
            y.append(np.zeros(0))
            r.append(np.zeros(0))
    first = int(np.flatnonzero(np.isfinite(x).all(axis=1))[0])
    m0 = np.r_[x[first], np.zeros(3)]
    P0 = np.diag([1e4] * 3 + [1e4] * 3)
    xs, _ = rts_smooth(kalman_filter(m0, P0, F, Q, H, y, r), F)
    return xs[:, :3]


def evaluate(obs: Path, nav: list[Path], ref_of, base: dict[str, object]) -> dict[str, dict]:  # type: ignore[no-untyped-def]
    rows: dict[str, dict] = {}
    wls = None
    for name, (options, method) in RUNS.items():
        result = process(obs, nav, load_config(None, {**base, **options}))
        ref = ref_of(result.epochs.time_gps_s)
        sol = result.solutions[method]
        rows[name] = stats(np.where((sol.status == "ok")[:, None], sol.x_ecef_m, np.nan), ref)
        if method == "wls":
            wls, t, ref_w = sol, result.epochs.time_gps_s, ref
    assert wls is not None
    fixes = np.where((wls.status == "ok")[:, None], wls.x_ecef_m, np.nan)
    best = min((stats(kf_rts_on_fixes(t, fixes, wls.cov_m2[:, :3, :3], q), ref_w) | {"q_m2_s3": float(q)}
                for q in Q_GRID), key=lambda s: s["rms_3d_m"])
    rows["kf+rts on fixes (truth-tuned)"] = best
    return rows


def flights(tmp: Path) -> dict[str, dict]:
    out: dict[str, dict] = {}
    for errors in ("noise", "all", "none"):
        base = {"iono": "none", "tropo": "none"} if errors != "all" else {}
        for seed in SEEDS:
            d = simulate(tmp / f"{errors}{seed}", errors, seed)
            out[f"flight {errors} seed {seed}"] = evaluate(d / "obs.rnx", [d / "nav.rnx"],
                                                          lambda t, d=d: reference_from_csv(d / "truth.csv", t), base)
    return out


def urban_static() -> dict[str, dict] | None:
    d = RINEX / "tst2-2020155-urban-static"
    if not d.is_dir():
        return None
    navs = sorted(d.glob("hksc155d.20?"))
    out: dict[str, dict] = {}
    for name, options, method in (("wls (integrity fde)", {"methods": "wls"}, "wls"),
                                  ("stls static, whole segments", {"methods": "wls,stls", "smoothing.lag": 1,
                                                                  "smoothing.model": "static", "smoothing.window": 0}, "stls"),
                                  ("stls static, window auto (default)", {"methods": "wls,stls", "smoothing.lag": 1,
                                                                         "smoothing.model": "static"}, "stls"),
                                  ("stls static, 15-epoch windows", {"methods": "wls,stls", "smoothing.lag": 1,
                                                                    "smoothing.model": "static", "smoothing.window": 15}, "stls"),
                                  ("stls lag 3 (defaults: doppler)", {"methods": "wls,stls", "smoothing.lag": 3}, "stls"),
                                  ("kf", {"methods": "wls,kf"}, "kf")):
        result = process(d / "2020_06_03_TST_03.obs.gz", navs, load_config(None, options))
        sol = result.solutions[method]
        _, tow = gps_s2week_tow(result.epochs.time_gps_s)
        truth_epochs = (tow >= TST_TOW[0] - 0.01) & (tow <= TST_TOW[1] + 0.01)
        x = np.where((truth_epochs & (sol.status == "ok"))[:, None], sol.x_ecef_m, np.nan)
        out[name] = stats(x, np.broadcast_to(TST_TRUTH, x.shape))
    return out


def summary(table: dict[str, dict[str, dict]], prefix: str) -> dict[str, float]:
    """Mean 3D RMS over the seeds of ``prefix`` per method, and each method's ratio to the truth-tuned peer."""
    sets = [v for k, v in table.items() if k.startswith(prefix)]
    names = list(sets[0])
    mean = {n: float(np.mean([s[n]["rms_3d_m"] for s in sets])) for n in names}
    peer = mean["kf+rts on fixes (truth-tuned)"]
    return {**{f"{n} rms_3d_m": v for n, v in mean.items()}, **{f"{n} / peer": v / peer for n, v in mean.items()}}


def mean_rows(table: dict[str, dict[str, dict]], prefix: str) -> dict[str, dict]:
    """Per method, the mean over the seeds of ``prefix`` of every statistic (epochs: the sum)."""
    sets = [v for k, v in table.items() if k.startswith(prefix)]
    return {n: {k: (int(sum(s[n][k] for s in sets)) if k == "epochs" else float(np.mean([s[n][k] for s in sets])))
                for k in ("rms_3d_m", "rms_h_m", "p95_3d_m", "max_3d_m", "epochs")} for n in sets[0]}


def print_table(title: str, rows: dict[str, dict]) -> None:
    print(f"\n{title}\n{'method':<32} {'3D RMS':>8} {'H RMS':>8} {'p95':>8} {'max':>8} {'epochs':>7}")
    for name, r in rows.items():
        print(f"{name:<32} {r['rms_3d_m']:8.3f} {r['rms_h_m']:8.3f} {r['p95_3d_m']:8.3f} {r['max_3d_m']:8.3f} {r['epochs']:7d}")


def main() -> None:
    results: dict[str, object] = {}
    with tempfile.TemporaryDirectory() as tmp:
        table = flights(Path(tmp))
    for name, rows in table.items():
        print_table(name, rows)
    results["flights"] = table
    for prefix in ("flight noise", "flight all", "flight none"):
        results[f"mean {prefix}"] = rows = mean_rows(table, prefix)
        print_table(f"{prefix}, mean over seeds {SEEDS}", rows)
    for prefix in ("flight noise", "flight all"):
        results[f"summary {prefix}"] = s = summary(table, prefix)
        print(f"\n{prefix}, mean over seeds {SEEDS}: " + ", ".join(f"{k} {v:.3f}" for k, v in s.items() if "/ peer" in k))
    d = RINEX / "yamatogawa-2010006-kinematic"
    if d.is_dir():
        walk = evaluate(d / "yamatogawa_rover.obs", [d / "brdc0060.10n"],
                        lambda t: reference_from_pos(d / "rtk_ref_rover.pos", t, np.zeros_like(t)), {})
        print_table("Yamatogawa walk (RTK reference)", walk)
        results["yamatogawa"] = walk
    urban = urban_static()
    if urban is not None:
        print_table("tst2 urban static, 157 truth epochs (ok epochs)", urban)
        results["tst2"] = urban
    path = REPO / "benchmarks" / "results" / "kinematic_vs_kf.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(results, indent=1) + "\n")


if __name__ == "__main__":
    main()
