"""The C/N0 (SIGMA-epsilon) term of the pseudorange variance: the formula, and what a run uses."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from gnss_cli.config import load_config
from gnss_cli.errors import ConfigError
from gnss_cli.gnss.range_model import cn0_variance_m2
from gnss_cli.pipeline import process


def test_the_term_is_sigma_epsilon_above_the_reference_signal() -> None:
    cn0 = np.array([20.0, 30.0, 39.9, 40.0, 48.0, np.nan])
    got = cn0_variance_m2(cn0, 1.61e4, 40.0)
    expected = [1.61e4 * (10 ** (-c / 10) - 1e-4) if c < 40 else 0.0 for c in (20.0, 30.0, 39.9, 40.0, 48.0)]
    np.testing.assert_allclose(got[:5], expected, rtol=1e-12, atol=0.0)
    assert got[5] == 0.0  # no C/N0 in the file: nothing added
    assert got[0] == pytest.approx(161.0 - 1.61, rel=1e-12)  # 20 dB-Hz: sigma^2 +159 m^2


def test_a_run_adds_the_term_to_every_used_row(tmp_path: Path) -> None:
    """WLS sigmas with and without the term differ by exactly the term of each row's C/N0, and the
    weak signals of the canyon (the simulator's reflections) are the ones that lose weight."""
    from gnss_cli.cli.exits import run_app
    from gnss_cli.cli.simulate import app

    out = tmp_path / "canyon"
    with pytest.raises(SystemExit) as done:
        run_app(app, "gnss-simulate", ["--environment", "urban", "--receiver", "single", "--trajectory", "drive",
                                       "--duration", "40", "--seed", "5", "--out-dir", str(out), "-q"])
    assert done.value.code == 0
    base = load_config(None, {"methods": "wls", "integrity": "off", "weights.cn0_model": "off"})
    on = replace(base, weights=replace(base.weights, cn0_model="sigma-epsilon", cn0_ref_dbhz=42.0))
    a = process(out / "obs.rnx", [out / "nav.rnx"], base)
    b = process(out / "obs.rnx", [out / "nav.rnx"], on)
    s_off, s_on = a.solutions["wls"].sigma_m, b.solutions["wls"].sigma_m
    cn0 = a.epochs.snr_dbhz
    assert cn0 is not None and np.isfinite(cn0).any()
    both = np.isfinite(s_off) & np.isfinite(s_on)
    assert both.sum() > 100
    # the positions move, so the elevation terms move a little too: compare at the same elevation model
    # by the difference of variances, which is the C/N0 term alone up to that motion (centimetres)
    diff = s_on[both] ** 2 - s_off[both] ** 2
    term = cn0_variance_m2(cn0[both], 1.61e4, 42.0)
    np.testing.assert_allclose(diff, term, atol=0.05, rtol=1e-3)
    assert (term > 1.0).any() and (term == 0.0).any()


def test_an_unknown_model_is_refused() -> None:
    with pytest.raises(ConfigError, match="cn0_model"):
        load_config(None, {"weights.cn0_model": "snr"})
