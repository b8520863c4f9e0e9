"""Kernel records: what a fitted kernel reports (coefficients, order, poles), JSON-ready."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from gnss_cli.behavior.kernel import KernelRepresentation
from gnss_cli.errors import GnssError

__all__ = ["KernelRecord", "kernel_record", "shared_kernel_records", "shared_roots"]

F64 = NDArray[np.float64]


@dataclass(frozen=True, slots=True)
class KernelRecord:
    """A kernel ``R(z)`` as plain numbers.

    Attributes
    ----------
    p, q : int
        Rows (equations) and variables of the kernel.
    lag : int
        Lag ``l``.
    order : int
        McMillan degree (order) of the behavior.
    kernel_R : list of list of float
        ``R = [R_0 ... R_lag]``, ``p x q(l+1)``.
    poles : list of [re, im]
        Poles of the behavior (empty when they cannot be computed).
    shared_coefficients : list of float or None
        ``r_0 ... r_l`` when the kernel is ``r(z) I_q``.
    """

    p: int
    q: int
    lag: int
    order: int
    kernel_R: list[list[float]]
    poles: list[list[float]]
    shared_coefficients: list[float] | None = None

    def to_dict(self) -> dict[str, object]:
        """A JSON-serialisable mapping (``shared_coefficients`` only for shared kernels)."""
        out: dict[str, object] = {"p": self.p, "q": self.q, "lag": self.lag, "order": self.order,
                                  "kernel_R": self.kernel_R, "poles": self.poles}
        if self.shared_coefficients is not None:
            out["shared_coefficients"] = self.shared_coefficients
        return out


def kernel_record(ker: KernelRepresentation) -> KernelRecord:
    """The record of a kernel (poles empty when they cannot be computed)."""
    try:
        poles = ker.poles()
        pole_list = np.stack([poles.real, poles.imag], axis=1).tolist()
    except GnssError:
        pole_list = []
    shared = ker.blocks[:, 0, 0].tolist() if ker.is_shared(1e-9) else None
    return KernelRecord(ker.p, ker.q, ker.lag, ker.order, np.asarray(ker.R).tolist(), pole_list, shared)


def shared_kernel_records(r: F64, q: int) -> list[KernelRecord]:
    """Records of shared kernels ``r(z) I_q``, ``r`` of shape ``(B, l+1)`` (:func:`kernel_record` batched)."""
    n_b, n_blk = r.shape
    lag = n_blk - 1
    big_r = (r[:, None, :, None] * np.eye(q)[None, :, None, :]).reshape(n_b, q, n_blk * q)
    nonzero = r != 0.0
    degree = np.where(nonzero.any(axis=1), n_blk - 1 - np.argmax(nonzero[:, ::-1], axis=1), -1)
    out: list[KernelRecord] = []
    roots = shared_roots(r)
    for k in range(n_b):
        poles = np.sort_complex(np.repeat(roots[k], q)) if roots[k] is not None else np.zeros(0, complex)
        out.append(KernelRecord(q, q, lag, int(q * max(degree[k], 0)), big_r[k].tolist(),
                                np.stack([poles.real, poles.imag], axis=1).tolist(), r[k].tolist()))
    return out


def shared_roots(r: F64) -> list[NDArray[np.complex128] | None]:
    """Roots of every ``r`` ``(B, l+1)`` (companion eigenvalues, batched when ``r_l != 0``)."""
    n_b, n_blk = r.shape
    lag = n_blk - 1
    out: list[NDArray[np.complex128] | None] = [None] * n_b
    regular = np.flatnonzero(r[:, -1] != 0.0)
    if regular.size and lag > 0:
        comp = np.zeros((regular.size, lag, lag))
        comp[:, 1:, :-1] = np.eye(lag - 1)
        comp[:, :, -1] = -r[regular, :lag] / r[regular, -1:]
        ev = np.linalg.eigvals(comp)
        for k, j in enumerate(regular):
            out[j] = ev[k]
    for j in np.flatnonzero(r[:, -1] == 0.0):
        out[j] = np.roots(r[j, ::-1]) if np.any(r[j] != 0.0) else np.zeros(0, complex)
    return out
