"""Kernel representations ``R(z) = R_0 + R_1 z + ... + R_lag z^lag`` of linear time-invariant behaviors.

A time series ``w`` (``(T, q)``) belongs to the behavior ``ker R(sigma)`` when
``R_0 w(t) + R_1 w(t+1) + ... + R_lag w(t+lag) = 0`` for ``t = 0 .. T-lag-1``, i.e. when
``R @ hankel(w, lag + 1) == 0`` with ``R = [R_0 ... R_lag]`` of shape ``(p, q*(lag+1))``.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gnss_cli.behavior.hankel import as_series, hankel
from gnss_cli.errors import UsageError

__all__ = ["KernelRepresentation"]


class KernelRepresentation:
    """A polynomial kernel ``R(z) = sum_k R_k z^k`` with ``p`` rows over ``q`` variables.

    Parameters
    ----------
    R : array_like, shape (p, q*(lag+1)) or (lag+1, p, q)
        The coefficients ``[R_0 R_1 ... R_lag]`` side by side, or stacked as blocks.
    q : int, optional
        Number of variables. For a 2-D ``R`` it defaults to ``p`` (a square kernel: as many
        equations as variables, the autonomous case used for trajectories); give it for
        kernels with fewer rows than variables.

    Attributes
    ----------
    R : ndarray, shape (p, q*(lag+1))
        The coefficients, read-only.
    blocks : ndarray, shape (lag+1, p, q)
        ``blocks[k] = R_k``, read-only.

    Notes
    -----
    ``order`` is the total lag (sum of the row degrees), which is the McMillan degree of the
    behavior when the kernel is row proper (``is_row_proper()``) and of full row rank.

    Examples
    --------
    >>> K = KernelRepresentation.static(3)
    >>> K.lag, K.order, K.p, K.q
    (1, 3, 3, 3)
    """

    __slots__ = ("R", "blocks", "p", "q", "lag")

    def __init__(self, R: ArrayLike, q: int | None = None) -> None:
        arr = np.array(R, dtype=np.float64)
        if arr.ndim == 3:
            if q is not None and q != arr.shape[2]:
                raise UsageError(f"q: expected {arr.shape[2]} for blocks of shape {arr.shape}, received {q}")
            n_blk, p, qq = arr.shape
            arr2 = np.concatenate(list(arr), axis=1) if n_blk > 0 else arr.reshape(p, 0)
        elif arr.ndim == 2:
            p = arr.shape[0]
            qq = p if q is None else int(q)
            if qq <= 0 or arr.shape[1] % qq != 0 or arr.shape[1] < qq:
                raise UsageError(
                    f"R: expected shape (p, q*(lag+1)) with q={qq} dividing the column count, received shape {arr.shape}"
                )
            arr2 = arr
        else:
            raise UsageError(f"R: expected a 2-D (p, q*(lag+1)) or 3-D (lag+1, p, q) array, received shape {arr.shape}")
        if arr2.shape[0] == 0 or arr2.shape[1] == 0:
            raise UsageError(f"R: expected at least one row and one block, received shape {arr2.shape}")
        if not np.all(np.isfinite(arr2)):
            raise UsageError("R: expected finite coefficients, received non-finite values")
        self.p = int(arr2.shape[0])
        self.q = int(qq)
        self.lag = int(arr2.shape[1] // qq - 1)
        self.R = arr2
        self.R.setflags(write=False)
        self.blocks = np.ascontiguousarray(arr2.reshape(self.p, self.lag + 1, self.q).transpose(1, 0, 2))
        self.blocks.setflags(write=False)

    # ------------------------------------------------------------------ constructors
    @classmethod
    def shared(cls, r: ArrayLike, q: int) -> KernelRepresentation:
        """``R(z) = r(z) I_q`` from the scalar coefficients ``r = [r_0, ..., r_lag]`` (ascending powers)."""
        coef = np.asarray(r, dtype=np.float64)
        if coef.ndim != 1 or coef.size < 2:
            raise UsageError(f"r: expected 1-D coefficients [r_0 .. r_lag] with lag >= 1, received shape {coef.shape}")
        if isinstance(q, bool) or not isinstance(q, (int, np.integer)) or q < 1:
            raise UsageError(f"q: expected a positive integer, received {q!r}")
        eye = np.eye(int(q))
        return cls(coef[:, None, None] * eye[None, :, :])

    @classmethod
    def static(cls, q: int) -> KernelRepresentation:
        """The static model ``(z - 1) I_q`` (lag 1): ``w(t+1) = w(t)``."""
        return cls.shared([-1.0, 1.0], q)

    @classmethod
    def pva(cls, q: int) -> KernelRepresentation:
        """The constant-acceleration model ``(z - 1)^3 I_q`` (lag 3)."""
        return cls.shared([-1.0, 3.0, -3.0, 1.0], q)

    # ------------------------------------------------------------------ properties
    @property
    def order(self) -> int:
        """Total lag: the sum of the row degrees (degree of row i = largest k with ``R_k[i] != 0``)."""
        return int(sum(self.row_degrees()))

    def row_degrees(self) -> NDArray[np.int64]:
        """Degree of each row of ``R(z)``, shape ``(p,)`` (-1 for a zero row)."""
        nonzero = np.any(self.blocks != 0.0, axis=2)  # (lag+1, p)
        deg = np.full(self.p, -1, dtype=np.int64)
        for k in range(self.lag + 1):
            deg[nonzero[k]] = k
        return deg

    def leading_row_coefficients(self) -> NDArray[np.float64]:
        """The leading row coefficient matrix ``(p, q)``: row i is the coefficient of ``z^deg_i``."""
        deg = self.row_degrees()
        out = np.zeros((self.p, self.q))
        for i, d in enumerate(deg):
            if d >= 0:
                out[i] = self.blocks[d, i]
        return out

    def is_row_proper(self, rtol: float = 1e-10) -> bool:
        """Whether the leading row coefficient matrix has full row rank (shortest-lag representation)."""
        lead = self.leading_row_coefficients()
        if np.any(self.row_degrees() < 0):
            return False
        sv = np.linalg.svd(lead, compute_uv=False)
        return bool(sv.size == self.p and sv[-1] > rtol * max(sv[0], np.finfo(float).tiny))

    def is_shared(self, rtol: float = 0.0) -> bool:
        """Whether ``R(z) = r(z) I_q`` (every block a multiple of the identity)."""
        if self.p != self.q:
            return False
        scale = np.max(np.abs(self.R)) if self.R.size else 0.0
        diag = np.einsum("kii->ki", self.blocks)
        off = self.blocks - diag[:, :, None] * np.eye(self.q)[None]
        spread = np.max(np.abs(diag - diag[:, :1]))
        return bool(np.max(np.abs(off)) <= rtol * scale and spread <= rtol * scale)

    def shared_coefficients(self) -> NDArray[np.float64]:
        """The scalar ``r = [r_0 .. r_lag]`` of a shared kernel ``r(z) I_q``.

        Raises
        ------
        UsageError
            If the kernel is not of the form ``r(z) I_q`` (to 1e-12 relative).
        """
        if not self.is_shared(rtol=1e-12):
            raise UsageError("kernel: expected a shared kernel r(z) I_q, received a general kernel")
        return self.blocks[:, 0, 0].copy()

    # ------------------------------------------------------------------ data checks
    def residual(self, w: ArrayLike) -> NDArray[np.float64]:
        """Equation error ``e(t) = sum_k R_k w(t+k)``, shape ``(T - lag, p)`` in the unit of ``w``.

        Raises
        ------
        UsageError
            If ``w`` is not ``(T, q)`` with ``T > lag``.
        """
        arr = self._check_w(w)
        return (self.R @ hankel(arr, self.lag + 1)).T

    def annihilates(self, w: ArrayLike, rtol: float = 1e-10) -> bool:
        """Whether ``||R H(w)||_F <= rtol * ||R||_F * ||H(w)||_F``."""
        arr = self._check_w(w)
        h = hankel(arr, self.lag + 1)
        res = np.linalg.norm(self.R @ h)
        return bool(res <= rtol * np.linalg.norm(self.R) * np.linalg.norm(h))

    def _check_w(self, w: ArrayLike) -> NDArray[np.float64]:
        arr = as_series(w)
        if arr.shape[1] != self.q or arr.shape[0] <= self.lag:
            raise UsageError(
                f"w: expected shape (T, {self.q}) with T > lag = {self.lag}, received shape {arr.shape}"
            )
        return arr

    # ------------------------------------------------------------------ dynamics
    def transition(self) -> NDArray[np.float64]:
        """``A = -R_lag^{-1} [R_0 ... R_{lag-1}]``, shape ``(q, q*lag)``: ``w(t+lag) = A [w(t); ...; w(t+lag-1)]``.

        Raises
        ------
        UsageError
            If ``R_lag`` is not square and well conditioned (condition number above 1e12).
        """
        r_lag = self.blocks[-1]
        if self.p != self.q or self.lag < 1:
            raise UsageError(f"kernel: prediction needs a square kernel with lag >= 1, received p={self.p}, q={self.q}, lag={self.lag}")
        if np.linalg.cond(r_lag) > 1e12:
            raise UsageError("kernel: R_lag is singular (condition number > 1e12); cannot solve for w(t+lag)")
        return -np.linalg.solve(r_lag, self.R[:, : self.q * self.lag])

    def predict(self, w_init: ArrayLike, steps: int) -> NDArray[np.float64]:
        """Continue a trajectory with ``w(t+lag) = -R_lag^{-1} sum_{k<lag} R_k w(t+k)``.

        Parameters
        ----------
        w_init : array_like, shape (lag, q)
            The last ``lag`` samples (oldest first); more rows are accepted and only the last
            ``lag`` are used.
        steps : int
            Number of samples to produce, ``>= 0``.

        Returns
        -------
        w_pred : ndarray, shape (steps, q)
            The samples following ``w_init``, same unit.

        Raises
        ------
        UsageError
            If ``R_lag`` is singular, the kernel is not square, or the shapes do not match.
        """
        if isinstance(steps, bool) or not isinstance(steps, (int, np.integer)) or steps < 0:
            raise UsageError(f"steps: expected a non-negative integer, received {steps!r}")
        arr = as_series(w_init, "w_init")
        if arr.shape[1] != self.q or arr.shape[0] < self.lag:
            raise UsageError(f"w_init: expected shape ({self.lag}, {self.q}), received shape {arr.shape}")
        a = self.transition()  # (q, q*lag)
        lag, q = self.lag, self.q
        buf = np.empty((lag + steps, q))
        buf[:lag] = arr[-lag:]
        # a_blocks[k] multiplies w(t+k)
        a_blocks = a.reshape(q, lag, q).transpose(1, 2, 0)  # (lag, q_in, q_out)
        for t in range(steps):
            acc = buf[t] @ a_blocks[0]
            for k in range(1, lag):
                acc = acc + buf[t + k] @ a_blocks[k]
            buf[t + lag] = acc
        return buf[lag:].copy()

    def poles(self) -> NDArray[np.complex128]:
        """Roots of ``det R(z)`` (finite ones), shape ``(order,)`` at most.

        For a square kernel these are the eigenvalues of the block companion pencil; for the
        shared kernel ``r(z) I_q`` they are the roots of ``r`` repeated ``q`` times.

        Raises
        ------
        UsageError
            If the kernel is not square (``p != q``): it then has inputs and no poles of its own.
        """
        if self.p != self.q:
            raise UsageError(f"kernel: poles need a square kernel, received p={self.p}, q={self.q}")
        q, lag = self.q, self.lag
        if self.is_shared() and self.blocks[-1, 0, 0] != 0.0:
            return np.sort_complex(np.repeat(np.roots(self.blocks[::-1, 0, 0]), q))
        n = q * lag
        # Companion pencil  A x = z B x  with x = [w(t); ...; w(t+lag-1)].
        a = np.zeros((n, n))
        b = np.eye(n)
        a[: n - q, q:] = np.eye(n - q)
        a[n - q :, :] = -self.R[:, :n]
        b[n - q :, n - q :] = self.blocks[-1]
        import scipy.linalg  # imported by the multi-epoch methods only

        ev = scipy.linalg.eigvals(a, b)
        return np.sort_complex(ev[np.isfinite(ev)])

    def mirrored(self, margin: float = 1e-3, max_cond: float = 1e8) -> KernelRepresentation | None:
        """The behavior with every pole outside the unit circle replaced by its mirror ``1 / conj(z)``.

        The weighted Hankel misfit depends on the kernel mostly through the spectrum of
        ``R(e^{i w}) Sigma R(e^{i w})^*``, which does not change when a root of ``det R`` is
        reflected across the unit circle; a descent that ends with a spurious unstable pole
        (e.g. a fast decay fitted as a growth) therefore has a mirrored kernel of similar
        misfit in another basin, a natural restart point.

        Parameters
        ----------
        margin : float
            Poles with ``|z| <= 1 + margin`` are kept (default 1e-3: a root of multiplicity
            ``k`` on the unit circle is computed only to about ``eps^(1/k)``).
        max_cond : float
            Give up (return None) when the eigenvector matrix of the companion realization is
            worse conditioned than this (repeated or defective poles).

        Returns
        -------
        KernelRepresentation or None
            A square kernel with the same lag (shared kernels stay shared), or None when no
            pole lies outside ``|z| = 1 + margin`` or the kernel cannot be realized
            (non-square, singular ``R_lag``).

        Notes
        -----
        General square kernels use the realization ``x_t = [w_t; ...; w_{t+l-1}]``,
        ``x_{t+1} = A x_t``, ``w_t = C x_t``; the eigenvalues of ``A`` are reflected and the new
        kernel is the left null space of ``[C; C A'; ...; C A'^l]``.
        """
        if self.p != self.q:
            return None
        if self.is_shared(1e-12):
            r = self.shared_coefficients()
            roots = np.roots(r[::-1])
            out = np.abs(roots) > 1.0 + margin
            if not np.any(out):
                return None
            roots = np.where(out, 1.0 / np.conj(roots), roots)
            return KernelRepresentation.shared(np.real(np.poly(roots))[::-1].copy(), self.q)
        try:
            a = self.transition()
        except UsageError:
            return None
        q, lag = self.q, self.lag
        n = q * lag
        comp = np.zeros((n, n))
        comp[: n - q, q:] = np.eye(n - q)
        comp[n - q :] = a
        ev, vec = np.linalg.eig(comp)
        out = np.abs(ev) > 1.0 + margin
        if not np.any(out) or np.linalg.cond(vec) > max_cond:
            return None
        ev = np.where(out, 1.0 / np.conj(ev), ev)
        a_new = np.real(vec @ np.diag(ev) @ np.linalg.inv(vec))
        obs = np.zeros((q * (lag + 1), n))
        row = np.eye(q, n)
        for k in range(lag + 1):
            obs[k * q : (k + 1) * q] = row
            row = row @ a_new
        u = np.linalg.svd(obs, full_matrices=True)[0]
        return KernelRepresentation(u[:, n:].T, q=q)

    # ------------------------------------------------------------------ misc
    def orthonormalized(self) -> KernelRepresentation:
        """The same behavior with orthonormal rows of ``R`` (``R R^T = I``): of all the
        representations ``M R`` of the kernel, the one whose ``G Sigma G^T`` is best scaled.

        ``R = U S V^T`` (thin SVD) becomes ``V^T``; rows that are numerically dependent
        (``s_i <= 1e-12 s_1``) are kept as they are, since dropping them would change the
        number of rows.
        """
        u, s, vt = np.linalg.svd(self.R, full_matrices=False)
        if s.size == 0 or not s[-1] > 1e-12 * s[0]:
            return self
        return KernelRepresentation(vt, q=self.q)

    def normalized(self) -> KernelRepresentation:
        """The same behavior with ``R_lag = I`` when ``R_lag`` is square and well conditioned, else ``R`` unchanged."""
        if self.p == self.q and np.linalg.cond(self.blocks[-1]) < 1e10:
            return KernelRepresentation(np.linalg.solve(self.blocks[-1], self.R), q=self.q)
        return self

    def __repr__(self) -> str:
        return f"KernelRepresentation(p={self.p}, q={self.q}, lag={self.lag})"

    def __eq__(self, other: object) -> bool:
        return isinstance(other, KernelRepresentation) and self.q == other.q and np.array_equal(self.R, other.R)

    __hash__ = None  # type: ignore[assignment]


def kernel_from(kernel: KernelRepresentation | ArrayLike, q: int) -> KernelRepresentation:
    """Accept a :class:`KernelRepresentation` or its coefficient array for ``q`` variables."""
    if isinstance(kernel, KernelRepresentation):
        if kernel.q != q:
            raise UsageError(f"kernel: expected a kernel over q={q} variables, received q={kernel.q}")
        return kernel
    return KernelRepresentation(np.asarray(kernel, dtype=np.float64), q=q)


def shared_kernel_coefficients(roots: Sequence[complex]) -> NDArray[np.float64]:
    """Real ascending coefficients of the monic polynomial with the given roots.

    Raises
    ------
    UsageError
        If complex roots do not come in conjugate pairs (the polynomial would not be real).
    """
    rts = np.asarray(list(roots), dtype=np.complex128)
    desc = np.poly(rts) if rts.size else np.array([1.0])
    if np.max(np.abs(np.imag(desc))) > 1e-9 * max(1.0, np.max(np.abs(desc))):
        raise UsageError(f"fixed_roots: expected real roots or conjugate pairs, received {list(roots)!r}")
    return np.real(desc)[::-1].copy()
