"""Simulated 1 Hz flights for the smoothing tests (written with the project's own simulator)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

from gnss_cli.sim.error_sources import parse_error_list
from gnss_cli.sim.scenario import ScenarioConfig, run_scenario, write_scenario


def simulate_flight(out: Path, errors: str, seed: int = 11, duration_s: float = 300.0) -> Path:
    """A GPS flight at 1 Hz with the comma list of ``errors`` (``none``, ``noise``, ...) written into ``out``."""
    base = ScenarioConfig()
    cfg = replace(base, trajectory="standard-flight", duration_s=duration_s, interval_s=1.0, seed=seed,
                  errors=base.errors.with_sources(parse_error_list(errors)))
    write_scenario(run_scenario(cfg), out)
    return out
