"""Integrity monitoring of the snapshot fixes: chi-square test, fault detection and exclusion
(FDE), protection levels by solution separation, GDOP and alert limits for ls/wls
(:func:`monitor`); the chi-square test and GDOP limit for the methods solved once at the WLS fix, tls, dls, mtls, stls and wtls
(:func:`monitor_fixes`: the test at each method's own fix, last paragraph).

At the converged fix of an epoch, with the used satellite rows ``A`` (``n x (3 + k)``), the
observed-minus-computed ``q``, the pseudorange variances ``sigma_i^2`` (``W = diag(1/sigma^2)``)
and the estimator's gain ``K = (A^T W_e A)^-1 A^T W_e`` (``W_e = W`` for wls, ``I`` for ls):

- residuals ``r = (I - A K) q``, test statistic ``T = sum_i r_i^2 / sigma_i^2`` (satellite rows;
  the clock constraint rows of absent systems are not observations), ``dof = n - (3 + k)``
  (``k``: clocks of the systems with satellites in the epoch);
- the test fails when ``T > chi2.isf(pfa, dof)`` (``integrity_pfa``); with ``dof = 0`` there is
  no redundancy and nothing to test: the epoch is ``untested`` (position kept, no protection
  level; RTKLIB's ``valsol`` lets it pass);
- w-test: ``w_i = |r_i| / sqrt(Qr_ii)``, ``Qr = (I - A K) Sigma (I - A K)^T`` the residual
  covariance. FDE excludes the satellite with the largest ``w_i`` and solves the epoch again
  (Gauss-Newton from the previous fix) while the test fails, ``dof >= fde_min_dof`` (default 3:
  two degrees of freedom remain to test the rest; classic RAIM FDE's 2 leaves one, which
  cannot tell a second fault) and fewer than ``max_exclusions`` satellites are out;
  several satellites per epoch may go, one per round.
  Each round works on the still-failing epochs only, stacked.

Solution separation (ARAIM-style, Blanch et al. 2015; the simplified protection level of the
ARAIM Airborne Algorithm Description Document): the fault hypotheses are each used satellite
and, with several systems in the epoch, each constellation of two or more satellites (all of
them out), where the remaining subset still solves (a subset that leaves a system without
satellites fixes that clock by a pseudo-observation). For hypothesis ``k`` the subset solution
``x_k`` (one linear step at the fix, :func:`separate_subsets`: the normal matrix less the left-out
rows' outer products), the separation ``Delta_k = x_k - x_0`` in ENU and its standard deviation
per axis ``sigma_ss,k,q`` from ``(K_k - K_0) Sigma (K_k - K_0)^T`` (``sigma_k^2 - sigma_0^2`` for
wls). With ``N_h`` hypotheses, prior fault probabilities ``p_k`` (``prior_fault_satellite``,
``prior_fault_constellation``), the risk ``IR = integrity_risk - P_nm`` left after the faults no
hypothesis covers (``P_nm``: two or more satellites at once, constellation faults with one
constellation, hypotheses whose subset cannot solve) and split ``1/4, 1/4, 1/2`` over E, N, U
(``integrity_pfa`` split the same way):

- threshold ``T_k,q = K_fa,q sigma_ss,k,q``, ``K_fa,q = Q^-1(pfa_q / (2 N_h))``; the separation test
  detects a fault when some ``|Delta_k,q| > T_k,q``;
- ``PL_q = max(K_ff,q sigma_0,q, max_k (T_k,q + K_md,k,q sigma_k,q))``,
  ``K_ff,q = Q^-1(IR_q / (2 (N_h + 1)))``, ``K_md,k,q = Q^-1(IR_q / (p_k (N_h + 1)))`` (at least 0);
  ``VPL = PL_U``, ``HPL = hypot(PL_E, PL_N)`` (each horizontal axis bounded at half the
  horizontal risk, combined conservatively); infinite when ``P_nm >= integrity_risk``.

Nominal biases (``nominal_bias_cn0_sigmas = beta``; the ARAIM ``b_nom`` of each satellite): a
reflected or attenuated signal's extra error lasts for seconds, so it is a bias as much as noise,
and several such signals at once are what single-fault hypotheses cannot cover. Each used row
gets a bias bound ``b_i = beta sqrt(c (10^(-C/N0_i/10) - 10^(-ref/10)))``, ``beta`` times the C/N0
part of its sigma (the SIGMA-epsilon term of ``[weights]``; 0 for strong signals, for files without
C/N0 and with ``cn0_model = "off"``), and every term of a level gains the largest error those
biases can make through its estimator, ``sum_i |S_q,i| b_i`` (``S = R K``, the ENU rows of the
full-set gain ``K_0`` or the subset's ``K_k``):
``PL_q = max(K_ff,q sigma_0,q + B_0,q, max_k (T_k,q + K_md,k,q sigma_k,q + B_k,q))``. The biases
change the levels only: weights, tests, exclusions and positions stay.

Several faulty satellites (``max_simultaneous_faults = j_max``, default 1: the above): with
satellite faults independent, each of probability ``p`` (``prior_fault_satellite``), the epoch
also gets every subset of 2 (and 3) of its ``n`` used satellites as a hypothesis, of prior
``p^j`` for ``j`` satellites (the classic single hypotheses keep ``p``), and the unmonitored
probability becomes the binomial tail ``P(more than j_max faulty) = sum_{j > j_max} C(n, j) p^j
(1-p)^(n-j)`` (:func:`unmonitored_probability`; ``j_max = 1`` gives the two-or-more term above).
As in ARAIM only the subsets whose prior matters are monitored: an epoch monitors order ``j + 1``
only while ``P(more than j)`` exceeds a tenth of ``integrity_risk`` (:func:`_monitored_order`),
and no pairs when even ``j_max`` leaves more than the risk (its levels are infinite; the single
hypotheses still test). A subset that empties a system fixes its clock, as the constellation
hypotheses do. Subsets are combinations of each epoch's used satellites: the epochs are grouped
by their count of used satellites and monitored order and solved in blocks of at most
``_SUBSET_BUDGET`` epoch-hypotheses (memory bounded; ~800 pairs for 40 satellites). A pair or
triple whose separation exceeds its threshold is a detection like any other: the epoch is
``integrity_fail`` (the separation test decides no exclusion; the chi-square test does).

A fault the test misses leaves the fault-free subset within ``K_md sigma_k`` of the truth and
the full fix within ``T_k`` of that subset: the error stays within the level except with the
allocated probability. The chi-square test decides the exclusions; an epoch whose separation
test still detects a fault after them is ``integrity_fail`` too (its levels do not hold).

With a robust estimator (``robust = "huber" | "cauchy"``, :func:`gnss_cli.pipeline.snapshot.solve_method`)
the fix is the M-estimate and ``K`` its gain at the final weights, ``W_e = diag(w_i / sigma_i^2)``
(``w_i`` the robust weight factors; ``diag(w_i)`` for ls). At the M-estimate ``A^T W_e q = 0``, so
``r = (I - A K) q = q``: the statistic is the sum of the squared final (reweighted) residuals over
the a-priori variances, ``T = sum_i r_i^2 / sigma_i^2``, with the same threshold and ``dof``. A
fault the robust fit down-weights keeps its large residual, so the test still fails and the
status stays honest; ``fde`` then excludes it (largest w-test, ``Q_r`` with the
same ``K``) and the epoch is solved again, robustly. The protection levels are those of the
linear estimator with the final weights (a first-order description of the M-estimate).

Epochs that did not converge (``iteration_limit``) are tested at their last iterate too: a
large fault can keep Gauss-Newton from converging (measured: a 250 m bias left a simulated
static fix oscillating across Saastamoinen's -100 m height cut-off), and excluding it lets the
epoch converge; ones that still do not converge keep the status with empty numbers.
Epochs that still fail get ``integrity_fail``; epochs that pass but have ``GDOP > max_gdop``
get ``gdop_limit``; epochs without redundancy ``untested``; epochs that pass with a horizontal
protection level above ``alert_limit_h_m`` get ``hpl_limit``, with a vertical one above
``alert_limit_v_m`` ``vpl_limit`` (:func:`final_status`). All keep their position. With
``integrity = "off"`` nothing is tested and the solver's word stays (``ok``: solved, not tested).

Levels of the multi-epoch methods (smoother, kf, stls with lag): their position ``x_hat`` at an
epoch comes from several epochs, and its errors last (a reflection for seconds, a bias over a
span), so a covariance of white measurement noise bounds nothing in a street (measured: the
smoother's own covariance gave a median HPL of 3.3 m against a 4.9 m error on simulated drives).
Their levels come instead from the same epoch's fault hypotheses and WLS subset solutions
(:func:`estimate_levels`): under hypothesis ``k`` the subset ``x_k`` leaves the faulty satellite
out at this epoch, whatever span its fault has, and ``|x_hat - truth| <= |x_hat - x_k| +
|x_k - truth|``, so

    ``PL_q = max(|x_hat_q - x_0,q| + K_ff,q sigma_0,q, max_k (|x_hat_q - x_k,q| + K_md,k,q sigma_k,q))``

with ``K_md,k,q = Q^-1(IR_q / (2 p_k (N_h + 1)))`` (the subset's error on either side) bounds the
error except with the allocated probability, for any ``x_hat``: a position pulled by other
epochs' faults is farther from every subset and gets a larger level. No time averaging is
credited: a multi-epoch level is never below ``K_ff sigma_0`` of the epoch's own fix. It uses the
actual separations ``|x_hat - x_k|`` where the WLS level uses their thresholds ``T_k`` (the WLS fix
has passed the separation test), so it can be the smaller of the two at the same epoch. An epoch
whose WLS fix has no levels (fewer than five satellites, no fix) gives the method's row none:
``untested``, never ``ok``.

The other methods take one step at the final WLS fix with the WLS epoch's satellites (after its
exclusions) and weights. Their fix gets the same test at its own estimate (:func:`check_fixes`):
``T = sum_i r_i^2 / sigma_i^2`` with ``r_i`` the observed minus modelled pseudorange at the
method's position and clocks (the physical model, not the method's own misfit: an
errors-in-variables estimator also moves ``A``), the WLS sigmas, ``dof = n - (3 + k)`` and the
same threshold; then the method's own GDOP against ``max_gdop``. Nothing is excluded for them
(they have the WLS set); ``dof = 0`` is ``untested`` as above (for a multi-epoch row, tested
with ``position_unknowns = 0``, ``dof = n - k``); for tls ... wtls ``hpl_limit`` and
``vpl_limit`` come from the WLS epoch (no protection levels of their own), for a multi-epoch
row from its own levels (above). With ``integrity = "off"`` they keep the WLS epoch's word.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, fields, replace
from functools import lru_cache
from itertools import combinations

import numpy as np
from numpy.typing import NDArray
from scipy.special import bdtrc, chdtri, ndtri

from gnss_cli.config import ProcessingConfig
from gnss_cli.gnss.range_model import ISB_CONSTRAINT_VAR_M2, Linearization, cn0_variance_m2, linearize, width_groups
from gnss_cli.pipeline.results import EPOCH_AXIS_FIELDS, EpochData, EpochStatus, MethodSolution

__all__ = ["IntegrityCheck", "check_epochs", "monitor", "take_epochs", "merge_epochs", "chi2_threshold",
           "FixCheck", "check_fixes", "monitor_fixes", "Separation", "separate_subsets", "separation_levels",
           "final_status", "unmonitored_probability", "estimate_levels"]

F64 = NDArray[np.float64]
Solver = Callable[[EpochData, F64, F64], MethodSolution]
"""Gauss-Newton on a subset of epochs: ``(epochs, x0 (t, 3), clocks0 (t, k)) -> solution``."""


@lru_cache(maxsize=256)
def chi2_threshold(dof: int, pfa: float) -> float:
    """The test's threshold ``chi2.isf(pfa, dof)``: the chi-square value exceeded with
    probability ``pfa`` (:func:`scipy.special.chdtri`); infinite for ``dof < 1`` (nothing to test).

    >>> round(chi2_threshold(1, 1e-3), 4)  # (3.2905 sigma)^2
    10.8276
    """
    if dof < 1:
        return float("inf")
    return float(chdtri(dof, pfa))


@dataclass
class IntegrityCheck:
    """The test of ``t`` epochs: statistic, degrees of freedom, pass, worst satellite, PLs."""

    stat: F64
    dof: NDArray[np.int64]
    passed: NDArray[np.bool_]
    worst: NDArray[np.intp]
    hpl_m: F64
    vpl_m: F64
    separated: NDArray[np.bool_]
    """The solution-separation test detected a fault (``passed``: the chi-square test only)."""


def check_epochs(data: EpochData, x: F64, clocks: F64, config: ProcessingConfig, weighted: bool,
                 robust_weights: F64 | None = None, width: int | None = None,
                 estimate: F64 | None = None) -> IntegrityCheck:
    """The chi-square test, w-test and protection levels of every epoch of ``data`` at the
    fixes ``x`` (``(t, 3)`` ECEF, m) and ``clocks`` (``(t, k)``, m); ``robust_weights``
    (``(t, n)``, the M-estimate's final weight factors) multiply the estimator's weights.
    ``width``: the systems in the compact layout of :func:`~gnss_cli.gnss.range_model.linearize`
    (the used satellites' rows only; default the dense layout). ``estimate`` (``(t, 3)`` ECEF, m):
    the protection levels are those of this other estimate of the epochs (a multi-epoch
    method's), from the subsets of the fixes ``x`` (:func:`separation_levels`)."""
    k = len(data.systems)
    rows = np.arange(data.time_gps_s.size)
    lin = linearize(data, rows, x, clocks, config, width=width)
    n = lin.sat_rows
    A, mask = lin.A, lin.mask
    var = np.where(mask, lin.var_m2, 1.0)
    w = np.where(mask, 1.0 / var, 0.0)
    we = w if weighted else mask.astype(np.float64)
    if robust_weights is not None:  # satellite rows only: the clock constraint rows keep theirs
        we = we.copy()
        rw = np.take_along_axis(robust_weights, np.maximum(lin.sv_index, 0), axis=1)
        we[:, :n] *= np.where(np.isfinite(rw), rw, 1.0)
    AtWe = np.swapaxes(A * we[..., None], 1, 2)  # (t, m, N)
    try:
        G = np.linalg.inv(AtWe @ A)
    except np.linalg.LinAlgError:  # a singular epoch (not converged): its test is NaN and fails
        G = np.linalg.pinv(AtWe @ A)
    K = G @ AtWe  # (t, m, N)
    q = np.where(mask, lin.q, 0.0)
    r = np.where(mask, q - np.einsum("tnm,tm->tn", A, np.einsum("tmn,tn->tm", K, q)), 0.0)
    h = np.einsum("tnm,tmn->tn", A, K)  # diag(A K)
    C = (K * (var * mask)[:, None, :]) @ np.swapaxes(K, 1, 2)  # K Sigma K^T (matmul: 5-20x faster than einsum)
    qr = var - 2.0 * h * var + np.sum((A @ C) * A, axis=2)
    sat = mask[:, :n]
    stat = np.sum(np.where(sat, r[:, :n] ** 2 * w[:, :n], 0.0), axis=1)
    n_clocks = k - mask[:, n:].sum(axis=1) if k > 1 else np.ones(rows.size, dtype=np.int64)
    dof = sat.sum(axis=1) - 3 - n_clocks
    thr = np.array([chi2_threshold(int(d), config.integrity_pfa) for d in dof])
    wtest = np.where(sat, np.abs(r[:, :n]) / np.sqrt(np.clip(qr[:, :n], 1e-12, None)), -1.0)
    tested = dof >= 1
    bias = nominal_bias_m(data, lin, config)
    hpl, vpl = np.full(rows.size, np.nan), np.full(rows.size, np.nan)
    detected = np.zeros(rows.size, dtype=bool)
    if tested.any():
        t = np.flatnonzero(tested)
        hpl[t], vpl[t], detected[t] = separation_levels(A[t], q[t], mask[t], var[t], np.where(mask, we, 0.0)[t],
                                                        lin.rot[t], n, config,
                                                        None if estimate is None else (estimate - x)[t],
                                                        None if bias is None else bias[t])
    # the satellite (column of data.sv) of the largest w-test; 0 when no satellite is used
    worst = np.where(sat.any(axis=1), np.take_along_axis(lin.sv_index, np.argmax(wtest, axis=1)[:, None], 1)[:, 0], 0)
    return IntegrityCheck(stat=stat, dof=dof, passed=stat <= thr, worst=worst, hpl_m=hpl, vpl_m=vpl, separated=detected)


def nominal_bias_m(data: EpochData, lin: Linearization, config: ProcessingConfig) -> F64 | None:
    """Each used row's nominal bias bound ``b_i`` (``(t, N)``, m) for the protection levels:
    ``nominal_bias_cn0_sigmas`` times the C/N0 part of its sigma,
    ``sqrt(cn0_c_m2hz (10^(-C/N0/10) - 10^(-cn0_ref_dbhz/10)))`` (module docstring, "Nominal
    biases"); 0 for clock constraint rows and signals without C/N0. None when the term is off
    (``nominal_bias_cn0_sigmas = 0``, ``cn0_model = "off"``, or a file without C/N0)."""
    beta = config.nominal_bias_cn0_sigmas
    w = config.weights
    if beta <= 0.0 or w.cn0_model != "sigma-epsilon" or data.snr_dbhz is None:
        return None
    n = lin.sat_rows
    cn0 = np.take_along_axis(data.snr_dbhz, np.maximum(lin.sv_index, 0), axis=1)
    b = beta * np.sqrt(cn0_variance_m2(cn0, w.cn0_c_m2hz, w.cn0_ref_dbhz))
    out = np.zeros(lin.mask.shape)
    out[:, :n] = np.where(lin.mask[:, :n], b, 0.0)
    return out


@dataclass
class Separation:
    """Subset solutions of ``t`` epochs under ``h`` fault hypotheses (:func:`separate_subsets`).

    Attributes
    ----------
    delta : ``(t, h, m)`` subset minus full-set solution (the unknowns' units).
    cov_delta : ``(t, h, m, m)`` covariance of ``delta``.
    cov_subset : ``(t, h, m, m)`` covariance of each subset solution.
    cov_full : ``(t, m, m)`` covariance of the full-set solution.
    solvable : ``(t, h)`` the hypothesis is active and its subset determines every unknown.
    full : ``(t, m)`` the full-set solution ``x_0`` (the correction to the linearization point).
    """

    delta: F64
    cov_delta: F64
    cov_subset: F64
    cov_full: F64
    solvable: NDArray[np.bool_]
    full: F64
    bias_full: F64 | None = None
    """``(t, 3)`` the largest ENU position error the rows' nominal biases make through the full-set
    estimator, ``sum_i |(R K_0)_q,i| b_i`` (with ``bias``), else None."""
    bias_subset: F64 | None = None
    """``(t, h, 3)`` the same through each subset's estimator ``K_k`` (with ``bias``)."""


def separate_subsets(A: F64, q: F64, we: F64, var: F64, removed: NDArray[np.bool_], fixed: F64,
                     fixed_weight: float, bias: tuple[F64, F64] | None = None) -> Separation:
    """Linear least-squares solutions of ``t`` stacked systems ``A x = q`` with each of ``h``
    row subsets left out, against the full-set solution, with their covariances.

    Parameters
    ----------
    A : ``(t, N, m)`` design rows (rows of weight 0 take no part).
    q : ``(t, N)`` right-hand sides.
    we : ``(t, N)`` the estimator's row weights (``x = (A^T W_e A)^-1 A^T W_e q``).
    var : ``(t, N)`` row variances (``Sigma``).
    removed : ``(t, h, N)`` the rows subset ``k`` leaves out.
    fixed : ``(t, h, m)`` 1 for the unknowns subset ``k`` fixes by a pseudo-observation
        ``x_j = 0`` of weight ``fixed_weight`` (and variance ``1 / fixed_weight``): an unknown its
        left-out rows alone determined (a receiver clock of a removed constellation).
    fixed_weight : weight of those pseudo-observations.
    bias : ``(b, R)``: each row's nominal bias bound ``b`` (``(t, N)``, m) and the ECEF -> ENU
        rotations ``R`` (``(t, 3, 3)``) for the nominal-bias terms of the levels
        (:func:`_bias_terms`); None: none.

    Returns
    -------
    Separation
        ``delta_k = x_k - x_0``; ``cov_subset_k = K_k Sigma K_k^T`` and
        ``cov_delta_k = (K_k - K_0) Sigma (K_k - K_0)^T`` with ``K = (A^T W_e A)^-1 A^T W_e``
        (for ``W_e = Sigma^-1``: ``cov_subset_k - cov_full``). A subset whose normal matrix is
        singular (scaled smallest eigenvalue below 1e-10) is not solvable; its numbers are NaN.

    Notes
    -----
    Most hypotheses leave out ``k`` satellite rows (one satellite, or a pair or triple of them) and
    fix nothing: for those the subset solution follows from the full set's in closed form
    (:func:`_separate_rows`, a rank-``k`` downdate), without forming or inverting a normal matrix
    per hypothesis. The others (constellations, a satellite alone in its system) are solved as a
    batch (:func:`_separate_batched`). The two give the same numbers (tests compare both with
    explicit least squares). With the single rows in closed form and blocks of at most
    ``_SUBSET_BUDGET`` epoch-hypotheses the levels of the ESBC day (2880 epochs, all systems) took a
    third of the time of forming every subset, and the run's peak memory fell from 505 to 320 MB
    (whole run: ``benchmarks/bench_full_run.py``); with the pairs in closed form too the default run
    of the tst2 canyon file (986 epochs, all systems, pairs monitored) takes about half its time
    (85.9 -> 45.6 s, the same load).
    """
    t, N, m = A.shape
    h = removed.shape[1]
    Aw = np.swapaxes(A * we[..., None], 1, 2)  # (t, m, N): A^T W_e
    G0 = np.linalg.inv(Aw @ A)
    V0 = (Aw * (we * var)[:, None, :]) @ A
    x0 = np.einsum("tab,tb->ta", G0, np.einsum("tan,tn->ta", Aw, q))
    P0 = G0 @ V0 @ G0
    delta, cov_delta = np.zeros((t, h, m)), np.zeros((t, h, m, m))
    cov_subset = np.broadcast_to(P0[:, None], (t, h, m, m)).copy()
    solvable = np.ones((t, h), dtype=bool)
    n_removed = removed.sum(axis=2)
    rows_only = ~fixed.any(axis=2)
    closed: list[tuple[NDArray[np.intp], NDArray[np.intp], NDArray[np.intp], F64, F64]] = []
    for k in np.unique(n_removed[rows_only & (n_removed > 0)]):
        ti, hi = np.nonzero(rows_only & (n_removed == k))
        rows = np.sort(np.argsort(~removed[ti, hi], axis=1, kind="stable")[:, :k], axis=1)  # (p, k)
        d, cd, ck, ok, U, C = _separate_rows(np.take_along_axis(A[ti], rows[..., None], axis=1),
                                             np.take_along_axis(q[ti], rows, axis=1),
                                             np.take_along_axis(we[ti], rows, axis=1),
                                             np.take_along_axis(var[ti], rows, axis=1), G0[ti], x0[ti], V0[ti], P0[ti])
        delta[ti, hi], cov_delta[ti, hi], cov_subset[ti, hi], solvable[ti, hi] = d, cd, ck, ok
        closed.append((ti, hi, rows, U, C))
    several = None
    ti, hi = np.nonzero(~rows_only)
    if ti.size:
        sub, Gk = _separate_batched(A[ti], q[ti], we[ti], var[ti], removed[ti, hi][:, None], fixed[ti, hi][:, None],
                                    fixed_weight)
        delta[ti, hi], cov_delta[ti, hi] = sub.delta[:, 0], sub.cov_delta[:, 0]
        cov_subset[ti, hi], solvable[ti, hi] = sub.cov_subset[:, 0], sub.solvable[:, 0]
        several = (ti, hi, Gk[:, 0])
    bad = ~solvable
    delta[bad], cov_delta[bad], cov_subset[bad] = np.nan, np.nan, np.nan
    bias_full = bias_subset = None
    if bias is not None:
        bias_full, bias_subset = _bias_terms(A, we, removed, G0, Aw, *bias, closed, several)
        bias_subset[bad] = np.nan
    return Separation(delta=delta, cov_delta=cov_delta, cov_subset=cov_subset, cov_full=P0, solvable=solvable,
                      full=x0, bias_full=bias_full, bias_subset=bias_subset)


def _bias_terms(A: F64, we: F64, removed: NDArray[np.bool_], G0: F64, Aw: F64, b: F64, rot: F64,
                closed: list[tuple[NDArray[np.intp], NDArray[np.intp], NDArray[np.intp], F64, F64]],
                several: tuple[NDArray[np.intp], NDArray[np.intp], F64] | None) -> tuple[F64, F64]:
    """The nominal-bias terms of the levels: ``sum_i |S_q,i| b_i`` with ``S = R K[:3]`` the ENU
    position rows of the full-set estimator ``K_0 = G0 A^T W_e`` (``(t, 3)``) and of each subset's
    ``K_k`` (``(t, h, 3)``) of :func:`separate_subsets`, from what it already computed.

    ``closed``: per number of left-out rows, the subsets ``(epochs, hypotheses, left-out rows, U, C)``
    of :func:`_separate_rows`, whose estimator is ``K_k = K_0 - U C L^T`` with
    ``L^T = E_r - A_r K_0`` (Woodbury), so ``S_k = S_0 - (R U) C L^T``; ``several``: the other
    subsets ``(epochs, hypotheses, N_k^-1)`` of :func:`_separate_batched`, ``K_k = N_k^-1 A^T W_e,k``.
    Only each epoch's rows with a bias and the position rows are formed (one named function for
    speed: with every estimator formed whole the terms cost the 24 h ESBC WLS run 45 % of its CPU
    time, and the whole run missed ``benchmarks/bench_full_run.py``'s target)."""
    t, h = removed.shape[:2]
    width = int((b > 0).sum(axis=1).max())
    cols = np.argsort(~(b > 0), axis=1, kind="stable")[:, :width]  # (t, c): each epoch's biased rows first
    bc = np.take_along_axis(b, cols, axis=1)
    K0 = np.einsum("tab,tbn->tan", G0, np.take_along_axis(Aw, cols[:, None, :], axis=2))  # (t, m, c)
    S0 = np.einsum("tij,tjn->tin", rot, K0[:, :3])  # (t, 3, c)
    full = np.einsum("tqn,tn->tq", np.abs(S0), bc)
    subset = np.broadcast_to(full[:, None], (t, h, 3)).copy()
    for ti, hi, rows, U, C in closed:
        a = np.take_along_axis(A[ti], rows[..., None], axis=1)  # (p, k, m)
        ell = (rows[:, :, None] == cols[ti][:, None, :]) - np.einsum("pan,pja->pjn", K0[ti], a)  # (p, k, c): L^T
        ruc = np.einsum("pij,pjk,pkl->pil", rot[ti], U[:, :3], C)  # (p, 3, k)
        subset[ti, hi] = np.einsum("pqn,pn->pq", np.abs(S0[ti] - ruc @ ell), bc[ti])
    if several is not None:
        ti, hi, Gk = several
        AWk = np.take_along_axis(Aw[ti] * ~removed[ti, hi][:, None, :], cols[ti][:, None, :], axis=2)
        Sk = np.einsum("pij,pjn->pin", rot[ti], (Gk @ AWk)[:, :3])
        subset[ti, hi] = np.einsum("pqn,pn->pq", np.abs(Sk), bc[ti])
    return full, subset


def _separate_rows(a: F64, q: F64, w: F64, var: F64, G0: F64, x0: F64, V0: F64, P0: F64
                   ) -> tuple[F64, F64, F64, NDArray[np.bool_], F64, F64]:
    """Subsets that leave out ``k`` rows each, in closed form: ``p`` cases of the rows ``a``
    (``(p, k, m)``), their right-hand sides ``q``, estimator weights ``w`` and variances ``var``
    (``(p, k)``), and the full set's ``G0 = N0^-1``, solution ``x0``, ``V0 = A^T W_e Sigma W_e A``
    and covariance ``P0``.

    With ``U = G0 a^T`` (``(m, k)``), ``S = a U`` and ``C = (W^-1 - S)^-1 = W^1/2 (I - W^1/2 S
    W^1/2)^-1 W^1/2`` (``W = diag(w)``; Woodbury: ``N_k^-1 = G0 + U C U^T``), the subset minus
    the full solution is ``Delta = -U C r`` with the rows' residuals ``r = q - a x0``;
    ``Delta = -U C L^T q`` for ``L^T = E_r - a K_0``, so ``cov(Delta) = U C (L^T Sigma L) C U^T``
    with ``L^T Sigma L = diag(var) - D S - S D + U^T V0 U`` (``D = diag(w var)``), and the subset's
    covariance ``P_k = P0 + cov(Delta) - (G C U^T + U C G^T)`` with ``G = U D - G0 V0 U``
    (``cov(x0, Delta) = -G C U^T``). For ``W_e = Sigma^-1``, ``G = 0`` and ``cov(Delta) = U C U^T
    = P_k - P0``. For ``k = 1`` this is Sherman-Morrison: ``c = w / (1 - w s)``. Rows the others
    cannot do without (smallest eigenvalue of ``I - W^1/2 S W^1/2`` below 1e-9) leave a singular
    subset: not solvable. Also returns ``U`` and ``C`` (for the subsets' estimators in
    :func:`_bias_terms`).
    """
    k = a.shape[1]
    U = G0 @ np.swapaxes(a, 1, 2)  # (p, m, k)
    S = a @ U
    S = 0.5 * (S + np.swapaxes(S, 1, 2))
    sw = np.sqrt(w)
    B = np.eye(k) - sw[:, :, None] * S * sw[:, None, :]
    solvable = np.linalg.eigvalsh(B)[:, 0] > 1e-9
    Binv = np.linalg.inv(np.where(solvable[:, None, None], B, np.eye(k)))
    C = np.where(solvable[:, None, None], sw[:, :, None] * Binv * sw[:, None, :], np.nan)
    r = q - np.einsum("pka,pa->pk", a, x0)
    UC = U @ C
    delta = -np.einsum("pak,pk->pa", UC, r)
    wv = w * var
    V0U = V0 @ U
    spread = (np.einsum("pk,kl->pkl", var, np.eye(k)) - wv[:, :, None] * S - S * wv[:, None, :]
              + np.swapaxes(U, 1, 2) @ V0U)
    cov_delta = UC @ spread @ np.swapaxes(UC, 1, 2)
    g = U * wv[:, None, :] - G0 @ V0U
    cross = g @ np.swapaxes(UC, 1, 2)  # G C U^T (C symmetric)
    cov_subset = P0 + cov_delta - (cross + np.swapaxes(cross, 1, 2))
    return delta, cov_delta, cov_subset, solvable, U, C


def _separate_batched(A: F64, q: F64, we: F64, var: F64, removed: NDArray[np.bool_], fixed: F64,
                      fixed_weight: float) -> tuple[Separation, F64]:
    """:func:`separate_subsets` by forming every subset's normal matrix
    ``N_k = A^T W_e,k A (+ fixed_weight e_j e_j^T)``, ``W_e,k`` the estimator weights with the
    left-out rows at 0, by batched ``(m, N) x (N, m)`` products, and inverting it (``m`` at most
    3 + clocks). Also returns the inverses ``N_k^-1`` ``(t, h, m, m)`` (identity where not solvable)."""
    t, N, m = A.shape
    keep = ~removed
    wv = we * we * var
    AT = np.swapaxes(A, 1, 2)  # (t, m, N)
    N0 = (AT * we[:, None, :]) @ A
    V0 = (AT * wv[:, None, :]) @ A
    b0 = np.einsum("tn,tna->ta", we * q, A)
    wk = we[:, None, :] * keep  # (t, h, N)
    E = fixed[..., :, None] * np.eye(m) * fixed_weight  # (t, h, m, m)
    Nk = (AT[:, None] * wk[:, :, None, :]) @ A[:, None] + E
    Xk = (AT[:, None] * (wv[:, None, :] * keep)[:, :, None, :]) @ A[:, None]  # K_k Sigma W_e A without the new rows
    Vk = Xk + E  # the pseudo-observations: weight^2 * variance = weight
    bk = np.einsum("thn,tna->tha", wk * q[:, None, :], A)
    scale = np.sqrt(np.clip(np.diagonal(Nk, axis1=2, axis2=3), 1e-300, None))
    unit = Nk / scale[..., :, None] / scale[..., None, :]
    solvable = (np.diagonal(Nk, axis1=2, axis2=3) > 0).all(axis=2) & np.isfinite(unit).all(axis=(2, 3))
    unit = np.where(solvable[..., None, None], unit, np.eye(m))
    solvable &= np.linalg.eigvalsh(unit)[..., 0] > 1e-10
    Nk = np.where(solvable[..., None, None], Nk, np.eye(m))
    G0 = np.linalg.inv(N0)
    Gk = np.linalg.inv(Nk)
    x0 = np.einsum("tab,tb->ta", G0, b0)
    xk = np.einsum("thab,thb->tha", Gk, bk)
    P0 = G0 @ V0 @ G0
    Pk = Gk @ Vk @ Gk
    Ck = Gk @ Xk @ G0[:, None]  # cross covariance of x_k and x_0
    cov_delta = Pk - Ck - np.swapaxes(Ck, 2, 3) + P0[:, None]
    bad = ~solvable
    delta = np.where(bad[..., None], np.nan, xk - x0[:, None])
    return Separation(delta=delta, cov_delta=np.where(bad[..., None, None], np.nan, cov_delta),
                      cov_subset=np.where(bad[..., None, None], np.nan, Pk), cov_full=P0, solvable=solvable,
                      full=x0), Gk


def _q_inverse(p: F64) -> F64:
    """The normal quantile exceeded with probability ``p``, ``Q^-1(p) = -ndtri(p)``."""
    return -ndtri(p)


def unmonitored_probability(n: NDArray[np.int64], p: float, order: NDArray[np.int64] | int) -> F64:
    """Probability that more than ``order`` of ``n`` satellites are faulty at once, each
    independently with probability ``p``: the binomial tail ``sum_{j > order} C(n, j) p^j (1-p)^(n-j)``
    (:func:`scipy.special.bdtrc`; 0 when ``order >= n``).

    >>> float(unmonitored_probability(np.array([2]), 0.1, 1)[0])  # both of two: 0.1^2
    0.01...
    """
    n = np.asarray(n, dtype=np.int64)
    order = np.broadcast_to(np.asarray(order, dtype=np.int64), n.shape)
    out = bdtrc(np.minimum(order, np.maximum(n - 1, 0)), n, p)
    return np.where(order >= n, 0.0, np.nan_to_num(out))


_SUBSET_BUDGET = 12_000
"""Epochs x hypotheses per stacked separation (:func:`separate_subsets` keeps ~15 ``(m, m)``
arrays per pair: ~100 MB with seven unknowns)."""
_MONITOR_SHARE = 0.1
"""Faults of ``j + 1`` satellites are monitored (``max_simultaneous_faults`` permitting) while
the probability of more than ``j`` exceeds this share of ``integrity_risk``."""


def _monitored_order(n: NDArray[np.int64], config: ProcessingConfig) -> NDArray[np.int64]:
    """Per epoch with ``n`` used satellites, the largest number of simultaneously faulty
    satellites its hypotheses cover (module docstring, "Several faulty satellites")."""
    p, risk = config.prior_fault_satellite, config.integrity_risk
    order = np.ones(n.shape, dtype=np.int64)
    for j in range(2, config.max_simultaneous_faults + 1):
        more = (order == j - 1) & (unmonitored_probability(n, p, j - 1) > _MONITOR_SHARE * risk) & (n > j)
        order = np.where(more, j, order)
    # beyond the largest order the levels are infinite anyway: the single hypotheses (detection) suffice
    hopeless = unmonitored_probability(n, p, order) >= risk
    return np.where(hopeless, 1, order)


def separation_levels(lin_A: F64, q: F64, mask: NDArray[np.bool_], var: F64, we: F64, rot: F64, n_sat: int,
                      config: ProcessingConfig, offset: F64 | None = None,
                      bias: F64 | None = None) -> tuple[F64, F64, NDArray[np.bool_]]:
    """ARAIM-style protection levels by solution separation, and the separation test, of
    ``t`` epochs linearized at their fixes (module docstring, "Solution separation").

    ``lin_A``, ``q``, ``mask``, ``var`` (``(t, N)``, m^2), ``we`` (the estimator's weights, 0
    for rows not used) and ``rot`` (ECEF -> ENU) of :func:`~gnss_cli.gnss.range_model.linearize`;
    ``n_sat`` satellite rows, then (several systems) one clock constraint row per system.
    Returns ``hpl_m``, ``vpl_m`` (``(t,)``; inf when the unmonitored faults alone exceed
    ``integrity_risk``) and ``detected`` (some ``|Delta_k,q| > T_k,q``).

    ``offset`` (``(t, 3)`` ECEF, m): the levels are those of another estimate ``x_hat`` of the
    same epochs, ``offset = x_hat - x_fix`` (module docstring, "Levels of the multi-epoch
    methods"): ``PL_q = max(|x_hat_q - x_0,q| + K_ff,q sigma_0,q, max_k (|x_hat_q - x_k,q| +
    K_md,k,q sigma_k,q))``.

    ``bias`` (``(t, N)``, m): each row's nominal bias bound ``b_i`` (module docstring, "Nominal
    biases"); every term of the level gains ``sum_i |S_q,i| b_i`` of its estimator ``S``.

    With ``max_simultaneous_faults > 1`` the epochs are grouped by their number of used
    satellites and monitored order (:func:`_monitored_order`) and solved in blocks of at most
    ``_SUBSET_BUDGET`` epoch-hypotheses; each subset of ``j`` satellites has the prior ``p^j``.
    """
    t, N, m = lin_A.shape
    sat = mask[:, :n_sat]
    n = sat.sum(axis=1)
    single = _single_hypotheses(lin_A, sat, N, config)
    order = _monitored_order(n, config) if config.max_simultaneous_faults > 1 else np.ones(t, dtype=np.int64)
    hpl, vpl, detected = np.empty(t), np.empty(t), np.zeros(t, dtype=bool)
    if (order == 1).all():  # in blocks of epochs: memory bounded by _SUBSET_BUDGET
        step = max(1, _SUBSET_BUDGET // max(single[0].shape[1], 1))
        for b in range(0, t, step):
            r = slice(b, b + step)
            hpl[r], vpl[r], detected[r] = _levels(lin_A[r], q[r], mask[r], var[r], we[r], rot[r], n_sat, config,
                                                  *(a[r] for a in single), order[r],
                                                  None if offset is None else offset[r],
                                                  None if bias is None else bias[r])
        return hpl, vpl, detected
    groups = np.unique(np.stack([n, order], axis=1), axis=0)
    for n_e, o in groups:
        rows = np.flatnonzero((n == n_e) & (order == o))
        combos = [np.array(list(combinations(range(int(n_e)), j)), dtype=np.intp).reshape(-1, j)
                  for j in range(2, int(o) + 1)]
        h = sum(c.shape[0] for c in combos) + single[0].shape[1]
        step = max(1, _SUBSET_BUDGET // h)
        for b in range(0, rows.size, step):
            r = rows[b:b + step]
            used = np.argsort(~sat[r], axis=1, kind="stable")[:, :n_e]  # (tb, n_e): rows of the used satellites
            parts = [tuple(a[r] for a in single)]
            for c in combos:
                parts.append(_multi_hypotheses(lin_A[r], sat[r], used[:, c], N, config))
            removed, fixed, candidate, prior = (np.concatenate(z, axis=1) for z in zip(*parts))
            hpl[r], vpl[r], detected[r] = _levels(lin_A[r], q[r], mask[r], var[r], we[r], rot[r], n_sat, config,
                                                  removed, fixed, candidate, prior, order[r],
                                                  None if offset is None else offset[r],
                                                  None if bias is None else bias[r])
    return hpl, vpl, detected


def _systems(lin_A: F64, sat: NDArray[np.bool_]) -> tuple[NDArray[np.intp], NDArray[np.bool_], NDArray[np.int64]]:
    """The clock column of each satellite row, the members ``(t, k, n)`` of each system, their counts."""
    k = lin_A.shape[2] - 3
    sysid = np.argmax(lin_A[:, :sat.shape[1], 3:], axis=2)
    members = sat[:, None, :] & (sysid[:, None, :] == np.arange(k)[None, :, None])
    return sysid, members, members.sum(axis=2)


def _single_hypotheses(lin_A: F64, sat: NDArray[np.bool_], N: int, config: ProcessingConfig) -> tuple[
        NDArray[np.bool_], F64, NDArray[np.bool_], F64]:
    """Each used satellite and (several systems) each constellation: ``removed`` ``(t, h, N)``,
    ``fixed`` ``(t, h, m)``, ``candidate`` ``(t, h)`` and ``prior`` ``(t, h)``."""
    t, n_sat = sat.shape
    m = lin_A.shape[2]
    k = m - 3
    sysid, members, count = _systems(lin_A, sat)
    h_sat = np.zeros((t, n_sat, N), dtype=bool)
    h_sat[:, np.arange(n_sat), np.arange(n_sat)] = sat
    fix_sat = np.zeros((t, n_sat, m))
    alone = sat & (np.take_along_axis(count, sysid, axis=1) == 1) & (k > 1)
    fix_sat[np.nonzero(alone)[0], np.nonzero(alone)[1], 3 + sysid[alone]] = 1.0
    p_sat, p_con = config.prior_fault_satellite, config.prior_fault_constellation
    if k > 1:  # a constellation of two or more satellites, with another constellation present
        h_con = np.zeros((t, k, N), dtype=bool)
        h_con[:, :, :n_sat] = members
        con = (count >= 2) & ((count > 0).sum(axis=1) >= 2)[:, None]
        removed = np.concatenate([h_sat, h_con & con[..., None]], axis=1)
        fixed = np.concatenate([fix_sat, np.broadcast_to(np.eye(m)[3:], (t, k, m)) * con[..., None]], axis=1)
        candidate = np.concatenate([sat, count >= 2], axis=1)
        prior = np.concatenate([np.full(n_sat, p_sat), np.full(k, p_con)])
    else:  # one constellation: its own fault cannot be told from the others'
        removed, fixed, candidate, prior = h_sat, fix_sat, sat, np.full(n_sat, p_sat)
    return removed, fixed, candidate, np.broadcast_to(prior, candidate.shape)


def _multi_hypotheses(lin_A: F64, sat: NDArray[np.bool_], rows: NDArray[np.intp], N: int,
                      config: ProcessingConfig) -> tuple[NDArray[np.bool_], F64, NDArray[np.bool_], F64]:
    """The subsets ``rows`` ``(t, c, j)`` of ``j`` satellite rows each, as :func:`_single_hypotheses`
    returns them; a system all of whose satellites are out has its clock fixed, prior ``p^j``."""
    t, c, j = rows.shape
    m = lin_A.shape[2]
    k = m - 3
    removed = np.zeros((t, c, N), dtype=bool)
    for col in range(j):
        removed[np.arange(t)[:, None], np.arange(c)[None, :], rows[..., col]] = True
    fixed = np.zeros((t, c, m))
    if k > 1:
        _, members, count = _systems(lin_A, sat)
        out = np.einsum("thn,tkn->thk", removed[..., :sat.shape[1]].astype(np.int64), members.astype(np.int64))
        fixed[..., 3:] = ((out == count[:, None, :]) & (count[:, None, :] > 0)).astype(np.float64)
    prior = np.full((t, c), config.prior_fault_satellite ** j)
    return removed, fixed, np.ones((t, c), dtype=bool), prior


def _enu_variances(rot: F64, cov: F64) -> F64:
    """East, north and up variances ``(t, h, 3)`` of ECEF position covariances ``cov``
    ``(t, h, 3, 3)``: the diagonal of ``R C R^T`` for the rotations ``rot`` ``(t, 3, 3)``."""
    R = rot[:, None]
    return np.sum((R @ cov) * R, axis=3)


def _levels(lin_A: F64, q: F64, mask: NDArray[np.bool_], var: F64, we: F64, rot: F64, n_sat: int,
            config: ProcessingConfig, removed: NDArray[np.bool_], fixed: F64, candidate: NDArray[np.bool_],
            prior: F64, order: NDArray[np.int64], offset: F64 | None = None,
            bias: F64 | None = None) -> tuple[F64, F64, NDArray[np.bool_]]:
    """The levels and the separation test of ``t`` epochs under the given hypotheses, the
    satellite faults of more than ``order`` satellites unmonitored; with ``offset`` (``(t, 3)``
    ECEF, m: another estimate minus the linearization point) the levels of that estimate
    (:func:`separation_levels`); ``bias`` (``(t, N)``, m): each row's nominal bias bound."""
    t, N, m = lin_A.shape
    k = m - 3
    sat = mask[:, :n_sat]
    unseen_constellation = config.prior_fault_constellation if k == 1 else 0.0
    biased = bias is not None and bool((bias > 0).any())
    sep = separate_subsets(lin_A, np.where(mask, q, 0.0), we, var, removed, fixed, 1.0 / ISB_CONSTRAINT_VAR_M2,
                           bias=(bias, rot) if biased and bias is not None else None)
    active = candidate & sep.solvable
    n_h = active.sum(axis=1)
    n = sat.sum(axis=1)
    # faults no hypothesis covers: more than `order` satellites at once, and the unsolvable hypotheses
    multiple = unmonitored_probability(n, config.prior_fault_satellite, order)
    budget = config.integrity_risk - multiple - unseen_constellation - np.sum(np.where(candidate & ~active, prior, 0.0), axis=1)
    # E, N, U: half the risk and the false-alert probability vertically, a quarter to each horizontal axis
    share = np.array([0.25, 0.25, 0.5])
    ir = np.clip(budget, 1e-300, None)[:, None] * share  # (t, 3)
    k_ff = _q_inverse(ir / (2.0 * (n_h + 1))[:, None])
    k_fa = _q_inverse(config.integrity_pfa * share / (2.0 * np.maximum(n_h, 1))[:, None])  # (t, 3)
    k_md = _q_inverse(np.minimum(0.5, ir[:, None, :] / (prior[:, :, None] * (n_h + 1)[:, None, None])))
    pos = slice(0, 3)
    var_d = _enu_variances(rot, sep.cov_delta[..., pos, pos])
    var_k = _enu_variances(rot, sep.cov_subset[..., pos, pos])
    var_0 = _enu_variances(rot, sep.cov_full[:, None, pos, pos])[:, 0]
    d_enu = np.einsum("tij,thj->thi", rot, sep.delta[..., pos])
    thr = k_fa[:, None, :] * np.sqrt(np.clip(var_d, 0.0, None))
    detected = (active[..., None] & (np.abs(d_enu) > thr)).any(axis=(1, 2))
    b_0, b_k = np.zeros((t, 3)), np.zeros((t, 1, 3))
    if sep.bias_full is not None and sep.bias_subset is not None:  # per axis: sum_i |S_q,i| b_i
        b_0, b_k = sep.bias_full, sep.bias_subset
    if offset is None:  # the full-set fix: its separation from each subset is within the threshold
        per_k = np.where(active[..., None], thr + k_md * np.sqrt(np.clip(var_k, 0.0, None)) + b_k, 0.0)
        pl = np.maximum(k_ff * np.sqrt(var_0) + b_0, per_k.max(axis=1))  # (t, 3)
    else:  # another estimate: its actual distance from the full set and from each subset
        d_est = np.einsum("tij,tj->ti", rot, offset - sep.full[:, pos])  # estimate - full-set fix, ENU
        gap = np.abs(d_est[:, None, :] - d_enu)
        # |x_k - truth| > K sigma_k on either side: twice the one-sided tail of the threshold form
        k_two = _q_inverse(np.minimum(0.5, ir[:, None, :] / (2.0 * prior[:, :, None] * (n_h + 1)[:, None, None])))
        per_k = np.where(active[..., None], gap + k_two * np.sqrt(np.clip(var_k, 0.0, None)) + b_k, 0.0)
        pl = np.maximum(np.abs(d_est) + k_ff * np.sqrt(var_0) + b_0, per_k.max(axis=1))
    pl = np.where((budget > 0)[:, None], pl, np.inf)
    return np.hypot(pl[:, 0], pl[:, 1]), pl[:, 2], detected


def take_epochs(data: EpochData, rows: NDArray[np.intp], excluded: NDArray[np.bool_] | None = None) -> EpochData:
    """The epochs ``rows`` of ``data``; satellites ``excluded`` (``(T, n)``) are not usable."""
    parts = {f: getattr(data, f)[rows] for f in EPOCH_AXIS_FIELDS if getattr(data, f) is not None}
    if excluded is not None:
        parts["usable"] = parts["usable"] & ~excluded[rows]
    return replace(data, **parts)


def merge_epochs(sol: MethodSolution, rows: NDArray[np.intp], sub: MethodSolution) -> MethodSolution:
    """``sol`` with the epochs ``rows`` replaced by ``sub``'s (every per-epoch array)."""
    parts = {}
    for f in fields(MethodSolution):
        full, part = getattr(sol, f.name), getattr(sub, f.name)
        if isinstance(full, np.ndarray) and isinstance(part, np.ndarray):
            full = full.copy()
            full[rows] = part
            parts[f.name] = full
    return replace(sol, **parts)


_BLOCK = 1024  # epochs per stacked test (bounds the memory of the (t, n, 3 + k) arrays)


def _check_blocks(data: EpochData, sol: MethodSolution, rows: NDArray[np.intp], excluded: NDArray[np.bool_],
                  config: ProcessingConfig, weighted: bool, estimate: F64 | None = None) -> IntegrityCheck:
    """:func:`check_epochs` of the epochs ``rows`` (without the ``excluded`` satellites), by the
    width of their compact systems (:func:`~gnss_cli.gnss.range_model.width_groups`), in blocks;
    ``estimate`` (``(T, 3)``): the levels of that estimate instead of ``sol``'s."""
    clocks = sol.clocks_m
    rw = sol.robust_weights if config.robust != "off" else None
    out: dict[str, NDArray[np.generic]] = {}
    for idx, width in width_groups(data.usable[rows] & ~excluded[rows], _BLOCK):
        r = rows[idx]
        part = check_epochs(take_epochs(data, r, excluded), sol.x_ecef_m[r], clocks[r], config, weighted,
                            None if rw is None else rw[r], width, None if estimate is None else estimate[r])
        for f in fields(IntegrityCheck):
            value = getattr(part, f.name)
            if f.name not in out:
                out[f.name] = np.empty(rows.shape + value.shape[1:], dtype=value.dtype)
            out[f.name][idx] = value
    return IntegrityCheck(**out)  # type: ignore[arg-type]


def _blank(sol: MethodSolution, rows: NDArray[np.bool_]) -> MethodSolution:
    """``sol`` with the float numbers of ``rows`` (epochs that did not converge) set to NaN."""
    if not rows.any():
        return sol
    parts = {}
    for f in fields(MethodSolution):
        value = getattr(sol, f.name)
        if isinstance(value, np.ndarray) and value.dtype.kind == "f" and value.shape[0] == rows.size:
            value = value.copy()
            value[rows] = np.nan
            parts[f.name] = value
    return replace(sol, **parts)


def monitor(data: EpochData, sol: MethodSolution, config: ProcessingConfig, solver: Solver) -> MethodSolution:
    """Test the ``ok`` epochs of ``sol``; with ``integrity = "fde"`` exclude and re-solve
    (module docstring). Returns the solution with statuses, exclusions, statistic and PLs."""
    T, n = data.time_gps_s.size, data.sv.size
    weighted = sol.method != "ls"
    excluded = np.zeros((T, n), dtype=bool)
    stat, hpl, vpl = np.full(T, np.nan), np.full(T, np.nan), np.full(T, np.nan)
    failed = np.zeros(T, dtype=bool)
    dof = np.zeros(T, dtype=np.int64)
    tried = (EpochStatus.OK.value, EpochStatus.ITERATION_LIMIT.value)  # (iteration_limit: kept by "fde" only)
    rows = np.flatnonzero(np.isin(sol.status, tried)) if config.integrity != "off" else np.zeros(0, dtype=np.intp)
    while rows.size:
        chk = _check_blocks(data, sol, rows, excluded, config, weighted)
        stat[rows], hpl[rows], vpl[rows], dof[rows] = chk.stat, chk.hpl_m, chk.vpl_m, chk.dof
        failed[rows] = ~chk.passed | chk.separated  # exclusion on the chi-square test alone (below)
        if config.integrity != "fde":
            break
        retry = ~chk.passed & (chk.dof >= config.fde_min_dof) & (excluded[rows].sum(axis=1) < config.max_exclusions)
        rows, worst = rows[retry], chk.worst[retry]
        if not rows.size:
            break
        excluded[rows, worst] = True
        clocks = sol.clocks_m
        sub = solver(take_epochs(data, rows, excluded), sol.x_ecef_m[rows], clocks[rows])
        sol = merge_epochs(sol, rows, sub)
        rows = rows[np.isin(sub.status, tried)]
    unconverged = sol.status == EpochStatus.ITERATION_LIMIT
    sol = _blank(sol, unconverged)
    stat[unconverged], hpl[unconverged], vpl[unconverged] = np.nan, np.nan, np.nan
    if config.integrity == "off":
        return replace(sol, excluded=excluded, test_stat=stat, hpl_m=hpl, vpl_m=vpl)
    status = final_status(sol.status, failed, dof, sol.gdop, hpl, vpl, config)
    return replace(sol, status=status, excluded=excluded, test_stat=stat, hpl_m=hpl, vpl_m=vpl)


def final_status(status: NDArray[np.str_], failed: NDArray[np.bool_], dof: NDArray[np.int64], gdop: F64,
                 hpl_m: F64, vpl_m: F64, config: ProcessingConfig) -> NDArray[np.str_]:
    """The words of the ``ok`` epochs of ``status`` after their test, in this order:
    ``integrity_fail`` (``failed``), ``gdop_limit`` (``gdop > max_gdop``, also NaN), ``untested``
    (``dof < 1``: no redundancy, no test, no protection level; or an infinite level: the faults
    no hypothesis covers exceed the integrity risk, nothing is protected), ``hpl_limit``
    (``hpl_m > alert_limit_h_m``, or no HPL under a finite limit), ``vpl_limit`` (the same
    vertically); the rest stays ``ok``. Every other word is kept."""
    out = status.copy()
    ok = status == EpochStatus.OK
    wide = ~(gdop <= config.max_gdop)
    untested = (dof < 1) | np.isinf(hpl_m) | np.isinf(vpl_m)
    over_h = ~(hpl_m <= config.alert_limit_h_m)  # NaN (no PL) is over any limit but inf
    over_v = ~(vpl_m <= config.alert_limit_v_m)
    over_h &= np.isfinite(config.alert_limit_h_m) | ~np.isnan(hpl_m)
    over_v &= np.isfinite(config.alert_limit_v_m) | ~np.isnan(vpl_m)
    out[ok & untested] = EpochStatus.UNTESTED.value
    out[ok & ~untested & over_v] = EpochStatus.VPL_LIMIT.value
    out[ok & ~untested & over_h] = EpochStatus.HPL_LIMIT.value
    out[ok & wide] = EpochStatus.GDOP_LIMIT.value
    out[ok & failed] = EpochStatus.INTEGRITY_FAIL.value
    return out


@dataclass
class FixCheck:
    """The residual test of given fixes of ``t`` epochs: statistic, degrees of freedom, pass,
    and the pseudorange residuals ``(t, n)`` (m, NaN for satellites not used)."""

    stat: F64
    dof: NDArray[np.int64]
    passed: NDArray[np.bool_]
    residuals_m: F64


def check_fixes(data: EpochData, x: F64, clocks: F64, sigma_m: F64, config: ProcessingConfig,
                position_unknowns: int = 3) -> FixCheck:
    """The chi-square test of fixes that were not fitted by this test (tls, dls, mtls, stls, wtls).

    At each fix ``x`` (``(t, 3)`` ECEF, m) and ``clocks`` (``(t, k)``, m) the residuals are those
    of the physical model, observed minus modelled pseudorange ``r_i = rho_i - rho_hat_i(x, clocks)``
    (:func:`~gnss_cli.gnss.range_model.linearize`: Sagnac, ionosphere, troposphere at the fix), for
    the satellites the method used: those with a finite ``sigma_m`` (``(t, n)``, m, the a-priori
    sigmas of the WLS weights, ``W = diag(1/sigma^2)``). The satellite set is kept as it is (no
    elevation mask at the fix: the mask chose it at the linearization point). Statistic
    ``T = r^T W r``, ``dof = n - (3 + k)``, threshold :func:`chi2_threshold` (``integrity_pfa``),
    as :func:`check_epochs` does for ls/wls, where ``r`` is the fit's own residual.
    ``position_unknowns = 0`` for a position fixed by several epochs (a multi-epoch method: its
    epoch's pseudoranges did not fit the position alone, so at the truth ``T`` is chi-square with
    ``n - k`` degrees of freedom, not ``n - 3 - k``; measured on simulated flights with matched
    noise, ``n - 3 - k`` gave 0.2-0.5 % false alarms instead of 0.1 %).

    An errors-in-variables estimator (TLS, DLS, MTLS) also perturbs the geometry ``A`` and
    minimizes its own misfit; that misfit is not tested here. The test is on what the fix
    predicts for the pseudoranges: a fix far from the truth leaves large pseudorange residuals
    whatever its own misfit was. At a common linearization point WLS minimizes ``r^T W r`` of
    the linear model, so its statistic is (to first order) a lower bound of every other
    method's with the same satellites and weights.
    """
    T, n = x.shape[0], data.sv.size
    used = np.isfinite(sigma_m)
    unmasked = replace(config, elevation_mask_deg=-90.0)
    stat, resid = np.full(T, np.nan), np.full((T, n), np.nan)
    dof = np.zeros(T, dtype=np.int64)
    for idx, width in width_groups(used, _BLOCK):
        sub = replace(take_epochs(data, idx), usable=used[idx])
        lin = linearize(sub, np.arange(idx.size), x[idx], clocks[idx], unmasked, width=width)
        w_rows, k = lin.sat_rows, len(data.systems)
        sat = lin.mask[:, :w_rows]
        r = np.where(sat, lin.q[:, :w_rows], np.nan)
        resid[idx] = lin.scatter(r, n)
        sigma = np.take_along_axis(sigma_m[idx], np.maximum(lin.sv_index, 0), axis=1)
        stat[idx] = np.sum(np.where(sat, (np.nan_to_num(r) / sigma) ** 2, 0.0), axis=1)
        n_clocks = k - lin.mask[:, w_rows:].sum(axis=1) if k > 1 else 1
        dof[idx] = sat.sum(axis=1) - position_unknowns - n_clocks
    thr = np.array([chi2_threshold(int(d), config.integrity_pfa) for d in dof])
    return FixCheck(stat=stat, dof=dof, passed=stat <= thr, residuals_m=resid)


def monitor_fixes(data: EpochData, sol: MethodSolution, wls_status: NDArray[np.str_],
                  config: ProcessingConfig, position_unknowns: int = 3,
                  levels: tuple[F64, F64] | None = None) -> MethodSolution:
    """Test the ``ok`` epochs of a method solved once at the WLS fix (:func:`check_fixes`) and
    check their GDOP; ``wls_status``: the WLS epochs' words, whose ``hpl_limit`` carries over
    (the snapshot methods' protection levels are those of ls/wls). ``levels``: the method's own
    ``(hpl_m, vpl_m)`` (a multi-epoch method, :func:`estimate_levels`), checked against the alert
    limits instead; an epoch without them (NaN) is ``untested`` (no protection level, no ``ok``).

    Statuses in the order of :func:`monitor`: ``integrity_fail`` when the test at the method's
    own fix fails, else ``gdop_limit`` when the method's GDOP is above ``max_gdop``, else
    ``hpl_limit`` where the WLS epoch has it, else ``ok``. An epoch without redundancy
    (``dof = 0``) passes the test, as for ls/wls. The method's own test decides, not the WLS
    epoch's word: a WLS ``integrity_fail`` or ``gdop_limit`` epoch is ``ok`` for a method whose
    fix passes both (rare: the WLS statistic is a lower bound, except for a robust WLS fix).
    Nothing is excluded: the method used the WLS epoch's satellites, after its exclusions.
    The residuals and the statistic of the tested epochs are returned with the solution.
    """
    T = sol.status.size
    rows = np.flatnonzero(sol.status == EpochStatus.OK)
    clocks = sol.clocks_m
    sigma = sol.sigma_m if sol.sigma_m is not None else np.full(sol.residuals_m.shape, np.nan)
    chk = check_fixes(take_epochs(data, rows), sol.x_ecef_m[rows], clocks[rows], sigma[rows], config,
                      position_unknowns)
    stat, residuals = np.full(T, np.nan), sol.residuals_m.copy()
    stat[rows], residuals[rows] = chk.stat, chk.residuals_m
    failed, dof = np.zeros(T, dtype=bool), np.zeros(T, dtype=np.int64)
    failed[rows], dof[rows] = ~chk.passed, chk.dof
    if levels is not None:
        hpl, vpl = levels
        dof = np.where(np.isnan(hpl) | np.isnan(vpl), 0, dof)  # no protection level: untested
        status = final_status(sol.status, failed, dof, sol.gdop, hpl, vpl, config)
        return replace(sol, status=status, test_stat=stat, residuals_m=residuals, hpl_m=hpl, vpl_m=vpl)
    status = final_status(sol.status, failed, dof, sol.gdop, np.full(T, np.nan), np.full(T, np.nan),
                          replace(config, alert_limit_h_m=np.inf, alert_limit_v_m=np.inf))
    for word in (EpochStatus.VPL_LIMIT, EpochStatus.HPL_LIMIT, EpochStatus.NLOS_DEPENDENT):  # the WLS epoch's
        status[(status == EpochStatus.OK) & (wls_status == word)] = word.value  # levels and direct satellites
    return replace(sol, status=status, test_stat=stat, residuals_m=residuals)


def estimate_levels(data: EpochData, wls: MethodSolution, x_hat: F64, config: ProcessingConfig) -> tuple[F64, F64]:
    """Protection levels ``(hpl_m, vpl_m)`` (``(T,)``, m) of another estimate ``x_hat``
    (``(T, 3)`` ECEF, m) of the epochs of ``wls`` (a multi-epoch method's positions), from the WLS
    epochs' fault hypotheses and subset solutions (module docstring, "Levels of the multi-epoch
    methods"). NaN where the WLS epoch has no levels (no fix, no redundancy, not tested) or
    ``x_hat`` no position; all NaN with ``integrity = "off"``."""
    T = x_hat.shape[0]
    hpl, vpl = np.full(T, np.nan), np.full(T, np.nan)
    if config.integrity == "off" or wls.hpl_m is None or wls.excluded is None:
        return hpl, vpl
    rows = np.flatnonzero(~np.isnan(wls.hpl_m) & np.isfinite(x_hat).all(axis=1) & np.isfinite(wls.x_ecef_m).all(axis=1))
    if rows.size:
        chk = _check_blocks(data, wls, rows, wls.excluded, config, wls.method != "ls", estimate=x_hat)
        hpl[rows], vpl[rows] = chk.hpl_m, chk.vpl_m
    return hpl, vpl
