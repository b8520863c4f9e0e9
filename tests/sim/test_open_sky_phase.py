"""Carrier phases in open sky (``gnss-simulate --phase``): the error-free carrier is the code
without its group delay, continuous; asking for it changes nothing else of the run."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from gnss_cli.errors import UsageError
from gnss_cli.sim.error_sources import parse_error_list
from gnss_cli.sim.observables import _wavelengths
from gnss_cli.sim.scenario import ScenarioConfig, run_scenario
from gnss_cli.sim.urban import UrbanConfig, phase_sigma_m


def _config(errors: str, phase: bool) -> ScenarioConfig:
    base = ScenarioConfig()
    return replace(base, trajectory="flight", seed=4, duration_s=60.0, systems=("G", "E"),
                   errors=replace(base.errors, enabled=parse_error_list(errors)),
                   layout=replace(base.layout, phase=phase, dual_frequency=True))


def test_the_error_free_carrier_is_the_code_less_a_constant() -> None:
    """Without ionosphere and noise, ``lambda Phi - P`` is the integer ambiguity (times the
    wavelength) less the group delay: constant along each satellite's pass, to float precision."""
    obs = run_scenario(_config("clock,tropo", True)).observations
    assert obs.phase_cycles is not None
    seen = obs.visible.any(axis=0)
    cmc = np.where(obs.visible[..., None], obs.phase_cycles * _wavelengths(obs.sv)[None] - obs.pseudorange_m,
                   np.nan)[:, seen]
    assert np.nanmax(np.nanmax(cmc, axis=0) - np.nanmin(cmc, axis=0)) < 1e-4
    # the ambiguities are whole cycles apart from the group delay: not all zero, not all equal
    assert np.unique(np.round(np.nanmean(cmc[..., 0], axis=0), 3)).size > 1


def test_the_noise_is_the_pll_jitter_and_nothing_else_changes() -> None:
    plain = run_scenario(_config("noise,clock", False)).observations
    with_phase = run_scenario(_config("noise,clock", True)).observations
    assert plain.phase_cycles is None and with_phase.phase_cycles is not None
    for name in ("pseudorange_m", "doppler_hz", "snr_dbhz"):  # the same draws (another draw moves them by O(1));
        # to the last bits only: numpy's vectorized math may round an element differently by its place in memory
        np.testing.assert_allclose(getattr(with_phase, name), getattr(plain, name), rtol=1e-13, atol=0, equal_nan=True,
                                   err_msg=name)
    quiet = run_scenario(_config("clock", True)).observations
    lam = _wavelengths(with_phase.sv)[None]
    noise_m = (with_phase.phase_cycles - quiet.phase_cycles) * lam  # the jitter, plus constant ambiguities
    # first differences of the jitter (the ambiguities cancel): each sqrt(2) times the PLL's sigma at the written C/N0
    both = with_phase.visible[1:] & with_phase.visible[:-1]
    sigma = phase_sigma_m(lam, with_phase.snr_dbhz, UrbanConfig().pll_bandwidth_hz)
    expected = np.sqrt(np.mean((sigma[1:] ** 2 + sigma[:-1] ** 2)[both]))
    measured = np.sqrt(np.mean(np.diff(noise_m, axis=0)[both] ** 2))
    assert 1e-4 < expected < 1e-2 and abs(measured / expected - 1.0) < 0.1


def test_rinex_2_refuses_phases() -> None:
    with pytest.raises(UsageError, match="RINEX 3"):
        run_scenario(replace(_config("none", True), systems=("G",), rinex_version="2.11"))
