"""A trajectory in a piecewise behavior: consecutive spans, each with its own identified shared kernel.

The spans that ``stls --lag L`` chooses from the data (:mod:`gnss_cli.pipeline.spans`) each hold
a kernel ``r_k(z) I_3`` (root at ``z = 1``). Solved one at a time, each span's position rests on
its own pseudoranges only; the trajectory is one, however, and its measurements (the range rates
of every epoch, the carrier-phase pairs that straddle a switch) tie the spans. This module writes
the piecewise behavior as equality constraints on the per-epoch positions ``x_t`` and velocities
``v_t`` of a run of ``N`` epochs, in the form of :class:`~gnss_cli.behavior.kinematic_solve.MotionTerms`
(so the segment is solved by :func:`~gnss_cli.behavior.kinematic_solve.solve_kinematic`, with the
rows, gates and passes of the measurement-domain smoother):

* the kernel rows of span ``k`` (epochs ``p:q``): ``sum_i r_k,i x_{t0+i} = 0`` for every shift
  ``t0`` whose ``l + 1`` epochs lie in the span;
* the switch from span ``k`` to ``k + 1``: one more row of ``r_k`` at the shift ``t0 = q - l``,
  the last ``l`` epochs of span ``k`` and the first of span ``k + 1`` (span ``k``'s behavior
  carries the trajectory into the next span, whose own rows take over from there), as a soft
  row of standard deviation ``switch_sigma_m``: a manoeuvre that begins between two epochs is
  in neither behavior, so the switch holds only approximately (as a hard row it moved a
  noise-free manoeuvring flight by 8 cm). Without the switch rows the spans would be
  independent; with a hard row of either kernel at every shift the whole run would be a single
  recursion with ``l`` free values per coordinate, which the behavior test rejected (that is
  why the spans are there);
* velocities, with range rates: the rows of the quadrature rule that links positions and
  velocities in ``smoother`` (``x_{t+1} - x_t = dt sum_k c_k v_{t+k}``,
  :func:`~gnss_cli.behavior.kinematic_solve.step_rule`), the kernels' lag's rule but at most
  the quadratic one (:data:`VELOCITY_RULE_LAG`), on every step of the run. The range rates
  then carry the position from epoch to epoch through the velocities they observe, and the
  kernel rows keep the positions in each span's behavior. The rule is exact for velocities of
  its degree, so not for every trajectory of an identified behavior, but its error is small at
  GNSS rates (the noise-free manoeuvring flight stays exact to 1 mm). It replaced the modes'
  derivatives below, which are exact in the behavior but hold the range rates to the derivative
  of a kernel identified from noisy data: on the six training runs of
  ``benchmarks/multi_epoch_fair.py`` (range rates, ``behavior_pfa`` 1e-12, 3D RMS pooled) the
  quadrature rows give 0.435 m against 0.524 m in whole segments, 0.443 against 0.508 m in
  20-epoch windows (``benchmarks/stls_structure.py``). The rule comes with the quadrature
  motion's weak prior on the velocities' second difference
  (:data:`~gnss_cli.behavior.kinematic_solve.JERK_SIGMA_M_S3`; soft rows after the switch rows,
  counted in no misfit), which decides what the rows do not: the velocities of epochs whose range
  rates are few or gated. A run whose spans are all free is then exactly the lag-2 quadrature
  smoother; without the prior, such a run of a simulated urban drive (every span's behavior
  rejected with phase) drifted to 18 m (3D RMS 6.8 m against the smoother's 2.1 m), while the
  Yamatogawa walk and tst2 are the same to 0.1 mm with or without it;
* velocities, without range rates (they are then outputs only):
  ``v_t = F_k[j] x_{t0 : t0+l}`` with ``F_k = log(A_k) / dt`` (the modes' derivative,
  :func:`~gnss_cli.behavior.behavior_solve.mode_derivatives`) and ``t0`` the start of the ``l``
  epochs of the span nearest to ``t`` (``j = t - t0``): exact in the behavior. A span of fewer
  than ``l`` epochs takes its velocities from its kernel's modes on the ``l`` epochs around it
  within its window (``windows``: the epochs on which the behavior test accepted the kernel);
  a kernel without a real logarithm (a root on the negative real axis), the central
  difference of the positions (a row that touches nothing else);
* a span of fewer than ``l`` epochs (the epochs a short window supplies) is too short for its
  kernel rows: its neighbours' switch rows and the measurements hold its positions. A kernel
  row never reaches back into the span before its own (so a short span cannot carry a kernel
  across several others: tried so, on a simulated drive of 148 spans of 2-4 epochs, the track
  was 9 m off, WLS 3.6 m).

With ``latency_sigma_m > 0`` the kernel rows are soft, of that standard deviation (m): the
trajectory is then the behavior's driven by a latent input ``e``, ``r_k(z) x = e`` (the
*latency* of Markovsky's misfit-and-latency models, beside the measurements' misfit), so a
manoeuvre the identified kernel does not hold can leave it at a cost. Zero keeps the trajectory
exactly in each span's behavior; a large value leaves the kernel nothing to say, and the run is
then the quadrature smoother's (with range rates) plus the switch rows.

Every row's coefficients sum to zero (the root at ``z = 1``: a constant position has no kernel
residual and no velocity), so the constraints on absolute positions are written on the
corrections ``z`` and the steps of the linearization points (``hard_step``).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray

from gnss_cli.behavior.behavior_solve import mode_derivatives
from gnss_cli.behavior.kinematic_solve import Motion, MotionTerms, motion_terms

__all__ = ["piecewise_terms", "VELOCITY_RULE_LAG", "velocity_rule"]

F64 = NDArray[np.float64]

#: The largest lag of the quadrature rule that ties the velocities to the positions with range
#: rates (below it, the kernels' lag: the trapezoid for a static ``--lag 1``): the quadratic rule
#: ``dt/12 (-v_{t-1} + 8 v_t + 5 v_{t+1})``. The cubic rule (the kernels' lag 3, used before)
#: integrates a velocity whose acceleration changes abruptly (a car entering a corner) with an
#: error of centimetres per step, which the millimetre phase pairs then carry into the
#: positions: on a simulated drive with phase outside the training and evaluation seeds of
#: ``benchmarks/multi_epoch_fair.py`` (seed 1007) the error stepped by 0.2 m at each of two
#: corners (3D RMS 0.41 m, ``kf ca`` 0.16 m). Chosen on that benchmark's six training runs
#: (``stls --lag 3``, its chosen settings; 3D RMS pooled), lag 1 / 2 / 3: with phase 0.183 /
#: 0.170 / 0.176 m, with range rates 0.434 / 0.435 / 0.433 m; on the four drives of seeds 1004-1007
#: with phase 0.17 / 0.11, 0.32 / 0.24, 0.20 / 0.13, 0.41 / 0.19 m for lag 3 / 2 (their flights
#: unchanged to 6 mm). ``smoother``'s training chose its quadratic rule with phase too.
VELOCITY_RULE_LAG = 2


def velocity_rule(lag: int, range_rates: bool) -> str:
    """How a tied run's velocities are linked to its positions, in the words of the records (module
    docstring): with range rates the quadrature rule of lag ``min(lag, VELOCITY_RULE_LAG)``, else
    the modes' derivatives.

    >>> velocity_rule(3, True), velocity_rule(1, True), velocity_rule(3, False)
    ('velocities by the lag-2 quadrature', 'velocities by the lag-1 quadrature', "velocities from the modes' derivatives")
    """
    return f"velocities by the lag-{min(lag, VELOCITY_RULE_LAG)} quadrature" if range_rates \
        else "velocities from the modes' derivatives"


def _central_difference(t: int, n: int, dt: float) -> tuple[NDArray[np.intp], F64]:
    """Consecutive columns and coefficients of the (one-sided at the ends) difference quotient at
    ``t`` of a run of ``n >= 2`` epochs."""
    lo, hi = max(t - 1, 0), min(t + 1, n - 1)
    coef = np.zeros(hi - lo + 1)
    coef[0], coef[-1] = -1.0 / ((hi - lo) * dt), 1.0 / ((hi - lo) * dt)
    return np.arange(lo, hi + 1), coef


def piecewise_terms(kernels: F64, starts: NDArray[np.intp], n: int, dt_s: F64, switch_sigma_m: float,
                    range_rates: bool = False, windows: NDArray[np.intp] | None = None,
                    free: NDArray[np.bool_] | None = None, latency_sigma_m: float = 0.0,
                    steps_s: F64 | None = None, gap_after: NDArray[np.bool_] | None = None) -> MotionTerms:
    """The piecewise behavior of a run of ``n`` epochs as equality constraints (module docstring).

    Parameters
    ----------
    kernels : ``(K, l+1)``
        Ascending coefficients of each span's shared kernel (root at ``z = 1``).
    starts : ``(K,)``
        First epoch of each span (``starts[0] == 0``, increasing; span ``k`` ends where ``k + 1`` starts).
    n : int
        Epochs of the run (``>= l + 1``).
    dt_s : ``(K,)``
        Sampling interval of each span, s.
    switch_sigma_m : float
        Standard deviation of the switch rows' residuals, m (``> 0``).
    range_rates : bool
        Whether the epochs have range rates: the velocities are then tied to the positions by the
        quadrature rule, else by the modes' derivatives (module docstring).
    windows : ``(K, 2)``, optional
        Without range rates: first and last + 1 epoch (of the run; may reach outside it) of the
        window each span's kernel was identified and tested on (default: the span itself).
    free : ``(K,)`` bool, optional
        Spans without a behavior (no kernel rows, no switch row into the next span): those whose
        behavior the run's measurements rejected (:mod:`gnss_cli.pipeline.tied`). Without range
        rates their velocities are the central differences.
    latency_sigma_m : float
        Standard deviation of the latent input, m (module docstring): 0 (default) makes the
        kernel rows hard, ``> 0`` soft rows of that standard deviation.
    steps_s : ``(n - 1,)``, optional
        With range rates: the run's time steps, s, where they are not each span's interval (a run
        bridging missed epochs, :mod:`gnss_cli.pipeline.tied`); the quadrature rows take them.
    gap_after : ``(K,)`` bool, optional
        Spans followed by a gap (missed epochs): no switch row into the next span, whose first
        epoch is not on the kernel's sampling grid.

    Returns
    -------
    MotionTerms
        On ``u = [x_0..x_{n-1}, v_0..v_{n-1}]`` (per coordinate): the kernel rows hard (soft with
        a latency) and the velocity rows hard, the switch rows soft; the soft rows are counted
        in the misfit.

    Examples
    --------
    A quadratic, then a straight line from epoch 5 on, satisfies its constraints:

    >>> r = np.array([[-1.0, 3.0, -3.0, 1.0], [-0.5, 2.0, -2.5, 1.0]])  # (z - 1)^3, (z - 1)^2 (z - 0.5)
    >>> t = np.arange(10.0)
    >>> x = np.where(t <= 5, t**2, 25 + 10 * (t - 5))                   # velocity 2 t, then 10
    >>> v = np.where(t < 5, 2 * t, 10.0)
    >>> terms = piecewise_terms(r, np.array([0, 5]), 10, np.array([1.0, 1.0]), 0.1)
    >>> u = np.concatenate([x, v])
    >>> bool(np.allclose(terms.hard @ u, 0.0)), bool(np.allclose(terms.soft @ u, 0.0)), terms.soft.shape[0]
    (True, True, 1)
    """
    lag = kernels.shape[1] - 1
    ends = np.append(starts[1:], n)
    rows: list[tuple[NDArray[np.intp], F64]] = []  # (position columns, coefficients); velocity rows below
    switch: list[tuple[NDArray[np.intp], F64]] = []
    vel: list[tuple[int, NDArray[np.intp], F64]] = []
    free = np.zeros(len(starts), dtype=bool) if free is None else free
    gap_after = np.zeros(len(starts), dtype=bool) if gap_after is None else gap_after
    for k, (p, q) in enumerate(zip(starts, ends)):
        r = kernels[k]
        if free[k]:
            continue
        for t0 in range(p, q - lag):
            rows.append((np.arange(t0, t0 + lag + 1), r))
        if q < n and q - lag >= p and not gap_after[k]:  # the switch row at q - l, into the next span
            switch.append((np.arange(q - lag, q + 1), r))
    soft_rows, sigmas = switch, np.full(len(switch), switch_sigma_m)
    if latency_sigma_m > 0:  # the kernel rows join the switch rows as soft rows
        soft_rows, sigmas = rows + switch, np.concatenate([np.full(len(rows), latency_sigma_m), sigmas])
        rows = []
    soft, soft_step = _position_rows(soft_rows, n)
    weight = sp.diags(sigmas**-2.0, format="csr")
    if range_rates:
        steps = np.repeat(dt_s, ends - starts)[:-1] if steps_s is None else steps_s
        step = motion_terms(Motion("quadrature", lag=min(lag, VELOCITY_RULE_LAG)), steps)
        kern, kern_step = _position_rows(rows, n)
        return MotionTerms(sp.vstack([kern, step.hard], format="csr"), sp.vstack([kern_step, step.hard_step], format="csr"),
                           sp.vstack([soft, step.soft], format="csr"), sp.vstack([soft_step, step.soft_step], format="csr"),
                           sp.block_diag([weight, step.soft_weight], format="csr"), soft.shape[0])
    deriv, has_v = mode_derivatives(kernels, dt_s)
    for k, (p, q) in enumerate(zip(starts, ends)):
        lo, hi = (p, q) if q - p >= lag or windows is None else (max(windows[k, 0], 0), min(windows[k, 1], n))
        for t in range(p, q):
            if has_v[k] and hi - lo >= lag and not free[k]:
                t0 = min(max(t - (lag - 1) // 2, lo), hi - lag)
                vel.append((t, np.arange(t0, t0 + lag), deriv[k, t - t0]))
            else:
                cols, coef = _central_difference(t, n, float(dt_s[k]))
                vel.append((t, cols, coef))
    hard, hard_step = _position_rows(rows + [(c, -f) for _, c, f in vel], n)
    hard = hard + sp.csr_matrix((np.ones(len(vel)), (len(rows) + np.arange(len(vel)), n + np.array([t for t, _, _ in vel],
                                dtype=np.intp))), shape=hard.shape)
    return MotionTerms(hard.tocsr(), hard_step, soft, soft_step, weight, soft.shape[0])


def _position_rows(rows: list[tuple[NDArray[np.intp], F64]], n: int) -> tuple[sp.csr_matrix, sp.csr_matrix]:
    """Rows ``sum_i a_i x_{c_i}`` (consecutive columns ``c``, the ``a`` summing to 0) on ``u`` and on the steps:
    ``sum_i a_i x_{c_i} = sum_j s_{c_0 + j} sum_{m > j} a_m`` for the linearization points' steps ``s``."""
    r_i: list[int] = []
    c_i: list[int] = []
    val: list[float] = []
    s_i: list[int] = []
    s_c: list[int] = []
    s_v: list[float] = []
    for i, (cols, coef) in enumerate(rows):
        r_i += [i] * cols.size
        c_i += cols.tolist()
        val += coef.tolist()
        tail = np.cumsum(coef[::-1])[::-1][1:]
        s_i += [i] * tail.size
        s_c += cols[:-1].tolist()
        s_v += tail.tolist()
    return (sp.csr_matrix((val, (r_i, c_i)), shape=(len(rows), 2 * n)),
            sp.csr_matrix((s_v, (s_i, s_c)), shape=(len(rows), max(n - 1, 0))))
