"""How far the real sets' ratios stls / best peer move with the gate threshold that every method shares.

``benchmarks/multi_epoch_fair.py`` compares ``kf``, ``smoother`` and the identified ``stls`` on
equal information, its settings chosen on training seeds; on the two real sets (the Yamatogawa
walk, tst2 solved as a moving receiver) its ratios stls / best peer lie near 1 (0.83-1.08). Every
method there is given the same false-alarm probability ``integrity_pfa`` (default 1e-3): the
snapshot fixes' FDE, the kf's innovation gate, the smoother's and stls's residual gate all take
their thresholds from it. This script solves both real sets again with that one shared setting at
each of :data:`PFAS`, every other setting as ``multi_epoch_fair.py`` chose it (read from its
committed JSON), and reports per case, measurement set and ``integrity_pfa`` the best peer, stls
and stls with the package's defaults, and their ratios to the best peer.

Nothing is chosen here: the package keeps ``integrity_pfa`` 1e-3, and ``multi_epoch_fair.py``
reports at it. The table says how much of a ratio near 1 on a single real trajectory a shared
measurement-handling setting decides: where the ratio crosses 1 as the shared threshold moves,
that real set cannot say whether stls is ahead of its best peer or behind it.

Beside it, at the default threshold, how many rows the residual gate of ``smoother`` (each
motion) and of ``stls`` left out in its final pass (:func:`gated_rows`: pseudoranges, range rates,
phase-pair rows; each method solved alone, the gate's calls recorded; on the sets of
:data:`DIAGNOSED`). The gate standardizes a
residual by its measurement's standard deviation, not by the residual's own, so a stiffer fit (one
whose residuals keep more of the noise) has more rows above one threshold; the kf's innovation
gate, standardized by the innovation's predicted variance, is not counted there.

Then every method given the rows one peer's gate decided (:func:`one_gates_rows`, on the sets of
:data:`DIAGNOSED` with range rates or phase): the rows the kf with constant acceleration left out
(its innovation gate; a phase pair's row by its w-test) and those the quadrature smoother at stls's
velocity rule left out (:data:`~gnss_cli.behavior.piecewise.VELOCITY_RULE_LAG`: the measurements of
stls's tied spans, the behavior deciding none of them) are each taken out of every method, whose own
multi-epoch gate is then off (:func:`rows_given`). stls's windows keep their own gate while the
kernels are identified: the rows of its result are those of the tied solve, which takes the given
ones. With the pseudoranges alone stls's windows are its result, so that set is not run.

Last, every method given exactly the same rows (:func:`solve_same_rows`): the multi-epoch gates
off (the kf's innovation gate, the smoother's and stls's residual gate:
:func:`multi_epoch_gates_off`), the snapshot fixes' FDE at the default threshold and the cycle-slip
checks as they ship, so that no method leaves out a row another keeps. The gates test different
statistics (innovations before an update, residuals after a fit), so at one threshold they leave
out different rows: equal information in measurements and threshold, not in the rows used. This
row is equal information in the rows too, at the price of each method's own defence against a
faulty row.

Usage: ``python benchmarks/real_set_gate.py [--rinex DIR]``; prints the table and writes
``benchmarks/results/real_set_gate.json``. About 10-15 minutes on two cores.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import replace
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))
from multi_epoch_fair import (OUT as FAIR, PEERS, RINEX, REAL_CASES, SETS, evaluate_real, in_parallel,  # noqa: E402
                              solve_real, summarise, variants_for)

import numpy as np  # noqa: E402

import gnss_cli.pipeline.identified as identified  # noqa: E402
import gnss_cli.pipeline.kalman as kalman  # noqa: E402
import gnss_cli.pipeline.smoother as smoother  # noqa: E402
from gnss_cli.behavior.piecewise import VELOCITY_RULE_LAG  # noqa: E402
from gnss_cli.pipeline.kalman_rows import gate_threshold  # noqa: E402
from gnss_cli.pipeline.measurements import gate_rows  # noqa: E402

OUT = Path(__file__).resolve().parent / "results" / "real_set_gate.json"
PFAS = (1e-2, 1e-3, 1e-4, 1e-5)
"""The shared false-alarm probabilities (1e-3 the package's default): two-sided gates of 2.58,
3.29, 3.89 and 4.42 standard deviations."""
NAMES = (*PEERS, "stls", "stls defaults")
GATED = ("smoother quadrature", "smoother cv", "smoother ca", "stls", "stls defaults")
"""The methods whose residual gate :func:`gated_rows` counts (those that test residuals after their fit)."""
KINDS = ("pseudorange", "range rate", "phase pair")
ROW_SOURCES = ("kf ca", "smoother quadrature")
"""Whose gate decides every method's rows in :func:`one_gates_rows` (:func:`source_variant`)."""
DIAGNOSED = ("yamatogawa",)
"""The real sets of the gate's counts and of :func:`one_gates_rows`: those solved in one piece by one solve, whose gate's last
pass is the file's. tst2 (986 epochs) is solved in overlapping pieces and again without its
reflection spans (:func:`gnss_cli.pipeline.methods.solve_multi_epoch`), so no single pass is its."""


def solve_case(rinex: Path, case: str, label: str, pfa: float, chosen: dict[str, Any]) -> dict[str, Any]:
    """The summary row of one real set, measurement set and shared ``integrity_pfa``."""
    run = solve_real(rinex, case, variants_for(chosen[label]["choice"], NAMES),
                     {"measurements": SETS[label], "integrity_pfa": pfa})
    rows = evaluate_real(case, run)
    out = summarise(case, label, rows, "rms_h_m")
    best = out["best_smoother"] if out["best_smoother_m"] <= out["best_kf_m"] else out["best_kf"]
    return {**out, "integrity_pfa": pfa, "best_peer": best, "best_peer_m": rows[best]["rms_h_m"],
            "rms_h_m": {n: rows[n]["rms_h_m"] for n in NAMES}}


@contextmanager
def gate_replaced(gate_fn: Any) -> Iterator[None]:
    """The residual gate of :mod:`gnss_cli.pipeline.smoother` (which stls's joint solve calls too)
    replaced by ``gate_fn`` (the signature of :func:`~gnss_cli.pipeline.measurements.gate_rows`)."""
    smoother.gate_rows = gate_fn  # type: ignore[attr-defined]
    try:
        yield
    finally:
        smoother.gate_rows = gate_rows  # type: ignore[attr-defined]


@contextmanager
def recorded_gate() -> Iterator[list[tuple[np.ndarray, np.ndarray]]]:
    """The residual gate as it is, each call's excluded and tested rows ((kinds, T, n) bool each)
    recorded in call order."""
    calls: list[tuple[np.ndarray, np.ndarray]] = []

    def recorded(u: Any, used: Any, gate: float, config: Any) -> Any:
        mult, gated = gate_rows(u, used, gate, config)
        calls.append((gated.copy(), np.stack(used)))
        return mult, gated

    with gate_replaced(recorded):
        yield calls


def fixed(excluded: np.ndarray) -> Any:
    """A residual gate that leaves out the rows ``excluded`` ((kinds, T, n) bool) of another solve of
    the same file: robust weights as configured, no threshold of its own."""
    def gate(u: Any, used: Any, threshold: float, config: Any) -> Any:
        mult, _ = gate_rows(u, used, np.inf, config)
        out = excluded & np.stack(used)
        return np.where(out, 0.0, mult), out

    return gate


def gated_rows(rinex: Path, case: str, label: str, chosen: dict[str, Any]) -> dict[str, Any]:
    """Rows of each kind (:data:`KINDS`) that the residual gate of each :data:`GATED` method left out
    in its last pass at the default threshold, and how many it tested; each method solved alone."""
    out: dict[str, Any] = {"case": case, "measurements": label}
    for name in GATED:
        with recorded_gate() as calls:
            solve_real(rinex, case, variants_for(chosen[label]["choice"], (name,)), {"measurements": SETS[label]})
        excluded, tested = calls[-1] if calls else (np.zeros((len(KINDS), 0)), np.zeros((len(KINDS), 0)))
        out[name] = {"excluded": [int(k.sum()) for k in excluded], "tested": [int(k.sum()) for k in tested]}
    return out


@contextmanager
def multi_epoch_gates_off() -> Iterator[None]:
    """No multi-epoch gate: the kf's innovation gate and the smoother's and stls's residual gate
    take no threshold (as with ``integrity = "off"``), while the snapshot FDE, which ``integrity``
    also governs, runs as configured."""
    users = (kalman, smoother, identified)
    for module in users:
        module.gate_threshold = lambda config: None  # type: ignore[attr-defined]
    try:
        yield
    finally:
        for module in users:
            module.gate_threshold = gate_threshold  # type: ignore[attr-defined]


def solve_same_rows(rinex: Path, case: str, label: str, chosen: dict[str, Any]) -> dict[str, Any]:
    """:func:`solve_case` at the default threshold with :func:`multi_epoch_gates_off`: every
    method the same rows (module docstring)."""
    with multi_epoch_gates_off():
        return {**solve_case(rinex, case, label, 1e-3, chosen), "multi_epoch_gates": "off"}


def same_rows_table(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """The table of :func:`solve_same_rows`' rows."""
    return {"title": "Every method the same rows: no multi-epoch gate, the snapshot FDE at the default threshold",
            "columns": ["case", "measurements", "best peer", "best peer H RMS (m)", "stls lag 3", "stls / best peer",
                        "95 % interval", "stls defaults", "defaults / best peer"],
            "rows": [[r["case"], r["measurements"], r["best_peer"], round(r["best_peer_m"], 3), round(r["stls_m"], 3),
                      round(r["ratio_stls_best_peer"], 3), "{:.2f}-{:.2f}".format(*r["ratio_interval_95"]),
                      round(r["stls_defaults_m"], 3), round(r["ratio_stls_defaults_best_peer"], 3)] for r in rows]}


@contextmanager
def recorded_kf_gate() -> Iterator[list[np.ndarray]]:
    """The kf's innovation gate as it is, the rows it left out in each gated pass over the file
    recorded ((kinds, T, n) bool, in pass order): a pseudorange or range rate whose innovation it
    rejected, a phase pair's row whose w-test it rejected."""
    passes: list[tuple[Any, np.ndarray]] = []
    results: list[Any] = []
    run_segment, kalman_filter = kalman._run_segment, kalman.kalman_filter  # type: ignore[attr-defined]

    def filter_kept(*args: Any, **kwargs: Any) -> Any:
        results.append(kalman_filter(*args, **kwargs))
        return results[-1]

    def segment_recorded(seg: Any, data: Any, meas: Any, *args: Any) -> Any:
        before = (meas.used.copy(), None if meas.used_rr is None else meas.used_rr.copy(),
                  None if meas.phase is None else meas.phase.used.copy())
        out = run_segment(seg, data, meas, *args)
        if len(args) < 5 or args[4] is None:  # an ungated pass
            return out
        if not passes or passes[-1][0] is not meas:
            passes.append((meas, np.zeros((len(KINDS), *meas.used.shape), dtype=bool)))
        excluded, res = passes[-1][1], results[-1]
        for j, i in enumerate(seg):
            pr = np.flatnonzero(before[0][i])
            nu = res.innovations[j]
            excluded[0, i, pr[np.isnan(nu[:pr.size])]] = True
            if before[1] is not None:
                rr = np.flatnonzero(before[1][i])
                excluded[1, i, rr[np.isnan(nu[pr.size:pr.size + rr.size])]] = True
            if before[2] is not None and j > 0:  # a segment's first epoch has no pair
                ph = np.flatnonzero(before[2][i])
                excluded[2, i, ph[np.isnan(res.free_tests[j])]] = True
        return out

    kalman._run_segment, kalman.kalman_filter = segment_recorded, filter_kept  # type: ignore[attr-defined]
    recorded: list[np.ndarray] = []
    try:
        yield recorded
    finally:
        kalman._run_segment, kalman.kalman_filter = run_segment, kalman_filter  # type: ignore[attr-defined]
        recorded.extend(excluded for _, excluded in passes)


@contextmanager
def rows_given(excluded: np.ndarray) -> Iterator[None]:
    """Every multi-epoch method without the rows ``excluded`` ((kinds, T, n) bool, another solve of
    the same file) and without a gate of its own: the smoother's and stls's residual gate
    :func:`fixed` to them, the kf's innovation gate off and the rows taken out of its measurements
    before it filters."""
    linearized, pairs, threshold = kalman.linearized_measurements, kalman.filter_phase_rows, kalman.gate_threshold  # type: ignore[attr-defined]

    def linearized_without(*args: Any, **kwargs: Any) -> Any:
        meas = linearized(*args, **kwargs)
        meas.used &= ~excluded[0]
        if meas.used_rr is not None:
            meas.used_rr &= ~excluded[1]
        return meas

    def pairs_without(*args: Any, **kwargs: Any) -> Any:
        rows = pairs(*args, **kwargs)
        return None if rows is None else replace(rows, used=rows.used & ~excluded[2])

    kalman.linearized_measurements, kalman.filter_phase_rows = linearized_without, pairs_without  # type: ignore[attr-defined]
    kalman.gate_threshold = lambda config: None  # type: ignore[attr-defined]
    try:
        with gate_replaced(fixed(excluded)):
            yield
    finally:
        kalman.linearized_measurements, kalman.filter_phase_rows = linearized, pairs  # type: ignore[attr-defined]
        kalman.gate_threshold = threshold  # type: ignore[attr-defined]


def source_variant(source: str, label: str, chosen: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """The solve whose gate decides the rows: the kf ca as chosen for the set; the quadrature
    smoother at stls's velocity rule (module docstring)."""
    if source == "smoother quadrature":
        return {"smoother": {"smoother.motion": "quadrature", "smoother.lag": VELOCITY_RULE_LAG}}
    return variants_for(chosen[label]["choice"], (source,))


def source_rows(rinex: Path, case: str, label: str, source: str, chosen: dict[str, Any]) -> np.ndarray:
    """The rows (kinds, T, n) that ``source``'s gate left out in its last pass, solved alone."""
    common = {"measurements": SETS[label]}
    if source.startswith("kf"):
        with recorded_kf_gate() as passes:
            solve_real(rinex, case, source_variant(source, label, chosen), common)
        return passes[-1]
    with recorded_gate() as calls:
        solve_real(rinex, case, source_variant(source, label, chosen), common)
    return calls[-1][0]


def one_gates_rows(rinex: Path, case: str, label: str, chosen: dict[str, Any]) -> list[dict[str, Any]]:
    """:func:`solve_case` at the default threshold with every method given the rows of each of
    :data:`ROW_SOURCES` (:func:`rows_given`), and how many of each kind that source left out."""
    out = []
    for source in ROW_SOURCES:
        excluded = source_rows(rinex, case, label, source, chosen)
        with rows_given(excluded):
            row = solve_case(rinex, case, label, 1e-3, chosen)
        out.append({**row, "rows_of": source, "excluded": [int(k.sum()) for k in excluded]})
    return out


def one_gates_table(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """The table of :func:`one_gates_rows`' rows."""
    return {"title": "Every method the rows one gate left out (its own multi-epoch gate off; default threshold)",
            "columns": ["case", "measurements", "rows of", "left out (pr, rr, pairs)", "kf ca", "smoother quadrature",
                        "best peer", "best peer H RMS (m)", "stls lag 3", "stls / best peer", "95 % interval",
                        "stls defaults", "defaults / best peer"],
            "rows": [[r["case"], r["measurements"], r["rows_of"], ", ".join(map(str, r["excluded"])),
                      round(r["rms_h_m"]["kf ca"], 3), round(r["rms_h_m"]["smoother quadrature"], 3), r["best_peer"],
                      round(r["best_peer_m"], 3), round(r["stls_m"], 3), round(r["ratio_stls_best_peer"], 3),
                      "{:.2f}-{:.2f}".format(*r["ratio_interval_95"]), round(r["stls_defaults_m"], 3),
                      round(r["ratio_stls_defaults_best_peer"], 3)] for r in rows]}


def gated_table(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """The table of :func:`gated_rows`' rows: excluded / tested per kind the set has."""
    return {"title": "Rows the residual gate left out at the default threshold (last pass)",
            "columns": ["case", "measurements", *GATED],
            "rows": [[r["case"], r["measurements"],
                      *[", ".join(f"{e}/{n}" for e, n in zip(r[name]["excluded"], r[name]["tested"]) if n)
                        for name in GATED]] for r in rows]}


def table(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """The printed table of the summary rows."""
    return {"columns": ["case", "measurements", "integrity_pfa", "best peer", "best peer H RMS (m)", "stls lag 3",
                        "stls / best peer", "95 % interval", "stls defaults", "defaults / best peer"],
            "rows": [[r["case"], r["measurements"], f"{r['integrity_pfa']:g}" + (" (default)" if r["integrity_pfa"] == 1e-3 else ""),
                      r["best_peer"], round(r["best_peer_m"], 3), round(r["stls_m"], 3),
                      round(r["ratio_stls_best_peer"], 3),
                      "{:.2f}-{:.2f}".format(*r["ratio_interval_95"]), round(r["stls_defaults_m"], 3),
                      round(r["ratio_stls_defaults_best_peer"], 3)] for r in rows]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rinex", type=Path, default=RINEX, help="the real-data folder (default ../shared/rinex)")
    args = parser.parse_args()
    t0 = time.perf_counter()
    chosen = json.loads(FAIR.read_text(encoding="utf-8"))["settings_chosen"]
    cases = [c for c in REAL_CASES if (args.rinex / REAL_CASES[c]["folder"]).is_dir()]
    if not cases:
        sys.exit(f"real_set_gate: no real set under {args.rinex} (--rinex DIR names the real-data folder)")
    jobs = [(case, label, pfa) for case in cases for label in SETS for pfa in PFAS]
    rows = in_parallel(lambda job: solve_case(args.rinex, *job, chosen), jobs)
    diagnosed = [c for c in cases if c in DIAGNOSED]
    gated = in_parallel(lambda job: gated_rows(args.rinex, *job, chosen), [(c, label) for c in diagnosed for label in SETS])
    tied_sets = [label for label in SETS if label != "pr"]
    one_gate = [r for rs in in_parallel(lambda job: one_gates_rows(args.rinex, *job, chosen),
                                        [(c, label) for c in diagnosed for label in tied_sets]) for r in rs]
    same_rows = in_parallel(lambda job: solve_same_rows(args.rinex, *job, chosen),
                            [(case, label) for case in cases for label in SETS])
    data = {"title": "Real sets: the ratios stls / best peer at each shared gate threshold",
            "command": "python benchmarks/real_set_gate.py",
            "notes": "Every method of a row gets the same integrity_pfa (the snapshot FDE, the kf's innovation gate and "
                     "the smoother's and stls's residual gate take their thresholds from it); every other setting as "
                     "multi_epoch_fair.py chose it on its training seeds. Horizontal RMS (m) on the compared epochs "
                     "(yamatogawa: against its RTK trajectory; tst2: the truth window, environment open). Best peer: of "
                     + ", ".join(PEERS) + ", at that row's threshold. 95 % interval: moving-block bootstrap (20 epochs) "
                     "of stls / best peer. Nothing is chosen here; the package's default is 1e-3. Second table: "
                     "excluded / tested rows of each kind the set has (pseudoranges, range rates, phase-pair rows) "
                     "in the last pass of each method's residual gate, each method solved alone. Third table: every method "
                     "given the rows the kf ca's gate, or the quadrature smoother's at stls's velocity rule (lag 2), left "
                     "out, its own multi-epoch gate off (stls's windows keep theirs while its kernels are identified). "
                     "Second and third table on the walk only: tst2 is solved in overlapping pieces and again without "
                     "its reflection spans, so no single pass of its gate is the file's. Fourth table: every method "
                     "the same rows (the kf's innovation gate and the smoother's and stls's residual gate off, the "
                     "snapshot FDE and the slip checks as shipped), both real sets. "
                     f"Whole run {(time.perf_counter() - t0) / 60:.1f} min.",
            "pfas": list(PFAS), "table": table(rows), "more_tables": [gated_table(gated), one_gates_table(one_gate),
                                                       same_rows_table(same_rows)],
            "rows": rows, "gated": gated, "one_gates_rows": one_gate, "same_rows": same_rows, "seconds": time.perf_counter() - t0}
    OUT.parent.mkdir(exist_ok=True)
    OUT.write_text(json.dumps(data, indent=1) + "\n", encoding="utf-8")
    print(" | ".join(data["table"]["columns"]))
    for r in data["table"]["rows"]:
        print(" | ".join(str(x) for x in r))
    for more in data["more_tables"]:
        print(more["title"])
        print(" | ".join(more["columns"]))
        for r in more["rows"]:
            print(" | ".join(str(x) for x in r))
    print(f"wrote {OUT} ({data['seconds'] / 60:.1f} min)", file=sys.stderr)


if __name__ == "__main__":
    main()
