"""Epochs -> solutions: the single-epoch (snapshot) run of every method (no terminal I/O).

For every method the same Gauss-Newton iteration runs on all epochs at once (DESIGN.md
section 2): linearize the pseudoranges at the current position
(:func:`gnss_cli.gnss.range_model.linearize`), solve the linear step with the method, update,
until the step is below ``convergence_m``. Corrections (Klobuchar, Saastamoinen), the
elevation mask and the weights are evaluated at the current position once it is near the
Earth's surface (the first iterations from the Earth's centre use none of them, as in
RTKLIB). The DOPs come from each method's noise gain ``J J^T`` at the solution.

With ``robust = "huber" | "cauchy"`` the ls/wls fixes are M-estimates: from the converged plain
fix, Gauss-Newton again, each linear step solved by IRLS to settled weights
(:mod:`gnss_cli.solvers.robust`), so that at the fix ``sum_i psi(u_i) a_i / sigma_i = 0`` with
``u_i = r_i / sigma_i`` and ``sigma_i`` the a-priori sigma of :mod:`gnss_cli.gnss.range_model`
(wls; for ls ``sum_i sigma_i psi(u_i) a_i = 0``: equal weights, outliers down-weighted). The
scale is the a-priori sigma, not a residual scale such as the MAD: an epoch has 4-15 residuals
and a few degrees of freedom after the fit, too few for a stable scale estimate, and in urban
epochs half of them can be reflected signals (the MAD breaks down at 50 %); the a-priori sigma
is also the one the chi-square test uses. Then :func:`~gnss_cli.pipeline.integrity.monitor`
tests the final residuals; its FDE re-solves are robust too. The other methods take their one
step at the robust WLS fix with the a-priori weights.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from gnss_cli.config import ProcessingConfig
from gnss_cli.gnss.range_model import EARTH_SURFACE_BAND_M, Linearization, linearize, stls_row_cov, width_groups, wtls_column_scale
from gnss_cli.pipeline.integrity import merge_epochs, monitor, monitor_fixes, take_epochs
from gnss_cli.pipeline.nlos import monitor_without_nlos
from gnss_cli.pipeline.results import KEEPS_POSITION, EpochData, EpochStatus, MethodSolution, Progress, solver_epoch_status, as_wls_used
from gnss_cli.solvers import solve_batch
from gnss_cli.solvers.dop import dop_from_cov, tls_paper_cov
from gnss_cli.solvers.robust import IrlsResult, irls_batch

__all__ = ["solve_method", "solve_methods", "status_counts", "status_summary", "solver_options", "WEIGHTED_METHODS", "ITERATED_METHODS"]

F64 = NDArray[np.float64]

WEIGHTED_METHODS = frozenset({"wls", "wtls", "stls"})
"""Methods whose definition includes row weights: they get the configured pseudorange variances."""
ITERATED_METHODS = frozenset({"ls", "wls"})
"""Methods iterated to convergence; the others take one step at the converged WLS fix."""
_FLAGGED = (EpochStatus.INTEGRITY_FAIL.value, EpochStatus.GDOP_LIMIT.value, EpochStatus.HPL_LIMIT.value,
            EpochStatus.VPL_LIMIT.value, EpochStatus.UNTESTED.value, EpochStatus.NLOS_DEPENDENT.value)
_ITERATION_BLOCK = 1024  # epochs per stacked Gauss-Newton solve of LS/WLS


def solver_options(method: str, lin: Linearization, config: ProcessingConfig) -> dict[str, object]:
    """Keyword options of :func:`~gnss_cli.solvers.solve_batch` for ``method`` on ``lin``.

    Weighted methods get the inverse pseudorange variances; MTLS and STLS take the clock
    columns as exact; STLS gets the row covariance with the orbit error and WTLS the
    orbit column scale (``[stls] orbit_sigma_m``, ``[wtls] column_scaling``).
    """
    kwargs: dict[str, object] = {}
    if method in WEIGHTED_METHODS:
        kwargs["weights"] = 1.0 / lin.var_m2
    if method in ("mtls", "stls"):
        kwargs["exact_columns"] = list(range(3, lin.A.shape[-1]))
    if method == "stls":
        kwargs.pop("weights", None)
        kwargs["row_cov"] = stls_row_cov(lin, config.orbit_sigma_m)
    if method == "wtls" and config.wtls_column_scaling == "orbit":
        kwargs["column_scale"] = wtls_column_scale(lin, config.orbit_sigma_m)
    return kwargs


def solve_method(
    data: EpochData,
    method: str,
    config: ProcessingConfig,
    progress: Progress | None = None,
    linearization: MethodSolution | None = None,
) -> MethodSolution:
    """Solve every epoch with one method of the solver family.

    ``ls`` and ``wls`` iterate Gauss-Newton to convergence (DESIGN.md section 2). The other
    methods solve the linear system once, linearized at the converged WLS fix
    (``linearization``; computed when not given): iterating them with their own steps does
    not work on pseudorange data. TLS, DLS, MTLS and unscaled WTLS treat the unit-vector columns of
    ``A`` as being as noisy as the pseudoranges in metres, so ``sigma_min(A) < sigma_min([A q])``
    and the iteration overshoots without converging (measured on rtklib-0759: no epoch
    converged in 60 iterations); where the steps do vanish (TLS, MTLS, STLS) they vanish at
    the (W)LS point. One solve at a common linearization point is what tells the estimators
    apart, and it is the comparison the paper makes.

    Returns
    -------
    MethodSolution
        Failed epochs keep a row: NaN position and a status word.
    """
    if method not in ITERATED_METHODS:
        base = linearization if linearization is not None else solve_method(data, "wls", config, progress)
        return _solve_once(data, method, config, base)
    unconverged = config.integrity == "fde"  # FDE also tries the epochs a fault keeps from converging

    def fit(sub: EpochData, x0: F64 | None = None, b0: F64 | None = None, report: Progress | None = None) -> MethodSolution:
        sol = _gauss_newton(sub, method, config, report, x0, b0, keep_unconverged=unconverged)
        return _robust_refit(sub, method, config, sol, unconverged) if config.robust != "off" else sol

    first = fit(data, report=progress)
    if config.nlos.detector == "arcs" and config.integrity != "off":  # off: the plain fix, nothing excluded
        return monitor_without_nlos(data, first, fit, config)
    return monitor(data, first, config, fit)


def _robust_refit(data: EpochData, method: str, config: ProcessingConfig, sol: MethodSolution,
                  keep_unconverged: bool) -> MethodSolution:
    """The M-estimate (``config.robust``) of the epochs ``sol`` solved, by Gauss-Newton from
    their plain ls/wls fix, each linear step an IRLS solve to settled weights
    (:func:`~gnss_cli.solvers.robust.irls_batch`): its fixed point solves
    ``sum_i psi(u_i) a_i / sigma_i = 0``, ``u_i = (rho_i - rho_hat_i(x, b)) / sigma_i`` with the
    a-priori sigmas (wls; ls: ``sum_i sigma_i psi(u_i) a_i = 0``). ``iterations`` counts both runs."""
    tried = (EpochStatus.OK.value,) + ((EpochStatus.ITERATION_LIMIT.value,) if keep_unconverged else ())
    rows = np.flatnonzero(np.isin(sol.status, tried))
    if not rows.size:
        return sol
    clocks = sol.clocks_m
    sub = _gauss_newton(take_epochs(data, rows), method, config, None, sol.x_ecef_m[rows], clocks[rows],
                        keep_unconverged=keep_unconverged, robust=True)
    return merge_epochs(sol, rows, replace(sub, iterations=sub.iterations + sol.iterations[rows]))


def _gauss_newton(data: EpochData, method: str, config: ProcessingConfig, progress: Progress | None,
                  x0: F64 | None = None, b0: F64 | None = None, keep_unconverged: bool = False,
                  robust: bool = False) -> MethodSolution:
    """Iterate ``method`` (ls, wls) to convergence on every epoch, from ``x0, b0`` when given
    (else the header position, or the Earth's centre, and zero clocks). With ``keep_unconverged``
    the ``iteration_limit`` epochs keep their last iterate (for the integrity monitoring, which
    blanks them in the end). With ``robust`` every linear step is the M-estimate of
    ``config.robust`` and an epoch has converged when the step is small and its weights settled."""
    T = data.time_gps_s.size
    n = data.sv.size
    x = np.zeros((T, 3))
    if x0 is not None:
        x[:] = x0
    elif data.approx_ecef_m is not None:
        x[:] = data.approx_ecef_m
    k = len(data.systems)
    b = np.zeros((T, k)) if b0 is None else np.array(b0, dtype=np.float64)
    status = np.full(T, EpochStatus.ITERATION_LIMIT.value, dtype="<U24")
    iterations = np.zeros(T, dtype=np.int64)
    active = np.ones(T, dtype=bool)
    out = _Accumulator(T, n, k, method)
    for it in range(config.max_iterations):
        unconverged = np.flatnonzero(active)
        if unconverged.size == 0:
            break
        # epochs are independent: stacked by the width of their compact systems, in blocks of
        # _ITERATION_BLOCK that bound the memory of the stacked arrays
        for idx, width in width_groups(data.usable[unconverged], _ITERATION_BLOCK):
            rows = unconverged[idx]
            lin, res, n_used, enough, ok, step, irls = _linear_step(data, method, config, rows, x, b, width, robust)
            iterations[rows] = it + 1
            radius = np.linalg.norm(x[rows], axis=1)
            near = (radius > EARTH_SURFACE_BAND_M[0]) & (radius < EARTH_SURFACE_BAND_M[1])
            converged = ok & near & (np.linalg.norm(step, axis=1) < config.convergence_m)
            if irls is not None:
                converged &= irls.converged
            out.record(rows, lin, res, n_used, None if irls is None else irls.weights)
            _set_status(status, rows, converged, enough, ok, res.status)
            active[rows[converged | ~ok]] = False
        if progress is not None:
            progress(f"{method}: iteration {it + 1}", float(1.0 - active.mean()))
    keep = KEEPS_POSITION + ((EpochStatus.ITERATION_LIMIT.value,) if keep_unconverged else ())
    return out.finish(x, b, status, iterations, keep)


def _linear_step(data: EpochData, method: str, config: ProcessingConfig, rows: NDArray[np.intp], x: F64, b: F64,  # type: ignore[no-untyped-def]
                 width: int, robust: bool = False):
    """Linearize ``rows`` at ``(x, b)``, solve the step with ``method`` and apply it in place.

    The system holds the used satellites' rows only, ``width`` of them (``linearize(..., width)``,
    :func:`~gnss_cli.gnss.range_model.width_groups`): the solver's work grows with the rows, and an
    epoch uses a third of a multi-GNSS file's satellites.

    With ``robust`` the step is the IRLS M-estimate of the linear system; the satellite rows
    are reweighted, the clock constraint rows keep their weight. Its final weights then give
    one weighted solve, which supplies the gain, covariance and residuals.

    Returns the linearization, the solver result, satellites used, the epochs with enough
    satellites, the epochs solved, the step ``(len(rows), 3 + k)`` (m) and the IRLS result
    (None without ``robust``).
    """
    lin = linearize(data, rows, x[rows], b[rows], config, width=width)
    n_used, enough = _count_used(lin, len(data.systems), config)
    mask = lin.mask & enough[:, None]
    options = solver_options(method, lin, config)
    irls: IrlsResult | None = None
    if robust:
        satellite_rows = np.arange(lin.q.shape[1]) < lin.sat_rows
        irls = irls_batch(lin.A, lin.q, mask, np.sqrt(lin.var_m2), estimator=config.robust,
                                tuning=config.robust_huber_k if config.robust == "huber" else config.robust_cauchy_c,
                                weighted=method == "wls", reweight=np.broadcast_to(satellite_rows, mask.shape),
                                tolerance=config.robust_tolerance, max_iterations=config.robust_max_iterations)
        base = 1.0 / lin.var_m2 if method == "wls" else np.ones_like(lin.q)
        options = {"weights": base * np.where(mask, np.nan_to_num(irls.weights, nan=1.0), 1.0)}
    res = solve_batch("wls" if robust else method, lin.A, lin.q, mask, **options)
    ok = (res.status > 0) & enough
    step = np.where(ok[:, None], res.x, 0.0)
    x[rows] += step[:, :3]
    b[rows] += step[:, 3:]
    return lin, res, n_used, enough, ok, step, irls


def _set_status(status: NDArray[np.str_], rows: NDArray[np.intp], converged: NDArray[np.bool_],
                enough: NDArray[np.bool_], ok: NDArray[np.bool_], codes: NDArray[np.int8]) -> None:
    status[rows[converged]] = EpochStatus.OK.value
    status[rows[~enough]] = EpochStatus.TOO_FEW_SATELLITES.value
    solver_failed = ~ok & enough
    for r, code in zip(rows[solver_failed], codes[solver_failed]):
        status[r] = solver_epoch_status(int(code)).value


def _solve_once(data: EpochData, method: str, config: ProcessingConfig, base: MethodSolution) -> MethodSolution:
    """One step at the WLS fix, with the WLS epoch's satellites (its FDE exclusions apply).

    The WLS epochs with a fix (``ok`` and the flagged words) are solved. With ``integrity``
    ``check`` or ``fde`` every solved epoch is then tested at the method's own fix
    (:func:`~gnss_cli.pipeline.integrity.monitor_fixes`: chi-square test of its pseudorange
    residuals with the WLS weights, GDOP limit); with ``off`` it keeps the WLS epoch's word.
    """
    data = as_wls_used(data, base)
    T, n, k = data.time_gps_s.size, data.sv.size, len(data.systems)
    x = base.x_ecef_m.copy()
    b = base.clocks_m.copy()
    status = base.status.copy()
    flagged = np.isin(status, _FLAGGED)  # integrity_fail ... untested: solved, and keep the WLS word
    iterations = np.where((status == EpochStatus.OK) | flagged, 1, 0).astype(np.int64)
    out = _Accumulator(T, n, k, method)
    solved = np.flatnonzero((status == EpochStatus.OK) | flagged)
    for idx, width in width_groups(data.usable[solved], _ITERATION_BLOCK):
        rows = solved[idx]
        lin, res, n_used, enough, ok, _, _ = _linear_step(data, method, config, rows, x, b, width)
        out.record(rows, lin, res, n_used)
        _set_status(status, rows, ok, enough, ok, res.status)
    if config.integrity != "off":
        sol = monitor_fixes(data, out.finish(x, b, status, iterations), base.status, config)
        return replace(sol, excluded=base.excluded)
    status[flagged & (status == EpochStatus.OK)] = base.status[flagged & (status == EpochStatus.OK)]
    return replace(out.finish(x, b, status, iterations), excluded=base.excluded)


def _count_used(lin: Linearization, k: int, config: ProcessingConfig) -> tuple[NDArray[np.int64], NDArray[np.bool_]]:
    """Satellites used per epoch, and whether they determine position and every present clock."""
    n = lin.sat_rows
    n_used = lin.mask[:, :n].sum(axis=1)
    n_clocks = k - lin.mask[:, n:].sum(axis=1) if k > 1 else np.ones_like(n_used)
    return n_used, n_used >= np.maximum(config.min_satellites, 3 + n_clocks)


class _Accumulator:
    """Keeps the last linear-step quantities of every epoch and builds the MethodSolution."""

    def __init__(self, T: int, n: int, k: int, method: str) -> None:
        self.method = method
        self.n = n
        m = 3 + k
        self.cov = np.full((T, m, m), np.nan)
        self.gain_q = np.full((T, m, m), np.nan)
        self.paper_cov = np.full((T, m, m), np.nan) if method == "tls" else None
        self.residuals = np.full((T, n), np.nan)
        self.sigma = np.full((T, n), np.nan)
        self.robust_w = np.full((T, n), np.nan)
        self.n_sat = np.zeros(T, dtype=np.int64)
        self.rot = np.full((T, 3, 3), np.nan)
        self.present = np.zeros((T, k), dtype=bool)

    def record(self, rows: NDArray[np.intp], lin: Linearization, res, n_used: NDArray[np.int64],  # type: ignore[no-untyped-def]
               robust_w: F64 | None = None) -> None:
        self.cov[rows] = res.cov
        w_rows = lin.sat_rows
        gain = res.gain[:, :, :w_rows]  # satellites only: constraint rows are not geometry
        self.gain_q[rows] = gain @ np.swapaxes(gain, 1, 2)  # (matmul: several times faster than einsum)
        if self.paper_cov is not None and res.details is not None and hasattr(res.details, "sigma_min"):
            self.paper_cov[rows] = tls_paper_cov(lin.A, res.details.sigma_min, mask=lin.mask)
        sat = lin.mask[:, :w_rows]
        self.residuals[rows] = lin.scatter(np.where(sat, res.residuals[:, :w_rows], np.nan), self.n)
        self.sigma[rows] = lin.scatter(np.where(sat, np.sqrt(lin.var_m2[:, :w_rows]), np.nan), self.n)
        w = np.ones((rows.size, w_rows)) if robust_w is None else robust_w[:, :w_rows]
        self.robust_w[rows] = lin.scatter(np.where(sat, w, np.nan), self.n)
        self.n_sat[rows] = n_used
        self.rot[rows] = lin.rot
        k = self.present.shape[1]
        # with several systems, a set constraint row (after the n satellite rows) marks an absent system
        self.present[rows] = ~lin.mask[:, w_rows:] if k > 1 else True

    def finish(self, x: F64, b: F64, status: NDArray[np.str_], iterations: NDArray[np.int64],
               keep: tuple[str, ...] = KEEPS_POSITION) -> MethodSolution:
        bad = ~np.isin(status, keep)
        x = np.where(bad[:, None], np.nan, x)
        b = np.where(bad[:, None], np.nan, b)
        gain_q = np.where(bad[:, None, None], np.eye(self.gain_q.shape[-1]), self.gain_q)
        rot = np.where(bad[:, None, None], np.eye(3), self.rot)
        dop = dop_from_cov(gain_q, rot)
        gdop_paper = None
        if self.paper_cov is not None:
            gdop_paper = np.sqrt(np.clip(np.trace(self.paper_cov, axis1=1, axis2=2), 0.0, None))
            gdop_paper = np.where(bad, np.nan, gdop_paper)

        def masked(v: F64) -> F64:
            return np.where(bad, np.nan, v)

        k = self.present.shape[1]
        q_clk = self.gain_q[:, 3 + np.arange(k), 3 + np.arange(k)]
        tdops = np.where(self.present & ~bad[:, None], np.sqrt(np.clip(q_clk, 0.0, None)), np.nan)

        return MethodSolution(
            method=self.method,
            x_ecef_m=x,
            clocks_m=b,
            n_sat=self.n_sat,
            gdop=masked(dop.gdop),
            pdop=masked(dop.pdop),
            hdop=masked(dop.hdop),
            vdop=masked(dop.vdop),
            tdop=np.where(self.present[:, 0], masked(dop.tdop), np.nan),
            tdops=tdops,
            gdop_paper=gdop_paper,
            cov_m2=np.where(bad[:, None, None], np.nan, self.cov),
            status=status,
            iterations=iterations,
            residuals_m=np.where(bad[:, None], np.nan, self.residuals),
            sigma_m=np.where(bad[:, None], np.nan, self.sigma),
            robust_weights=np.where(bad[:, None], np.nan, self.robust_w),
        )


def solve_methods(data: EpochData, config: ProcessingConfig, progress: Progress | None = None) -> dict[str, MethodSolution]:
    """Every method of ``config.methods`` on ``data`` (the others linearized at the WLS fix)."""
    solutions: dict[str, MethodSolution] = {}
    base: MethodSolution | None = None
    for m in config.methods:
        if progress:
            progress(f"solving {m}", 0.0)
        if m not in ITERATED_METHODS and base is None:
            base = solutions.get("wls") or solve_method(data, "wls", config, progress)
        solutions[m] = solve_method(data, m, config, progress, linearization=base)
        if m == "wls":
            base = solutions[m]
    return solutions


def status_counts(solutions: dict[str, MethodSolution]) -> dict[str, dict[str, int]]:
    """Epochs per status word of every method."""
    out: dict[str, dict[str, int]] = {}
    for m, s in solutions.items():
        words, counts = np.unique(s.status, return_counts=True)
        out[m] = {str(w): int(c) for w, c in zip(words, counts)}
    return out


def status_summary(solutions: dict[str, MethodSolution] | dict[str, dict[str, int]]) -> str:
    """``method: N word, ...; ...`` (the message of a run without a solved epoch)."""
    counts = {m: (s if isinstance(s, dict) else status_counts({m: s})[m]) for m, s in solutions.items()}
    return "; ".join(f"{m}: " + ", ".join(f"{c} {w}" for w, c in sorted(wc.items())) for m, wc in counts.items())
