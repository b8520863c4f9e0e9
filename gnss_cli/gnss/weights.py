"""Pseudorange error models: broadcast ephemeris sigmas, pseudorange variances, STLS/WTLS scales.

The variance model follows RTKLIB 2.4.3 ``pntpos.c`` (``gnss_cli/configs/default.toml`` [weights]);
the broadcast orbit-and-clock sigma is RTKLIB's ``var_uraeph``. The single-epoch STLS row
covariance and the WTLS column scale add the broadcast-orbit error to the geometry columns
(``[stls] orbit_sigma_m``, DESIGN.md section 3).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

if TYPE_CHECKING:
    from gnss_cli.config import ProcessingConfig
    from gnss_cli.gnss.geometry import Linearization

F64 = NDArray[np.float64]

URA_TABLE_M = np.array([2.4, 3.4, 4.85, 6.85, 9.65, 13.65, 24.0, 48.0, 96.0, 192.0, 384.0, 768.0, 1536.0, 3072.0, 6144.0])
"""URA index table of IS-GPS-200 (m), as RTKLIB uses it for the ephemeris variance."""


def ura_from_index_table(ura_m: F64) -> F64:
    """Broadcast URA (m) rounded up to the IS-GPS-200 URA table, as RTKLIB does; NaN -> 2.4 m."""
    u = np.where(np.isfinite(ura_m), ura_m, 0.0)
    k = np.searchsorted(URA_TABLE_M, u - 1e-9)
    return np.where(k < URA_TABLE_M.size, URA_TABLE_M[np.minimum(k, URA_TABLE_M.size - 1)], 6144.0)


MAX_EPHEMERIS_SIGMA_M = 300.0
"""A satellite whose broadcast orbit-and-clock sigma (URA, SISA) exceeds this (m) is not used, as
RTKLIB's ``MAX_VAR_EPH`` (URA index 10 and above, Galileo NAPA). Weighted instead, such a
satellite adds nothing to the position but a degree of freedom to the residual test: a record
with a damaged URA of 266 km let six reflected GPS signals in the urban canyon pass the test
100-180 m off (benchmarks/fuzz.py)."""
GLONASS_EPHEMERIS_SIGMA_M = 5.0
"""GLONASS broadcast orbit-and-clock error sigma (RTKLIB ``ERREPH_GLO``): RINEX 3 records carry no URA."""
GALILEO_NAPA_SIGMA_M = 500.0
"""Galileo SISA 'no accuracy prediction available' (RTKLIB ``STD_GAL_NAPA``)."""


def ephemeris_sigma_m(system: str, accuracy_m: F64) -> F64:
    """Orbit-and-clock error sigma (m) of broadcast records, as RTKLIB's ``var_uraeph``.

    GPS, QZSS, BeiDou: the URA field rounded up to the IS-GPS-200 table (blank: 2.4 m).
    Galileo: the SISA field, 0 < SISA <= 6 m; larger or negative values mean NAPA (500 m);
    blank: 2.4 m. GLONASS: 5 m for every record.
    """
    acc = np.asarray(accuracy_m, dtype=np.float64)
    if system == "R":
        return np.full(acc.shape, GLONASS_EPHEMERIS_SIGMA_M)
    if system == "E":
        napa = np.isfinite(acc) & ((acc <= 0.0) | (acc > 6.0))
        return np.where(np.isfinite(acc), np.where(napa, GALILEO_NAPA_SIGMA_M, acc), URA_TABLE_M[0])
    return ura_from_index_table(acc)


def pseudorange_variance_m2(
    config: ProcessingConfig, el_rad: F64, ura_m: F64, iono_m: F64, efact: F64 | float = 1.0
) -> F64:
    """Pseudorange variances (m^2) of the configured weight model (see ``gnss_cli/configs/default.toml``).

    ``ura_m`` is the broadcast orbit-and-clock sigma (:func:`ephemeris_sigma_m`); ``efact``
    scales the code-noise term per satellite (RTKLIB: 1.5 for GLONASS, else 1).
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
