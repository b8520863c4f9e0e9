"""Trajectory -> behavioral model: identify a kernel on a trajectory (local ENU) and predict it.

The library side of ``gnss-identify``: the trajectory (:func:`gnss_cli.io.trajectory.read_trajectory`)
is converted to East-North-Up with the origin at its **first sample**, a lag-``L`` kernel is
identified by STLS or WTLS on the first ``train`` samples, and the kernel continues the
corrected trajectory for ``predict`` epochs.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from gnss_cli.behavior import StlsResult, stls, wtls
from gnss_cli.errors import InputError, NoSolutionError, UsageError
from gnss_cli.gnss.frames import ecef2enu, enu2ecef
from gnss_cli.io.trajectory import Trajectory

__all__ = ["Identification", "identify_trajectory"]

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class Identification:
    """An identified trajectory model, its corrected samples and its prediction.

    Attributes
    ----------
    method, structure : str
        ``stls`` or ``wtls``; ``full`` or ``shared``.
    result : StlsResult
        The identification (kernel, misfit, iterations, status).
    t_s : ndarray (N,)
        Time of every output row, s (GPS seconds when ``is_gps_time``).
    is_gps_time : bool
        Whether the input had ISO-8601 GPS time stamps.
    xyz_m, enu_m : ndarray (N, 3)
        ECEF and local ENU positions of the rows, m.
    kinds : list of str
        ``fit`` (the corrected training samples) or ``predicted`` per row.
    train, predicted : int
        Training samples and predicted epochs.
    dt_s : float
        Sampling interval, s.
    origin_ecef_m : ndarray (3,)
        ENU origin (the first sample), ECEF m.
    """

    method: str
    structure: str
    result: StlsResult
    t_s: F64
    is_gps_time: bool
    xyz_m: F64
    enu_m: F64
    kinds: list[str]
    train: int
    predicted: int
    dt_s: float
    origin_ecef_m: F64

    def model_record(self) -> dict[str, object]:
        """The model as a JSON-serialisable mapping (``gnss-identify --model-out``)."""
        res = self.result
        try:
            poles = [[float(p.real), float(p.imag)] for p in res.kernel.poles()]
        except UsageError:
            poles = []
        return {
            "method": self.method,
            "structure": self.structure,
            "lag": res.kernel.lag,
            "order": res.kernel.order,
            "rows": res.kernel.p,
            "variables": ["e_m", "n_m", "u_m"],
            "coefficients": res.kernel.R.tolist(),
            "coefficients_layout": "R = [R_0 R_1 ... R_lag], rows x 3(lag+1); sum_k R_k w(t+k) = 0",
            "poles": poles,
            "misfit_m2": res.misfit,
            "iterations": res.iterations,
            "status": res.status.name.lower(),
            "message": res.message,
            "train_samples": self.train,
            "predicted_samples": self.predicted,
            "dt_s": self.dt_s,
            "enu_origin_ecef_m": self.origin_ecef_m.tolist(),
            "enu_origin": "first sample of the trajectory",
        }


def identify_trajectory(
    traj: Trajectory, lag: int, order: int | None, method: str, structure: str, train: int | None,
    predict: int | None,
) -> Identification:
    """Identify a kernel on the first ``train`` samples (ENU, origin = first sample) and predict.

    Parameters
    ----------
    traj : Trajectory
        Uniformly sampled ECEF trajectory.
    lag, order : int, int or None
        Kernel lag and order (see :func:`gnss_cli.behavior.stls`).
    method, structure : str
        ``stls`` or ``wtls``; ``full`` or ``shared``.
    train : int or None
        Training samples (default: all).
    predict : int or None
        Epochs to predict after the training samples (default: the rest of the trajectory).

    Raises
    ------
    UsageError
        ``train`` or ``predict`` out of range.
    InputError
        Fewer than ``lag + 2`` training samples.
    NoSolutionError
        The identification failed (one sentence saying what to try), or the kernel cannot predict.
    """
    n_t = traj.xyz_m.shape[0]
    k = n_t if train is None else train
    if not 1 <= k <= n_t:
        raise UsageError(f"--train: expected 1..{n_t} samples, received {train}")
    if k < lag + 2:
        raise InputError(f"too few samples for lag {lag}: {k} training samples, at least lag + 2 = {lag + 2} needed")
    n_pred = (n_t - k) if predict is None else predict
    if n_pred < 0:
        raise UsageError(f"--predict: expected a non-negative number of epochs, received {predict}")
    origin = traj.xyz_m[0]
    enu = ecef2enu(traj.xyz_m[:k], origin)
    solver = stls if method == "stls" else wtls
    res = solver(enu, lag, order, structure=structure)
    if not np.isfinite(res.misfit):  # no starting kernel gave a regular weighted problem
        tries = (["--structure shared"] if structure == "full" else []) + (["a smaller --lag"] if lag > 1 else []) \
            + (["a longer --train"] if k < n_t else [])
        if len(tries) > 1:
            tries = [f"{', '.join(tries[:-1])} or {tries[-1]}"]
        hint = f"; try {tries[0]}" if tries else ""
        raise NoSolutionError(f"{method}: no {structure} lag-{lag} kernel can be fitted to these {k} samples "
                              f"(the problem is numerically singular){hint}")
    fit = res.w_hat
    rows_enu = [fit]
    kinds = ["fit"] * k
    if n_pred > 0:
        try:
            rows_enu.append(res.kernel.predict(fit[-lag:], n_pred))
        except UsageError as exc:
            raise NoSolutionError(f"cannot predict with the identified kernel: {exc}") from None
        kinds += ["predicted"] * n_pred
    all_enu = np.vstack(rows_enu)
    times = traj.t_s[0] + traj.dt_s * np.arange(k + n_pred)
    times[:k] = traj.t_s[:k]
    return Identification(method, structure, res, times, traj.is_gps_time, enu2ecef(all_enu, origin), all_enu,
                          kinds, k, n_pred, traj.dt_s, origin)
