"""Stanford-diagram regions: each epoch's position error against its protection level and the
alert limit, and the integrity statistics of a method's epochs.

With the error ``e`` (m, horizontal or vertical, against a reference), the protection level
``PL`` (m) and the alert limit ``AL`` (m; infinite when none is set), an epoch is in one of
five regions (Tossaint et al. 2007, "The Stanford diagram: a graphical means for evaluating
integrity", ION GNSS):

============================  ==========================  ============================================
region                        condition                   meaning
============================  ==========================  ============================================
``normal``                    ``e <= PL <= AL``           available, and the level bounds the error
``misleading``                ``PL < e <= AL``            available, the level fails to bound the error
``hazardous``                 ``PL <= AL < e``            misleading, and the error is beyond the limit
``unavailable``               ``AL < PL``, ``e <= PL``    the level is above the limit: not available
``unavailable_misleading``    ``AL < PL < e``             not available, and the level fails as well
============================  ==========================  ============================================

An epoch counts in the diagram when it has an error and a protection level (a position, a
reference, and a tested fix). The run's integrity figures (:func:`integrity_statistics`)
judge the words the run wrote: an ``ok`` epoch whose horizontal error exceeds its HPL or whose
vertical error exceeds its VPL is *misleading information*, whatever the alert limit.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

__all__ = ["REGIONS", "regions", "region_counts", "integrity_statistics"]

F64 = NDArray[np.float64]

REGIONS = ("normal", "misleading", "hazardous", "unavailable", "unavailable_misleading")
"""The regions of the diagram, in the order of the module docstring's table."""


def regions(error_m: F64, pl_m: F64, alert_m: float = np.inf) -> NDArray[np.str_]:
    """The region of each epoch (:data:`REGIONS`), ``""`` where the error or the level is missing.

    Parameters
    ----------
    error_m : ndarray (T,)
        Absolute position error (horizontal or vertical), m.
    pl_m : ndarray (T,)
        Protection level of the same component, m.
    alert_m : float
        Alert limit, m (infinite: no limit, so never ``hazardous`` nor ``unavailable``).

    >>> regions(np.array([1.0, 5.0, 50.0, 3.0, 80.0, np.nan]), np.array([2.0, 4.0, 9.0, 60.0, 70.0, 1.0]), 40.0).tolist()
    ['normal', 'misleading', 'hazardous', 'unavailable', 'unavailable_misleading', '']
    """
    e, pl = np.abs(np.asarray(error_m, dtype=float)), np.asarray(pl_m, dtype=float)
    have = np.isfinite(e) & np.isfinite(pl)
    bounded = e <= pl
    available = pl <= alert_m
    out = np.full(e.shape, "", dtype="<U22")
    out[have & available & bounded] = "normal"
    out[have & available & ~bounded & (e <= alert_m)] = "misleading"
    out[have & available & ~bounded & (e > alert_m)] = "hazardous"
    out[have & ~available & bounded] = "unavailable"
    out[have & ~available & ~bounded] = "unavailable_misleading"
    return out


def region_counts(labels: NDArray[np.str_]) -> dict[str, int]:
    """Epochs per region (every region of :data:`REGIONS`, zero included)."""
    return {name: int(np.count_nonzero(labels == name)) for name in REGIONS}


def integrity_statistics(ok: NDArray[np.bool_], enu_m: F64, hpl_m: F64 | None, vpl_m: F64 | None) -> dict[str, float]:
    """What a method's words are worth against a reference.

    Parameters
    ----------
    ok : ndarray (T,) of bool
        Epochs with the status ``ok``.
    enu_m : ndarray (T, 3)
        E/N/U errors against the reference, m (NaN where there is no position or no reference).
    hpl_m, vpl_m : ndarray (T,), optional
        Protection levels, m (None or NaN where the method writes none).

    Returns
    -------
    dict
        ``availability_pct``: ``ok`` epochs in % of all; ``p95_3d_m``, ``max_3d_m``: 95th
        percentile and maximum of the 3D error of the ``ok`` epochs with a reference;
        ``misleading_epochs`` and ``misleading_pct``: the ``ok`` epochs with a reference whose
        horizontal error exceeds HPL or vertical error exceeds VPL, in number and in % of the
        ``ok`` epochs with a reference -- NaN when some of those epochs have no protection level
        (a count that cannot be made is not zero).
    """
    T = ok.size
    with_ref = ok & np.isfinite(enu_m).all(axis=1)
    err3 = np.linalg.norm(enu_m[with_ref], axis=1)
    out = {"availability_pct": 100.0 * np.count_nonzero(ok) / T if T else np.nan,
           "p95_3d_m": float(np.percentile(err3, 95)) if err3.size else np.nan,
           "max_3d_m": float(err3.max()) if err3.size else np.nan,
           "misleading_epochs": np.nan, "misleading_pct": np.nan}
    if not with_ref.any() or hpl_m is None or vpl_m is None:
        return out
    h_pl, v_pl = hpl_m[with_ref], vpl_m[with_ref]
    if not (np.isfinite(h_pl).all() and np.isfinite(v_pl).all()):
        return out
    enu = enu_m[with_ref]
    misleading = (np.hypot(enu[:, 0], enu[:, 1]) > h_pl) | (np.abs(enu[:, 2]) > v_pl)
    out["misleading_epochs"] = float(np.count_nonzero(misleading))
    out["misleading_pct"] = 100.0 * np.count_nonzero(misleading) / misleading.size
    return out
