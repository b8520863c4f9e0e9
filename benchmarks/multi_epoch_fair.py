"""kf, smoother and the identified stls on equal information, with settings chosen on training seeds.

For each measurement set (pseudoranges; + Doppler range rates; + time-differenced carrier phase
where the file has it) every multi-epoch method runs through the same public path as
``gnss_cli.solve`` (:func:`gnss_cli.pipeline.process` on a configuration from
:func:`gnss_cli.config.load_config`, rows by :func:`gnss_cli.api.to_dataset`) with
``measurements`` set explicitly, so all of them get the same observations, weights, variance
factors and gate threshold (the kf tests innovations before its update, the smoother and stls
residuals after their fit):

* ``kf`` with ``kalman.model`` ``cv`` and ``ca``; each also with ``free clocks`` (its receiver clock
  model, random walks of the clocks and drift, removed: every epoch's clock free, as the smoother
  and stls have them), reported beside the peers, not a peer: how much of the kf's result comes
  from that model;
* ``smoother`` with each ``smoother.motion``: ``quadrature``, ``cv``, ``ca`` (and ``static`` on
  tst2 only, as a row for reference: it knows the antenna does not move, so it is not a peer of
  a kinematic solution);
* ``stls`` with ``lag = 3`` (the identified Hankel STLS in the measurement domain, by
  alternation, with the measurements of the set; with range rates or phase its spans solved
  together, :mod:`gnss_cli.pipeline.tied`). The JSON and the table record what each
  method reported it ran (``estimator, model, lag, window, measurements`` of the run's settings).
* ``stls defaults``: ``stls --lag 3`` with the package's ``[stls]`` defaults, the same in every
  set. Their window and false-alarm probability are chosen on the training runs too
  (:func:`default_candidate`: one setting for every set, nearest the best in its worst set); the
  run says so when the package's defaults differ from that choice. Its rows say what a user who
  gives only ``--lag 3`` gets.

**Settings are chosen before anything is reported.** On the training seeds (1-6; drives 1001-1006,
:data:`SEED_OFFSET`) of simulated
flights and drives with 1 m code noise, a small grid per method and measurement set is run and
the most constrained candidate whose training error is within one standard error of the best
(paired over the twelve training runs, :func:`choose`) is picked: ``kf cv``
``accel_psd_m2_s3``, ``kf ca`` ``jerk_psd_m2_s5``, the same PSDs for ``smoother cv`` and
``smoother ca`` (chosen on their own), the smoother's quadrature lag, the stls
window (0: whole segments, halved where the behavior test rejects) and its behavior test's
false-alarm probability (``behavior_pfa``); then, where its spans are tied (range rates or
phase), stls's ``latency_m`` at those (:data:`LATENCY_M`). They are written to the JSON and then
fixed for the evaluation seeds (101-110), the noise-free flight and the real sets. The simulated
files carry open-sky carrier phases (``gnss-simulate --phase``: continuous, millimetre PLL jitter,
no multipath), so the phase set is chosen on its own training runs too.

Cases:

Every method of a case and measurement set is compared on the same epochs: those where all of
them have a position (the rows say how many each solved).

* ``flight`` / ``drive``: ``gnss-simulate --trajectory flight|drive`` (path and start time drawn
  from the seed), GPS, 1 Hz, 300 s, ``--errors noise --noise-sigma 1 --phase``, solved with ``iono none, tropo
  none``; errors against ``truth.csv``, pooled over the evaluation seeds: 3D RMS, horizontal RMS,
  95th percentile of the 3D error.
* ``flight exact``: the same with ``--errors none`` (evaluation seed 101): the largest 3D error
  of each method.
* ``yamatogawa``: the u-blox walk against its RTK trajectory (``rtk_ref_rover.pos``), default
  processing: horizontal RMS, and the vertical and horizontal RMS after removing the mean
  vertical, east and north error common to all methods (one number each per measurement set,
  over every method's compared epochs: the RTK base fixes the absolute position only to a few
  metres, the shape to centimetres).
* ``tst2``: the Hong Kong urban static antenna solved as a kinematic receiver with the open-sky
  settings (``environment = "open"``, the defaults when this was measured: the default ``auto``
  now judges tst2 a street canyon and starts every method alike from the NLOS detector's fixes,
  docs/integrity.md), errors against its static reference over the truth window (GPS seconds of week
  270149-270305); horizontal RMS in the summary (as the Yamatogawa walk), 3D in the full table.

The table gives per case and measurement set the best smoother and the best kf (by 3D RMS,
horizontal RMS on Yamatogawa and tst2), the identified stls, the ratio stls / best peer and its 95 %
bootstrap interval (:func:`ratio_interval`: the ten evaluation runs resampled on the simulated
tracks; on a real set, one trajectory, blocks of :data:`BLOCK_EPOCHS` epochs); every row is in
the JSON and in a second table.

Usage: ``python benchmarks/multi_epoch_fair.py [--quick] [--rinex DIR]``; writes
``benchmarks/results/multi_epoch_fair.json`` (``--quick``: ``multi_epoch_fair_quick.json`` under
the system's temporary folder; one training seed, two evaluation seeds, 120 s, real sets
skipped). The runs of a step are dealt among the machine's cores (:func:`in_parallel`); the JSON
records the run's time.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import replace
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from gnss_cli.api import to_dataset  # noqa: E402
from gnss_cli.config import load_config  # noqa: E402
from gnss_cli.io.reference import Reference  # noqa: E402
from gnss_cli.parallel import WorkerError, can_fork, cores, fork_all  # noqa: E402
from gnss_cli.pipeline import process  # noqa: E402
from gnss_cli.report import utc_offset_s  # noqa: E402
from gnss_cli.sim.error_sources import parse_error_list  # noqa: E402
from gnss_cli.sim.scenario import ScenarioConfig, run_scenario, write_scenario  # noqa: E402

RINEX = REPO.parent / "shared" / "rinex"
OUT = REPO / "benchmarks" / "results" / "multi_epoch_fair.json"
SETS = {"pr": "pseudorange", "pr+doppler": "pseudorange,doppler", "pr+doppler+phase": "pseudorange,doppler,phase"}
TST2_TRUTH = [-2418077.2710, 5386069.6872, 2405174.1252]
TRAIN_SEEDS, EVAL_SEEDS = tuple(range(1, 7)), tuple(range(101, 111))
SEED_OFFSET = {"flight": 0, "drive": 1000}
"""The drives use seeds 1001-1006 and 1101-1110: a seed fixes the noise and the start time
whatever the trajectory, so flight and drive of one seed would share them."""

GRID: dict[str, tuple[str, tuple[Any, ...]]] = {
    "kf cv": ("kalman.accel_psd_m2_s3", (0.01, 0.1, 1.0, 10.0, 100.0)),
    "kf ca": ("kalman.jerk_psd_m2_s5", (0.01, 0.1, 1.0, 10.0, 100.0)),
    "smoother quadrature": ("smoother.lag", (1, 2, 3)),
    "smoother cv": ("kalman.accel_psd_m2_s3", (0.01, 0.1, 1.0, 10.0, 100.0)),
    "smoother ca": ("kalman.jerk_psd_m2_s5", (0.01, 0.1, 1.0, 10.0, 100.0)),
    "stls": ("stls.window,stls.behavior_pfa", tuple((w, p) for w in (0, 30, 20, 15, 10) for p in (1e-12, 1e-9, 1e-6, 1e-3))),
}
"""The setting tuned per method (config key, candidates; keys joined by commas take tuples of
values). The smoother's ``cv`` and ``ca`` take the kf's process noise keys (the same model:
white acceleration / jerk of that PSD), each chosen on its own.

Candidates are listed most constrained first, the order :func:`choose` prefers among those the
training cannot tell apart: the smallest process noise (the stiffest motion); the quadrature rule
of the lowest order; for stls the longest windows (0: whole segments) and, at one window length,
the smallest false-alarm probability (fewest windows rejected and split, so fewest kernels)."""
LATENCY_M = (0.0, 0.003, 0.01, 0.03, 0.1, 0.3)
"""Candidates of ``stls.latency_m`` (most constrained first: 0 is the exact behavior), chosen after
stls's window and false-alarm probability, at those, where spans are tied (range rates or phase);
with the pseudoranges alone it does nothing."""


def setting(key: str, candidate: Any) -> dict[str, Any]:
    """The overrides of one candidate of :data:`GRID` (``key``: one config key or several, comma-joined)."""
    keys = key.split(",")
    return dict(zip(keys, candidate if len(keys) > 1 else (candidate,)))


def label_of(candidate: Any) -> str:
    """A candidate as written in the scores (no spaces: ``15/1e-09`` for a pair)."""
    return "/".join(map(str, candidate)) if isinstance(candidate, tuple) else str(candidate)


def choose(candidates: Sequence[Any], mse_m2: dict[str, list[float]]) -> Any:
    """The first of ``candidates`` (listed most constrained first) whose training error is within
    one standard error of the best's (the one-standard-error rule of Breiman et al. 1984 and
    Hastie, Tibshirani & Friedman, *Elements of Statistical Learning*, section 7.10).

    ``mse_m2``: per candidate label, the mean squared 3D error (m^2) of each training run, in the
    same order of runs for every candidate. The best is the lowest mean over the runs; a candidate
    is within when its mean paired difference to the best is at most the standard error of those
    differences (their standard deviation over the square root of the number of runs). With
    three seeds per trajectory two candidates 0.5 % apart swapped places from one installation's
    rounding to another's (docs/results.md); the rule keeps such a tie from choosing the setting.
    With one training run there is no spread: the best is chosen.
    """
    err = {label_of(c): np.asarray(mse_m2[label_of(c)], float) for c in candidates}
    best = min(candidates, key=lambda c: float(err[label_of(c)].mean()))
    for c in candidates:
        with np.errstate(invalid="ignore"):  # a run a candidate did not solve: inf, its spread NaN, never within
            d = err[label_of(c)] - err[label_of(best)]
            se = float(d.std(ddof=1) / np.sqrt(d.size)) if d.size > 1 else 0.0
        if float(d.mean()) <= se:
            return c
    return best


def default_candidate(chosen: dict[str, dict[str, Any]]) -> tuple[Any, dict[str, float]]:
    """The stls candidate of :data:`GRID` for the package's defaults (``[stls] window`` and
    ``behavior_pfa``), from the training runs alone: one setting serves every measurement set a
    file may have (``--measurements all``), so each candidate is scored by its training 3D RMS over
    the best candidate's of the same set, in its worst set, and the lowest score is taken (the
    first listed, the most constrained, on a tie). Returns the candidate and every candidate's
    score by label.

    >>> rms = {"pr": {"0/1e-06": 1.0, "15/1e-12": 1.3}, "pr+doppler": {"0/1e-06": 0.41, "15/1e-12": 0.40}}
    >>> default_candidate({k: {"rms_3d_m": {"stls": v}} for k, v in rms.items()})
    ((0, 1e-06), {'0/1e-06': 1.025, '15/1e-12': 1.3})
    """
    sets = [c["rms_3d_m"]["stls"] for c in chosen.values()]
    cands = [c for c in GRID["stls"][1] if all(label_of(c) in rms for rms in sets)]
    scores = {label_of(c): max(rms[label_of(c)] / min(rms.values()) for rms in sets) for c in cands}
    return min(cands, key=lambda c: scores[label_of(c)]), scores


def packaged_default() -> tuple[int, float]:
    """The package's ``[stls] window`` and ``behavior_pfa`` (what ``stls defaults`` runs)."""
    stls = load_config(None, {"stls.lag": 3}).stls
    return stls.window, stls.behavior_pfa


def in_parallel(fn: Callable[[Any], Any], items: Sequence[Any]) -> list[Any]:
    """``[fn(x) for x in items]``, the items dealt among the machine's cores (forked children,
    :mod:`gnss_cli.parallel`; one after the other where no process can be forked). Each run is
    independent of the others (its own files, configuration and solve), so the results do not
    depend on how they are dealt."""
    n = min(cores(), len(items))
    children = fork_all([partial(_in_turn, fn, items[k::n]) for k in range(n)]) if n > 1 and can_fork() else None
    if children is None or isinstance(children, OSError):
        return [fn(x) for x in items]
    out: list[Any] = [None] * len(items)
    try:
        for k, child in enumerate(children):
            out[k::n] = child.result()
    finally:  # one failed or the run was interrupted: no child goes on alone
        for child in children:
            child.cancel()
    return out


def _in_turn(fn: Callable[[Any], Any], items: Sequence[Any]) -> list[Any]:
    return [fn(x) for x in items]

BASE: dict[str, dict[str, Any]] = {
    "kf cv": {"kalman.model": "cv"}, "kf ca": {"kalman.model": "ca"},
    "smoother quadrature": {"smoother.motion": "quadrature"}, "smoother cv": {"smoother.motion": "cv"},
    "smoother ca": {"smoother.motion": "ca"}, "smoother static": {"smoother.motion": "static"},
    "stls": {"stls.lag": 3}, "stls defaults": {"stls.lag": 3},
}
FREE_CLOCKS = {"kalman.clock_psd_m2_s": 1e6, "kalman.drift_psd_m2_s3": 1e6}
"""The kf's receiver clock without its oscillator model: random walks of 1 km per square-root second,
so every epoch's clock and drift are free, as in ``smoother`` and ``stls``."""
BASE.update({f"{name} free clocks": {**BASE[name], **FREE_CLOCKS} for name in ("kf cv", "kf ca")})
"""Each variant's fixed settings (its method key is the first word; a ``free clocks`` variant takes
the chosen setting of the variant it extends; ``stls defaults`` is stls at lag 3 with every other
setting the package's default, chosen on the training runs by :func:`default_candidate`)."""
PEERS = ("kf cv", "kf ca", "smoother quadrature", "smoother cv", "smoother ca")
"""The peers of stls; the ``free clocks`` rows are reported beside them (how much of the kf's result
comes from its clock model, which the other methods do not have), ``smoother static`` on tst2 too."""


def simulate(out: Path, kind: str, seed: int, duration_s: float, errors: str) -> Path:
    """``gnss-simulate --trajectory KIND --seed SEED --errors ERRORS --noise-sigma 1 --phase`` (GPS,
    1 Hz; the carrier phases leave the other observables, and the sets without phase, unchanged)."""
    base = ScenarioConfig()
    cfg = replace(base, trajectory=kind, seed=seed, duration_s=duration_s, interval_s=1.0, systems=("G",),
                  errors=replace(base.errors.with_sources(parse_error_list(errors)), noise_sigma_m=1.0),
                  layout=replace(base.layout, phase=True))
    write_scenario(run_scenario(cfg), out)
    return out


def plan_rounds(variants: dict[str, dict[str, Any]]) -> list[dict[str, dict[str, Any]]]:
    """The runs that solve ``variants`` (name: settings; the method is the name's first word): a
    variant joins the first run with no variant of its method and no setting of another value
    (the smoother's cv and the kf's cv share ``kalman.accel_psd_m2_s3``), else starts a run."""
    rounds: list[dict[str, dict[str, Any]]] = []
    for name, settings in variants.items():
        method = name.split()[0]
        slot = next((r for r in rounds if all(n.split()[0] != method for n in r)
                     and all(o.get(k, v) == v for o in r.values() for k, v in settings.items())), None)
        if slot is None:
            rounds.append(slot := {})
        slot[name] = settings
    return rounds


REAL_CASES: dict[str, dict[str, Any]] = {
    "yamatogawa": {"folder": "yamatogawa-2010006-kinematic", "obs": "yamatogawa_rover.obs", "navs": "brdc0060.10n",
                   "reference": "rtk_ref_rover.pos", "settings": {}, "evaluate": {"common_bias": True}, "more": ()},
    "tst2": {"folder": "tst2-2020155-urban-static", "obs": "2020_06_03_TST_03.obs.gz", "navs": "hksc155d.20?",
             "reference": TST2_TRUTH, "settings": {"environment": "open"},
             "evaluate": {"window": (270149.0, 270305.0)}, "more": ("smoother static",)},
}
"""The real sets (module docstring): the folder under the real-data folder, the observation file,
the navigation files (a glob), the reference, the settings every method of the case is given, the
arguments of :func:`evaluate`, and the rows reported beside the peers (``more``)."""


def solve_real(rinex: Path, case: str, variants: dict[str, dict[str, Any]], common: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """:func:`solve_variants` on the real set ``case`` of :data:`REAL_CASES` (its ``more`` rows added),
    with its own settings over ``common``."""
    c = REAL_CASES[case]
    d = rinex / c["folder"]
    reference = c["reference"] if isinstance(c["reference"], list) else d / c["reference"]
    more = {name: dict(BASE[name]) for name in c["more"]}
    return solve_variants(d / c["obs"], sorted(d.glob(c["navs"])), reference, {**variants, **more},
                          {**common, **c["settings"]})


def evaluate_real(case: str, run: dict[str, dict[str, Any]]) -> dict[str, Any]:
    """:func:`evaluate` of one run of the real set ``case`` with its arguments."""
    return evaluate([run], **REAL_CASES[case]["evaluate"])


def solve_variants(obs: Path, navs: list[Path], reference: Any, variants: dict[str, dict[str, Any]],
                   common: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """Errors (E, N, U, ``(T, 3)``, m) and reported settings of each variant, with ``wls``.

    Variants of different methods share a run (they do not see each other: each starts from the
    same WLS fixes and observations) unless they set a key to different values (the smoother's cv
    and the kf's cv share ``kalman.accel_psd_m2_s3``); a method's variants take one run each.
    """
    out: dict[str, dict[str, Any]] = {}
    for r in plan_rounds(variants):
        overrides = {**common, "methods": "wls," + ",".join(dict.fromkeys(n.split()[0] for n in r))}
        for settings in r.values():
            overrides.update(settings)
        cfg = load_config(None, overrides)
        result = process(obs, navs, cfg)
        epochs = result.epochs
        ref = Reference.from_value(reference).of(epochs.time_gps_s, epochs.marker_name, utc_offset_s(result), obs.name)
        ds = to_dataset(result, ref)
        enu = np.stack([ds[c].values for c in ("e_err_m", "n_err_m", "u_err_m")], axis=-1)  # (T, method, 3)
        methods = list(ds["method"].values)
        tow = np.mod(epochs.time_gps_s, 604800.0)
        for name in ["wls", *r]:
            m = name.split()[0]
            s = result.settings[m]
            out[name] = {"enu_m": enu[:, methods.index(m)], "tow_s": tow,
                         "ran": {k: getattr(s, k) for k in ("estimator", "model", "lag", "window", "measurements")}}
    return out


def stats(enu: np.ndarray, v_bias_m: float = 0.0, h_bias_m: tuple[float, float] = (0.0, 0.0)) -> dict[str, float]:
    """RMS of the errors ``enu (T, 3)`` (m): 3D, horizontal, vertical less ``v_bias_m``, horizontal less
    ``h_bias_m`` (E, N), the 95th percentile and the largest 3D error."""
    ok = np.isfinite(enu).all(axis=1)
    e = enu[ok]
    d3 = np.linalg.norm(e, axis=1)
    return {"rms_3d_m": float(np.sqrt(np.mean(d3**2))),
            "rms_h_m": float(np.sqrt(np.mean(np.sum(e[:, :2] ** 2, axis=1)))),
            "rms_v_debiased_m": float(np.sqrt(np.mean((e[:, 2] - v_bias_m) ** 2))),
            "rms_h_debiased_m": float(np.sqrt(np.mean(np.sum((e[:, :2] - np.asarray(h_bias_m)) ** 2, axis=1)))),
            "p95_3d_m": float(np.percentile(d3, 95)), "max_3d_m": float(d3.max())}


def pooled(runs: list[dict[str, dict[str, Any]]], name: str) -> np.ndarray:
    return np.concatenate([r[name]["enu_m"] for r in runs])


def evaluate(runs: list[dict[str, dict[str, Any]]], window: tuple[float, float] | None = None,
             common_bias: bool = False) -> dict[str, Any]:
    """Every method's statistics over the same epochs: those (of each run, within ``window`` of GPS
    seconds of week) where every method of the run has a position; ``solved`` counts each method's
    own. ``common_bias``: the vertical RMS after removing the mean vertical error of all methods, and the
    horizontal RMS after removing their mean east and north errors (a reference accurate in shape, not
    in absolute position).

    Each method's row also keeps the squared errors by unit, for :func:`ratio_interval`:
    ``sq_units_m2`` (``"3d"`` and ``"h"``) holds per run the sum of its compared epochs' squared 3D
    and horizontal errors where there are several runs (independent seeds), and each compared
    epoch's own where there is one (a single trajectory, resampled in blocks)."""
    names = list(runs[0])
    keep = []
    for r in runs:
        k = np.ones(r["wls"]["tow_s"].size, bool)
        if window is not None:
            k &= (r["wls"]["tow_s"] >= window[0]) & (r["wls"]["tow_s"] <= window[1])
        keep.append(k)
    solved = {n: int(sum((np.isfinite(r[n]["enu_m"]).all(axis=1) & k).sum() for r, k in zip(runs, keep))) for n in names}
    common = [k & np.all([np.isfinite(r[n]["enu_m"]).all(axis=1) for n in names], axis=0) for r, k in zip(runs, keep)]
    enu = {n: np.concatenate([r[n]["enu_m"][c] for r, c in zip(runs, common)]) for n in names}
    mean = np.mean(np.concatenate(list(enu.values())), axis=0) if common_bias else np.zeros(3)
    bias, h_bias = float(mean[2]), (float(mean[0]), float(mean[1]))
    rows: dict[str, Any] = {n: {**stats(enu[n], bias, h_bias), "solved": solved[n], "compared": int(enu[n].shape[0]),
                                "ran": runs[0][n]["ran"], "sq_units_m2": squared_units(runs, n, common)} for n in names}
    if common_bias:
        rows["vertical_bias_removed_m"] = bias
        rows["horizontal_bias_removed_m"] = list(h_bias)
    return rows


def variants_for(chosen: dict[str, Any], names: tuple[str, ...]) -> dict[str, dict[str, Any]]:
    out = {}
    for name in names:
        v = dict(BASE[name])
        tuned = name.removesuffix(" free clocks")
        if tuned in GRID:
            v.update(setting(GRID[tuned][0], chosen[tuned]))
        if name == "stls":
            v["stls.latency_m"] = chosen.get("stls latency_m", 0.0)
        out[name] = v
    return out


def solve_simulated(files: list[Path], variants: dict[str, dict[str, Any]], common: dict[str, Any]) -> list[dict[str, dict[str, Any]]]:
    """:func:`solve_variants` on simulated folders (``obs.rnx``, ``nav.rnx``, ``truth.csv``), on all cores."""
    return in_parallel(partial(_solve_folder, variants=variants, common=common), files)


def _solve_folder(d: Path, variants: dict[str, dict[str, Any]], common: dict[str, Any]) -> dict[str, dict[str, Any]]:
    return solve_variants(d / "obs.rnx", [d / "nav.rnx"], d / "truth.csv", variants, common)


def mse_per_run(runs: list[dict[str, dict[str, Any]]], name: str) -> list[float]:
    """Mean squared 3D error (m^2) of variant ``name`` in each run (its solved epochs); ``inf`` for a
    run in which it solved no epoch, so that :func:`choose` never takes it for that run's sake."""
    out = []
    for r in runs:
        e = r[name]["enu_m"]
        e = e[np.isfinite(e).all(axis=1)]
        out.append(float(np.mean(np.sum(e**2, axis=1))) if e.size else float("inf"))
    return out


def squared_units(runs: list[dict[str, dict[str, Any]]], name: str, common: list[np.ndarray]) -> dict[str, list[float]]:
    """Squared 3D and horizontal errors (m^2) of variant ``name`` on the compared epochs ``common`` of
    each run: summed per run when there are several runs, per epoch (in time order) for one."""
    e = [r[name]["enu_m"][c] for r, c in zip(runs, common)]
    sq = {"3d": [np.sum(x**2, axis=1) for x in e], "h": [np.sum(x[:, :2] ** 2, axis=1) for x in e]}
    if len(runs) > 1:
        return {k: [float(v.sum()) for v in vs] for k, vs in sq.items()}
    return {k: vs[0].tolist() for k, vs in sq.items()}


RUN_CASES = ("flight", "drive")
"""Cases of several independent runs (the simulated evaluation seeds): their units are runs."""


def drop_epoch_units(cases: dict[str, Any]) -> None:
    """The squared errors by unit as the JSON keeps them (in place, after the intervals are computed):
    the per-run sums of :data:`RUN_CASES`, to six significant digits, from which the intervals there
    can be recomputed; none for the single trajectories, whose units are their epochs (every epoch
    of every method made the file 1.2 MB of generated numbers)."""
    for case, sets in cases.items():
        for rows in sets.values():
            for m in rows.values():
                if isinstance(m, dict) and "sq_units_m2" in m:
                    if case in RUN_CASES:
                        m["sq_units_m2"] = {k: [float(f"{v:.6g}") for v in vs] for k, vs in m["sq_units_m2"].items()}
                    else:
                        del m["sq_units_m2"]


BLOCK_EPOCHS = 20
"""Block length (epochs) of the bootstrap on a single trajectory (:func:`ratio_interval`): its
epochs' errors are correlated (smoothed solutions, multipath) and must be resampled in blocks. On
the Yamatogawa walk the interval of the ratio widens with the block up to about 20 epochs and no
further (pseudoranges: 0.95-1.16 with single epochs, 0.76-1.34 with 20, 0.72-1.37 with 30)."""


def ratio_interval(a_m2: Sequence[float], b_m2: Sequence[float], block: int = 1, n_boot: int = 10000,
                   seed: int = 0) -> tuple[float, float]:
    """95 % percentile bootstrap interval of ``sqrt(sum a / sum b)``, the ratio of two methods' RMS
    over the same units (``a_m2``, ``b_m2``: squared errors per unit, paired).

    The units are resampled together, in blocks of ``block`` consecutive units drawn with
    replacement anywhere in the series (the moving-block bootstrap of Kuensch 1989; ``block = 1``
    is the ordinary bootstrap, for independent units such as the runs of different seeds).
    ``scipy.stats.bootstrap`` resamples single observations only, so this is written out.
    NaN for fewer than two units.

    >>> lo, hi = ratio_interval([4.0, 4.4, 3.6, 4.2], [1.0, 1.1, 0.9, 1.05])  # stls twice the peer's RMS
    >>> bool(1.9 < lo <= 2.0 <= hi < 2.1)
    True
    """
    a, b = np.asarray(a_m2, float), np.asarray(b_m2, float)
    n = a.size
    if n < 2 or b.size != n:
        return float("nan"), float("nan")
    block = int(min(max(block, 1), n))
    starts = np.random.default_rng(seed).integers(0, n - block + 1, (n_boot, -(-n // block)))
    idx = (starts[:, :, None] + np.arange(block)).reshape(n_boot, -1)[:, :n]
    with np.errstate(divide="ignore", invalid="ignore"):
        r = np.sqrt(a[idx].sum(axis=1) / b[idx].sum(axis=1))
    lo, hi = np.percentile(r, [2.5, 97.5])
    return float(lo), float(hi)


def train(tmp: Path, seeds: tuple[int, ...], duration_s: float) -> dict[str, dict[str, Any]]:
    """Per measurement set: each tuned variant's candidate by :func:`choose` over the training runs
    (the seeds of the flight and of the drive), every candidate's pooled 3D RMS and per-run mean
    squared error; then, where spans are tied, stls's latency (:data:`LATENCY_M`) at its chosen
    window and false-alarm probability, chosen the same way."""
    files = [simulate(tmp / f"train-{kind}-{seed}", kind, seed + SEED_OFFSET[kind], duration_s, "noise")
             for kind in ("flight", "drive") for seed in seeds]
    chosen: dict[str, dict[str, Any]] = {}
    for label in SETS:
        common = {"measurements": SETS[label], "iono": "none", "tropo": "none"}
        scores: dict[str, dict[str, float]] = {name: {} for name in GRID}
        mse: dict[str, dict[str, list[float]]] = {name: {} for name in GRID}
        n = max(len(c) for _, c in GRID.values())
        for i in range(n):
            variants = {f"{name} {key}={label_of(cands[i])}": {**BASE[name], **setting(key, cands[i])}
                        for name, (key, cands) in GRID.items() if i < len(cands)}
            runs = solve_simulated(files, variants, common)
            for vname in variants:
                name, cand = vname.rsplit(" ", 1)
                scores[name][cand.split("=")[1]] = stats(pooled(runs, vname))["rms_3d_m"]
                mse[name][cand.split("=")[1]] = mse_per_run(runs, vname)
        chosen[label] = {"choice": {}, "rms_3d_m": scores, "mse_per_run_m2": mse}
        for name, (key, cands) in GRID.items():
            chosen[label]["choice"][name] = choose(cands, mse[name])
        if label != "pr":
            stls = {**BASE["stls"], **setting(GRID["stls"][0], chosen[label]["choice"]["stls"])}
            at = label_of(chosen[label]["choice"]["stls"])
            lat, lat_mse = {0.0: scores["stls"][at]}, {"0.0": mse["stls"][at]}
            for value in LATENCY_M[1:]:
                runs = solve_simulated(files, {"stls": {**stls, "stls.latency_m": value}}, common)
                lat[value] = stats(pooled(runs, "stls"))["rms_3d_m"]
                lat_mse[str(value)] = mse_per_run(runs, "stls")
            chosen[label]["choice"]["stls latency_m"] = choose(LATENCY_M, lat_mse)
            scores["stls latency_m"] = {str(v): r for v, r in lat.items()}
            mse["stls latency_m"] = lat_mse
        print(f"training {label}: " + ", ".join(f"{n} {GRID[n][0] if n in GRID else ''}={c}"
                                                for n, c in chosen[label]["choice"].items()),
              file=sys.stderr)
    return chosen


def summarise(case: str, label: str, rows: dict[str, Any], key: str) -> dict[str, Any]:
    """The best smoother and kf of a case and set by ``key``, stls, the ratio stls / best peer and
    its 95 % bootstrap interval (:func:`ratio_interval`: over the evaluation runs of the simulated
    tracks, over blocks of :data:`BLOCK_EPOCHS` epochs of a real set; NaN for the largest error);
    stls with the package's defaults and its ratio."""
    peers = {n: rows[n][key] for n in PEERS if n in rows}
    best_s = min((n for n in peers if n.startswith("smoother")), key=peers.__getitem__)
    best_k = min((n for n in peers if n.startswith("kf")), key=peers.__getitem__)
    best = best_s if peers[best_s] <= peers[best_k] else best_k
    interval = (float("nan"), float("nan"))
    if key in ("rms_3d_m", "rms_h_m"):
        unit = "3d" if key == "rms_3d_m" else "h"
        a, b = rows["stls"]["sq_units_m2"][unit], rows[best]["sq_units_m2"][unit]
        interval = ratio_interval(a, b, block=1 if case in RUN_CASES else BLOCK_EPOCHS)
    out = {"case": case, "measurements": label, "metric": key, "best_smoother": best_s, "best_smoother_m": peers[best_s],
           "best_kf": best_k, "best_kf_m": peers[best_k], "stls_m": rows["stls"][key],
           "ratio_stls_best_peer": rows["stls"][key] / peers[best], "ratio_interval_95": list(interval),
           "wls_m": rows["wls"][key]}
    if "stls defaults" in rows:
        out["stls_defaults_m"] = rows["stls defaults"][key]
        out["ratio_stls_defaults_best_peer"] = rows["stls defaults"][key] / peers[best]
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="one training seed, two evaluation seeds, 120 s, no real sets")
    parser.add_argument("--rinex", type=Path, default=RINEX, help="the real-data folder (default ../shared/rinex)")
    args = parser.parse_args()
    t_start = time.perf_counter()
    train_seeds, eval_seeds = (TRAIN_SEEDS[:1], EVAL_SEEDS[:2]) if args.quick else (TRAIN_SEEDS, EVAL_SEEDS)
    duration_s = 120.0 if args.quick else 300.0
    names = ("kf cv", "kf ca", "smoother quadrature", "smoother cv", "smoother ca", "stls", "stls defaults",
             "kf cv free clocks", "kf ca free clocks")
    cases: dict[str, dict[str, Any]] = {}
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        chosen = train(tmp, train_seeds, duration_s)
        rule, rule_scores = default_candidate(chosen)
        defaults = {"rule": rule, "packaged": packaged_default(), "worst_set_rms_over_best": rule_scores}
        if tuple(defaults["packaged"]) != tuple(rule):
            print(f"multi_epoch_fair: the package's stls defaults (window, behavior_pfa) {defaults['packaged']} are not "
                  f"the training runs' {rule} (default_candidate): 'stls defaults' reports the package's", file=sys.stderr)
        t_trained = time.perf_counter()
        for kind in ("flight", "drive"):
            files = [simulate(tmp / f"eval-{kind}-{seed}", kind, seed + SEED_OFFSET[kind], duration_s, "noise")
                     for seed in eval_seeds]
            cases[kind] = {}
            for label in SETS:
                common = {"measurements": SETS[label], "iono": "none", "tropo": "none"}
                runs = solve_simulated(files, variants_for(chosen[label]["choice"], names), common)
                cases[kind][label] = evaluate(runs)
        d = simulate(tmp / "exact", "flight", eval_seeds[0], duration_s, "none")
        cases["flight exact"] = {}
        for label in SETS:
            common = {"measurements": SETS[label], "iono": "none", "tropo": "none"}
            run = solve_variants(d / "obs.rnx", [d / "nav.rnx"], d / "truth.csv", variants_for(chosen[label]["choice"], names), common)
            cases["flight exact"][label] = evaluate([run])
        for case in () if args.quick else REAL_CASES:
            if not (args.rinex / REAL_CASES[case]["folder"]).is_dir():
                print(f"multi_epoch_fair: no {args.rinex / REAL_CASES[case]['folder']}: its case is left out "
                      "(--rinex DIR names the real-data folder)", file=sys.stderr)
                continue
            runs = in_parallel(lambda label: solve_real(args.rinex, case, variants_for(chosen[label]["choice"], names),
                                                        {"measurements": SETS[label]}), list(SETS))
            cases[case] = {label: evaluate_real(case, r) for label, r in zip(SETS, runs)}
    seconds = time.perf_counter() - t_start
    summary = []
    for case, sets in cases.items():
        key = {"flight exact": "max_3d_m", "yamatogawa": "rms_h_m", "tst2": "rms_h_m"}.get(case, "rms_3d_m")
        for label, rows in sets.items():
            summary.append(summarise(case, label, rows, key))
    drop_epoch_units(cases)
    data = table(cases, summary, chosen, defaults, args.quick, seconds, time.perf_counter() - t_trained, train_seeds,
                 eval_seeds, duration_s)
    print_tables(data)
    out = Path(tempfile.gettempdir()) / "multi_epoch_fair_quick.json" if args.quick else OUT
    out.parent.mkdir(exist_ok=True)
    out.write_text(json.dumps(data, indent=1) + "\n", encoding="utf-8")
    print(f"wrote {out} ({seconds / 60:.1f} min)", file=sys.stderr)


def _r(x: float) -> float:
    return round(float(x), 3)


def _interval(lo_hi: Sequence[float]) -> str | None:
    lo, hi = lo_hi
    return f"{lo:.2f}-{hi:.2f}" if np.isfinite(lo) and np.isfinite(hi) else None


def table(cases: dict[str, Any], summary: list[dict[str, Any]], chosen: dict[str, Any], defaults: dict[str, Any],
          quick: bool, seconds: float, eval_seconds: float, train_seeds: tuple[int, ...], eval_seeds: tuple[int, ...],
          duration_s: float) -> dict[str, Any]:
    """The result file: the summary as the page's table, every row in a second table, the raw numbers."""
    metric_names = {"rms_3d_m": "3D RMS", "rms_h_m": "horizontal RMS", "max_3d_m": "max 3D error"}
    rows = [[s["case"], s["measurements"], metric_names[s["metric"]], _r(s["wls_m"]), s["best_kf"], _r(s["best_kf_m"]),
             s["best_smoother"], _r(s["best_smoother_m"]), _r(s["stls_m"]), _r(s["ratio_stls_best_peer"]),
             _interval(s["ratio_interval_95"]), _r(s["stls_defaults_m"]), _r(s["ratio_stls_defaults_best_peer"])]
            for s in summary]
    detail = []
    for case, sets in cases.items():
        for label, methods in sets.items():
            if not isinstance(methods, dict):
                continue
            for name, m in methods.items():
                if not isinstance(m, dict):
                    continue
                ran = m["ran"]
                what = "; ".join(p for p in (ran["model"], f"lag {ran['lag']}" if ran["lag"] else "", ran["window"],
                                             ran["measurements"]) if p)
                detail.append([case, label, name, what, m["solved"], m["compared"], _r(m["rms_3d_m"]), _r(m["rms_h_m"]),
                               _r(m["rms_v_debiased_m"]) if case == "yamatogawa" else None,
                               _r(m["rms_h_debiased_m"]) if case == "yamatogawa" else None, _r(m["p95_3d_m"]), _r(m["max_3d_m"])])
    choices = {label: c["choice"] for label, c in chosen.items()}
    rule = label_of(tuple(defaults["rule"]))
    return {
        "title": "Equal information: kf, smoother and identified stls (settings chosen on training seeds)",
        "command": "nice -n 5 python benchmarks/multi_epoch_fair.py" + (" --quick" if quick else ""),
        "table": {"columns": ["case", "measurements", "metric (m)", "wls", "best kf", "kf", "best smoother", "smoother",
                              "stls lag 3", "stls / best peer", "95 % interval", "stls defaults",
                              "defaults / best peer"], "rows": rows},
        "more_tables": [{"title": "Every method and measurement set",
                         "columns": ["case", "measurements", "method", "what ran (model; lag; window; measurements)", "solved",
                                     "compared",
                                     "3D RMS", "H RMS", "V RMS - common bias", "H RMS - common bias", "p95 3D", "max 3D"],
                         "rows": detail}],
        "notes": (f"Settings chosen on training seeds {list(train_seeds)} (flight and drive, {duration_s:.0f} s, GPS, 1 Hz, "
                  f"1 m code noise; the most constrained candidate within one standard error of the best training "
                  f"error, paired over the training runs) and then fixed: {json.dumps(choices)}. "
                  f"Evaluation seeds {eval_seeds[0]}-{eval_seeds[-1]} (drives: + 1000), errors pooled over them. "
                  "Every method of a case and set is compared on the same epochs (all methods solved; "
                  "'solved' counts each method's own). flight exact: no errors, "
                  "seed " f"{eval_seeds[0]}, largest 3D error. yamatogawa: against the RTK trajectory, horizontal RMS; "
                  "vertical RMS after removing the mean vertical error of all its methods (per set: "
                  + ", ".join(f"{v['vertical_bias_removed_m']:.2f}" for v in cases.get("yamatogawa", {}).values())
                  + " m); horizontal RMS after removing the mean east and north error of all its methods (per set: "
                  + ", ".join("{:.2f} / {:.2f}".format(*v["horizontal_bias_removed_m"]) for v in cases.get("yamatogawa", {}).values())
                  + " m): the RTK reference is accurate to centimetres in shape, to a few metres in absolute position. "
                  "kf ... free clocks: the chosen kf with its receiver clock model removed (every epoch's clock and drift "
                  "free, as in smoother and stls); reported, not a peer. tst2: the static "
                  "antenna solved as a moving receiver, truth window; smoother static is listed for reference and is no "
                  "peer. Each method uses the set it is given (its settings say so: see what ran). "
                  "stls defaults: stls --lag 3 with the package's defaults (window "
                  f"{defaults['packaged'][0]}, behavior_pfa {defaults['packaged'][1]:g}, latency 0), whatever the set; the "
                  "training runs' candidate for them is the one nearest the best in its worst set "
                  f"({rule}, within {defaults['worst_set_rms_over_best'][rule]:.3f}x of each set's best). "
                  "95 % interval: percentile bootstrap of the ratio stls / best peer, its best peer fixed, "
                  f"resampling the evaluation runs (simulated) or blocks of {BLOCK_EPOCHS} epochs (real sets: one "
                  "trajectory each, its errors correlated in time). "
                  f"Whole run {seconds / 60:.1f} min ({eval_seconds / 60:.1f} min after training), runs dealt among "
                  f"{cores()} processes, nice 5, on the shared 2-core machine."),
        "settings_chosen": chosen,
        "stls_defaults": defaults,
        "cases": cases,
        "summary": summary,
        "train_seeds": list(train_seeds), "eval_seeds": list(eval_seeds), "duration_s": duration_s,
        "seconds": seconds,
    }


def print_tables(data: dict[str, Any]) -> None:
    for tab in ({"columns": data["table"]["columns"], "rows": data["table"]["rows"]}, *data["more_tables"]):
        cols = tab["columns"]
        cells = [[("" if v is None else f"{v:g}" if isinstance(v, float) else str(v)) for v in row] for row in tab["rows"]]
        widths = [max(len(str(c)), *(len(r[i]) for r in cells)) if cells else len(str(c)) for i, c in enumerate(cols)]
        print("  ".join(str(c).ljust(w) for c, w in zip(cols, widths)))
        for r in cells:
            print("  ".join(v.ljust(w) for v, w in zip(r, widths)))
        print()


if __name__ == "__main__":
    try:
        main()
    except KeyboardInterrupt:
        print("multi_epoch_fair: interrupted; nothing written", file=sys.stderr)
        sys.exit(130)
    except WorkerError as exc:  # a run's process was killed (Ctrl-C reaches it first, or memory ran out)
        print(f"multi_epoch_fair: {exc}; nothing written", file=sys.stderr)
        sys.exit(1)
