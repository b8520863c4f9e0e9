import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gnss_cli.behavior import KernelRepresentation, hankel
from gnss_cli.errors import UsageError


@settings(max_examples=40, deadline=None)
@given(n_t=st.integers(2, 12), q=st.integers(1, 3), data=st.data())
def test_hankel_entries_are_shifted_samples(n_t: int, q: int, data: st.DataObject) -> None:
    depth = data.draw(st.integers(1, n_t))
    w = np.arange(n_t * q, dtype=float).reshape(n_t, q)
    h = hankel(w, depth)
    assert h.shape == (q * depth, n_t - depth + 1)
    for j in range(n_t - depth + 1):
        np.testing.assert_array_equal(h[:, j], w[j : j + depth].ravel())


def test_kernel_times_hankel_is_the_equation_error() -> None:
    rng = np.random.default_rng(3)
    w = rng.normal(size=(15, 3))
    k = KernelRepresentation(rng.normal(size=(2, 9)), q=3)
    direct = np.array([sum(k.blocks[i] @ w[t + i] for i in range(3)) for t in range(13)])
    np.testing.assert_allclose(k.residual(w), direct, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose((k.R @ hankel(w, 3)).T, direct, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("depth", [0, 6, 2.5])
def test_hankel_rejects_bad_depth(depth: object) -> None:
    with pytest.raises(UsageError, match="depth"):
        hankel(np.zeros((5, 2)), depth)  # type: ignore[arg-type]


def test_hankel_rejects_nan() -> None:
    w = np.zeros((5, 2))
    w[2, 1] = np.nan
    with pytest.raises(UsageError, match="non-finite"):
        hankel(w, 2)
