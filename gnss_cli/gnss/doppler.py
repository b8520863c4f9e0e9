"""Range rates from Doppler: the linear system of receiver velocity and clock drift.

A Doppler ``D`` (Hz) of a signal of wavelength ``lambda`` gives the range rate
``rr = -lambda D`` (m/s; positive when the range grows). With the satellite at ``s`` moving at
``s_dot`` (ECEF of the transmit time, rotating frame), its clock drift ``dt_sv_dot`` (s/s) and
the receiver at ``x`` moving at ``v`` (ECEF) with clock drift ``d`` (m/s), the model is the time
derivative of the range of :func:`gnss_cli.gnss.range_model.sagnac_range`, Earth rotation during
signal flight included:

    rr = e . (s_dot - v) + (omega_E / c) (s_dot_x y + s_x v_y - s_dot_y x - s_y v_x) + d - c dt_sv_dot

with ``e`` the unit vector receiver -> satellite (the rotation term is a few mm/s). RTKLIB
2.4.3's ``resdop`` writes that term with the opposite sign; the tests differentiate the range
numerically. It is linear in ``p = [v; d]``: ``H p = y`` with the row
``H = [-e_x - (omega_E / c) s_y, -e_y + (omega_E / c) s_x, -e_z, 1]`` and
``y = rr + c dt_sv_dot - e . s_dot - (omega_E / c) (s_dot_x y - s_dot_y x)``. The row
depends on the position only through ``e`` (a 10 m position error changes it by ~5e-7).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from gnss_cli.constants import C_M_S, OMEGA_E_RAD_S

F64 = NDArray[np.float64]

__all__ = ["range_rate_system"]


def range_rate_system(sat_ecef_m: F64, sat_vel_ecef_m_s: F64, sat_clock_drift_s_s: F64, range_rate_m_s: F64,
                      rx_ecef_m: F64) -> tuple[F64, F64]:
    """Design rows and right-hand sides of the range rates of ``T`` epochs (module docstring).

    Parameters
    ----------
    sat_ecef_m, sat_vel_ecef_m_s : ``(T, n, 3)``
        Satellite positions (m) and velocities (m/s) at transmit time, ECEF.
    sat_clock_drift_s_s : ``(T, n)``
        Satellite clock drifts, s/s.
    range_rate_m_s : ``(T, n)``
        Observed range rates ``-lambda D``, m/s (NaN where missing).
    rx_ecef_m : ``(T, 3)``
        Receiver positions, m.

    Returns
    -------
    H : ``(T, n, 4)``
        Rows for ``[v_x, v_y, v_z, d]`` (m/s).
    y : ``(T, n)``
        Right-hand sides, m/s (NaN where an input is missing).

    Examples
    --------
    A satellite straight overhead moving away at 100 m/s, a receiver at rest with no clock drift:

    >>> import numpy as np
    >>> s = np.array([[[0.0, 0.0, 2.6e7]]]); sv = np.array([[[0.0, 0.0, 100.0]]])
    >>> H, y = range_rate_system(s, sv, np.zeros((1, 1)), np.array([[100.0]]), np.array([[0.0, 0.0, 6.4e6]]))
    >>> (H[0, 0].round(6) + 0.0).tolist(), float(y[0, 0])
    ([0.0, 0.0, -1.0, 1.0], 0.0)
    """
    d = sat_ecef_m - rx_ecef_m[:, None, :]
    e = d / np.linalg.norm(d, axis=-1, keepdims=True)
    w = OMEGA_E_RAD_S / C_M_S
    H = np.empty((*range_rate_m_s.shape, 4))
    H[..., 0] = -e[..., 0] - w * sat_ecef_m[..., 1]
    H[..., 1] = -e[..., 1] + w * sat_ecef_m[..., 0]
    H[..., 2] = -e[..., 2]
    H[..., 3] = 1.0
    sagnac = w * (sat_vel_ecef_m_s[..., 0] * rx_ecef_m[:, None, 1] - sat_vel_ecef_m_s[..., 1] * rx_ecef_m[:, None, 0])
    y = range_rate_m_s + C_M_S * sat_clock_drift_s_s - np.einsum("tnk,tnk->tn", e, sat_vel_ecef_m_s) - sagnac
    return H, y
