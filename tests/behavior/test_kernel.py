import numpy as np
import pytest

from gnss_cli.behavior import KernelRepresentation
from gnss_cli.errors import UsageError

from behavior_trajectories import arc_polynomial, circular_arc, quadratic


def test_static_and_pva_models() -> None:
    s, p = KernelRepresentation.static(3), KernelRepresentation.pva(3)
    assert (s.lag, s.order, p.lag, p.order) == (1, 3, 3, 9)
    assert s.is_row_proper() and p.is_row_proper()
    const = np.tile([1.0, 2.0, 3.0], (6, 1))
    assert s.annihilates(const) and p.annihilates(quadratic(10))
    assert not s.annihilates(quadratic(10))


def test_predict_continues_a_quadratic_exactly() -> None:
    w = quadratic(30)
    pred = KernelRepresentation.pva(3).predict(w[:3], 27)
    np.testing.assert_allclose(pred, w[3:], rtol=1e-10)


def test_shared_kernel_poles_are_the_roots_of_r() -> None:
    omega = 0.3
    k = KernelRepresentation.shared(arc_polynomial(omega), 3)
    poles = k.poles()
    assert poles.size == 9
    for root in (1.0, np.exp(1j * omega), np.exp(-1j * omega)):
        assert np.sum(np.abs(poles - root) < 1e-6) == 3
    assert k.annihilates(circular_arc(20, omega))


def test_row_proper_and_order_of_a_mixed_degree_kernel() -> None:
    # row 0 of degree 1, row 1 of degree 0 (a static constraint): order 1
    r = np.array([[1.0, 0.0, -1.0, 0.0], [0.0, 1.0, 0.0, 0.0]])
    k = KernelRepresentation(r)
    assert k.order == 1
    assert k.is_row_proper()
    k_bad = KernelRepresentation(np.array([[0.0, 0.0, 1.0, 1.0], [1.0, 0.0, 1.0, 1.0]]))
    assert not k_bad.is_row_proper()


def test_predict_needs_invertible_leading_block() -> None:
    k = KernelRepresentation(np.array([[1.0, 0.0, 1.0, 0.0], [0.0, 1.0, 0.0, 0.0]]))
    with pytest.raises(UsageError, match="R_lag is singular"):
        k.predict(np.zeros((1, 2)), 3)


def test_constructor_validates() -> None:
    with pytest.raises(UsageError, match="R:"):
        KernelRepresentation(np.zeros((2, 5)))
    with pytest.raises(UsageError, match="finite"):
        KernelRepresentation(np.full((1, 2), np.nan))
    three_d = KernelRepresentation(np.stack([-np.eye(2), np.eye(2)]))
    assert three_d == KernelRepresentation.static(2)
