"""Block-Hankel matrices of vector time series.

A time series ``w`` of ``T`` samples in ``R^q`` is stored as an array ``(T, q)`` (time first).
The block-Hankel matrix with ``depth`` block rows stacks ``depth`` consecutive samples per
column::

    H_depth(w) = [[w(0),         w(1),     ..., w(T-depth)    ],
                  [w(1),         w(2),     ..., w(T-depth+1)  ],
                  ...
                  [w(depth-1),   w(depth), ..., w(T-1)        ]]

so that a kernel ``R = [R_0 ... R_lag]`` annihilates ``w`` (``sum_k R_k w(t+k) = 0`` for every
``t``) exactly when ``R @ H_{lag+1}(w) == 0``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gnss_cli.errors import UsageError

__all__ = ["hankel", "as_series", "hankel_rows"]


def as_series(w: ArrayLike, name: str = "w") -> NDArray[np.float64]:
    """Validate a time series and return it as a float64 array ``(T, q)``.

    A 1-D input ``(T,)`` is a scalar series (``q = 1``).

    Raises
    ------
    UsageError
        If ``w`` is not 1-D or 2-D, is empty or holds non-finite values.
    """
    arr = np.asarray(w, dtype=np.float64)
    if arr.ndim == 1:
        arr = arr[:, None]
    if arr.ndim != 2 or arr.shape[0] == 0 or arr.shape[1] == 0:
        raise UsageError(f"{name}: expected a non-empty time series of shape (T, q), received shape {np.shape(w)}")
    if not np.all(np.isfinite(arr)):
        bad = int(np.count_nonzero(~np.isfinite(arr)))
        raise UsageError(f"{name}: expected finite values, received {bad} non-finite entries")
    return arr


def hankel(w: ArrayLike, depth: int) -> NDArray[np.float64]:
    """Block-Hankel matrix ``H_depth(w)`` of a vector time series.

    Parameters
    ----------
    w : array_like, shape (T, q) or (T,)
        Time series, one sample per row (any unit; the result has the same unit).
    depth : int
        Number of block rows, ``1 <= depth <= T`` (``lag + 1`` for a kernel of lag ``lag``).

    Returns
    -------
    H : ndarray, shape (q * depth, T - depth + 1)
        Column ``j`` is ``[w(j); w(j+1); ...; w(j+depth-1)]``. A new array (not a view).

    Raises
    ------
    UsageError
        If ``w`` is not a finite ``(T, q)`` array or ``depth`` is outside ``[1, T]``.

    Examples
    --------
    >>> hankel([[1.0], [2.0], [3.0], [4.0]], 2)
    array([[1., 2., 3.],
           [2., 3., 4.]])
    """
    arr = as_series(w)
    n_t, q = arr.shape
    if isinstance(depth, bool) or not isinstance(depth, (int, np.integer)) or not 1 <= depth <= n_t:
        raise UsageError(f"depth: expected an integer in [1, T={n_t}], received {depth!r}")
    n_col = n_t - depth + 1
    # windows[j, :, k] = w(j + k); H[k*q + a, j] = w(j + k)[a]
    windows = np.lib.stride_tricks.sliding_window_view(arr, depth, axis=0)  # (n_col, q, depth)
    return np.ascontiguousarray(windows.transpose(2, 1, 0).reshape(q * depth, n_col))


def hankel_rows(x: NDArray[np.float64], depth: int) -> NDArray[np.float64]:
    """Read-only view of the columns of ``H_depth(x)`` as rows: ``out[j] = x[j : j + depth]``.

    Parameters
    ----------
    x : ndarray, shape (T, k)
        Time series (any unit), ``1 <= depth <= T`` (not validated: an internal helper).

    Returns
    -------
    ndarray, shape (T - depth + 1, depth, k)
        A strided view (no copy); ``out.reshape(T - depth + 1, depth * k)`` is ``H_depth(x)^T``.
    """
    arr = np.ascontiguousarray(x)
    s0, s1 = arr.strides
    # an ndarray over arr's memory (numpy checks the strides stay inside it); cheaper than as_strided
    out: NDArray[np.float64] = np.ndarray(
        (arr.shape[0] - depth + 1, depth, arr.shape[1]), arr.dtype, arr, 0, (s0, s0, s1)
    )
    out.flags.writeable = False
    return out
