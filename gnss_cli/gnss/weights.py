"""Pseudorange error models: pseudorange variances, STLS/WTLS scales.

The variance model follows RTKLIB 2.4.3 ``pntpos.c`` (``gnss_cli/configs/default.toml`` [weights]);
the broadcast orbit-and-clock sigma is RTKLIB's ``var_uraeph`` (:mod:`gnss_cli.gnss.broadcast`).
The single-epoch STLS row covariance and the WTLS column scale add the broadcast-orbit error to
the geometry columns (``[stls] orbit_sigma_m``, DESIGN.md section 3).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

if TYPE_CHECKING:
    from gnss_cli.config import ProcessingConfig
    from gnss_cli.gnss.geometry import Linearization

F64 = NDArray[np.float64]


def pseudorange_variance_m2(
    config: ProcessingConfig, el_rad: F64, ura_m: F64, iono_m: F64, efact: F64 | float = 1.0
) -> F64:
    """Pseudorange variances (m^2) of the configured weight model (see ``gnss_cli/configs/default.toml``).

    ``ura_m`` is the broadcast orbit-and-clock sigma (:func:`~gnss_cli.gnss.broadcast.ephemeris_sigma_m`);
    ``efact`` scales the code-noise term per satellite (RTKLIB: 1.5 for GLONASS, else 1).
    """
    w = config.weights
    sin_el = np.sin(np.clip(el_rad, np.deg2rad(0.1), None))
    if w.model == "equal":
        return np.full_like(el_rad, w.a_m**2)
    if w.model == "elevation":
        return w.a_m**2 + w.b_m**2 / sin_el**2
    var = (w.a_m**2 + w.b_m**2 / sin_el) * np.asarray(efact) ** 2
    if config.iono == "iono-free":  # RTKLIB dual-freq: noise x iono_free_factor, no code-bias or iono term
        return var * w.iono_free_factor**2 + ura_m**2 + (
            (w.saas_sigma_m / (sin_el + 0.1)) ** 2 if config.tropo == "saastamoinen" else w.tropo_off_sigma_m**2
        )
    var = var + ura_m**2 + w.code_bias_m**2
    var = var + ((w.iono_factor * iono_m) ** 2 if config.iono == "klobuchar" else w.iono_off_sigma_m**2)
    var = var + ((w.saas_sigma_m / (sin_el + 0.1)) ** 2 if config.tropo == "saastamoinen" else w.tropo_off_sigma_m**2)
    return var


def stls_row_cov(lin: Linearization, orbit_sigma_m: float) -> F64:
    """Row covariances ``(T, n, 4, 4)`` of ``[e_x, e_y, e_z, q]`` for single-epoch STLS.

    The pseudorange variance of each row plus the broadcast-orbit error ``orbit_sigma_m``
    (3D RMS, m; ``[stls] orbit_sigma_m``): ``orbit_sigma_m^2 / 3`` along the line of sight
    in ``q`` and across it in the direction cosines, divided by the range squared.
    """
    var_orb = orbit_sigma_m**2 / 3.0
    unit = lin.unit
    # |u|^2 I - u u^T: the projector across the line of sight (0 for constraint rows, u = 0)
    perp = np.sum(unit**2, axis=-1)[..., None, None] * np.eye(3) - unit[..., :, None] * unit[..., None, :]
    T, n = lin.q.shape
    cov = np.zeros((T, n, 4, 4))
    cov[..., :3, :3] = var_orb * perp / np.maximum(lin.range_m, 1.0)[..., None, None] ** 2
    cov[..., 3, 3] = lin.var_m2 + var_orb
    return cov


def wtls_column_scale(lin: Linearization, orbit_sigma_m: float) -> F64:
    """Column scales ``(m + 1,)`` of ``W^{1/2} [A q]`` for WTLS (``[wtls] column_scaling = "orbit"``).

    After row whitening by ``1/sigma_i`` (m), the pseudorange column has unit error and a
    direction cosine has error ``sigma_orbit / (sqrt(3) range_i) / sigma_i``. One scale per
    column cannot whiten every row, so the medians over the used satellite rows set it:
    ``d_A = median(sigma_i) median(range_i) sqrt(3) / sigma_orbit`` for every column of ``A``
    (the clock columns are exact 1s; they get the same, large, scale), ``d_q = 1``.
    """
    m = lin.A.shape[-1]
    sat_rows = lin.mask & (np.sum(lin.unit**2, axis=-1) > 0.5)  # constraint rows have u = 0
    if not sat_rows.any():
        return np.ones(m + 1)
    sigma_m = np.sqrt(np.median(lin.var_m2[sat_rows]))
    range_m = np.median(lin.range_m[sat_rows])
    d_a = sigma_m * range_m * np.sqrt(3.0) / orbit_sigma_m
    return np.concatenate([np.full(m, d_a), [1.0]])
