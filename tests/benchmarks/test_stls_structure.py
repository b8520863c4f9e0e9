"""The kernel fits of ``benchmarks/stls_structure.py``: the bound it reports (the true track's
kernels) and the run-level alternation rest on them."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
import stls_structure as structure  # noqa: E402


def _turn(n: int, omega_rad_s: float, dt_s: float = 1.0) -> np.ndarray:
    """A level constant-rate turn of radius 50 m about an ECEF-like point (m)."""
    t = np.arange(n) * dt_s
    return np.column_stack([50 * np.cos(omega_rad_s * t), 50 * np.sin(omega_rad_s * t), 0 * t]) + [4e6, 5e5, 4.9e6]


def test_a_sampled_turn_gives_back_its_kernel():
    omega = 0.1
    r = structure.monic_kernel(_turn(12, omega), np.arange(9), np.ones(9), 3)
    expected = np.polynomial.polynomial.polymul([-1.0, 1.0], [1.0, -2 * np.cos(omega), 1.0])
    np.testing.assert_allclose(r, expected, atol=1e-9)
    assert abs(r.sum()) < 1e-12  # the root at z = 1


def test_the_fit_minimizes_the_weighted_rows():
    rng = np.random.default_rng(5)
    x = _turn(15, 0.05) + rng.normal(0.0, 0.3, (15, 3))
    shifts, weights = np.arange(12), rng.uniform(0.5, 2.0, 12)
    r = structure.monic_kernel(x, shifts, weights, 3)

    def cost(k: np.ndarray) -> float:
        rows = np.stack([k @ x[t : t + 4] for t in shifts])
        return float(np.sum(weights[:, None] * rows**2))

    for _ in range(20):  # any other monic kernel with its root at 1 costs more
        dq = rng.normal(0.0, 0.05, 2)
        other = r + np.append(0.0, np.append(dq, 0.0)) - np.append(np.append(dq, 0.0), 0.0)
        assert cost(other) > cost(r)
    assert structure.monic_kernel(x, np.arange(0), np.ones(0), 3) is None


def test_refitting_keeps_free_spans_and_fits_the_others():
    omega = 0.1
    x = _turn(20, omega)
    old = np.array([[-1.0, 3.0, -3.0, 1.0]] * 2)
    args = {"kernels": old, "starts": np.array([0, 10]), "n": 20, "switch_sigma_m": 0.1, "latency_sigma_m": 0.01,
            "free": np.array([True, False])}
    new = structure.refitted_kernels(args, x)
    np.testing.assert_array_equal(new[0], old[0])
    expected = np.polynomial.polynomial.polymul([-1.0, 1.0], [1.0, -2 * np.cos(omega), 1.0])
    np.testing.assert_allclose(new[1], expected, atol=1e-9)
