"""The slra anchor problem: reference misfits and trajectory errors of its README."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from gnss_cli.behavior import stls

# From ../shared/slra-anchor/README.md (Markovsky's slra, confirmed by an independent code).
REFERENCE = {100: (0.852551, 0.006566), 1000: (7.61286, 0.003601), 10000: (75.9692, 0.000889)}


@pytest.mark.parametrize("n_t", sorted(REFERENCE))
def test_anchor_misfit_and_trajectory_error(anchor_dir: Path, n_t: int) -> None:
    y = np.loadtxt(anchor_dir / f"y_{n_t}.txt", delimiter=",")
    y0 = np.loadtxt(anchor_dir / f"y0_{n_t}.txt", delimiter=",")
    res = stls(y, lag=1, order=3)
    m_ref, rms_ref = REFERENCE[n_t]
    assert res.success, res.message
    # the README gives 6 significant digits: agreement to 1e-5 relative
    assert res.misfit == pytest.approx(m_ref, rel=1e-5)
    rms = float(np.sqrt(np.mean((res.w_hat - y0) ** 2)))
    assert f"{rms:.2g}" == f"{rms_ref:.2g}"
    # the misfit is the squared correction (unweighted problem)
    assert np.sum((y - res.w_hat) ** 2) == pytest.approx(res.misfit, rel=1e-9)
