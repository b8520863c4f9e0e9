"""DOP from the noise gain: classic formula, the paper's TLS formula, a hand-computed sky."""

from __future__ import annotations

import numpy as np
import pytest
from solver_cases import method_kwargs, sky_matrix

from gnss_cli.errors import UsageError
from gnss_cli.solvers import METHODS, solve, solve_batch
from gnss_cli.solvers.dop import Dop, dop_from_cov, tls_paper_cov


def _enu_rotation(lat_rad: float, lon_rad: float) -> np.ndarray:
    """ECEF -> ENU rotation written out from its definition (rows: east, north, up)."""
    sl, cl, so, co = np.sin(lat_rad), np.cos(lat_rad), np.sin(lon_rad), np.cos(lon_rad)
    return np.array([[-so, co, 0.0], [-sl * co, -sl * so, cl], [cl * co, cl * so, sl]])


def _hand_sky_enu() -> np.ndarray:
    """One satellite at zenith, three on the horizon at azimuths 0°, 120°, 240°.

    Rows [-e, 1]. By hand: Σ sin²az = Σ cos²az = 3/2, cross and linear sums vanish, so
    AᵀA = [[3/2,0,0,0],[0,3/2,0,0],[0,0,1,-1],[0,0,-1,4]] and its inverse has
    Q_EE = Q_NN = 2/3 and the (U, b) block [[4/3, 1/3], [1/3, 1/3]]:
    HDOP = sqrt(4/3), VDOP = sqrt(4/3), PDOP = sqrt(8/3), TDOP = sqrt(1/3), GDOP = sqrt(3).
    """
    az = np.deg2rad([0.0, 120.0, 240.0])
    e = [np.array([0.0, 0.0, 1.0])] + [np.array([np.sin(a), np.cos(a), 0.0]) for a in az]
    return np.column_stack([-np.array(e), np.ones(4)])


EXPECTED_HAND = {
    "gdop": np.sqrt(3.0),
    "pdop": np.sqrt(8.0 / 3.0),
    "hdop": np.sqrt(4.0 / 3.0),
    "vdop": np.sqrt(4.0 / 3.0),
    "tdop": np.sqrt(1.0 / 3.0),
}


def test_hand_computed_sky_in_enu() -> None:
    A = _hand_sky_enu()
    dop = dop_from_cov(solve("ls", A, np.zeros(4)).cov)
    assert isinstance(dop, Dop)
    for name, value in EXPECTED_HAND.items():
        assert float(getattr(dop, name)) == pytest.approx(value, rel=1e-12), name


def test_hand_computed_sky_in_ecef_with_rotation() -> None:
    lat, lon = np.deg2rad(52.0), np.deg2rad(13.0)
    R = _enu_rotation(lat, lon)
    A_enu = _hand_sky_enu()
    A_ecef = A_enu.copy()
    A_ecef[:, :3] = A_enu[:, :3] @ R  # e_ecef = Rᵀ e_enu, written row-wise
    cov = solve("ls", A_ecef, np.zeros(4)).cov
    dop = dop_from_cov(cov, R)
    for name, value in EXPECTED_HAND.items():
        assert float(getattr(dop, name)) == pytest.approx(value, rel=1e-12), name
    # without the rotation only the rotation-invariant values survive
    raw = dop_from_cov(cov)
    assert float(raw.gdop) == pytest.approx(EXPECTED_HAND["gdop"], rel=1e-12)
    assert float(raw.pdop) == pytest.approx(EXPECTED_HAND["pdop"], rel=1e-12)
    assert float(raw.vdop) != pytest.approx(EXPECTED_HAND["vdop"], rel=1e-3)


def test_ls_gain_dop_equals_classic_formula() -> None:
    rng = np.random.default_rng(21)
    T = 20
    A = np.stack([sky_matrix(rng, 10) for _ in range(T)])
    res = solve_batch("ls", A, rng.normal(size=(T, 10)))
    classic = np.linalg.inv(np.swapaxes(A, -1, -2) @ A)  # the textbook (HᵀH)⁻¹
    np.testing.assert_allclose(res.cov, classic, rtol=1e-10, atol=1e-13)
    dop = dop_from_cov(res.cov)
    np.testing.assert_allclose(dop.gdop, np.sqrt(np.trace(classic, axis1=1, axis2=2)), rtol=1e-10)
    np.testing.assert_allclose(dop.tdop, np.sqrt(classic[:, 3, 3]), rtol=1e-10)
    # the noise gain itself is the LS pseudo-inverse
    np.testing.assert_allclose(res.gain, classic @ np.swapaxes(A, -1, -2), rtol=1e-9, atol=1e-12)


def test_tls_gain_with_sigma_fixed_equals_paper_formula() -> None:
    rng = np.random.default_rng(22)
    T, n = 10, 8
    A = np.stack([sky_matrix(rng, n) for _ in range(T)])
    q = np.einsum("tnm,tm->tn", A, rng.normal(0, 20, (T, 4))) + rng.normal(0, 1, (T, n))
    A[:, :, :3] += rng.normal(0, 0.03, (T, n, 3))
    res = solve_batch("tls", A, q)
    s = res.details.sigma_min
    eye = np.eye(4)
    AtA = np.swapaxes(A, -1, -2) @ A
    M = AtA - (s**2)[:, None, None] * eye
    J_fixed = np.linalg.solve(M, np.swapaxes(A, -1, -2))  # (AᵀA − σ²I)⁻¹ Aᵀ, σ held fixed
    paper_by_gain = J_fixed @ np.swapaxes(J_fixed, -1, -2)
    paper_formula = np.linalg.inv(M) @ AtA @ np.linalg.inv(M)
    np.testing.assert_allclose(paper_by_gain, paper_formula, rtol=1e-9)
    np.testing.assert_allclose(tls_paper_cov(A, s), paper_formula, rtol=1e-8, atol=1e-12)
    np.testing.assert_allclose(res.details.cov_paper, paper_formula, rtol=1e-8, atol=1e-12)
    # the exact gain differs from the fixed-σ gain by the rank-one σ(q) term ...
    assert not np.allclose(res.gain, J_fixed, rtol=1e-6, atol=1e-9)
    # ... whose contribution to J Jᵀ cancels (Aᵀr = σ² x at the TLS solution), so the
    # exact noise gain and the paper's formula give the same matrix
    np.testing.assert_allclose(res.cov, paper_formula, rtol=1e-8, atol=1e-12)
    # σ = 0 reduces the paper formula to the LS matrix
    np.testing.assert_allclose(tls_paper_cov(A, np.zeros(T)), np.linalg.inv(AtA), rtol=1e-9, atol=1e-13)


@pytest.mark.parametrize("method", METHODS)
def test_dop_invariant_to_satellite_order(method: str) -> None:
    rng = np.random.default_rng(23)
    n = 9
    A = sky_matrix(rng, n)
    q = A @ rng.normal(0, 20, 4) + rng.normal(0, 1, n)
    A[:, :3] += rng.normal(0, 0.02, (n, 3))
    perm = rng.permutation(n)
    d1 = dop_from_cov(solve(method, A, q, **method_kwargs(method)).cov)
    d2 = dop_from_cov(solve(method, A[perm], q[perm], **method_kwargs(method)).cov)
    for name in ("gdop", "pdop", "hdop", "vdop", "tdop"):
        assert float(getattr(d2, name)) == pytest.approx(float(getattr(d1, name)), rel=1e-9)


def test_several_clock_columns_all_enter_gdop() -> None:
    cov = np.diag([1.0, 2.0, 3.0, 4.0, 5.0])
    dop = dop_from_cov(cov, clock_index=4)
    assert float(dop.gdop) == pytest.approx(np.sqrt(15.0))
    assert float(dop.tdop) == pytest.approx(np.sqrt(5.0))
    assert float(dop.pdop) == pytest.approx(np.sqrt(6.0))


def test_dop_input_errors() -> None:
    with pytest.raises(UsageError, match="'cov'"):
        dop_from_cov(np.eye(3))
    with pytest.raises(UsageError, match="'clock_index'"):
        dop_from_cov(np.eye(4), clock_index=4)
    with pytest.raises(UsageError, match="'ecef2enu'"):
        dop_from_cov(np.eye(4), np.eye(2))
    with pytest.raises(UsageError, match="negative"):
        dop_from_cov(-np.eye(4))
    with pytest.raises(UsageError, match="'sigma'"):
        tls_paper_cov(np.ones((2, 5, 4)), np.ones(3))
    # failed epochs (NaN cov) give NaN DOPs for those epochs only
    cov = np.stack([np.eye(4), np.full((4, 4), np.nan)])
    dop = dop_from_cov(cov)
    assert dop.gdop[0] == pytest.approx(2.0) and np.isnan(dop.gdop[1])
