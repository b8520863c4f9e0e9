"""Conformance suite: every registered method obeys the same contract."""

from __future__ import annotations

import numpy as np
import pytest
from solver_cases import method_kwargs, sky_matrix

from gnss_cli.errors import UsageError
from gnss_cli.solvers import METHODS, REGISTRY, BatchResult, SolveResult, Status, solve, solve_batch


# The registry seen from outside: its entries against the solver modules and an independent solution.
_MODULE_OF = {"wls": "ls"}  # weighted LS lives with LS; every other method has a module of its own name


def _solver_functions() -> set[object]:
    """Every ``solve_*_batch`` function defined in a module of gnss_cli.solvers (found by import, not the registry)."""
    import importlib
    import inspect
    import pkgutil

    import gnss_cli.solvers as pkg

    found = set()
    for info in pkgutil.iter_modules(pkg.__path__):
        mod = importlib.import_module(f"gnss_cli.solvers.{info.name}")
        found |= {f for name, f in inspect.getmembers(mod, inspect.isfunction)
                  if name.startswith("solve_") and name.endswith("_batch") and f.__module__ == mod.__name__}
    return found


def test_registry_holds_every_solver_module_function_once() -> None:
    functions = [REGISTRY[name].function for name in METHODS]
    assert len(set(functions)) == len(METHODS)
    assert set(functions) == _solver_functions()
    for name in METHODS:
        entry = REGISTRY[name]
        assert entry.name == name
        assert entry.function.__module__ == f"gnss_cli.solvers.{_MODULE_OF.get(name, name)}"
        assert entry.function.__name__ == f"solve_{name}_batch"


def _problem(A: np.ndarray, q: np.ndarray, w: np.ndarray | None = None):
    from gnss_cli.solvers.problem import Problem

    used = np.ones(q.shape, dtype=bool)
    sqrt_w = np.ones(q.shape) if w is None else np.sqrt(w)
    return Problem(A=A, q=q, sqrt_w=sqrt_w, used=used, exact_columns=(), row_cov=None)


@pytest.mark.parametrize("method", METHODS)
def test_registry_functions_solve_a_small_problem(method: str) -> None:
    rng = np.random.default_rng(11)
    T, n = 3, 9
    A = np.stack([sky_matrix(rng, n) for _ in range(T)])
    x_true = rng.normal(0.0, 20.0, (T, 4))
    w = rng.uniform(0.5, 2.0, (T, n))
    fn = REGISTRY[method].function
    # consistent data: every estimator returns the exact solution
    exact = fn(_problem(A, np.einsum("tnm,tm->tn", A, x_true)))
    np.testing.assert_allclose(exact.x, x_true, rtol=0, atol=1e-8)
    # noisy data: LS and WLS equal numpy's least squares on the (weighted) system
    q = np.einsum("tnm,tm->tn", A, x_true) + rng.normal(0.0, 3.0, (T, n))
    if method in ("ls", "wls"):
        weights = w if method == "wls" else np.ones((T, n))
        res = fn(_problem(A, q, weights))
        sw = np.sqrt(weights)
        expected = np.stack([np.linalg.lstsq(sw[t, :, None] * A[t], sw[t] * q[t], rcond=None)[0] for t in range(T)])
        np.testing.assert_allclose(res.x, expected, rtol=0, atol=1e-9)


def _noisy_batch(rng: np.random.Generator, T: int, n: int, sigma_a: float, sigma_q: float):
    A_true = np.stack([sky_matrix(rng, n) for _ in range(T)])
    x_true = rng.normal(0.0, 10.0, size=(T, 4))
    q = np.einsum("tnm,tm->tn", A_true, x_true) + rng.normal(0.0, sigma_q, (T, n))
    A = A_true.copy()
    A[:, :, :3] += rng.normal(0.0, sigma_a, (T, n, 3))
    return A, q, x_true


@pytest.mark.parametrize("method", METHODS)
def test_exact_recovery_on_consistent_data(method: str) -> None:
    rng = np.random.default_rng(1)
    for n in (4, 5, 8, 12):
        A = sky_matrix(rng, n)
        x_true = rng.normal(0.0, 50.0, 4)
        res = solve(method, A, A @ x_true, **method_kwargs(method))
        assert isinstance(res, SolveResult)
        assert res.status == Status.CONVERGED and res.success
        np.testing.assert_allclose(res.x, x_true, rtol=0, atol=1e-9 * (1 + np.abs(x_true).max()))
        np.testing.assert_allclose(res.residuals, 0.0, atol=1e-8)


@pytest.mark.parametrize("method", METHODS)
def test_agrees_with_lstsq_when_perturbations_vanish(method: str) -> None:
    """Differences from LS are second order in the perturbation: they shrink ~100x per 10x."""
    rng = np.random.default_rng(2)
    A0 = sky_matrix(rng, 9)
    x_true = rng.normal(0.0, 5.0, 4)
    dq = rng.normal(size=9)
    dA = np.zeros((9, 4))
    dA[:, :3] = rng.normal(size=(9, 3))
    diffs = []
    for eps in (1e-3, 1e-4, 1e-5):
        A = A0 + eps * dA
        q = A0 @ x_true + eps * dq
        ref = np.linalg.lstsq(A, q, rcond=None)[0]
        res = solve(method, A, q, **method_kwargs(method))
        assert res.success
        diffs.append(np.abs(res.x - ref).max())
    if method in ("ls", "wls"):
        assert max(diffs) < 1e-10
    else:
        # second order: each 10x smaller perturbation shrinks the difference ~100x
        assert diffs[1] < diffs[0] / 50 and diffs[2] < diffs[1] / 50
        assert diffs[2] < 1e-7


@pytest.mark.parametrize("method", METHODS)
def test_batch_equals_single_epochs_and_mask_removes_rows(method: str) -> None:
    rng = np.random.default_rng(3)
    T, n = 6, 10
    A, q, _ = _noisy_batch(rng, T, n, 0.01, 1.0)
    mask = np.ones((T, n), dtype=bool)
    for t in range(T):
        mask[t, rng.choice(n, size=t % 4, replace=False)] = False
    A_nan, q_nan = A.copy(), q.copy()
    A_nan[~mask] = np.nan  # masked rows may hold garbage
    q_nan[~mask] = np.inf
    res = solve_batch(method, A_nan, q_nan, mask, **method_kwargs(method))
    assert isinstance(res, BatchResult)
    assert res.x.shape == (T, 4) and res.cov.shape == (T, 4, 4) and res.gain.shape == (T, 4, n)
    assert res.residuals.shape == (T, n) and res.status.dtype == np.int8
    np.testing.assert_array_equal(res.n_used, mask.sum(axis=1))
    for t in range(T):
        single = solve(method, A[t][mask[t]], q[t][mask[t]], **method_kwargs(method))
        np.testing.assert_allclose(res.x[t], single.x, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(res.cov[t], single.cov, rtol=1e-7, atol=1e-12)
        np.testing.assert_allclose(res.gain[t][:, mask[t]], single.gain, rtol=1e-7, atol=1e-10)
        assert np.all(res.gain[t][:, ~mask[t]] == 0.0)
        assert np.all(res.residuals[t][~mask[t]] == 0.0)
        assert res.status[t] == single.status


@pytest.mark.parametrize("method", METHODS)
def test_cov_is_gain_product_and_positive_definite(method: str) -> None:
    rng = np.random.default_rng(4)
    A, q, _ = _noisy_batch(rng, 5, 8, 0.01, 1.0)
    w = rng.uniform(0.2, 3.0, (5, 8))
    kw = method_kwargs(method)
    if REGISTRY[method].weights:
        kw["weights"] = w
    res = solve_batch(method, A, q, **kw)
    assert res.success.all()
    sigma2 = 1.0 / w if "weights" in kw else np.ones_like(w)
    expected = np.einsum("tmn,tn,tkn->tmk", res.gain, sigma2, res.gain)
    np.testing.assert_allclose(res.cov, expected, rtol=1e-9, atol=1e-12)
    assert np.all(np.linalg.eigvalsh(res.cov) > 0)
    assert np.all(np.isfinite(res.cond)) and np.all(res.rank == 4)


@pytest.mark.parametrize("method", METHODS)
def test_gain_matches_finite_differences(method: str) -> None:
    """J = dx/dq checked against central differences of the estimator itself."""
    rng = np.random.default_rng(5)
    A, q, _ = _noisy_batch(rng, 3, 7, 0.02, 1.0)
    kw = method_kwargs(method)
    if REGISTRY[method].weights:
        kw["weights"] = rng.uniform(0.5, 2.0, (3, 7))
    res = solve_batch(method, A, q, **kw)
    h = 1e-5
    for i in range(7):
        qp, qm = q.copy(), q.copy()
        qp[:, i] += h
        qm[:, i] -= h
        fd = (solve_batch(method, A, qp, **kw).x - solve_batch(method, A, qm, **kw).x) / (2 * h)
        np.testing.assert_allclose(res.gain[:, :, i], fd, rtol=1e-5, atol=1e-7)


@pytest.mark.parametrize("method", METHODS)
def test_row_order_does_not_matter(method: str) -> None:
    rng = np.random.default_rng(6)
    A, q, _ = _noisy_batch(rng, 1, 9, 0.01, 1.0)
    perm = rng.permutation(9)
    a = solve(method, A[0], q[0], **method_kwargs(method))
    b = solve(method, A[0][perm], q[0][perm], **method_kwargs(method))
    np.testing.assert_allclose(b.x, a.x, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(b.cov, a.cov, rtol=1e-8, atol=1e-12)
    np.testing.assert_allclose(b.gain, a.gain[:, perm], rtol=1e-7, atol=1e-10)


@pytest.mark.parametrize("method", METHODS)
def test_rank_deficient_gives_failure_status(method: str) -> None:
    rng = np.random.default_rng(7)
    A = sky_matrix(rng, 8)
    A[:, 2] = A[:, 0]  # two identical columns
    res = solve(method, A, rng.normal(size=8), **method_kwargs(method))
    assert res.status == Status.RANK_DEFICIENT and not res.success
    assert np.all(np.isnan(res.x)) and res.rank == 3
    assert res.message


@pytest.mark.parametrize("method", METHODS)
def test_too_few_rows_is_a_status_not_an_exception(method: str) -> None:
    rng = np.random.default_rng(8)
    A = np.stack([sky_matrix(rng, 6) for _ in range(3)])
    q = rng.normal(size=(3, 6))
    mask = np.ones((3, 6), dtype=bool)
    mask[1, :3] = False  # 3 rows for 4 unknowns
    res = solve_batch(method, A, q, mask, **method_kwargs(method))
    assert res.status.tolist()[1] == Status.TOO_FEW_ROWS
    assert res.success[[0, 2]].all()
    assert np.isnan(res.x[1]).all() and np.isfinite(res.x[[0, 2]]).all()
    short = solve(method, A[0, :3], q[0, :3], **method_kwargs(method))
    assert short.status == Status.TOO_FEW_ROWS


@pytest.mark.parametrize("method", METHODS)
def test_shape_and_finiteness_errors_name_the_argument(method: str) -> None:
    rng = np.random.default_rng(9)
    A = sky_matrix(rng, 6)
    q = rng.normal(size=6)
    kw = method_kwargs(method)
    with pytest.raises(UsageError, match="'q'"):
        solve(method, A, q[:5], **kw)
    with pytest.raises(UsageError, match="'A'"):
        solve(method, A[None, None], q, **kw)
    A_bad = A.copy()
    A_bad[2, 1] = np.nan
    with pytest.raises(UsageError, match="'A' must be finite"):
        solve(method, A_bad, q, **kw)
    q_bad = q.copy()
    q_bad[0] = np.inf
    with pytest.raises(UsageError, match="'q' must be finite"):
        solve(method, A, q_bad, **kw)
    with pytest.raises(UsageError, match="'mask'"):
        solve_batch(method, A[None], q[None], np.ones((1, 5), dtype=bool), **kw)
    with pytest.raises(UsageError, match="no option 'bogus'"):
        solve(method, A, q, bogus=1, **kw)
    # an invalid error is also a ValueError for library users
    with pytest.raises(ValueError):
        solve(method, A, q[:5], **kw)


def test_unknown_method_and_unhonoured_options_raise() -> None:
    rng = np.random.default_rng(10)
    A = sky_matrix(rng, 6)
    q = rng.normal(size=6)
    with pytest.raises(UsageError, match="'method' must be one of"):
        solve("lsq", A, q)
    with pytest.raises(UsageError, match="does not accept weights"):
        solve("ls", A, q, weights=np.full(6, 2.0))
    with pytest.raises(UsageError, match="does not accept weights"):
        solve("tls", A, q, weights=np.full(6, 2.0))
    assert solve("ls", A, q, weights=np.ones(6)).success  # ones are fine everywhere
    with pytest.raises(UsageError, match="exact_columns"):
        solve("tls", A, q, exact_columns=[3])
    with pytest.raises(UsageError, match="row_cov"):
        solve("mtls", A, q, row_cov=np.tile(np.eye(4), (6, 1, 1)))
    with pytest.raises(UsageError, match="'weights' must be finite and > 0"):
        solve("wls", A, q, weights=np.r_[np.ones(5), 0.0])
    with pytest.raises(UsageError, match="'exact_columns'"):
        solve("mtls", A, q, exact_columns=[4])
    with pytest.raises(UsageError, match="'row_cov' must have shape"):
        solve("stls", A, q, exact_columns=[3], row_cov=np.tile(np.eye(5), (6, 1, 1)))
    with pytest.raises(UsageError, match="positive semidefinite"):
        solve("stls", A, q, exact_columns=[3], row_cov=np.tile(np.diag([-1.0, 1, 1, 1]), (6, 1, 1)))
    with pytest.raises(UsageError, match="either 'weights' or 'row_cov'"):
        solve("stls", A, q, weights=np.ones(6), exact_columns=[3], row_cov=np.tile(np.eye(4), (6, 1, 1)))
