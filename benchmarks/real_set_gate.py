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
gate, standardized by the innovation's predicted variance, is not counted there. And what that
costs stls (:func:`with_smoothers_exclusions`): stls solved again with the rows its gate leaves
out replaced by those the quadrature smoother's gate leaves out (``smoother --motion quadrature``
at stls's velocity rule, :data:`~gnss_cli.behavior.piecewise.VELOCITY_RULE_LAG`), its own gate
off: the same measurements as that peer, the behavior deciding none of them. A diagnostic (the
residual gate is not changed by it), run with range rates or phase, where stls's spans are solved
together through that gate.

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
EXCLUSION_COLUMNS = ("stls", "stls with the smoother's exclusions", "stls defaults",
                     "stls defaults with the smoother's exclusions")
DIAGNOSED = ("yamatogawa",)
"""The real sets of the two diagnostics: those solved in one piece by one solve, whose gate's last
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


def with_smoothers_exclusions(rinex: Path, case: str, label: str, chosen: dict[str, Any]) -> dict[str, Any]:
    """Horizontal RMS (m) of stls and stls defaults with the quadrature smoother's exclusions
    (module docstring); as they ship, they are the default-threshold rows of :func:`solve_case`."""
    common = {"measurements": SETS[label]}
    with recorded_gate() as calls:
        solve_real(rinex, case, {"smoother": {"smoother.motion": "quadrature", "smoother.lag": VELOCITY_RULE_LAG}}, common)
    out: dict[str, Any] = {"case": case, "measurements": label}
    for name in ("stls", "stls defaults"):
        with gate_replaced(fixed(calls[-1][0])):
            run = solve_real(rinex, case, variants_for(chosen[label]["choice"], (name,)), common)
        out[f"{name} with the smoother's exclusions"] = evaluate_real(case, run)[name]["rms_h_m"]
    return out


def exclusions_table(rows: list[dict[str, Any]], best: dict[tuple[str, str], dict[str, Any]]) -> dict[str, Any]:
    """The table of :func:`with_smoothers_exclusions`' rows beside the default-threshold summary rows
    ``best`` (by case and set: the best peer, stls and stls defaults as they ship), with the ratios
    to the best peer."""
    table_rows = []
    for r in rows:
        b = best[(r["case"], r["measurements"])]
        rms = {"stls": b["stls_m"], "stls defaults": b["stls_defaults_m"], **r}
        table_rows.append([r["case"], r["measurements"], b["best_peer"], round(b["best_peer_m"], 3),
                           *[f"{rms[n]:.3f} ({rms[n] / b['best_peer_m']:.3f}x)" for n in EXCLUSION_COLUMNS]])
    return {"title": "stls with the quadrature smoother's exclusions (default threshold; H RMS, m, and x best peer)",
            "columns": ["case", "measurements", "best peer", "best peer H RMS (m)", *EXCLUSION_COLUMNS],
            "rows": table_rows}


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
    exclusions = in_parallel(lambda job: with_smoothers_exclusions(args.rinex, *job, chosen),
                             [(c, label) for c in diagnosed for label in tied_sets])
    same_rows = in_parallel(lambda job: solve_same_rows(args.rinex, *job, chosen),
                            [(case, label) for case in cases for label in SETS])
    best = {(r["case"], r["measurements"]): r for r in rows if r["integrity_pfa"] == 1e-3}
    data = {"title": "Real sets: the ratios stls / best peer at each shared gate threshold",
            "command": "python benchmarks/real_set_gate.py",
            "notes": "Every method of a row gets the same integrity_pfa (the snapshot FDE, the kf's innovation gate and "
                     "the smoother's and stls's residual gate take their thresholds from it); every other setting as "
                     "multi_epoch_fair.py chose it on its training seeds. Horizontal RMS (m) on the compared epochs "
                     "(yamatogawa: against its RTK trajectory; tst2: the truth window, environment open). Best peer: of "
                     + ", ".join(PEERS) + ", at that row's threshold. 95 % interval: moving-block bootstrap (20 epochs) "
                     "of stls / best peer. Nothing is chosen here; the package's default is 1e-3. Second table: "
                     "excluded / tested rows of each kind the set has (pseudoranges, range rates, phase-pair rows) "
                     "in the last pass of each method's residual gate, each method solved alone. Third table: stls as it "
                     "ships and with the quadrature smoother's exclusions in place of its own gate (a diagnostic). "
                     "Second and third table on the walk only: tst2 is solved in overlapping pieces and again without "
                     "its reflection spans, so no single pass of its gate is the file's. Fourth table: every method "
                     "the same rows (the kf's innovation gate and the smoother's and stls's residual gate off, the "
                     "snapshot FDE and the slip checks as shipped), both real sets. "
                     f"Whole run {(time.perf_counter() - t0) / 60:.1f} min.",
            "pfas": list(PFAS), "table": table(rows), "more_tables": [gated_table(gated), exclusions_table(exclusions, best),
                                                       same_rows_table(same_rows)],
            "rows": rows, "gated": gated, "with_smoothers_exclusions": exclusions, "same_rows": same_rows, "seconds": time.perf_counter() - t0}
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
