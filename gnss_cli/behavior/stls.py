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

from gnss_cli.behavior.banded import COND_MAX, InnerProblem, SingularGramError
from gnss_cli.behavior.covariance import EpochCovariance
from gnss_cli.behavior.descent import Descent, final_kernel, minimize
from gnss_cli.behavior.kernel import KernelRepresentation
from gnss_cli.behavior.projection import PROJECTION_MAX_SIZE, misfit, projection_matrix
from gnss_cli.behavior.result import STATUS_MESSAGES, StlsResult, StlsStatus
from gnss_cli.behavior.starts import StartPoint, chart_point, fallback_start, mirrored_start, modal_kernel, start_candidates
from gnss_cli.behavior.wtls import validate_problem
from gnss_cli.errors import UsageError

__all__ = ["misfit", "stls", "projection_matrix", "PROJECTION_MAX_SIZE"]

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
#: Restarts from mirrored kernels after one descent.
MIRROR_ROUNDS = 2


def stls(w: ArrayLike, lag: int, order: int | None = None, cov: ArrayLike | None = None,
         kernel0: KernelRepresentation | ArrayLike | None = None, tol: float = 1e-10, max_iter: int = 1000, *,
         structure: str = "full", fixed_roots: Sequence[complex] = (), rechart_threshold: float = 10.0,
         hessian: str = "auto", max_starts: int = 3, restarts: bool = True) -> StlsResult:
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
        Limit on outer iterations per descent (default 1000: over-parameterized full kernels
        converge linearly; lag-3 order-9 fits of noisy 150-sample arcs took up to 482).
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
    >>> import numpy as np
    >>> t = np.arange(30.0)  # a level circle: (z-1)(z^2 - 2 cos(0.1) z + 1) w = 0, shared lag 3
    >>> w = np.stack([np.cos(0.1 * t), np.sin(0.1 * t), np.full(30, 0.5)], axis=1)
    >>> res = stls(w, lag=3, structure="shared")
    >>> res.success, bool(res.misfit < 1e-20)
    (True, True)
    """
    arr, covariance, g, fixed = validate_problem(w, lag, order, cov, structure, fixed_roots)
    settings = _Settings.checked(int(lag), order, g, fixed, structure, fixed_roots, tol, max_iter,
                                 rechart_threshold, hessian, max_starts, restarts)
    return _identify(arr, covariance, settings, kernel0)


@dataclass(frozen=True, slots=True)
class _Settings:
    """The validated options of one :func:`stls` call (``g`` rows, ``fixed`` factor of ``r(z)``)."""

    lag: int
    order: int | None
    g: int
    fixed: NDArray[np.float64]
    structure: str
    fixed_roots: Sequence[complex]
    tol: float
    max_iter: int
    rechart_threshold: float
    hessian: str
    max_starts: int
    restarts: bool

    @classmethod
    def checked(cls, lag: int, order: int | None, g: int, fixed: NDArray[np.float64], structure: str,
                fixed_roots: Sequence[complex], tol: float, max_iter: int, rechart_threshold: float,
                hessian: str, max_starts: int, restarts: bool) -> _Settings:
        """Validate the descent options; ``hessian="auto"`` is resolved for the structure."""
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
        return cls(lag, order, g, fixed, structure, fixed_roots, tol, max_iter, rechart_threshold, hessian,
                   max_starts, restarts)


@dataclass(slots=True)
class _Search:
    """One identification in progress: the inner problem, the options and the evaluation count."""

    problem: InnerProblem
    settings: _Settings
    q: int
    exact_level: float
    n_eval: int = 0

    def start(self, cand: NDArray[np.float64], origin: str) -> StartPoint:
        """Chart and evaluate a starting kernel (counted even when its Gram matrix is singular)."""
        self.n_eval += 1
        s = self.settings
        return chart_point(self.problem, cand, s.structure, s.fixed, self.q, origin)

    def descend(self, point: StartPoint) -> Descent:
        """One damped Newton descent from ``point``."""
        s = self.settings
        run = minimize(self.problem, point.chart, point.theta, point.state, s.fixed, self.q, s.tol, s.max_iter,
                       s.rechart_threshold, s.hessian, self.exact_level)
        self.n_eval += run.n_eval
        return run


def _identify(arr: NDArray[np.float64], covariance: EpochCovariance, settings: _Settings,
              kernel0: KernelRepresentation | ArrayLike | None) -> StlsResult:
    """The body of :func:`stls` on validated arguments: starts, descents, restarts, best result."""
    n_t, q = arr.shape
    data_norm2 = covariance.weighted_norm2(arr)
    exact_level = (64.0 * np.finfo(float).eps) ** 2 * max(data_norm2, np.finfo(float).tiny)
    coarse, n_coarse = _coarse_kernel(arr, covariance, settings, kernel0)
    cond_max = COND_MAX if settings.structure == "full" else None  # see banded.COND_MAX
    search = _Search(InnerProblem(arr, covariance, settings.lag, cond_max), settings, q, exact_level, n_coarse)
    points, last_error = _start_points(search, arr, covariance, kernel0, coarse)
    if not points:
        ker = KernelRepresentation(np.zeros((settings.lag + 1, settings.g, q)))
        return StlsResult(ker, arr.copy(), float("inf"), 0, StlsStatus.INFEASIBLE,
                          f"{STATUS_MESSAGES[StlsStatus.INFEASIBLE]}: {last_error}", "stls", settings.structure,
                          search.n_eval, 0.0)
    points.sort(key=lambda p: p.state.misfit)
    warm = points[0].origin in ("kernel0", "coarse")
    queue = points[:1] if warm else points[: settings.max_starts]
    best: Descent | None = None
    for point in queue:
        run = _descend_with_mirrors(search, point)
        if best is None or run.state.misfit < best.state.misfit:
            best = run
    assert best is not None
    best = _modal_restart(search, arr, covariance, best)
    kernel = final_kernel(best.chart, best.theta, q)
    state, message = best.state, STATUS_MESSAGES[best.status]
    try:  # the misfit and trajectory of the kernel returned, not of its chart form
        state = search.problem.project(np.asarray(kernel.blocks))
    except SingularGramError as exc:
        message = f"{message}; the returned kernel's misfit could not be recomputed ({exc})"
    if best.status == StlsStatus.ITERATION_LIMIT:
        message = f"{message} ({settings.max_iter} iterations; raise max_iter or loosen tol)"
    return StlsResult(kernel, state.w_hat, state.misfit, best.iterations, best.status,
                      message, "stls", settings.structure, search.n_eval, best.grad_norm)


def _coarse_kernel(arr: NDArray[np.float64], covariance: EpochCovariance, settings: _Settings,
                   kernel0: KernelRepresentation | ArrayLike | None) -> tuple[KernelRepresentation | None, int]:
    """Kernel identified on the leading ``T // COARSE_FACTOR`` samples of a long series, and its evaluations."""
    n_t = arr.shape[0]
    if kernel0 is not None or n_t < COARSE_MIN_SAMPLES:
        return None, 0
    s = settings
    n_sub = n_t // COARSE_FACTOR
    sub = stls(arr[:n_sub], s.lag, s.order, covariance.window(0, n_sub), tol=max(float(s.tol), COARSE_TOL),
               max_iter=min(int(s.max_iter), COARSE_MAX_ITER), structure=s.structure, fixed_roots=s.fixed_roots,
               rechart_threshold=s.rechart_threshold, hessian=s.hessian, max_starts=s.max_starts,
               restarts=s.restarts)
    return (sub.kernel if np.isfinite(sub.misfit) else None), sub.n_evaluations


def _start_points(search: _Search, arr: NDArray[np.float64], covariance: EpochCovariance,
                  kernel0: KernelRepresentation | ArrayLike | None,
                  coarse: KernelRepresentation | None) -> tuple[list[StartPoint], str]:
    """Every starting kernel with a regular Gram matrix, and the last error of the singular ones."""
    s = search.settings
    points: list[StartPoint] = []
    last_error = ""
    for origin, cand in start_candidates(arr, s.lag, s.g, s.fixed, covariance, s.structure, kernel0, coarse):
        try:
            points.append(search.start(cand, origin))
        except (SingularGramError, np.linalg.LinAlgError) as exc:
            last_error = str(exc)
    fallback = fallback_start(s.lag, s.g, search.q, s.structure)
    if not points and fallback is not None:
        try:
            points.append(search.start(fallback[1], fallback[0]))
        except (SingularGramError, np.linalg.LinAlgError) as exc:
            last_error = str(exc)
    return points, last_error


def _descend_with_mirrors(search: _Search, point: StartPoint) -> Descent:
    """Descend from ``point``, then restart from mirrored unstable poles while that lowers the misfit."""
    run = search.descend(point)
    for _ in range(MIRROR_ROUNDS if search.settings.restarts else 0):
        cand = mirrored_start(run, search.settings.structure, search.q)
        if cand is None:
            break
        try:
            start = search.start(cand, "mirrored")
        except (SingularGramError, np.linalg.LinAlgError):
            break
        other = search.descend(start)
        if other.state.misfit >= run.state.misfit:
            break
        run = other
    return run


def _modal_restart(search: _Search, arr: NDArray[np.float64], covariance: EpochCovariance, best: Descent) -> Descent:
    """One restart from the poles of the best fit with re-fitted output directions (full square kernels)."""
    s, q = search.settings, search.q
    if not (s.restarts and s.structure == "full" and s.g == q and arr.shape[0] < COARSE_MIN_SAMPLES):
        return best
    cand = modal_kernel(arr, final_kernel(best.chart, best.theta, q), covariance)
    if cand is None:
        return best
    try:
        start = search.start(cand, "modal")
    except (SingularGramError, np.linalg.LinAlgError):
        return best
    other = search.descend(start)
    return other if other.state.misfit < best.state.misfit else best
