"""A fixed-seed subset of the fuzz campaign (``benchmarks/fuzz.py``): damaged copies of the
shared observation files through the gnss-solve entry point, each run held to the contract.

300 cases damage observation files (rtklib-0759 RINEX 2, kms3 RINEX 4 Hatanaka, p433 RINEX 3
Hatanaka, the hand-made files of ``malformed/``); 150 damage navigation files of the same sets
and of tst2 (RINEX 2, 3 and 4; values out of range, garbage Klobuchar coefficients, records dated
1980, cut and shuffled records). About 15 % of the cases also run ``--method wls,stls --lag 3``.
The full campaign (10,000 cases, README "Damaged files") is a benchmark script.
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
N_CASES = 300
SEED = 13
DATASETS = ["0759", "kms3", "p433", "malformed-badtime", "malformed-blank", "malformed-blank3", "malformed-junktime",
            "malformed-obscount"]
N_NAV_CASES = 150
NAV_DATASETS = ["0759", "kms3", "p433", "tst2"]


def _fuzz():
    module = sys.modules.get("fuzz")
    if module is None:
        spec = importlib.util.spec_from_file_location("fuzz", ROOT / "benchmarks" / "fuzz.py")
        assert spec is not None and spec.loader is not None
        module = importlib.util.module_from_spec(spec)
        sys.modules["fuzz"] = module
        spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def campaign(rinex_dir: Path):
    fuzz = _fuzz()
    records, clean = fuzz.campaign(N_CASES, SEED, jobs=2, timeout_s=60.0, root=rinex_dir, datasets=DATASETS,
                                   targets=("obs",))
    return fuzz, records, clean


@pytest.fixture(scope="module")
def nav_campaign(rinex_dir: Path):
    fuzz = _fuzz()
    records, _ = fuzz.campaign(N_NAV_CASES, SEED, jobs=2, timeout_s=60.0, root=rinex_dir, datasets=NAV_DATASETS,
                               targets=("nav",))
    return records


def test_every_navigation_case_keeps_the_contract(nav_campaign) -> None:
    assert len(nav_campaign) == N_NAV_CASES
    assert {r["target"] for r in nav_campaign} == {"nav"}
    broken = [(r["case"], r["mutator"], r["violations"], r.get("stderr", "")[:200]) for r in nav_campaign if r["violations"]]
    assert not broken, f"{len(broken)} cases break the contract (re-run one: python benchmarks/fuzz.py " \
                       f"--seed {SEED} --targets nav --datasets {','.join(NAV_DATASETS)} --case ID): {broken[:10]}"
    assert sum(r["exit"] == 4 for r in nav_campaign) > N_NAV_CASES // 10


def test_clean_runs_solve_every_epoch(campaign) -> None:
    _, _, clean = campaign
    epochs = {"0759": 120, "kms3": 19, "p433": 70}
    assert {k: (v["exit"], v["n_ok"]) for k, v in clean.items()} == {k: (0, n) for k, n in epochs.items()}


def test_every_case_keeps_the_contract(campaign) -> None:
    _, records, _ = campaign
    assert len(records) == N_CASES
    broken = [(r["case"], r["mutator"], r["violations"], r.get("stderr", "")[:200]) for r in records if r["violations"]]
    assert not broken, f"{len(broken)} cases break the contract (re-run one: python benchmarks/fuzz.py " \
                       f"--seed {SEED} --targets obs --case ID): {broken[:10]}"


def test_every_observation_mutator_ran_and_most_cases_are_errors(campaign) -> None:
    fuzz, records, _ = campaign
    ran = {r["mutator"] for r in records}
    assert set(fuzz.mut.OBS_MUTATORS) | {"hatanaka_corrupt"} <= ran
    exits = [r["exit"] for r in records]
    assert exits.count(4) > N_CASES // 3 and exits.count(0) > N_CASES // 10


def test_repeated_and_restamped_epochs_are_rejected_with_their_line(campaign) -> None:
    _, records, _ = campaign
    cases = [r for r in records if r["mutator"] in ("restamp", "body_repeat") and not r["dataset"].startswith("malformed")]
    assert len(cases) >= 10
    for r in cases:
        assert r["exit"] == 4 and ": line " in r["stderr"] and "is not later than the epoch" in r["stderr"], r


@pytest.mark.skipif(not Path("/proc/self/stat").is_file(), reason="no /proc: the fuzz limit falls back to wall time")
def test_a_hang_is_processor_time_not_a_busy_machine() -> None:
    """A worker waiting (as on a machine busy with other work) is no hang until it has run
    ``WALL_FACTOR`` times the limit; a worker computing is one once its processor time passes it."""
    import multiprocessing
    import time

    fuzz = _fuzz()
    ctx = multiprocessing.get_context("fork")
    waiting = ctx.Process(target=time.sleep, args=(30.0,))
    waiting.start()
    try:
        time.sleep(0.5)
        assert not fuzz._is_hang(waiting.pid, 0.5, 0.2)  # 0.5 s of wall time, no processor time
        assert fuzz._is_hang(waiting.pid, fuzz.WALL_FACTOR * 0.2 + 0.1, 0.2)
    finally:
        waiting.kill()
        waiting.join()
    computing = ctx.Process(target=_spin, args=(30.0,))
    computing.start()
    try:
        t0 = time.perf_counter()
        while not fuzz._is_hang(computing.pid, time.perf_counter() - t0, 0.3):
            time.sleep(0.01)
            assert time.perf_counter() - t0 < 20.0
        assert fuzz._processor_s(computing.pid) > 0.3
    finally:
        computing.kill()
        computing.join()


def _spin(seconds: float) -> None:
    import time

    end = time.perf_counter() + seconds
    while time.perf_counter() < end:
        pass
