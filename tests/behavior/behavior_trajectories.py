"""Exact trajectories of the behavioral tests, built from their closed forms."""

from __future__ import annotations

from pathlib import Path

import numpy as np

ANCHOR_DIR = Path(__file__).resolve().parents[2] / ".." / "shared" / "slra-anchor"


def circle_basis() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Centre and two orthonormal vectors of a tilted plane in R^3."""
    centre = np.array([5.0, -3.0, 2.0])
    u = np.array([1.0, 0.2, 0.1])
    u /= np.linalg.norm(u)
    v = np.cross(u, [0.0, 0.0, 1.0])
    v /= np.linalg.norm(v)
    return centre, u, v


def circular_arc(n_t: int, omega_rad: float, radius_m: float = 10.0) -> np.ndarray:
    """Constant-speed arc ``c + rho (u cos(omega t) + v sin(omega t))``, shape (T, 3)."""
    centre, u, v = circle_basis()
    t = np.arange(n_t, dtype=float)
    return centre + radius_m * (np.outer(np.cos(omega_rad * t), u) + np.outer(np.sin(omega_rad * t), v))


def arc_polynomial(omega_rad: float) -> np.ndarray:
    """``(z - 1)(z^2 - 2 cos(omega) z + 1)``, ascending coefficients."""
    return np.convolve([-1.0, 1.0], [1.0, -2.0 * np.cos(omega_rad), 1.0])


def quadratic(n_t: int) -> np.ndarray:
    t = np.arange(n_t, dtype=float)
    return np.stack([1 + 0.5 * t + 0.02 * t**2, -2 + 0.1 * t - 0.03 * t**2, 3 - 0.01 * t**2], axis=1)


def damped_sinusoids(n_t: int) -> np.ndarray:
    """A damped sinusoid plus a decaying exponential in every coordinate (3 poles, lag 3)."""
    t = np.arange(n_t, dtype=float)
    osc = np.exp(-0.02 * t)
    return np.stack(
        [
            osc * np.cos(0.3 * t) + 0.5 * 0.95**t,
            osc * np.sin(0.3 * t + 0.4) - 0.95**t,
            2 * osc * np.cos(0.3 * t + 1.0) + 0.2 * 0.95**t,
        ],
        axis=1,
    )


def nine_mode_series(n_t: int, rng: np.random.Generator) -> np.ndarray:
    """A q = 3 series with 9 distinct modes: the general lag-3 order-9 behavior is unique."""
    t = np.arange(n_t, dtype=float)
    cols = []
    for pole in (0.98 * np.exp(0.2j), 0.97 * np.exp(0.5j), 0.99 * np.exp(0.9j), 0.95 * np.exp(1.4j)):
        cols += [(pole**t).real, (pole**t).imag]
    cols.append(0.9**t)
    return np.stack(cols, axis=1) @ rng.normal(size=(9, 3))


def random_covariances(n_t: int, rng: np.random.Generator, scale_m: float) -> np.ndarray:
    """Full SPD 3x3 covariances, shape (T, 3, 3), standard deviations ~ ``scale_m``."""
    a = rng.normal(size=(n_t, 3, 3)) * scale_m
    return a @ a.transpose(0, 2, 1) + 0.2 * scale_m**2 * np.eye(3)


def draw_noise(cov: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    chol = np.linalg.cholesky(cov)
    return np.einsum("tab,tb->ta", chol, rng.normal(size=cov.shape[:2]))


def weighted_norm2(d: np.ndarray, cov: np.ndarray) -> float:
    """``sum_t d_t^T cov_t^-1 d_t`` computed independently (dense solves)."""
    return float(sum(d_t @ np.linalg.solve(c_t, d_t) for d_t, c_t in zip(d, cov)))
