"""Kepler's equation: every anomaly stops at its own convergence, so a batch gives each element
the bits it gets alone (a long file solved in parts batches other observations together)."""

from __future__ import annotations

import numpy as np

from gnss_cli.gnss.orbits import solve_kepler


def test_each_anomaly_as_alone_in_any_batch() -> None:
    rng = np.random.default_rng(3)
    m = rng.uniform(-np.pi, np.pi, 200)
    e = np.concatenate([rng.uniform(0.0, 0.02, 199), [0.7]])  # one slow element: more iterations for the batch
    batch = solve_kepler(m, e)
    alone = np.array([solve_kepler(m[i:i + 1], e[i:i + 1])[0] for i in range(m.size)])
    assert np.array_equal(batch, alone)
    assert np.max(np.abs(batch - e * np.sin(batch) - m)) < 1e-13
