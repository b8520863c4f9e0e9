"""Fixed-kernel projection with variance components estimated from the data.

A signal ``w`` ``(T, q)`` whose variables fall into groups (e.g. positions and velocities)
with a-priori covariances ``Sigma_t`` known only up to one factor per group is projected onto
the behavior of a fixed kernel ``R`` (:func:`gnss_cli.behavior.projection.misfit`, O(T)).
The factors decide how the projection shares the kernel's misfit among the groups, so they
are estimated from the data by Helmert's variance component estimation (Koch 1999, sec. 3.6):
with the residuals ``r = w - w_hat`` and the redundancy of group ``k``,
``rho_k = tr(Sigma^-1 Sigma G^T Gamma^-1 G Sigma)_kk`` (the share of the constraints that
group ``k`` absorbs; ``sum_k rho_k`` is the number of constraint rows), each iteration sets

    s_k <- s_k * (r_k^T Sigma_k^-1 r_k) / rho_k

(the ratios between groups over-relaxed by :data:`RELAX` while they keep moving one way) and projects again. ``rho_k`` comes from Hutchinson's trace estimator: for Rademacher
probes ``z`` and ``y = L z`` (``Sigma_t = L_t L_t^T``), ``u = L^-1 (y - P y)`` gives
``E[z_k^T u_k] = rho_k``; each probe is one more O(T) projection.

Nothing here knows about GNSS; :mod:`gnss_cli.pipeline.kinematic` applies it to positions
and Doppler velocities under the kinematic kernel.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from gnss_cli.behavior.kernel import KernelRepresentation
from gnss_cli.behavior.projection import misfit
from gnss_cli.errors import UsageError

__all__ = ["VarianceComponentFit", "project_with_variance_components"]

F64 = NDArray[np.float64]
#: Over-relaxation of the ratios between the factors: plain Helmert iterations (1.0) converge
#: linearly and needed about 16 projections on a position/velocity track; 2.0 needs about 8.
#: (The common scale keeps the plain update: it does not move ``w_hat``, and over-relaxing it
#: made it drift.)
RELAX = 2.0


@dataclass(frozen=True)
class VarianceComponentFit:
    """Result of :func:`project_with_variance_components`.

    Attributes
    ----------
    w_hat : ``(T, q)`` the projection of ``w`` onto the behavior, with the final factors.
    factors : ``(k,)`` variance factor of each group (multiplies its a-priori covariance).
    redundancy : ``(k,)`` estimated redundancy of each group (sums to about ``p (T - lag)``).
    misfit : weighted misfit with the final factors (about ``p (T - lag)`` when they fit).
    iterations : projections made for the factors (probes excluded).
    """

    w_hat: F64
    factors: F64
    redundancy: F64
    misfit: float
    iterations: int


def project_with_variance_components(
    w: F64,
    kernel: KernelRepresentation,
    cov: F64,
    groups: list[slice],
    *,
    max_iter: int = 15,
    rtol: float = 0.02,
    probes: int = 8,
    rng: np.random.Generator | None = None,
    floor: float = 1e-12,
) -> VarianceComponentFit:
    """Project ``w`` onto the behavior of ``kernel`` with per-group variance factors from the data.

    Parameters
    ----------
    w : ndarray, shape (T, q)
        The signal (units of each variable as its covariance's square root).
    kernel : KernelRepresentation
        Fixed kernel over ``q`` variables.
    cov : ndarray, shape (T, q, q)
        A-priori covariances, block diagonal over ``groups`` (no cross-group covariance).
    groups : list of slice
        The variables of each group (e.g. ``[slice(0, 3), slice(3, 6)]``).
    max_iter : int
        Most projections for the factors (default 15).
    rtol : float
        Stop when every factor changes by less than this relative (default 0.02: the
        probes' own scatter is about that).
    probes : int
        Hutchinson probes per iteration (default 8; the redundancies' relative error falls
        as ``1 / sqrt(probes T)``).
    rng : numpy.random.Generator, optional
        Source of the probes (default: seeded with 0, so results are repeatable).
    floor : float
        Smallest factor relative to the largest (keeps the covariances regular).

    Returns
    -------
    VarianceComponentFit

    Raises
    ------
    UsageError
        Shapes that do not match, or a group without variables.

    Examples
    --------
    Two noisy measurements of one constant (kernel ``z - 1`` on each variable), one group per
    measurement, the second ten times noisier: the factors recover the true variances.

    >>> import numpy as np
    >>> rng = np.random.default_rng(3)
    >>> w = np.stack([rng.normal(0, 1, 4000), rng.normal(0, 10, 4000)], axis=1)
    >>> cov = np.broadcast_to(np.eye(2), (4000, 2, 2)).copy()
    >>> fit = project_with_variance_components(w, KernelRepresentation.static(2), cov, [slice(0, 1), slice(1, 2)])
    >>> (fit.factors / [1.0, 100.0]).round(1).tolist()
    [1.0, 1.0]
    """
    arr = np.asarray(w, dtype=np.float64)
    n_t, q = arr.shape
    base = np.asarray(cov, dtype=np.float64)
    if base.shape != (n_t, q, q):
        raise UsageError(f"cov: expected shape ({n_t}, {q}, {q}), received {base.shape}")
    if not groups or any(len(range(q)[g]) == 0 for g in groups):
        raise UsageError("groups: expected non-empty slices of the variables")
    gen = rng if rng is not None else np.random.default_rng(0)
    factors = np.ones(len(groups))
    scaled = base.copy()
    result = None
    previous: F64 | None = None
    iterations = 0
    for iterations in range(1, max_iter + 1):
        scaled = _scaled(base, groups, factors)
        m, w_hat = misfit(arr, kernel, scaled)
        quad = _group_quadratic(arr - w_hat, scaled, groups)
        red = _redundancy(kernel, scaled, groups, probes, gen)
        ratio = np.where((red > 0) & (quad > 0), quad / np.where(red > 0, red, 1.0), 1.0)
        share = red / red.sum() if red.sum() > 0 else np.full(red.size, 1.0 / red.size)
        # over-relaxed in the ratios between groups while they keep moving the same way (a
        # plain Helmert step is exact for uncoupled groups and relaxing it would oscillate),
        # plain Helmert in their common scale
        same_way = np.sign(np.log(ratio)) == np.sign(np.log(previous)) if previous is not None else np.zeros(ratio.size, bool)
        alpha = np.where(same_way, RELAX, 1.0)
        new = factors * ratio**alpha * np.prod(ratio ** ((1.0 - alpha) * share))
        previous = ratio
        new = np.maximum(new, floor * new.max()) if np.all(np.isfinite(new)) and new.max() > 0 else factors
        result = (w_hat, red, m)
        done = bool(np.all(np.abs(new - factors) <= rtol * factors))
        factors = new
        if done:
            break
    scaled = _scaled(base, groups, factors)
    m, w_hat = misfit(arr, kernel, scaled)
    assert result is not None
    return VarianceComponentFit(w_hat, factors, result[1], float(m), iterations)


def _scaled(base: F64, groups: list[slice], factors: F64) -> F64:
    out = base.copy()
    for g, f in zip(groups, factors):
        out[:, g, g] *= f
    return out


def _group_quadratic(r: F64, cov: F64, groups: list[slice]) -> F64:
    """``r_k^T Sigma_k^-1 r_k`` summed over epochs, per group."""
    out = np.empty(len(groups))
    for i, g in enumerate(groups):
        sub = cov[:, g, g]
        out[i] = float(np.einsum("ti,ti->", r[:, g], np.linalg.solve(sub, r[:, g][..., None])[..., 0]))
    return out


def _redundancy(kernel: KernelRepresentation, cov: F64, groups: list[slice], probes: int,
                rng: np.random.Generator) -> F64:
    """Hutchinson estimate of each group's redundancy (module docstring)."""
    chol = np.linalg.cholesky(cov)
    acc = np.zeros(len(groups))
    for _ in range(probes):
        z = rng.choice([-1.0, 1.0], size=cov.shape[:2])
        y = np.einsum("tij,tj->ti", chol, z)
        _, y_hat = misfit(y, kernel, cov)
        u = np.linalg.solve(chol, (y - y_hat)[..., None])[..., 0]
        for i, g in enumerate(groups):
            acc[i] += float(np.sum(z[:, g] * u[:, g]))
    return acc / probes
