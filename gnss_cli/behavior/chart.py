"""Affine charts on the set of kernels: the free parameters of the STLS outer problem.

The misfit depends only on the row space of ``R`` (``M(S R) = M(R)`` for invertible ``S``),
so the optimizer works in local coordinates ``theta``:

* :class:`FullChart` -- ``R = [X  -I]`` after a column permutation (``g`` identity columns
  chosen by column-pivoted QR); ``theta = vec(X)``, ``g (q(l+1) - g)`` parameters. When
  ``X`` grows (the identity block of the current kernel becomes ill-conditioned) the
  optimizer re-charts: it picks new identity columns with pivoted QR and rewrites ``theta``.
* :class:`SharedChart` -- ``R(z) = r(z) I_q`` with ``r(z) = f(z) r~(z)``, ``f`` a fixed monic
  polynomial (e.g. ``z - 1``) and one coefficient of ``r~`` pinned to 1; ``theta`` are the
  other coefficients of ``r~`` (``lag - deg f`` parameters).

Both provide ``(dG/dtheta_k) w_hat`` for the pseudo-Jacobian of the whitened residual.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from gnss_cli.behavior.hankel import hankel_rows

__all__ = ["FullChart", "SharedChart"]


class FullChart:
    """``R = [X -I]`` (columns permuted) for a general kernel with ``g`` rows.

    Parameters
    ----------
    R : ndarray, shape (g, q(l+1))
        A kernel whose row space defines the chart point (full row rank).
    q : int
        Number of variables.
    """

    def __init__(self, R: NDArray[np.float64], q: int) -> None:
        self.g, n_col = R.shape
        self.q = q
        self.n_blk = n_col // q
        import scipy.linalg  # imported by the multi-epoch methods only

        _, _, piv = scipy.linalg.qr(R, mode="economic", pivoting=True)
        self.ident = np.sort(piv[: self.g])
        self.free = np.setdiff1d(np.arange(n_col), self.ident)
        self.n_params = self.g * self.free.size
        self._basis: NDArray[np.float64] | None = None

    def coordinates(self, R: NDArray[np.float64]) -> NDArray[np.float64]:
        """Chart coordinates of (the row space of) ``R``; raises LinAlgError if the identity block is singular."""
        norm = -np.linalg.solve(R[:, self.ident], R)
        return norm[:, self.free].reshape(-1)

    def kernel(self, theta: NDArray[np.float64]) -> NDArray[np.float64]:
        """``R(theta)``, shape ``(g, q(l+1))``."""
        R = np.zeros((self.g, self.free.size + self.g))
        R[:, self.ident] = -np.eye(self.g)
        R[:, self.free] = theta.reshape(self.g, self.free.size)
        return R

    def blocks(self, theta: NDArray[np.float64]) -> NDArray[np.float64]:
        """``R(theta)`` as blocks ``(l+1, g, q)``."""
        return self.kernel(theta).reshape(self.g, self.n_blk, self.q).transpose(1, 0, 2).copy()

    def shared_r(self, theta: NDArray[np.float64]) -> None:
        """No scalar fast path for a general kernel."""
        return None

    def jacobian_rhs(self, w_hat: NDArray[np.float64]) -> NDArray[np.float64]:
        """``D[:, k] = (dG/dtheta_k) vec(w_hat)``, shape ``(g (T-l), n_params)``."""
        rows = hankel_rows(w_hat, self.n_blk)  # (n, l+1, q)
        n = rows.shape[0]
        h_t = rows.reshape(n, self.n_blk * self.q)[:, self.free]  # (n, nf)
        nf = self.free.size
        # Fortran order: the banded triangular solves take the columns without a copy
        d = np.zeros((self.g, nf, n, self.g))  # [a', c, j, a] = delta_{a a'} h_t[j, c]
        for a in range(self.g):
            d[a, :, :, a] = h_t.T
        return d.reshape(self.g * nf, n * self.g).T

    def basis_blocks(self) -> NDArray[np.float64]:
        """``dR/dtheta_k`` as blocks, shape ``(n_params, l+1, g, q)`` (computed once per chart)."""
        if self._basis is None:
            out = np.zeros((self.g, self.free.size, self.n_blk, self.g, self.q))
            for a in range(self.g):
                for c, col in enumerate(self.free):
                    out[a, c, col // self.q, a, col % self.q] = 1.0
            self._basis = out.reshape(self.n_params, self.n_blk, self.g, self.q)
        return self._basis

    def needs_rechart(self, theta: NDArray[np.float64], threshold: float) -> bool:
        """Whether ``|theta|`` is large enough that another identity block is better conditioned."""
        return bool(np.max(np.abs(theta), initial=0.0) > threshold)


class SharedChart:
    """``R(z) = f(z) r~(z) I_q`` with ``r~`` of degree ``lag - deg f`` and ``r~[c] = 1``.

    Parameters
    ----------
    fixed : ndarray, shape (n_fixed + 1,)
        Ascending coefficients of the fixed factor ``f`` (``[1.0]`` for none).
    r_tilde : ndarray, shape (lag - n_fixed + 1,)
        Starting coefficients of ``r~`` (ascending powers, not all zero).
    q : int
        Number of variables.
    """

    def __init__(self, fixed: NDArray[np.float64], r_tilde: NDArray[np.float64], q: int) -> None:
        self.fixed = np.asarray(fixed, dtype=np.float64)
        self.q = q
        self.deg_free = r_tilde.size - 1
        self.n_blk = self.fixed.size + self.deg_free
        # conv matrix: r = C r~,  C[i, j] = f[i - j]
        self.conv = np.zeros((self.n_blk, self.deg_free + 1))
        for j in range(self.deg_free + 1):
            self.conv[j : j + self.fixed.size, j] = self.fixed
        self.pin = int(np.argmax(np.abs(r_tilde)))
        self.free = np.array([i for i in range(self.deg_free + 1) if i != self.pin], dtype=np.intp)
        self.n_params = self.free.size
        self.g = q
        self._eye = np.eye(q)
        self._conv_free = self.conv[:, self.free]
        coef = self._conv_free.T  # (n_params, l+1)
        self._basis = coef[:, :, None, None] * self._eye[None, None]

    def coordinates_tilde(self, r_tilde: NDArray[np.float64]) -> NDArray[np.float64]:
        """Chart coordinates of ``r~`` (scaled so that ``r~[pin] = 1``)."""
        return (r_tilde / r_tilde[self.pin])[self.free]

    def r_tilde(self, theta: NDArray[np.float64]) -> NDArray[np.float64]:
        """``r~(theta)``, ascending coefficients."""
        rt = np.empty(self.deg_free + 1)
        rt[self.pin] = 1.0
        rt[self.free] = theta
        return rt

    def shared_r(self, theta: NDArray[np.float64]) -> NDArray[np.float64]:
        """``r = f * r~``, ascending coefficients ``(lag+1,)``."""
        return self.conv @ self.r_tilde(theta)

    def blocks(self, theta: NDArray[np.float64]) -> NDArray[np.float64]:
        """Blocks ``(lag+1, q, q)`` of ``r(z) I_q``."""
        return self.shared_r(theta)[:, None, None] * self._eye

    def jacobian_rhs(self, w_hat: NDArray[np.float64]) -> NDArray[np.float64]:
        """``D[:, k] = (dG/dtheta_k) vec(w_hat)``, shape ``(q (T-l), n_params)``."""
        rows = hankel_rows(w_hat, self.n_blk)  # (n, l+1, q)
        n = rows.shape[0]
        return (rows.transpose(0, 2, 1) @ self._conv_free).reshape(n * self.q, self.n_params)

    def basis_blocks(self) -> NDArray[np.float64]:
        """``dR/dtheta_k`` as blocks, shape ``(n_params, l+1, q, q)``."""
        return self._basis

    def needs_rechart(self, theta: NDArray[np.float64], threshold: float) -> bool:
        """Whether a free coefficient outgrew the pinned one."""
        return bool(np.max(np.abs(theta), initial=0.0) > threshold)
