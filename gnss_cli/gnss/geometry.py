"""Receiver-satellite geometry: ranges with the Earth-rotation correction, design rows.

For a receiver at ``x`` (ECEF, m) and a satellite at ``s`` (ECEF of the transmit time), the
geometric range including the rotation of the Earth during signal flight (Sagnac) is

``r = |s - x| + (omega_E / c) (s_x x_y - s_y x_x)``,

and the pseudorange design row is ``[-e, 1]`` with ``e = (s - x) / |s - x|`` (DESIGN.md
section 2). Everything is vectorized over ``(T, n)`` epochs x satellites.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from gnss_cli.constants import C_M_S, OMEGA_E_RAD_S

F64 = NDArray[np.float64]


def sagnac_range(sat_ecef_m: F64, rx_ecef_m: F64) -> tuple[F64, F64]:
    """Geometric ranges (m) with the Sagnac term, and unit vectors receiver -> satellite.

    Parameters
    ----------
    sat_ecef_m
        ``(T, n, 3)`` satellite positions at transmit time, m.
    rx_ecef_m
        ``(T, 3)`` receiver positions, m.

    Returns
    -------
    range_m : ``(T, n)``
    unit : ``(T, n, 3)`` line-of-sight unit vectors.
    """
    d = sat_ecef_m - rx_ecef_m[:, None, :]
    rho = np.linalg.norm(d, axis=-1)
    unit = d / rho[..., None]
    sagnac = OMEGA_E_RAD_S / C_M_S * (
        sat_ecef_m[..., 0] * rx_ecef_m[:, None, 1] - sat_ecef_m[..., 1] * rx_ecef_m[:, None, 0]
    )
    return rho + sagnac, unit
