"""Per-epoch receiver velocity and clock drift from Doppler (weighted least squares).

At each epoch's position (the method's fix), the range rates of the satellites the fix used
(:attr:`~gnss_cli.pipeline.results.MethodSolution.sigma_m` finite: above the mask, usable, not
excluded by the integrity monitoring) give the linear system of
:func:`gnss_cli.gnss.doppler.range_rate_system` in ``[v_x, v_y, v_z, d]``: the velocity
(ECEF, m/s) and one receiver clock drift ``d`` (m/s) common to every system (all of them
share the receiver's oscillator). The model is linear in the unknowns, so one weighted
solve per epoch (all epochs at once) is exact.

Weights: the range-rate sigma of satellite ``i`` is ``doppler_sigma_m_s * sigma_i / median_j sigma_j``
with ``sigma`` the pseudorange sigmas of the epoch (the weight model's elevation and URA
shape, scaled so that a typical satellite of the epoch has ``doppler_sigma_m_s``).
``gdop_vel = sqrt(trace(J J^T))`` with ``J`` the estimator's gain, as the position DOPs
(velocity and drift; unitless).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from gnss_cli.config import ProcessingConfig
from gnss_cli.gnss.doppler import range_rate_system
from gnss_cli.gnss.range_model import width_groups
from gnss_cli.pipeline.results import EpochData, MethodSolution, RunResult
from gnss_cli.solvers import solve_batch

F64 = NDArray[np.float64]

__all__ = ["VelocitySolution", "doppler_sigma_m_s", "solve_velocity", "with_velocity"]


@dataclass(frozen=True)
class VelocitySolution:
    """Per-epoch velocity from Doppler (NaN where fewer than 4 range rates were usable).

    Attributes
    ----------
    vel_ecef_m_s : ``(T, 3)`` receiver velocity, ECEF, m/s.
    clock_drift_m_s : ``(T,)`` receiver clock drift times c, m/s.
    cov : ``(T, 4, 4)`` covariance of ``[v, d]`` for the configured sigmas, (m/s)^2.
    gdop_vel : ``(T,)`` ``sqrt(trace(J J^T))`` of the velocity estimator, unitless.
    n_used : ``(T,)`` range rates used.
    """

    vel_ecef_m_s: F64
    clock_drift_m_s: F64
    cov: F64
    gdop_vel: F64
    n_used: NDArray[np.int64]


def doppler_sigma_m_s(sigma_pr_m: F64, config: ProcessingConfig) -> F64:
    """``(T, n)`` range-rate sigmas (m/s) from the pseudorange sigmas ``(T, n)`` (module docstring)."""
    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # epochs without a used row: NaN
        median = np.nanmedian(sigma_pr_m, axis=1, keepdims=True)
    return config.doppler_sigma_m_s * sigma_pr_m / median


def solve_velocity(data: EpochData, x_ecef_m: F64, sigma_pr_m: F64, config: ProcessingConfig) -> VelocitySolution | None:
    """Velocity and clock drift of every epoch at the positions ``x_ecef_m`` ``(T, 3)``.

    ``sigma_pr_m`` ``(T, n)``: the pseudorange sigmas of the rows the fix used (NaN = not used).
    None when the observation file has no Doppler.
    """
    if data.range_rate_m_s is None or data.sat_vel_ecef_m_s is None or data.sat_clock_drift_s_s is None:
        return None
    T = data.time_gps_s.size
    have_x = np.isfinite(x_ecef_m).all(axis=1)
    x = np.where(have_x[:, None], x_ecef_m, 0.0)
    H, y = range_rate_system(data.sat_ecef_m, data.sat_vel_ecef_m_s, data.sat_clock_drift_s_s, data.range_rate_m_s, x)
    sigma = doppler_sigma_m_s(sigma_pr_m, config)
    mask = have_x[:, None] & np.isfinite(y) & np.isfinite(sigma) & np.isfinite(H).all(axis=-1)
    x_v, cov, q_trace = np.full((T, 4), np.nan), np.full((T, 4, 4), np.nan), np.full(T, np.nan)
    # the used rows only, in satellite order, padded to a width of the epoch's own
    # (:func:`~gnss_cli.gnss.range_model.width_groups`): an epoch uses a third of a multi-GNSS
    # file's satellites, and the solve's work grows with the rows
    for idx, width in width_groups(mask, max(T, 1)):
        order = np.argsort(~mask[idx], axis=1, kind="stable")[:, :width]
        pad = width - order.shape[1]  # (a file with fewer satellites than the width)
        used = np.pad(np.take_along_axis(mask[idx], order, axis=1), ((0, 0), (0, pad)))
        Hg = np.pad(np.take_along_axis(H[idx], order[..., None], axis=1), ((0, 0), (0, pad), (0, 0)))
        yg, sg = (np.pad(np.take_along_axis(v[idx], order, axis=1), ((0, 0), (0, pad))) for v in (y, sigma))
        res = solve_batch("wls", np.where(used[..., None], Hg, 0.0), np.where(used, yg, 0.0), used,
                          weights=np.where(used, 1.0 / np.where(used, sg, 1.0) ** 2, 0.0))
        ok = res.status > 0
        gain = np.where(used[:, None, :], res.gain, 0.0)
        q_diag = np.einsum("tmn,tmn->tm", gain, gain)  # the diagonal of gain gain^T: the GDOP needs its trace only
        x_v[idx] = np.where(ok[:, None], res.x, np.nan)
        cov[idx] = np.where(ok[:, None, None], res.cov, np.nan)
        q_trace[idx] = np.where(ok, np.sqrt(np.clip(q_diag.sum(axis=1), 0.0, None)), np.nan)
    return VelocitySolution(
        vel_ecef_m_s=x_v[:, :3],
        clock_drift_m_s=x_v[:, 3],
        cov=cov,
        gdop_vel=q_trace,
        n_used=mask.sum(axis=1),
    )


def with_velocity(result: RunResult, config: ProcessingConfig) -> RunResult:
    """Every solution without a velocity of its own gets the Doppler velocity at its fixes (a file with Doppler)."""
    if result.epochs.range_rate_m_s is None:
        return result
    out: dict[str, MethodSolution] = {}
    for m, s in result.solutions.items():
        if s.vel_ecef_m_s is None:
            sigma = s.sigma_m if s.sigma_m is not None else result.solutions.get("wls", s).sigma_m
            vel = solve_velocity(result.epochs, s.x_ecef_m, sigma if sigma is not None else result.epochs.usable * 1.0, config)
            if vel is not None:
                s = replace(s, vel_ecef_m_s=vel.vel_ecef_m_s, clock_drift_m_s=vel.clock_drift_m_s, gdop_vel=vel.gdop_vel)
        out[m] = s
    return replace(result, solutions=out)
