"""Starting kernels of the STLS descent beyond the WTLS kernel.

The weighted Hankel misfit has local minima, so :func:`gnss_cli.behavior.stls` descends from
several kernels estimated from the data alone (never from a reference model):

* :func:`subspace_kernel` -- the left null space of an observability matrix estimated from a
  deeper block-Hankel matrix (``depth`` block rows instead of ``l + 1``);
* :func:`modal_kernel` -- for a square (autonomous) kernel, the behavior with the poles of a
  previous fit and output directions re-fitted to the data by linear least squares.

Both whiten the data with the mean covariance, as the WTLS does. The module also turns the
candidates into charted, evaluated starting points (:func:`start_candidates`,
:func:`chart_point`) and gives the restart of a descent from mirrored poles
(:func:`mirrored_start`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gnss_cli.behavior.banded import BandedGram, InnerProblem
from gnss_cli.behavior.chart import FullChart, SharedChart
from gnss_cli.behavior.covariance import EpochCovariance
from gnss_cli.behavior.descent import Descent
from gnss_cli.behavior.kernel import KernelRepresentation, kernel_from
from gnss_cli.behavior.wtls import full_wtls_kernel, shared_wtls_tilde, whitening_factor
from gnss_cli.errors import UsageError

__all__ = [
    "subspace_kernel", "modal_kernel", "StartPoint", "chart_point", "start_candidates", "fallback_start",
    "mirrored_start",
]

#: Relative singular-value gap below which an estimated observability matrix is rank deficient.
RANK_RTOL = 1e-10
#: Subspace starts (full structure, series shorter than ``COARSE_MIN_SAMPLES`` of
#: :mod:`gnss_cli.behavior.stls`): Hankel matrices with these multiples of ``l + 1`` block rows.
SUBSPACE_DEPTHS = (2, 3)
#: Poles farther than this outside the unit circle trigger a restart from the mirrored kernel.
MIRROR_MARGIN = 1e-3


def _left_null_space(obs: NDArray[np.float64], rank: int) -> NDArray[np.float64] | None:
    """Rows spanning the left null space of ``obs`` ``(m, k)`` of numerical rank ``rank``, or None."""
    u, s, _ = np.linalg.svd(obs, full_matrices=True)
    if s.size < rank or s[rank - 1] <= RANK_RTOL * s[0]:
        return None
    return u[:, rank:].T


def subspace_kernel(
    w: NDArray[np.float64], lag: int, g: int, cov: EpochCovariance, depth: int
) -> NDArray[np.float64] | None:
    """Kernel ``(g, q(l+1))`` from the column space of a deeper block-Hankel matrix.

    Parameters
    ----------
    w : ndarray, shape (T, q)
        Data.
    lag, g : int
        Lag and number of kernel rows (order ``n = q(l+1) - g``).
    cov : EpochCovariance
        Covariances (only their mean is used, for whitening).
    depth : int
        Block rows of the Hankel matrix, ``>= l + 1``.

    Returns
    -------
    R : ndarray or None
        None when ``depth`` does not fit the data (``T - depth + 1 <= n`` or ``q depth <= n``)
        or the estimate is rank deficient.

    Notes
    -----
    The ``n`` dominant left singular vectors of ``H_depth(v)`` (``v = C^{-1} w``, ``C C^T`` the
    mean covariance) estimate the extended observability matrix of the behavior; its first
    ``l+1`` block rows ``O_{l+1}`` span the trajectories of length ``l+1`` and the kernel is
    their left null space, mapped back as ``R = R_v (I_{l+1} (x) C^{-1})``. ``depth = l + 1``
    gives the WTLS kernel; a deeper Hankel matrix averages the noise over more shifts (the
    idea of Kung's realization algorithm).
    """
    n_t, q = w.shape
    n_order = q * (lag + 1) - g
    if depth < lag + 1 or q * depth <= n_order or n_t - depth + 1 <= n_order:
        return None
    c = whitening_factor(cov)
    v = np.linalg.solve(c, w.T).T
    win = np.lib.stride_tricks.sliding_window_view(v, depth, axis=0)  # (n, q, depth)
    h_t = win.transpose(0, 2, 1).reshape(win.shape[0], q * depth)  # H_depth(v)^T
    r_fac = np.linalg.qr(h_t, mode="r") if h_t.shape[0] > h_t.shape[1] else h_t
    _, _, vt = np.linalg.svd(r_fac, full_matrices=False)
    obs = vt[:n_order, : q * (lag + 1)].T  # O_{l+1} up to a change of state basis
    r_v = _left_null_space(obs, n_order)
    return None if r_v is None else r_v @ np.kron(np.eye(lag + 1), np.linalg.inv(c))


def modal_kernel(w: NDArray[np.float64], kernel: KernelRepresentation, cov: EpochCovariance,
                 max_growth: float = 1e8) -> NDArray[np.float64] | None:
    """The behavior with the poles of ``kernel`` and output directions fitted to ``w``.

    Parameters
    ----------
    w : ndarray, shape (T, q)
        Data.
    kernel : KernelRepresentation
        A square kernel (``p = q``) whose poles are kept.
    cov : EpochCovariance
        Covariances (only their mean is used, for whitening).
    max_growth : float
        Give up when a mode grows or decays by more than this factor over the series.

    Returns
    -------
    R : ndarray, shape (q, q(l+1)) or None
        None for a non-square kernel, fewer than ``q l`` finite poles, an ill-conditioned
        mode matrix or a rank-deficient result.

    Notes
    -----
    With distinct poles ``z_i`` the trajectories of an autonomous behavior are
    ``w_t = sum_i d_i z_i^t``. A descent can end with nearly the right poles but a wrong
    direction ``d_i`` for one of them (a basin the misfit cannot leave by small steps); the
    directions that fit the whitened data best for the given poles are the linear least-squares
    solution of ``v_t = sum_i d_i z_i^t``. The kernel is the left null space of
    ``[D; D Z; ...; D Z^l]`` (``D = [d_i]``, ``Z = diag(z_i)``, real and imaginary parts).
    """
    q = w.shape[1]
    if kernel.p != q:
        return None
    n_order = q * kernel.lag
    try:
        poles = kernel.poles()
    except Exception:  # noqa: BLE001 - any failure of the pencil means no modal start
        return None
    if poles.size != n_order:
        return None
    n_t = w.shape[0]
    log_mod = np.log(np.maximum(np.abs(poles), np.finfo(float).tiny)) * (n_t - 1)
    if np.max(np.abs(log_mod)) > np.log(max_growth):
        return None
    c = whitening_factor(cov)
    v = np.linalg.solve(c, w.T).T
    modes = poles[None, :] ** np.arange(n_t)[:, None]  # (T, n)
    if np.linalg.cond(modes) > 1e10:
        return None
    d_mat = np.linalg.lstsq(modes, v.astype(np.complex128), rcond=None)[0].T  # (q, n)
    obs = np.vstack([d_mat * poles[None, :] ** k for k in range(kernel.lag + 1)])
    r_v = _left_null_space(np.hstack([obs.real, obs.imag]), n_order)
    return None if r_v is None else r_v @ np.kron(np.eye(kernel.lag + 1), np.linalg.inv(c))


# ---------------------------------------------------------------------- starting points of stls
@dataclass(slots=True)
class StartPoint:
    """A kernel in chart coordinates with its projection."""

    origin: str
    chart: FullChart | SharedChart
    theta: NDArray[np.float64]
    state: BandedGram


def chart_point(problem: InnerProblem, cand: NDArray[np.float64], structure: str, fixed: NDArray[np.float64],
                 q: int, origin: str) -> StartPoint:
    """Chart a starting kernel (``R`` or ``r~``) and evaluate it; raises on a singular Gram matrix."""
    chart: FullChart | SharedChart
    if structure == "shared":
        chart = SharedChart(fixed, cand, q)
        theta = chart.coordinates_tilde(cand)
    else:
        chart = FullChart(cand, q)
        theta = chart.coordinates(cand)
    return StartPoint(origin, chart, theta, problem.project(chart.blocks(theta)))


def _shared_start(kernel0: KernelRepresentation | ArrayLike, lag: int, fixed: NDArray[np.float64],
                  q: int) -> NDArray[np.float64]:
    """``r~`` of a shared starting kernel (``r`` divided by the fixed factor)."""
    if isinstance(kernel0, KernelRepresentation) or np.ndim(kernel0) != 1:
        r0 = kernel_from(kernel0, q).shared_coefficients()
    else:
        r0 = np.asarray(kernel0, dtype=np.float64)
    if r0.size != lag + 1:
        raise UsageError(f"kernel0: expected a shared kernel of lag {lag}, received {r0.size - 1}")
    quot, _ = np.polydiv(r0[::-1], fixed[::-1])
    return np.asarray(quot[::-1], dtype=np.float64)


def _full_start(kernel0: KernelRepresentation | ArrayLike, lag: int, g: int, q: int) -> NDArray[np.float64]:
    k0 = kernel_from(kernel0, q)
    if k0.lag != lag or k0.p != g:
        raise UsageError(f"kernel0: expected {g} rows and lag {lag}, received {k0.p} rows and lag {k0.lag}")
    return np.array(k0.R)


def start_candidates(
    arr: NDArray[np.float64], lag: int, g: int, fixed: NDArray[np.float64], cov: EpochCovariance,
    structure: str, kernel0: KernelRepresentation | ArrayLike | None, coarse: KernelRepresentation | None,
) -> list[tuple[str, NDArray[np.float64]]]:
    """Starting points ``(origin, R or r~)`` in priority order (ties in misfit keep this order)."""
    q = arr.shape[1]
    given = [("kernel0", kernel0), ("coarse", coarse)]
    out: list[tuple[str, NDArray[np.float64]]] = []
    deg = lag - (fixed.size - 1)
    if structure == "shared":
        out += [(name, _shared_start(k, lag, fixed, q)) for name, k in given if k is not None]
        out.append(("wtls", shared_wtls_tilde(arr, lag, fixed, cov)))
        out.append(("polynomial", np.polynomial.polynomial.polypow([-1.0, 1.0], deg)[: deg + 1].astype(np.float64)))
        return out
    out += [(name, _full_start(k, lag, g, q)) for name, k in given if k is not None]
    out.append(("wtls", full_wtls_kernel(arr, lag, g, cov)))
    if coarse is None:
        for factor in SUBSPACE_DEPTHS:
            deeper = subspace_kernel(arr, lag, g, cov, factor * (lag + 1))
            if deeper is not None:
                out.append(("subspace", deeper))
    return out


def fallback_start(lag: int, g: int, q: int, structure: str) -> tuple[str, NDArray[np.float64]] | None:
    """``(z-1)^l I`` for a full square kernel, tried only when every other start is singular."""
    if structure == "full" and g == q:
        return "polynomial", np.array(KernelRepresentation.shared(np.polynomial.polynomial.polypow([-1.0, 1.0], lag), q).R)
    return None


def mirrored_start(run: Descent, structure: str, q: int) -> NDArray[np.float64] | None:
    """``R`` (or ``r~``) with the unstable poles of a descent's result mirrored into the unit disc."""
    if isinstance(run.chart, SharedChart):
        rt = run.chart.r_tilde(run.theta)
        if rt.size < 2:
            return None
        roots = np.roots(rt[::-1])
        out = np.abs(roots) > 1.0 + MIRROR_MARGIN
        if not np.any(out):
            return None
        roots = np.where(out, 1.0 / np.conj(roots), roots)
        return np.real(np.poly(roots))[::-1].copy()
    if run.chart.g != q:
        return None
    mirrored = KernelRepresentation(run.chart.kernel(run.theta), q=q).mirrored(margin=MIRROR_MARGIN)
    return None if mirrored is None else np.array(mirrored.R)
