"""Receiver-satellite geometry: ranges with the Earth-rotation correction, design rows.

For a receiver at ``x`` (ECEF, m) and a satellite at ``s`` (ECEF of the transmit time), the
geometric range including the rotation of the Earth during signal flight (Sagnac) is

``r = |s - x| + (omega_E / c) (s_x x_y - s_y x_x)``,

and the pseudorange design row is ``[-e, 1]`` with ``e = (s - x) / |s - x|`` (DESIGN.md
section 2). Everything is vectorized over ``(T, n)`` epochs x satellites.

:func:`linearize` builds the whole linearized system ``(A, q, W)`` of a block of epochs:
ranges, corrections (Klobuchar, Saastamoinen), the elevation mask, the variances of
:mod:`gnss_cli.gnss.weights`, and one clock column per system.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol

import numpy as np
from numpy.typing import NDArray

from gnss_cli.constants import C_M_S, OMEGA_E_RAD_S
from gnss_cli.errors import UsageError
from gnss_cli.gnss.atmosphere import klobuchar_delay_m, saastamoinen_delay_m
from gnss_cli.gnss.frames import azimuth_elevation, ecef2enu_rotation, ecef2geodetic
from gnss_cli.gnss.weights import pseudorange_variance_m2

if TYPE_CHECKING:
    from gnss_cli.config import ProcessingConfig

F64 = NDArray[np.float64]

EARTH_SURFACE_BAND_M = (6.0e6, 7.0e6)
"""Geocentric radii (m) between which a position counts as near the Earth's surface."""


class EpochArrays(Protocol):
    """What :func:`linearize` reads of the prepared epochs (:class:`gnss_cli.pipeline.EpochData`)."""

    time_gps_s: F64
    sv: NDArray[np.str_]
    pr_corrected_m: F64
    sat_ecef_m: F64
    ura_m: F64
    usable: NDArray[np.bool_]
    klobuchar: tuple[F64, F64] | None
    systems: tuple[str, ...]
    system_index: NDArray[np.int64] | None
    iono_scale: F64 | None


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


@dataclass
class Linearization:
    """Linearized pseudoranges of a block of epochs (``t`` epochs, ``n`` satellites, ``k`` clocks).

    Attributes
    ----------
    A : ``(t, n [+ k], 3 + k)`` design rows ``[-e, clock one-hot]``; with ``k > 1`` the last
        ``k`` rows are the clock-fixing constraints of systems without satellites.
    q : ``(t, n [+ k])`` observed minus computed, m.
    mask : ``(t, n [+ k])`` rows used (above the mask, usable; set constraint rows).
    var_m2 : ``(t, n [+ k])`` row variances, m^2 (:func:`~gnss_cli.gnss.weights.pseudorange_variance_m2`).
    unit : ``(t, n [+ k], 3)`` line-of-sight unit vectors (0 for constraint rows).
    range_m : ``(t, n [+ k])`` geometric ranges, m (1 for constraint rows).
    rot : ``(t, 3, 3)`` ECEF -> local ENU rotation at each position.
    sv_col : ``(t, w)`` in the compact layout (``linearize(..., width=w)``): the satellite
        (column of ``data.sv``) of each of the ``w`` satellite rows, -1 for the padding rows
        (``mask`` False); None in the dense layout, where satellite row ``i`` is ``data.sv[i]``.
    """

    A: F64
    q: F64
    mask: NDArray[np.bool_]
    var_m2: F64
    unit: F64
    range_m: F64
    rot: F64
    sv_col: NDArray[np.intp] | None = None

    @property
    def sat_rows(self) -> int:
        """Number of satellite rows (``n`` dense, ``w`` compact); the clock constraint rows follow."""
        k = self.A.shape[-1] - 3
        return self.q.shape[1] - (k if k > 1 else 0)

    @property
    def sv_index(self) -> NDArray[np.intp]:
        """``(t, sat_rows)`` satellite (column of ``data.sv``) of each satellite row; -1 for padding."""
        if self.sv_col is not None:
            return self.sv_col
        return np.broadcast_to(np.arange(self.sat_rows), self.q.shape[:1] + (self.sat_rows,))

    def scatter(self, values: F64, n: int, fill: float = np.nan) -> F64:
        """Per-satellite-row ``values`` (``(t, sat_rows)``) in the dense layout ``(t, n)``,
        ``fill`` where a satellite has no row (compact) or ``values`` itself (dense)."""
        if self.sv_col is None:
            return values[:, :n]
        out = np.full((values.shape[0], n), fill)
        t, j = np.nonzero(self.sv_col >= 0)
        out[t, self.sv_col[t, j]] = values[t, j]
        return out


ISB_CONSTRAINT_VAR_M2 = 0.01
"""Variance (m^2) of RTKLIB's pseudo-observation fixing the clock of a system without satellites."""


COMPACT_ROW_STEP = 8
"""The compact layout's satellite rows are a multiple of this (:func:`compact_width`)."""


def compact_width(n_usable: NDArray[np.int64]) -> NDArray[np.int64]:
    """Satellite rows of an epoch's compact linearization: its usable satellites (an upper bound of
    the used ones), rounded up to a multiple of :data:`COMPACT_ROW_STEP` (at least one step).

    The width is a function of the epoch alone, not of the epochs stacked with it: the last bits
    of a stacked factorization or sum change with the number of zero rows after the used ones,
    and an epoch must get the same numbers in a whole-file run and in a run by parts.
    """
    n = np.maximum(np.asarray(n_usable, dtype=np.int64), 1)
    return -(-n // COMPACT_ROW_STEP) * COMPACT_ROW_STEP


def width_groups(usable: NDArray[np.bool_], block: int) -> list[tuple[NDArray[np.intp], int]]:
    """The epochs of ``usable`` (``(t, n)``) by their :func:`compact_width`, in blocks of at most
    ``block`` epochs: ``(epoch indices (ascending), width)`` per block."""
    widths = compact_width(usable.sum(axis=1))
    groups: list[tuple[NDArray[np.intp], int]] = []
    for w in np.unique(widths):
        idx = np.flatnonzero(widths == w)
        groups += [(part, int(w)) for part in np.array_split(idx, -(-idx.size // block))]
    return groups


def linearize(data: EpochArrays, rows: NDArray[np.intp], x: F64, b: F64, config: ProcessingConfig,
              width: int | None = None) -> Linearization:
    """Linearized pseudoranges at ``x`` (ECEF m) and clocks ``b`` (``(t, k)``, m, one per system).

    Columns: ``[-e (3), clock of system 0, ..., clock of system k-1]``. With several systems,
    ``k`` constraint rows follow the ``n`` satellite rows: an epoch without satellites of a
    system gets ``clock_j = 0`` as a pseudo-observation (variance 0.01 m^2), as in RTKLIB.

    Parameters
    ----------
    data : EpochArrays
        The prepared epochs (:class:`gnss_cli.pipeline.EpochData`).
    rows : ``(t,)`` epoch indices of ``data`` to linearize.
    x : ``(t, 3)`` receiver positions, ECEF m.
    b : ``(t, k)`` receiver clocks, m (``(t,)``: one value for every system).
    config : ProcessingConfig
        Elevation mask, atmosphere models and the weight model. Corrections, the mask and
        the weights apply to positions near the Earth's surface (:data:`EARTH_SURFACE_BAND_M`)
        only: the first iterations from the Earth's centre use none of them, as RTKLIB.
    width : int, optional
        The compact layout: ``width`` satellite rows holding the satellites used (usable and
        above the mask) in the order of ``data.sv``, then padding rows (``mask`` False), with
        ``sv_col`` naming each row's satellite; at least the usable satellites of every epoch
        (:func:`compact_width`, :func:`width_groups`). An epoch has 30-50 of the ~110
        satellites of a multi-GNSS file: the solvers then factor ``(t, w + k, 3 + k)``
        instead of ``(t, n + k, 3 + k)`` matrices. Every number is the same as in the dense
        layout (the default); only the rows move.

    Raises
    ------
    UsageError
        ``width`` is smaller than an epoch's number of usable satellites.
    """
    k = len(data.systems)
    b = np.asarray(b, dtype=np.float64)
    if b.ndim == 1:  # one clock for all systems' columns given as (t,): broadcast
        b = np.repeat(b[:, None], k, axis=1)
    t_n, n = rows.size, data.sv.size
    # every per-satellite term is evaluated on the usable observations only, then scattered
    ti, si = np.nonzero(data.usable[rows])
    tr = rows[ti]
    rng_u, unit_u = sagnac_range(data.sat_ecef_m[tr, si][:, None, :], x[ti])
    rng_u, unit_u = rng_u[:, 0], unit_u[:, 0]
    radius = np.linalg.norm(x, axis=1)
    near = (radius > EARTH_SURFACE_BAND_M[0]) & (radius < EARTH_SURFACE_BAND_M[1])
    lat, lon, h = ecef2geodetic(x)
    rot = ecef2enu_rotation(lat, lon)
    az, el = azimuth_elevation(np.einsum("nij,nj->ni", rot[ti], unit_u))
    near_u = near[ti]
    mask_u = ~near_u | (el >= np.deg2rad(config.elevation_mask_deg))
    corrected = near_u & mask_u
    iono = np.zeros_like(rng_u)
    if config.iono == "klobuchar" and data.klobuchar is not None and corrected.any():
        alpha, beta = data.klobuchar
        c = np.flatnonzero(corrected)
        iono[c] = klobuchar_delay_m(alpha, beta, lat[ti[c]], lon[ti[c]], az[c], el[c], data.time_gps_s[tr[c]])
        if data.iono_scale is not None:
            iono[c] *= data.iono_scale[tr[c], si[c]]
    tropo = np.zeros_like(rng_u)
    if config.tropo == "saastamoinen" and corrected.any():
        c = np.flatnonzero(corrected)
        tropo[c] = saastamoinen_delay_m(lat[ti[c]], h[ti[c]], el[c])
    sysidx = data.system_index if data.system_index is not None else np.zeros(n, dtype=np.int64)
    efact = np.where(np.array([sv[0] for sv in data.sv]) == "R", 1.5, 1.0)  # RTKLIB EFACT_GLO
    var_u = np.where(near_u, pseudorange_variance_m2(config, el, data.ura_m[tr, si], iono, efact[si]), 1.0)
    q_u = data.pr_corrected_m[tr, si] - (rng_u + b[ti, sysidx[si]] + iono + tropo)
    sv_col = None
    if width is not None:  # the used observations only
        keep, col, sv_col = _compact_rows(ti, si, mask_u, t_n, width)
        ti, si, mask_u, q_u, var_u, unit_u, rng_u = (v[keep] for v in (ti, si, mask_u, q_u, var_u, unit_u, rng_u))
        n = width
    else:
        col = si
    # the k clock-constraint rows (several systems) follow the n satellite rows in the same arrays
    rows_n = n + (k if k > 1 else 0)
    mask = np.zeros((t_n, rows_n), dtype=bool)
    mask[ti, col] = mask_u
    q = np.zeros((t_n, rows_n))
    q[ti, col] = np.where(mask_u, q_u, 0.0)
    var = np.ones((t_n, rows_n))
    var[ti, col] = np.where(mask_u, var_u, 1.0)
    A = np.zeros((t_n, rows_n, 3 + k))
    A[ti, col, :3] = np.where(mask_u[:, None], -unit_u, 0.0)
    A[ti, col, 3 + sysidx[si]] = np.where(mask_u, 1.0, 0.0)
    unit_c = np.zeros((t_n, rows_n, 3))
    unit_c[ti, col] = unit_u
    rng_c = np.ones((t_n, rows_n))
    rng_c[ti, col] = rng_u
    if k > 1:
        present = np.zeros((t_n, k), dtype=bool)
        present[ti[mask_u], sysidx[si[mask_u]]] = True
        A[:, n + np.arange(k), 3 + np.arange(k)] = np.where(~present, 1.0, 0.0)
        q[:, n:] = np.where(~present, -b, 0.0)
        mask[:, n:] = ~present
        var[:, n:] = ISB_CONSTRAINT_VAR_M2
    return Linearization(A, q, mask, var, unit_c, rng_c, rot, sv_col)


def _compact_rows(ti: NDArray[np.intp], si: NDArray[np.intp], used: NDArray[np.bool_], t_n: int, width: int
                  ) -> tuple[NDArray[np.intp], NDArray[np.intp], NDArray[np.intp]]:
    """Where the usable observations ``(ti, si)`` (epoch-major, as ``np.nonzero`` gives them) go in
    the compact layout: the ``used`` ones (their indices), each at its rank among its epoch's
    (its row), and ``sv_col`` ``(t_n, width)``."""
    if ti.size and np.bincount(ti, minlength=t_n).max() > width:
        raise UsageError(f"width: expected at least the usable satellites of every epoch "
                         f"({np.bincount(ti, minlength=t_n).max()}); received {width}")
    keep = np.flatnonzero(used)
    counts = np.bincount(ti[keep], minlength=t_n)
    col = np.arange(keep.size) - (np.cumsum(counts) - counts)[ti[keep]]
    sv_col = np.full((t_n, width), -1, dtype=np.intp)
    sv_col[ti[keep], col] = si[keep]
    return keep, col, sv_col
