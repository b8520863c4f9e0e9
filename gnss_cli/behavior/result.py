"""Result and status types of the behavioral identification (STLS / WTLS)."""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum

import numpy as np
from numpy.typing import NDArray

from gnss_cli.behavior.kernel import KernelRepresentation

__all__ = ["StlsStatus", "StlsResult", "STATUS_MESSAGES"]


class StlsStatus(IntEnum):
    """Outcome of an identification: failures negative, iteration limit zero, success positive."""

    INFEASIBLE = -2
    """``G(R) Sigma G(R)^T`` is singular at every starting kernel: no fit was computed."""
    ITERATION_LIMIT = 0
    """``max_iter`` outer iterations without meeting the tolerance (the result is the best kernel found)."""
    CONVERGED = 1
    """Relative misfit decrease or relative step below ``tol``."""
    NO_FURTHER_DECREASE = 2
    """The damped steps cannot decrease the misfit any more (a minimum to rounding level)."""
    EXACT = 3
    """The data lie in the model class: misfit zero to rounding."""
    DIRECT = 4
    """Closed-form result without iterations (WTLS, or no free parameters)."""


STATUS_MESSAGES: dict[StlsStatus, str] = {
    StlsStatus.INFEASIBLE: "G(R) Sigma G(R)^T is singular for every starting kernel; no fit",
    StlsStatus.ITERATION_LIMIT: "iteration limit reached before the tolerance was met",
    StlsStatus.CONVERGED: "converged: relative misfit decrease or step below tol",
    StlsStatus.NO_FURTHER_DECREASE: "converged: no further decrease of the misfit is possible",
    StlsStatus.EXACT: "exact: the data satisfy the identified kernel (misfit at rounding level)",
    StlsStatus.DIRECT: "closed-form solution (no iterations)",
}


@dataclass(frozen=True, slots=True)
class StlsResult:
    """An identified kernel and the corrected trajectory.

    Attributes
    ----------
    kernel : KernelRepresentation
        Identified ``R(z)`` (``R_lag = I`` when it is square and invertible; the shared
        kernel is monic ``r(z) I_q``).
    w_hat : ndarray, shape (T, q)
        Closest trajectory of the identified behavior in the ``Sigma^{-1}`` norm (unit of ``w``).
    misfit : float
        ``sum_t (w(t) - w_hat(t))^T Sigma_t^{-1} (w(t) - w_hat(t))`` (dimensionless when
        ``Sigma`` is the covariance of ``w``; unit of ``w`` squared for ``cov=None``).
        ``inf`` only with status ``INFEASIBLE``.
    iterations : int
        Outer (Jacobian) iterations.
    status : StlsStatus
        See :class:`StlsStatus`.
    message : str
        Human-readable status.
    method : str
        ``"stls"`` or ``"wtls"``.
    structure : str
        ``"full"`` or ``"shared"``.
    n_evaluations : int
        Misfit evaluations (inner problems solved).
    gradient_norm : float
        Infinity norm of the misfit gradient in the final chart coordinates.
    """

    kernel: KernelRepresentation
    w_hat: NDArray[np.float64]
    misfit: float
    iterations: int
    status: StlsStatus
    message: str
    method: str
    structure: str
    n_evaluations: int = 0
    gradient_norm: float = 0.0

    @property
    def success(self) -> bool:
        """Whether the status is positive (a converged or closed-form fit)."""
        return self.status > 0
