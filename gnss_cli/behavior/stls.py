"""Weighted Hankel structured low-rank approximation (STLS) of a vector time series.

Problem (DESIGN.md section 5)::

    minimize over w_hat, R   sum_t (w(t) - w_hat(t))^T Sigma_t^{-1} (w(t) - w_hat(t))
    subject to               R H_{l+1}(w_hat) = 0,  R of full row rank.

*Inner problem* (fixed ``R``, :func:`misfit`): with ``G = G(R)`` the block-banded matrix of the
constraint ``G vec(w_hat) = 0`` and ``Gamma = G Sigma G^T = L L^T`` (banded Cholesky)::

    M(R) = e^T Gamma^{-1} e = ||L^{-1} e||^2,   e = G vec(w),
    w_hat = w - Sigma G^T Gamma^{-1} e,

in O(T) time and memory (:mod:`gnss_cli.behavior.banded`).

*Outer problem* (:func:`stls`): Levenberg--Marquardt on the whitened residual
``f(theta) = L^{-1} e`` in the chart coordinates ``theta`` of :mod:`gnss_cli.behavior.chart`,
started from the WTLS kernel and the other starts of :func:`stls` (a coarse sub-problem for
long series, subspace kernels of deeper Hankel matrices, restarts from mirrored poles and
re-fitted modes: the misfit has local minima). The Jacobian is the structured pseudo-Jacobian
``J = L^{-1} (dG/dtheta) vec(w_hat)``: it gives the *exact* gradient
(``dM = 2 lambda^T dG w_hat = 2 f^T J dtheta`` with ``lambda = Gamma^{-1} e``) and
``J^T J`` is the Gauss--Newton part of the Hessian (the neglected terms are of the order
of the residual). Steps where ``Gamma`` is singular or the misfit does not decrease are
rejected (larger damping); when the chart degenerates the optimizer re-charts (new identity
columns by pivoted QR), so the search never divides by a vanishing block.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.linalg import lapack

from gnss_cli.behavior.banded import BandedGram, InnerProblem, SingularGramError, project, solve_lower
from gnss_cli.behavior.chart import FullChart, SharedChart
from gnss_cli.behavior.covariance import EpochCovariance
from gnss_cli.behavior.hankel import as_series, hankel_rows
from gnss_cli.behavior.kernel import KernelRepresentation, kernel_from
from gnss_cli.behavior.result import STATUS_MESSAGES, StlsResult, StlsStatus
from gnss_cli.behavior.starts import modal_kernel, subspace_kernel
from gnss_cli.behavior.wtls import full_wtls_kernel, shared_wtls_tilde, validate_problem
from gnss_cli.errors import UsageError

__all__ = ["misfit", "stls", "projection_matrix"]

#: Largest ``T * q`` for which :func:`projection_matrix` builds its dense result.
PROJECTION_MAX_SIZE = 6000


def misfit(
    w: ArrayLike, kernel: KernelRepresentation | ArrayLike, cov: ArrayLike | None = None
) -> tuple[float, NDArray[np.float64]]:
    """Misfit of a fixed kernel and the closest trajectory of its behavior (the inner problem).

    Parameters
    ----------
    w : array_like, shape (T, q)
        Data (e.g. ENU positions in metres), ``T > lag``.
    kernel : KernelRepresentation or array_like (p, q(l+1))
        The kernel ``R``.
    cov : array_like, optional
        Covariances ``(T, q, q)``, variances ``(T, q)`` or None (identity).

    Returns
    -------
    misfit : float
        ``min sum_t (w - w_hat)^T Sigma_t^{-1} (w - w_hat)`` over trajectories of the kernel
        (dimensionless with covariances of ``w``; unit of ``w`` squared for ``cov=None``).
    w_hat : ndarray, shape (T, q)
        The minimizer, ``w - Sigma G^T (G Sigma G^T)^{-1} G vec(w)``.

    Raises
    ------
    UsageError
        Invalid shapes or values.
    SingularGramError
        ``G Sigma G^T`` is singular for this kernel (a :class:`~gnss_cli.errors.NoSolutionError`),
        e.g. more kernel rows than the data can satisfy.

    Notes
    -----
    O(T) time and memory: ``G Sigma G^T`` is block banded and factored by a banded Cholesky.

    Examples
    --------
    >>> import numpy as np
    >>> w = np.array([[0.0], [1.0], [0.0], [1.0]])
    >>> m, w_hat = misfit(w, KernelRepresentation.static(1))
    >>> round(m, 12), w_hat.ravel().round(12).tolist()
    (1.0, [0.5, 0.5, 0.5, 0.5])
    """
    arr = as_series(w)
    n_t, q = arr.shape
    ker = kernel_from(kernel, q)
    if n_t <= ker.lag:
        raise UsageError(f"w: expected more than lag = {ker.lag} samples, received {n_t}")
    covariance = EpochCovariance.from_arg(cov, n_t, q)
    proj = project(arr, np.asarray(ker.blocks), covariance)
    return proj.misfit, proj.w_hat


def projection_matrix(
    kernel: KernelRepresentation | ArrayLike, n_t: int, cov: ArrayLike | None = None
) -> NDArray[np.float64]:
    """First-order sensitivity ``d vec(w_hat) / d vec(w)`` of the fixed-kernel projection.

    Parameters
    ----------
    kernel : KernelRepresentation or array_like (p, q(l+1))
        The (fixed) kernel.
    n_t : int
        Number of epochs ``T`` (``T * q <= 6000``: the result is dense).
    cov : array_like, optional
        Covariances ``(T, q, q)``, ``(T, q)`` or None.

    Returns
    -------
    P : ndarray, shape (T q, T q)
        ``P = I - Sigma G^T (G Sigma G^T)^{-1} G``, the ``Sigma^{-1}``-orthogonal projector onto
        the trajectories of the kernel (``vec`` stacks epochs: index ``t q + i``). For a fixed
        kernel ``w_hat = P w`` exactly; for an identified kernel it is the first-order gain with
        the kernel held fixed. The covariance of ``w_hat`` is ``P Sigma P^T = P Sigma``, whose
        ``(t, t)`` blocks give a multi-epoch DOP of the smoothed trajectory.

    Raises
    ------
    UsageError
        Invalid arguments or ``T q > 6000``.
    SingularGramError
        ``G Sigma G^T`` is singular.
    """
    if isinstance(n_t, bool) or not isinstance(n_t, (int, np.integer)) or n_t < 1:
        raise UsageError(f"n_t: expected a positive integer, received {n_t!r}")
    if isinstance(kernel, KernelRepresentation):
        ker = kernel
    else:
        ker = KernelRepresentation(np.asarray(kernel, dtype=np.float64))
    q, lag, g = ker.q, ker.lag, ker.p
    if n_t <= lag:
        raise UsageError(f"n_t: expected more than lag = {lag} epochs, received {n_t}")
    if n_t * q > PROJECTION_MAX_SIZE:
        raise UsageError(f"n_t: the dense projector needs T q <= {PROJECTION_MAX_SIZE}, received {n_t * q}")
    covariance = EpochCovariance.from_arg(cov, n_t, q)
    n = n_t - lag
    big_g = np.zeros((n * g, n_t * q))
    for j in range(n):
        big_g[j * g : (j + 1) * g, j * q : (j + lag + 1) * q] = ker.R
    # factor Gamma with a zero data series (only the factor is used)
    chol = project(np.zeros((n_t, q)), np.asarray(ker.blocks), covariance).chol
    x = solve_lower(chol, solve_lower(chol, big_g), transpose=True)  # Gamma^{-1} G
    y = (big_g.T @ x).reshape(n_t, q, n_t * q)
    if covariance.kind == "identity":
        sy = y
    elif covariance.kind == "diag":
        assert covariance.values is not None
        sy = covariance.values[:, :, None] * y
    else:
        assert covariance.values is not None
        sy = np.einsum("tab,tbk->tak", covariance.values, y)
    return np.eye(n_t * q) - sy.reshape(n_t * q, n_t * q)


# ---------------------------------------------------------------------- outer problem
#: From this many samples on, the leading ``T // COARSE_FACTOR`` samples are identified first
#: (recursively) and their kernel competes with the WTLS kernel as the starting point: the
#: kernel of a long stretch of an LTI series is close to that of the whole, so the descent at
#: full size needs only the last few (O(T)) iterations.
COARSE_MIN_SAMPLES = 4000
COARSE_FACTOR = 4
#: Stopping tolerance and iteration limit of the coarse sub-problem (its kernel is only a
#: starting point).
COARSE_TOL = 1e-6
COARSE_MAX_ITER = 50
#: Initial Levenberg--Marquardt damping, relative to the diagonal of the curvature. The misfit
#: curvature is ill-conditioned (the Hankel data excite some kernel directions far more than
#: others), so a large initial damping would hold back the weak directions for many iterations.
MU_INITIAL = 1e-8
#: Damping after a rejected step (at least): a step that failed with almost no damping is
#: rejected again after a mere doubling, so the damping jumps to where it shortens the step.
MU_REJECTED = 1e-3
#: Subspace starts (full structure, series shorter than ``COARSE_MIN_SAMPLES``): Hankel
#: matrices with these multiples of ``l + 1`` block rows.
SUBSPACE_DEPTHS = (2, 3)
#: Poles farther than this outside the unit circle trigger a restart from the mirrored kernel.
MIRROR_MARGIN = 1e-3
#: Restarts from mirrored kernels after one descent.
MIRROR_ROUNDS = 2


@dataclass(slots=True)
class _Point:
    """A kernel in chart coordinates with its projection."""

    origin: str
    chart: FullChart | SharedChart
    theta: NDArray[np.float64]
    state: BandedGram


@dataclass(slots=True)
class _Descent:
    chart: FullChart | SharedChart
    theta: NDArray[np.float64]
    state: BandedGram
    status: StlsStatus
    iterations: int
    n_eval: int
    grad_norm: float


def _chart_point(problem: InnerProblem, cand: NDArray[np.float64], structure: str, fixed: NDArray[np.float64],
                 q: int, origin: str) -> _Point:
    """Chart a starting kernel (``R`` or ``r~``) and evaluate it; raises on a singular Gram matrix."""
    chart: FullChart | SharedChart
    if structure == "shared":
        chart = SharedChart(fixed, cand, q)
        theta = chart.coordinates_tilde(cand)
    else:
        chart = FullChart(cand, q)
        theta = chart.coordinates(cand)
    return _Point(origin, chart, theta, problem.project(chart.blocks(theta)))


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


def _start_candidates(
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


def _fallback_start(lag: int, g: int, q: int, structure: str) -> tuple[str, NDArray[np.float64]] | None:
    """``(z-1)^l I`` for a full square kernel, tried only when every other start is singular."""
    if structure == "full" and g == q:
        return "polynomial", np.array(KernelRepresentation.shared(np.polynomial.polynomial.polypow([-1.0, 1.0], lag), q).R)
    return None


def stls(
    w: ArrayLike,
    lag: int,
    order: int | None = None,
    cov: ArrayLike | None = None,
    kernel0: KernelRepresentation | ArrayLike | None = None,
    tol: float = 1e-10,
    max_iter: int = 200,
    *,
    structure: str = "full",
    fixed_roots: Sequence[complex] = (),
    rechart_threshold: float = 10.0,
    hessian: str = "auto",
    max_starts: int = 3,
    restarts: bool = True,
) -> StlsResult:
    """Identify a kernel of lag ``lag`` by weighted Hankel structured low-rank approximation.

    Parameters
    ----------
    w : array_like, shape (T, q)
        Uniformly sampled time series (e.g. ENU positions in metres; never raw ECEF).
    lag : int
        Kernel lag ``l >= 1``; ``T >= l + 2``.
    order : int, optional
        Full structure: rank ``q(l+1) - g`` of the Hankel matrix, i.e. the kernel has
        ``g = q(l+1) - order`` rows; default ``q * lag`` (``g = q``). Feasible only when
        ``g (T - l) <= q T`` (roughly ``g <= q``), otherwise ``UsageError``. Shared
        structure: must be None or ``q * lag``.
    cov : array_like, optional
        Per-epoch covariances ``(T, q, q)``, variances ``(T, q)`` or None (identity), in the
        unit of ``w`` squared.
    kernel0 : KernelRepresentation or array_like, optional
        A starting kernel (e.g. the kernel of an overlapping window). When its misfit is
        lower than that of every automatic start it is the only start (a warm start);
        otherwise it competes with them. For the shared structure also a 1-D array
        ``[r_0 .. r_l]``; it should contain the fixed roots.
    tol : float
        Stop when an accepted step decreases the misfit by less than ``tol`` relative, or
        changes the chart coordinates by less than ``tol`` relative, or the predicted decrease
        of a Newton step is below ``tol / 10`` relative (default 1e-10).
    max_iter : int
        Limit on outer iterations per descent (default 200).
    structure : {"full", "shared"}
        ``"full"``: general kernel with ``g`` rows, chart ``R = [X -I]``.
        ``"shared"``: ``R(z) = r(z) I_q``, ``lag`` free parameters (fewer with fixed roots).
    fixed_roots : sequence of complex
        Shared structure: roots kept fixed in ``r(z) = prod (z - z_i) r~(z)``; ``(1.0,)``
        keeps constants in the behavior, which makes the fit translation invariant.
        Complex roots must come in conjugate pairs.
    rechart_threshold : float
        Re-chart when a chart coordinate exceeds this magnitude (default 10).
    hessian : {"auto", "exact", "gauss-newton"}
        Curvature used by the damped Newton steps: the exact Hessian of the misfit
        (quadratic convergence, robust far from the optimum) or the Gauss--Newton ``J^T J`` of
        the pseudo-Jacobian (cheaper per iteration). ``"auto"`` (default): exact for the
        shared structure, Gauss--Newton for the full one (measured faster on the anchor data).
    max_starts : int
        Descents from at most this many automatic starting kernels, lowest misfit first
        (default 3; see Notes). ``1`` keeps only the best start.
    restarts : bool
        Restart from mirrored and modal kernels after a descent (default True; see Notes).
        ``max_starts=1, restarts=False`` is a single descent from the best start, the
        cheapest setting for many short series.

    Returns
    -------
    StlsResult
        ``kernel``, ``w_hat`` ``(T, q)``, ``misfit``, ``iterations`` (of the descent that gave
        the result), ``n_evaluations`` (of all descents), ``status``, ...
        On ``INFEASIBLE`` (no starting kernel with a regular ``G Sigma G^T``) ``misfit`` is
        ``inf`` and ``w_hat`` a copy of ``w``.

    Raises
    ------
    UsageError
        Invalid arguments or an infeasible full-structure dimension.

    Notes
    -----
    See the module docstring for the descent. The misfit has local minima, so the result is
    the best of several descents. Starting kernels: ``kernel0``; for ``T >= 4000`` the
    kernel identified (recursively) on the leading ``T / 4`` samples; the WTLS kernel; for the
    full structure on shorter series the subspace kernel of a Hankel matrix with ``2(l+1)``
    block rows; for the shared structure the polynomial ``(z-1)^l`` (for a full square kernel it
    is tried only when every other start is singular). All are evaluated; when ``kernel0`` or the coarse
    kernel has the lowest misfit it is the only start, otherwise the ``max_starts`` best are
    descended. A descent that ends with poles outside the unit circle restarts from the
    kernel with those poles mirrored inside (:meth:`KernelRepresentation.mirrored`; the misfit
    is nearly invariant under the reflection, so the mirrored kernel starts in the basin a
    decaying mode belongs to). Only decreasing steps are accepted, so ``stls`` is never worse
    than ``wtls`` on the same data.

    References
    ----------
    I. Markovsky, K. Usevich, "Software for weighted structured low-rank approximation",
    J. Comput. Appl. Math. 256 (2014) 278-292.

    Examples
    --------
    A level circle, 0.1 rad per sample, satisfies ``(z-1)(z^2 - 2 cos(0.1) z + 1) w = 0``, a
    shared lag-3 kernel: the fit is exact and the poles lie at angles 0 and +-0.1.

    >>> import numpy as np
    >>> t = np.arange(30.0)
    >>> w = np.stack([np.cos(0.1 * t), np.sin(0.1 * t), np.full(30, 0.5)], axis=1)
    >>> res = stls(w, lag=3, structure="shared")
    >>> res.success, bool(res.misfit < 1e-20)
    (True, True)
    >>> sorted({round(abs(float(np.angle(z))), 6) for z in res.kernel.poles()})
    [0.0, 0.1]
    """
    arr, covariance, g, fixed = validate_problem(w, lag, order, cov, structure, fixed_roots)
    lag = int(lag)
    if not (isinstance(tol, (float, int)) and 0.0 < tol < 1.0):
        raise UsageError(f"tol: expected a number in (0, 1), received {tol!r}")
    if isinstance(max_iter, bool) or not isinstance(max_iter, (int, np.integer)) or max_iter < 0:
        raise UsageError(f"max_iter: expected a non-negative integer, received {max_iter!r}")
    if hessian not in ("auto", "exact", "gauss-newton"):
        raise UsageError(f"hessian: expected 'auto', 'exact' or 'gauss-newton', received {hessian!r}")
    if isinstance(max_starts, bool) or not isinstance(max_starts, (int, np.integer)) or max_starts < 1:
        raise UsageError(f"max_starts: expected a positive integer, received {max_starts!r}")
    if not isinstance(restarts, bool):
        raise UsageError(f"restarts: expected True or False, received {restarts!r}")
    if hessian == "auto":
        hessian = "exact" if structure == "shared" else "gauss-newton"
    n_t, q = arr.shape
    data_norm2 = covariance.weighted_norm2(arr)
    exact_level = (64.0 * np.finfo(float).eps) ** 2 * max(data_norm2, np.finfo(float).tiny)
    n_eval = 0

    coarse: KernelRepresentation | None = None
    if kernel0 is None and n_t >= COARSE_MIN_SAMPLES:
        n_sub = n_t // COARSE_FACTOR
        sub = stls(arr[:n_sub], lag, order, covariance.window(0, n_sub), tol=max(float(tol), COARSE_TOL),
                   max_iter=min(int(max_iter), COARSE_MAX_ITER), structure=structure, fixed_roots=fixed_roots,
                   rechart_threshold=rechart_threshold, hessian=hessian, max_starts=max_starts, restarts=restarts)
        n_eval += sub.n_evaluations
        if np.isfinite(sub.misfit):
            coarse = sub.kernel

    problem = InnerProblem(arr, covariance, lag)
    points: list[_Point] = []
    last_error = ""
    for origin, cand in _start_candidates(arr, lag, g, fixed, covariance, structure, kernel0, coarse):
        n_eval += 1
        try:
            points.append(_chart_point(problem, cand, structure, fixed, q, origin))
        except (SingularGramError, np.linalg.LinAlgError) as exc:
            last_error = str(exc)
    fallback = _fallback_start(lag, g, q, structure)
    if not points and fallback is not None:
        n_eval += 1
        try:
            points.append(_chart_point(problem, fallback[1], structure, fixed, q, fallback[0]))
        except (SingularGramError, np.linalg.LinAlgError) as exc:
            last_error = str(exc)
    if not points:
        ker = KernelRepresentation(np.zeros((lag + 1, g, q)))
        return StlsResult(ker, arr.copy(), float("inf"), 0, StlsStatus.INFEASIBLE,
                          f"{STATUS_MESSAGES[StlsStatus.INFEASIBLE]}: {last_error}", "stls", structure, n_eval, 0.0)
    points.sort(key=lambda p: p.state.misfit)
    warm = points[0].origin in ("kernel0", "coarse")
    queue = points[:1] if warm else points[:max_starts]

    best: _Descent | None = None
    for point in queue:
        run = _minimize(problem, point.chart, point.theta, point.state, fixed, q, tol, max_iter,
                        rechart_threshold, hessian, exact_level)
        n_eval += run.n_eval
        for _ in range(MIRROR_ROUNDS if restarts else 0):
            cand = _mirrored_start(run, structure, q)
            if cand is None:
                break
            n_eval += 1
            try:
                start = _chart_point(problem, cand, structure, fixed, q, "mirrored")
            except (SingularGramError, np.linalg.LinAlgError):
                break
            other = _minimize(problem, start.chart, start.theta, start.state, fixed, q, tol, max_iter,
                              rechart_threshold, hessian, exact_level)
            n_eval += other.n_eval
            if other.state.misfit >= run.state.misfit:
                break
            run = other
        if best is None or run.state.misfit < best.state.misfit:
            best = run
    assert best is not None
    if restarts and structure == "full" and g == q and n_t < COARSE_MIN_SAMPLES:
        # poles of the best fit with re-fitted output directions (one restart)
        cand = modal_kernel(arr, _final_kernel(best.chart, best.theta, q), covariance)
        if cand is not None:
            n_eval += 1
            try:
                start = _chart_point(problem, cand, structure, fixed, q, "modal")
            except (SingularGramError, np.linalg.LinAlgError):
                start = None
            if start is not None:
                other = _minimize(problem, start.chart, start.theta, start.state, fixed, q, tol, max_iter,
                                  rechart_threshold, hessian, exact_level)
                n_eval += other.n_eval
                if other.state.misfit < best.state.misfit:
                    best = other
    kernel = _final_kernel(best.chart, best.theta, q)
    return StlsResult(kernel, best.state.w_hat, best.state.misfit, best.iterations, best.status,
                      STATUS_MESSAGES[best.status], "stls", structure, n_eval, best.grad_norm)


def _mirrored_start(run: _Descent, structure: str, q: int) -> NDArray[np.float64] | None:
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


def _derivatives(
    problem: InnerProblem, chart: FullChart | SharedChart, theta: NDArray[np.float64], state: BandedGram,
    hessian: str,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64] | None]:
    """Half gradient ``J^T f``, half Hessian and (exact mode) Gauss--Newton matrix in chart coordinates.

    With ``lambda = Gamma^{-1} e``, ``u_k = (dG/dtheta_k)^T lambda`` and
    ``c_k = (dG/dtheta_k) w_hat - G Sigma u_k`` the exact half Hessian is
    ``a_k^T a_m - u_k^T Sigma u_m`` with ``a_k = L^{-1} c_k``; Gauss--Newton keeps ``J^T J``.
    """
    d_mat = chart.jacobian_rhs(state.w_hat)
    jac = solve_lower(state.chol, d_mat)
    grad = jac.T @ state.f
    gn_mat = jac.T @ jac
    if hessian == "gauss-newton":
        return grad, gn_mat, None
    basis = chart.basis_blocks()  # (n_p, l+1, g, q)
    n_p, n_blk, g, q = basis.shape
    lam = state.lam
    n = lam.shape[0]
    n_t = n + n_blk - 1
    big = (lam @ basis.transpose(2, 1, 3, 0).reshape(g, n_blk * q * n_p)).reshape(n, n_blk, q, n_p)
    u = np.zeros((n_t, q, n_p))
    for i in range(n_blk):
        u[i : i + n] += big[:, i]
    s = problem.cov.apply_batch(u)
    r_mat = chart.blocks(theta).transpose(1, 0, 2).reshape(g, n_blk * q)
    s_rows = hankel_rows(s.reshape(n_t, q * n_p), n_blk).reshape(n, n_blk * q, n_p)
    gs = r_mat @ s_rows  # (n, g, n_p): G Sigma u_k
    a = solve_lower(state.chol, d_mat - gs.reshape(n * g, n_p))
    hess = a.T @ a - u.reshape(n_t * q, n_p).T @ s.reshape(n_t * q, n_p)
    return grad, 0.5 * (hess + hess.T), gn_mat


def _cholesky_solve(a_mat: NDArray[np.float64], rhs: NDArray[np.float64]) -> NDArray[np.float64] | None:
    """``a_mat^{-1} rhs`` for a symmetric positive definite ``a_mat``; None when the Cholesky factorization fails."""
    fac, info = lapack.dpotrf(a_mat, lower=1)
    if info != 0:
        return None
    x, info = lapack.dpotrs(fac, rhs, lower=1)
    return x if info == 0 else None


def _minimize(
    problem: InnerProblem, chart: FullChart | SharedChart, theta: NDArray[np.float64], state: BandedGram,
    fixed: NDArray[np.float64], q: int, tol: float, max_iter: int, rechart_threshold: float, hessian: str,
    exact_level: float,
) -> _Descent:
    """Damped Newton / Levenberg--Marquardt descent from ``theta`` (only decreasing steps accepted).

    With the exact Hessian, an iteration where it is not positive definite (far from a
    minimum) takes the Gauss--Newton curvature instead.
    """
    status = StlsStatus.ITERATION_LIMIT
    iterations = 0
    n_eval = 0
    grad_norm = 0.0
    mu = MU_INITIAL
    nu = 2.0
    if chart.n_params == 0:
        status = StlsStatus.DIRECT
    while status == StlsStatus.ITERATION_LIMIT and iterations < max_iter:
        if state.misfit <= exact_level:
            status = StlsStatus.EXACT
            break
        grad, a_mat, gn_mat = _derivatives(problem, chart, theta, state, hessian)
        grad_norm = float(np.abs(grad).max())
        iterations += 1
        if grad_norm == 0.0:
            status = StlsStatus.CONVERGED
            break
        newton = _cholesky_solve(a_mat, grad)
        if newton is not None:  # Newton decrement: the predicted decrease of an undamped step
            if float(grad @ newton) <= 0.1 * tol * state.misfit:
                status = StlsStatus.CONVERGED
                break
        elif gn_mat is not None:
            a_mat = gn_mat
        diag = np.abs(a_mat.diagonal())
        diag = np.maximum(diag, 1e-12 * max(float(diag.max()), np.finfo(float).tiny))
        theta_norm = float(np.sqrt(theta @ theta))
        while True:
            damped = a_mat.copy()
            damped.flat[:: damped.shape[0] + 1] += mu * diag
            sol = _cholesky_solve(damped, grad)
            step = -sol if sol is not None else None
            finite = step is not None and bool(np.isfinite(step).all())
            predicted = float(-2.0 * grad @ step - step @ a_mat @ step) if finite and step is not None else -1.0
            trial: BandedGram | None = None
            if predicted > 0.0:
                try:
                    n_eval += 1
                    trial = problem.project(chart.blocks(theta + step))
                except SingularGramError:
                    trial = None
            if trial is not None and trial.misfit < state.misfit and step is not None:
                rho = (state.misfit - trial.misfit) / predicted
                mu *= max(1.0 / 10.0, 1.0 - (2.0 * rho - 1.0) ** 3)
                nu = 2.0
                decrease = state.misfit - trial.misfit
                theta = theta + step
                state = trial
                step_norm = float(np.sqrt(step @ step))
                small_step = step_norm <= tol * (float(np.sqrt(theta @ theta)) + tol)
                if (decrease <= tol * state.misfit and rho > 0.25) or small_step:
                    status = StlsStatus.CONVERGED
                elif chart.needs_rechart(theta, rechart_threshold):
                    chart, theta = _rechart(chart, theta, fixed, q)
                break
            mu = max(mu * nu, MU_REJECTED)
            nu *= 2.0
            if mu > 1e16 or (finite and step is not None
                             and float(np.sqrt(step @ step)) <= 1e-15 * (theta_norm + 1e-15)):
                status = StlsStatus.NO_FURTHER_DECREASE
                break
    if status == StlsStatus.ITERATION_LIMIT and state.misfit <= exact_level:
        status = StlsStatus.EXACT
    return _Descent(chart, theta, state, status, iterations, n_eval, grad_norm)


def _rechart(chart: FullChart | SharedChart, theta: NDArray[np.float64], fixed: NDArray[np.float64],
             q: int) -> tuple[FullChart | SharedChart, NDArray[np.float64]]:
    """Move to the chart whose identity block (or pinned coefficient) is best conditioned."""
    if isinstance(chart, SharedChart):
        rt = chart.r_tilde(theta)
        new_s = SharedChart(fixed, rt, q)
        return new_s, new_s.coordinates_tilde(rt)
    r_mat = chart.kernel(theta)
    new_f = FullChart(r_mat, q)
    if np.array_equal(new_f.ident, chart.ident):
        return chart, theta
    try:
        return new_f, new_f.coordinates(r_mat)
    except np.linalg.LinAlgError:  # pragma: no cover - pivoted QR picks a regular block
        return chart, theta


def _final_kernel(chart: FullChart | SharedChart, theta: NDArray[np.float64], q: int) -> KernelRepresentation:
    if isinstance(chart, SharedChart):
        r = chart.shared_r(theta)
        scale = r[-1] if abs(r[-1]) > 1e-8 * np.max(np.abs(r)) else np.linalg.norm(r)
        return KernelRepresentation.shared(r / scale, q)
    return KernelRepresentation(chart.kernel(theta), q=q).normalized()
