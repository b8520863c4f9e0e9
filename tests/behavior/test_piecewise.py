"""The piecewise identified behavior as constraints (:mod:`gnss_cli.behavior.piecewise`): a trajectory
built span by span from its kernels satisfies every row, the velocity rows give the continuous-time
derivative (without range rates) or integrate to the steps (with them), the step form equals the
rows on absolute positions, a free span has no behavior, and a broken switch shows in its row."""

from __future__ import annotations

import numpy as np
import pytest

from gnss_cli.behavior.behavior_solve import mode_derivatives
from gnss_cli.behavior.kernel import shared_kernel_coefficients
from gnss_cli.behavior.kinematic_solve import Motion, motion_terms
from gnss_cli.behavior.piecewise import VELOCITY_RULE_LAG, piecewise_terms


def _kernel_with_roots(roots: list[complex]) -> np.ndarray:
    """Ascending real coefficients of ``prod (z - root)`` (complex roots in conjugate pairs)."""
    return np.real(np.poly(roots))[::-1].copy()


def _continue(r: np.ndarray, x: list[float], n: int) -> list[float]:
    """``x`` continued by the recursion ``sum_i r_i x_{t+i} = 0`` to ``n`` samples."""
    out = list(x)
    while len(out) < n:
        lag = r.size - 1
        out.append(-float(np.dot(r[:lag], out[-lag:])) / r[lag])
    return out


def test_a_trajectory_built_span_by_span_satisfies_every_row() -> None:
    """Three spans (a quadratic, a slow turn's mode pair, a decaying mode), the trajectory carried
    across each switch by the span before's recursion: hard rows and switch rows vanish."""
    w = 0.2
    kernels = np.stack([
        shared_kernel_coefficients((1.0, 1.0, 1.0)),                              # (z - 1)^3
        _kernel_with_roots([1.0, np.exp(1j * w), np.exp(-1j * w)]),               # a constant-rate turn
        _kernel_with_roots([1.0, 1.0, 0.8]),
    ])
    starts = np.array([0, 12, 25])
    n = 40
    rng = np.random.default_rng(3)
    x: list[float] = list(rng.normal(size=3))
    for k, (p, q) in enumerate(zip(starts, [*starts[1:], n])):
        x = _continue(kernels[k], x, q + (1 if q < n else 0))[: q + (1 if q < n else 0)]
        if q < n:  # the next span starts from the switch epoch and two free values after it
            x = x[: q + 1] + list(rng.normal(size=2) + x[q])
    x_arr = np.asarray(x[:n])
    terms = piecewise_terms(kernels, starts, n, np.ones(3), 0.05)
    # velocities from the modes, each span's on its own epochs
    F, ok = mode_derivatives(kernels, np.ones(3))
    assert ok.all()
    v = np.zeros(n)
    for k, (p, q) in enumerate(zip(starts, [*starts[1:], n])):
        for t in range(p, q):
            t0 = min(max(t - 1, p), q - 3)
            v[t] = F[k, t - t0] @ x_arr[t0 : t0 + 3]
    u = np.concatenate([x_arr, v])
    scale = np.abs(x_arr).max()
    assert np.abs(terms.hard @ u).max() < 1e-9 * scale
    assert terms.soft.shape[0] == 2 and np.abs(terms.soft @ u).max() < 1e-9 * scale
    assert terms.counted and np.allclose(terms.soft_weight.diagonal(), 1 / 0.05**2)


def test_velocity_rows_are_the_derivative_of_the_continuous_motion() -> None:
    """``x(t) = a + c sin(w t) + d cos(w t)`` (a coordinate of a constant-rate turn) sampled at ``dt``:
    the kernel ``(z - 1)(z^2 - 2 cos(w dt) z + 1)`` holds it, and the velocity rows give
    ``c w cos(w t) - d w sin(w t)`` (not a difference quotient)."""
    dt, w = 0.5, 0.3
    t = np.arange(20) * dt
    x = 2.0 + 4.0 * np.sin(w * t) - 1.5 * np.cos(w * t)
    v = 4.0 * w * np.cos(w * t) + 1.5 * w * np.sin(w * t)
    r = _kernel_with_roots([1.0, np.exp(1j * w * dt), np.exp(-1j * w * dt)])
    terms = piecewise_terms(r[None], np.array([0]), t.size, np.array([dt]), 1.0)
    assert np.abs(terms.hard @ np.concatenate([x, v])).max() < 1e-9
    diff = np.gradient(x, dt)  # a difference quotient does not satisfy them
    assert np.abs(terms.hard @ np.concatenate([x, diff])).max() > 1e-3


def test_with_range_rates_the_velocities_integrate_to_the_steps() -> None:
    """With range rates, the velocity rows are the quadratic quadrature rule's: a sampled
    constant-rate turn (1 s, 0.1 rad/s, 50 m/s) with its continuous velocity satisfies every hard
    row to 2.5 mm (the rule's error, about ``dt^4 / 24`` times the velocity's third derivative:
    2.1 mm; the kernel rows exactly), a velocity 1 % too large does not."""
    dt, w, speed = 1.0, 0.1, 50.0
    t = np.arange(30) * dt
    x = 7.0 + speed / w * np.sin(w * t)
    v = speed * np.cos(w * t)
    r = _kernel_with_roots([1.0, np.exp(1j * w * dt), np.exp(-1j * w * dt)])
    terms = piecewise_terms(np.stack([r, r]), np.array([0, 14]), t.size, np.array([dt, dt]), 1.0, True)
    n = t.size
    velocity = np.asarray(abs(terms.hard[:, n:]).sum(axis=1)).ravel() != 0
    assert int(velocity.sum()) == n - 1
    assert np.abs(terms.hard[~velocity] @ np.concatenate([x, v])).max() < 1e-9 * speed / w
    assert np.abs(terms.hard @ np.concatenate([x, v])).max() < 2.5e-3
    assert np.abs(terms.hard @ np.concatenate([x, 1.01 * v])).max() > 0.1


@pytest.mark.parametrize("range_rates", [False, True])
def test_step_form_equals_the_rows_on_absolute_positions(range_rates: bool) -> None:
    """Every row's coefficients sum to zero, so ``rows @ x == step rows @ diff(x)`` for any ``x``
    (the form in which the constraints act on corrections about linearization points); a span
    shorter than the lag has no kernel rows; without range rates its velocities come from its
    window's modes (a row per epoch), with them every step has its quadrature row."""
    kernels = np.stack([shared_kernel_coefficients((1.0, 0.9, 1.0)), shared_kernel_coefficients((1.0, 0.5, 0.7)),
                        shared_kernel_coefficients((1.0, 1.0, 1.0))])
    starts, n = np.array([0, 9, 11]), 20
    windows = np.array([[0, 12], [6, 15], [8, 20]])
    terms = piecewise_terms(kernels, starts, n, np.ones(3), 0.1, range_rates, windows)
    x = np.random.default_rng(0).normal(size=n) * 1e3 + 6.4e6
    for rows, steps in ((terms.hard, terms.hard_step), (terms.soft, terms.soft_step)):
        assert np.allclose(rows[:, :n] @ x, steps @ np.diff(x), rtol=0, atol=1e-6)
    kernel_rows = terms.hard[:, :n][np.asarray(terms.hard[:, n:].sum(axis=1)).ravel() == 0]
    # the short span 9:11 (2 epochs < lag 3): no kernel row starts in it
    starts_of_rows = np.array([row.indices.min() for row in kernel_rows])
    assert not np.isin(starts_of_rows, [9, 10]).any()
    n_velocity_rows = int(np.asarray(terms.hard[:, n:].sum(axis=1)).ravel().astype(bool).sum())
    assert n_velocity_rows == (n - 1 if range_rates else n)  # without: epochs 9-10 from their window 6:15


@pytest.mark.parametrize("range_rates", [False, True])
def test_a_free_span_has_no_behavior(range_rates: bool) -> None:
    """A span marked free takes no kernel rows and no switch row into the next span: a trajectory
    that jumps about inside it satisfies every kernel row and the one remaining switch row (into
    it), which the same trajectory breaks when the span is not free."""
    r = shared_kernel_coefficients((1.0, 1.0, 1.0))
    kernels = np.stack([r, r, r])
    starts, n = np.array([0, 8, 14]), 22
    t = np.arange(n, dtype=float)
    x = 0.5 * t**2
    x[8:14] += np.random.default_rng(1).normal(size=6)  # no motion inside the middle span
    x[14:] = 0.5 * t[14:] ** 2 + 3.0                    # a new quadratic after it
    free = np.array([False, True, False])
    terms = piecewise_terms(kernels, starts, n, np.ones(3), 0.1, range_rates, free=free)
    kernel = np.asarray(abs(terms.hard[:, n:]).sum(axis=1)).ravel() == 0
    assert int(kernel.sum()) == (8 - 3) + (8 - 3)
    assert np.abs(terms.hard[kernel][:, :n] @ x).max() < 1e-9
    assert terms.counted == 1 and abs((terms.soft[:1, :n] @ x)[0] - r[-1] * (x[8] - 0.5 * 64)) < 1e-9
    tied = piecewise_terms(kernels, starts, n, np.ones(3), 0.1, range_rates)
    tied_kernel = np.asarray(abs(tied.hard[:, n:]).sum(axis=1)).ravel() == 0
    assert np.abs(tied.hard[tied_kernel][:, :n] @ x).max() > 0.1 and tied.counted == 2


def test_a_run_of_free_spans_with_range_rates_is_the_quadrature_smoothers_motion() -> None:
    """With range rates and every span free, the run's terms are exactly ``smoother``'s quadrature
    motion of the same lag (:data:`VELOCITY_RULE_LAG`): its rule as hard rows and its weak prior on
    the velocities' second difference, which counts in no misfit. (Without the prior the velocities
    that no row observes were free: a simulated urban drive whose spans were all free drifted to
    18 m, 6.8 m 3D RMS against the quadrature smoother's 2.1 m.) With a behavior, the prior follows
    the counted switch rows."""
    r = shared_kernel_coefficients((1.0, 1.0, 1.0))
    starts, n = np.array([0, 8, 14]), 22
    steps = np.r_[np.ones(10), 2.0, np.ones(10)]  # a missed epoch bridged
    free = piecewise_terms(np.stack([r, r, r]), starts, n, np.ones(3), 0.1, True, free=np.ones(3, bool), steps_s=steps)
    smoother = motion_terms(Motion("quadrature", VELOCITY_RULE_LAG), steps)
    for a, b in ((free.hard, smoother.hard), (free.hard_step, smoother.hard_step), (free.soft, smoother.soft),
                 (free.soft_step, smoother.soft_step), (free.soft_weight, smoother.soft_weight)):
        assert a.shape == b.shape and abs(a - b).max() == 0
    assert free.counted == smoother.counted == 0 and smoother.soft.shape[0] == n - 2
    tied = piecewise_terms(np.stack([r, r, r]), starts, n, np.ones(3), 0.1, True, steps_s=steps)
    assert tied.counted == 2 and abs(tied.soft[2:] - smoother.soft).max() == 0


def test_a_broken_switch_shows_in_its_row() -> None:
    """A jump of ``d`` at the switch epoch gives that switch row the residual ``r_l d``."""
    r = shared_kernel_coefficients((1.0, 1.0, 1.0))
    kernels = np.stack([r, r])
    t = np.arange(12.0)
    x = 0.5 * t**2
    x_jump = x.copy()
    x_jump[6:] += 0.3
    terms = piecewise_terms(kernels, np.array([0, 6]), 12, np.ones(2), 0.1)
    n = 12
    assert abs((terms.soft[:, :n] @ x)[0]) < 1e-12
    assert (terms.soft[:, :n] @ x_jump)[0] == pytest.approx(r[-1] * 0.3, abs=1e-12)
    assert np.abs(terms.hard[:, :n][np.asarray(terms.hard[:, n:].sum(axis=1)).ravel() == 0] @ x_jump).max() < 1e-9


@pytest.mark.parametrize("range_rates", [False, True])
def test_a_latency_moves_the_kernel_rows_to_the_soft_rows(range_rates: bool) -> None:
    """With ``latency_sigma_m`` the kernel rows leave the equality constraints and lead the soft
    rows, unchanged and weighted ``1 / sigma^2``, before the switch rows and their own weight; the
    velocity rows stay hard."""
    kernels = np.stack([shared_kernel_coefficients((1.0, 0.9, 1.0)), shared_kernel_coefficients((1.0, 1.0, 1.0))])
    starts, n = np.array([0, 9]), 18
    exact = piecewise_terms(kernels, starts, n, np.ones(2), 0.1, range_rates)
    soft = piecewise_terms(kernels, starts, n, np.ones(2), 0.1, range_rates, latency_sigma_m=0.02)
    kernel = np.asarray(abs(exact.hard[:, n:]).sum(axis=1)).ravel() == 0
    k = int(kernel.sum())
    assert k == (9 - 3) + (9 - 3) and soft.hard.shape[0] == exact.hard.shape[0] - k
    assert (soft.hard != exact.hard[~kernel]).nnz == 0 and (soft.hard_step != exact.hard_step[~kernel]).nnz == 0
    assert (soft.soft[:k] != exact.hard[kernel]).nnz == 0 and (soft.soft[k:] != exact.soft).nnz == 0
    assert (soft.soft_step[:k] != exact.hard_step[kernel]).nnz == 0
    assert np.allclose(soft.soft_weight.diagonal(), np.r_[np.full(k, 0.02**-2), exact.soft_weight.diagonal()])
    assert soft.counted == k + exact.counted and np.allclose(exact.soft_weight.diagonal()[:exact.counted], 0.1**-2)
