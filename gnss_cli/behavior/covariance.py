"""Per-epoch covariances of a vector time series: validation and the products the STLS needs.

The behavioral layer accepts the covariance ``Sigma_t`` of every sample ``w(t)`` in one of
three forms: ``None`` (identity, unweighted), ``(T, q)`` (diagonal: variances) or
``(T, q, q)`` (full symmetric positive definite matrices, as the per-epoch solver produces).
Units are the square of the unit of ``w`` (m^2 for positions in metres).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gnss_cli.errors import UsageError

__all__ = ["EpochCovariance"]

CovKind = Literal["identity", "diag", "full"]


@dataclass(frozen=True, slots=True)
class EpochCovariance:
    """Validated per-epoch covariances ``Sigma_t`` for ``t = 0 .. T-1``.

    Attributes
    ----------
    kind : {"identity", "diag", "full"}
        Storage form.
    n_t, q : int
        Number of epochs and variables.
    values : ndarray or None
        ``None`` (identity), variances ``(T, q)`` or matrices ``(T, q, q)``.
    """

    kind: CovKind
    n_t: int
    q: int
    values: NDArray[np.float64] | None

    @classmethod
    def from_arg(cls, cov: ArrayLike | None, n_t: int, q: int, name: str = "cov") -> EpochCovariance:
        """Validate ``cov`` (None, ``(T, q)`` or ``(T, q, q)``) for a series of shape ``(n_t, q)``.

        Raises
        ------
        UsageError
            Wrong shape, non-finite values, non-positive variances, asymmetric or
            non-positive-definite matrices.
        """
        if cov is None:
            return cls("identity", n_t, q, None)
        if isinstance(cov, EpochCovariance):
            if (cov.n_t, cov.q) != (n_t, q):
                raise UsageError(f"{name}: expected covariances for T={n_t}, q={q}, received T={cov.n_t}, q={cov.q}")
            return cov
        arr = np.asarray(cov, dtype=np.float64)
        if arr.shape == (n_t, q):
            if not np.all(np.isfinite(arr)) or np.any(arr <= 0.0):
                raise UsageError(f"{name}: expected finite positive variances of shape ({n_t}, {q}), received min {np.nanmin(arr)!r}")
            return cls("diag", n_t, q, np.ascontiguousarray(arr))
        if arr.shape == (n_t, q, q):
            if not np.all(np.isfinite(arr)):
                raise UsageError(f"{name}: expected finite covariance matrices, received non-finite values")
            scale = np.max(np.abs(arr), axis=(1, 2))
            asym = np.max(np.abs(arr - arr.transpose(0, 2, 1)), axis=(1, 2))
            if np.any(asym > 1e-9 * scale):
                t_bad = int(np.argmax(asym / np.maximum(scale, np.finfo(float).tiny)))
                raise UsageError(f"{name}: expected symmetric matrices, epoch {t_bad} is asymmetric by {asym[t_bad]:.3g}")
            sym = 0.5 * (arr + arr.transpose(0, 2, 1))
            try:
                np.linalg.cholesky(sym)
            except np.linalg.LinAlgError:
                raise UsageError(f"{name}: expected positive definite covariance matrices, received at least one that is not") from None
            return cls("full", n_t, q, np.ascontiguousarray(sym))
        raise UsageError(f"{name}: expected None, shape ({n_t}, {q}) or ({n_t}, {q}, {q}), received shape {arr.shape}")

    def full(self) -> NDArray[np.float64]:
        """All matrices, shape ``(T, q, q)``."""
        if self.kind == "full":
            assert self.values is not None
            return self.values
        if self.kind == "diag":
            assert self.values is not None
            return self.values[:, :, None] * np.eye(self.q)[None]
        return np.broadcast_to(np.eye(self.q), (self.n_t, self.q, self.q)).copy()

    def apply(self, u: NDArray[np.float64]) -> NDArray[np.float64]:
        """``Sigma_t u(t)`` for every epoch: ``u`` ``(T, q)`` -> ``(T, q)``."""
        if self.kind == "identity":
            return u
        assert self.values is not None
        if self.kind == "diag":
            return self.values * u
        return np.einsum("tab,tb->ta", self.values, u)

    def apply_batch(self, u: NDArray[np.float64]) -> NDArray[np.float64]:
        """``Sigma_t u(t, :, k)`` for every epoch and column: ``u`` ``(T, q, k)`` -> ``(T, q, k)``."""
        if self.kind == "identity":
            return u
        assert self.values is not None
        if self.kind == "diag":
            return self.values[:, :, None] * u
        return np.matmul(self.values, u)

    def weighted_norm2(self, d: NDArray[np.float64]) -> float:
        """``sum_t d(t)^T Sigma_t^{-1} d(t)`` for ``d`` ``(T, q)``."""
        if self.kind == "identity":
            return float(np.sum(d * d))
        assert self.values is not None
        if self.kind == "diag":
            return float(np.sum(d * d / self.values))
        sol = np.linalg.solve(self.values, d[:, :, None])[:, :, 0]
        return float(np.sum(d * sol))

    def mean(self) -> NDArray[np.float64]:
        """The average covariance ``(q, q)``."""
        if self.kind == "identity":
            return np.eye(self.q)
        assert self.values is not None
        if self.kind == "diag":
            return np.diag(np.mean(self.values, axis=0))
        return np.mean(self.values, axis=0)

    def window(self, start: int, stop: int) -> EpochCovariance:
        """The covariances of epochs ``start .. stop-1``."""
        vals = None if self.values is None else self.values[start:stop]
        return EpochCovariance(self.kind, stop - start, self.q, vals)
