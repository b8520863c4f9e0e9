"""Doppler-aided behavioral smoothing (``[smoothing] model = "kinematic"``).

The signal of an epoch is ``w_t = (x_t - x_0, v_t)``: the WLS fix (ECEF, m, relative to the
segment's first fix) and the Doppler velocity at that fix (ECEF, m/s,
:func:`~gnss_cli.pipeline.velocity.solve_velocity`). Position and velocity are tied by the
kinematic kernel, lag 1 on six variables::

    R(z) = [ (z - 1) I_3,  -(dt/2)(z + 1) I_3 ],  i.e.  x_{t+1} - x_t = dt/2 (v_t + v_{t+1}),

the trapezoidal rule, exact for constant acceleration (the error of a step is
``dt^3 j / 12`` for a jerk ``j``). Each segment of uniformly sampled epochs is projected onto
the behavior of this kernel (:func:`~gnss_cli.behavior.projection.misfit`, O(T), the whole
segment at once: there are no windows), with the a-priori covariances of the fixes (WLS) and
of the velocities (Doppler WLS) scaled by one variance factor each, estimated from the data
(:func:`~gnss_cli.behavior.variance_components.project_with_variance_components`): the
configured pseudorange and Doppler sigmas set only the shape of the weights, not the balance
between the two, so nothing is tuned per data set. An epoch without a fix or without a
velocity keeps its other half (the missing one gets a variance of 1e16); an epoch with
neither splits the segment.

The receiver clocks are re-estimated at the smoothed positions as for the other smoothing
models. The covariance and DOP columns of the smoothed rows are those of the WLS fix (the
projection's own covariance is not computed yet); the velocity columns are the smoothed
velocities.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from gnss_cli.behavior import KernelRepresentation
from gnss_cli.behavior.records import kernel_record
from gnss_cli.behavior.variance_components import project_with_variance_components
from gnss_cli.behavior.windows import segments
from gnss_cli.config import ProcessingConfig
from gnss_cli.errors import ConfigError
from gnss_cli.pipeline.results import EpochData, EpochStatus, MethodSolution, WindowModel
from gnss_cli.pipeline.smoothing import finish_smoothing
from gnss_cli.pipeline.velocity import solve_velocity

__all__ = ["kinematic_kernel", "kinematic_smooth", "MISSING_VARIANCE"]

F64 = NDArray[np.float64]

#: Variance (m^2, (m/s)^2) given to a missing fix or velocity: it then has no weight.
MISSING_VARIANCE = 1e16
#: Fewest epochs with a fix a segment needs to be smoothed.
MIN_FIXES = 2
_GROUPS = [slice(0, 3), slice(3, 6)]


def kinematic_kernel(dt_s: float) -> KernelRepresentation:
    """``R(z) = [(z - 1) I, -(dt/2)(z + 1) I]`` on ``(position m, velocity m/s)``.

    >>> k = kinematic_kernel(1.0)
    >>> import numpy as np
    >>> t = np.arange(5.0)[:, None]
    >>> w = np.hstack([0.5 * t**2 * [1, 2, 3], t * [1, 2, 3]])  # constant acceleration
    >>> bool(k.annihilates(w, rtol=1e-12))
    True
    """
    eye = np.eye(3)
    return KernelRepresentation(np.hstack([-eye, -dt_s / 2 * eye, eye, -dt_s / 2 * eye]), q=6)


def kinematic_smooth(data: EpochData, wls: MethodSolution, config: ProcessingConfig, *,
                     method: str = "stls", gap_factor: float = 1.5) -> tuple[MethodSolution, tuple[WindowModel, ...]]:
    """Smooth the WLS fixes with their Doppler velocities (module docstring).

    Parameters
    ----------
    data : EpochData
        Prepared epochs with range rates (an observation file with Doppler).
    wls : MethodSolution
        The WLS fixes (``cov_m2`` m^2, ``sigma_m`` the pseudorange sigmas of the used rows).
    config : ProcessingConfig
        ``doppler_sigma_m_s`` and the clock solve's settings.
    method : str
        Method key of the result.
    gap_factor : float
        A step longer than ``gap_factor`` times the median step splits a segment.

    Returns
    -------
    solution, models
        Smoothed positions (ECEF, m) and velocities (m/s), status ``ok`` on smoothed epochs
        that had a WLS fix; an epoch without one (integrity_fail, ...) keeps its status and
        no position; the WLS row elsewhere; one
        :class:`WindowModel` per segment (``misfit``: the weighted misfit with the estimated
        factors, ``message``: the factors).

    Raises
    ------
    ConfigError
        The observation file has no Doppler.
    """
    sigma = wls.sigma_m if wls.sigma_m is not None else np.where(data.usable, 1.0, np.nan)
    vel = solve_velocity(data, wls.x_ecef_m, sigma, config)
    if vel is None:
        raise ConfigError(f"smoothing.model = 'kinematic' needs Doppler observations; {data.obs_path} has none")
    T = data.time_gps_s.size
    has_x = (wls.status == EpochStatus.OK.value) & np.isfinite(wls.x_ecef_m).all(axis=1) \
        & np.isfinite(wls.cov_m2[:, :3, :3]).all(axis=(1, 2))
    has_v = np.isfinite(vel.vel_ecef_m_s).all(axis=1) & np.isfinite(vel.cov[:, :3, :3]).all(axis=(1, 2))
    x_s = wls.x_ecef_m.copy()
    v_s = np.where(has_x[:, None], vel.vel_ecef_m_s, np.nan)
    status = wls.status.astype("<U24").copy()
    smoothed = np.zeros(T, dtype=bool)
    models: list[WindowModel] = []
    for k, idx in enumerate(segments(data.time_gps_s, has_x | has_v, gap_factor)):
        if has_x[idx].sum() < MIN_FIXES:
            continue
        dt = float(np.median(np.diff(data.time_gps_s[idx]))) if idx.size > 1 else 1.0
        origin = wls.x_ecef_m[idx[has_x[idx]][0]]
        w, cov = _signal(wls, vel.vel_ecef_m_s, vel.cov, idx, has_x, has_v, origin)
        fit = project_with_variance_components(w, kinematic_kernel(dt), cov, _GROUPS)
        x_s[idx] = origin + fit.w_hat[:, :3]
        v_s[idx] = fit.w_hat[:, 3:]
        status[idx[has_x[idx]]] = EpochStatus.OK.value  # an epoch without its own fix keeps its status
        smoothed[idx] = True
        models.append(WindowModel(
            segment=k, window=0, start_time_gps_s=float(data.time_gps_s[idx[0]]),
            end_time_gps_s=float(data.time_gps_s[idx[-1]]), n_epochs=int(idx.size), model="kinematic",
            structure="full", kernel=kernel_record(kinematic_kernel(dt)), misfit=fit.misfit, status="converged",
            message=(f"variance factors: fixes {fit.factors[0]:.4g}, Doppler velocities {fit.factors[1]:.4g} "
                     f"({fit.iterations} projections)"),
        ))
    sol = finish_smoothing(data, wls, config, x_s, status, smoothed, [], method)
    return replace(sol, vel_ecef_m_s=np.where(smoothed[:, None], v_s, sol.vel_ecef_m_s
                                              if sol.vel_ecef_m_s is not None else np.nan)), tuple(models)


def _signal(wls: MethodSolution, vel: F64, vel_cov: F64, idx: NDArray[np.intp], has_x: NDArray[np.bool_],
            has_v: NDArray[np.bool_], origin: F64) -> tuple[F64, F64]:
    """``w (n, 6)`` and block-diagonal ``cov (n, 6, 6)`` of a segment; missing halves get no weight."""
    n = idx.size
    hx, hv = has_x[idx], has_v[idx]
    w = np.zeros((n, 6))
    w[:, :3] = np.where(hx[:, None], wls.x_ecef_m[idx] - origin, 0.0)
    w[:, 3:] = np.where(hv[:, None], vel[idx], 0.0)
    cov = np.zeros((n, 6, 6))
    big = MISSING_VARIANCE * np.eye(3)
    cov[:, :3, :3] = np.where(hx[:, None, None], wls.cov_m2[idx, :3, :3], big)
    cov[:, 3:, 3:] = np.where(hv[:, None, None], vel_cov[idx, :3, :3], big)
    return w, cov
