"""Simulated data sets for the simulator tests, made once per session in temporary folders."""

from __future__ import annotations

from pathlib import Path

import pytest
from sim_datasets import simulate

@pytest.fixture(scope="session")
def static_exact_gps(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """1 h at 30 s, GPS, receiver clock only (exactly modelled), no atmosphere/orbit error/noise."""
    return simulate(tmp_path_factory.mktemp("static_gps"), systems=("G",), duration_s=3600.0, interval_s=30.0, errors="clock")


@pytest.fixture(scope="session")
def static_exact_gps_gal(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """As ``static_exact_gps`` with Galileo, and the per-satellite truth."""
    return simulate(
        tmp_path_factory.mktemp("static_ge"),
        systems=("G", "E"),
        duration_s=3600.0,
        interval_s=30.0,
        errors="clock",
        truth_ranges=True,
    )


@pytest.fixture(scope="session")
def flight_exact(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """10-min 1 Hz flight, GPS+Galileo, dual frequency, no errors."""
    from gnss_cli.sim.rinex_writer import ObsLayout

    return simulate(
        tmp_path_factory.mktemp("flight"),
        trajectory="standard-flight",
        systems=("G", "E"),
        duration_s=600.0,
        interval_s=1.0,
        errors="clock",
        layout=ObsLayout(dual_frequency=True),
    )
