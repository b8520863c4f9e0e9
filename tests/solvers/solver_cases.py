"""Shared builders for the solver tests: random but realistic sky geometries."""

from __future__ import annotations

import numpy as np


def sky_matrix(rng: np.random.Generator, n: int, el_min_rad: float = np.deg2rad(10.0)) -> np.ndarray:
    """Linearized pseudorange geometry ``(n, 4)``: rows ``[-e_enu, 1]`` for a random sky.

    Azimuths uniform, elevations uniform in ``sin(el)`` above the mask, as a GNSS receiver
    sees them; ``e`` is the unit line-of-sight vector in East-North-Up.
    """
    az = rng.uniform(0.0, 2.0 * np.pi, n)
    el = np.arcsin(rng.uniform(np.sin(el_min_rad), 1.0, n))
    e = np.column_stack([np.cos(el) * np.sin(az), np.cos(el) * np.cos(az), np.sin(el)])
    return np.column_stack([-e, np.ones(n)])


def method_kwargs(method: str) -> dict:
    """Arguments each method needs to treat the clock column (3) as exact."""
    return {"exact_columns": [3]} if method in ("mtls", "stls") else {}
