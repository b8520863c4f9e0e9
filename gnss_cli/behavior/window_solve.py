"""Clock-reduced normal equations of epochs (numerics only).

The per-epoch part of the measurement-domain multi-epoch problem of DESIGN.md section 6. Epoch
``t`` has linearized rows ``y_t = P_t z_t + C_t b_t + noise`` (weights ``W_t``): ``z_t`` the unknown
position (or velocity) minus the linearization point (m), ``b_t`` the epoch's free nuisance
columns (receiver clocks, one per system; for range rates the clock drift) and ``C_t`` their 0/1
columns. Eliminating ``b_t`` leaves the clock-reduced normal equations of the epoch
(:func:`reduce_epochs`)::

    M_t = P^T W P - P^T W C (C^T W C)^+ C^T W P,   r_t = P^T W y - P^T W C (C^T W C)^+ C^T W y,
    s_t = y^T W y - y^T W C (C^T W C)^+ C^T W y,

so that ``min_b |y - P z - C b|^2_W = s_t - 2 z^T r_t + z^T M_t z``. An epoch with fewer
satellites than position unknowns plus clocks has a singular ``M_t`` (one satellite: zero) and
still contributes what it has. The kinematic segment solve
(:func:`gnss_cli.behavior.kinematic_solve.solve_kinematic`) ties the epochs' normals together;
:func:`free_misfit` is the misfit of each epoch solved alone with a free position, the
reference of the variance factors of :mod:`gnss_cli.pipeline.measurements`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

__all__ = ["EpochNormals", "reduce_epochs", "free_misfit"]

F64 = NDArray[np.float64]


@dataclass(frozen=True, slots=True)
class EpochNormals:
    """Clock-reduced normal equations of ``T`` epochs (module docstring).

    Attributes
    ----------
    M : ``(T, 3, 3)`` reduced information of the position (or velocity), 1/m^2.
    r : ``(T, 3)`` reduced right-hand side, 1/m.
    s : ``(T,)`` reduced weighted square sum of the rows, unitless.
    n_rows : ``(T,)`` rows with a positive weight.
    n_free : ``(T,)`` nuisance columns estimated (clocks with at least one row).
    """

    M: F64
    r: F64
    s: F64
    n_rows: NDArray[np.int64]
    n_free: NDArray[np.int64]


def reduce_epochs(p: F64, weight: F64, y: F64, clock_cols: F64 | None = None) -> EpochNormals:
    """Eliminate each epoch's nuisance columns from its weighted rows.

    Parameters
    ----------
    p : ``(T, n, 3)``
        Rows' coefficients of the position (or velocity) correction.
    weight : ``(T, n)``
        Row weights, 1/m^2 (0 for rows not used).
    y : ``(T, n)``
        Right-hand sides, m (anything where the weight is 0).
    clock_cols : ``(T, n, k)``, optional
        0/1 nuisance columns (one per system); None: one column common to every row.

    Returns
    -------
    EpochNormals
    """
    c = np.ones((*weight.shape, 1)) if clock_cols is None else clock_cols
    used = weight > 0
    y = np.where(used, y, 0.0)
    p = np.where(used[..., None], p, 0.0)  # rows not used may hold NaN
    cw = c * weight[..., None]
    sw = cw.sum(axis=1)  # (T, k)
    inv = np.where(sw > 0, 1.0 / np.where(sw > 0, sw, 1.0), 0.0)
    g = np.einsum("tnk,tni->tki", cw, p)  # C^T W P
    cy = np.einsum("tnk,tn->tk", cw, y)  # C^T W y
    M = np.einsum("tni,tn,tnj->tij", p, weight, p) - np.einsum("tki,tk,tkj->tij", g, inv, g)
    r = np.einsum("tni,tn,tn->ti", p, weight, y) - np.einsum("tki,tk,tk->ti", g, inv, cy)
    s = np.einsum("tn,tn,tn->t", weight, y, y) - np.einsum("tk,tk,tk->t", cy, inv, cy)
    return EpochNormals(0.5 * (M + M.transpose(0, 2, 1)), r, s, (weight > 0).sum(axis=1), (sw > 0).sum(axis=1))


def free_misfit(normals: EpochNormals, rcond: float = 1e-10) -> tuple[F64, NDArray[np.int64]]:
    """Misfit and rank of each epoch solved alone with a free position: ``s - r^T M^+ r``.

    Returns
    -------
    misfit : ``(T,)`` weighted residual square sum.
    rank : ``(T,)`` rank of ``M`` (position unknowns the epoch determines).
    """
    M_pinv = np.linalg.pinv(normals.M, rcond=rcond, hermitian=True)
    if normals.M.size:  # matrix_rank(M, rtol=rcond, hermitian=True), which numpy < 2 lacks
        s = np.abs(np.linalg.eigvalsh(normals.M))
        rank = np.sum(s > s.max(axis=-1, keepdims=True) * rcond, axis=-1)
    else:
        rank = np.zeros(0, np.int64)
    return normals.s - np.einsum("ti,tij,tj->t", normals.r, M_pinv, normals.r), np.asarray(rank, dtype=np.int64)
