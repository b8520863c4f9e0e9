"""The pseudorange model of :mod:`gnss_cli.gnss.range_model`: transmit time, satellite clock and
group delay, Sagnac, variances, and the compact layout of :func:`linearize` (the dense layout's
rows, moved, to rounding). Expected values come from independent computations: the states evaluated again at
the transmit time, the Earth rotated during the signal's flight, RTKLIB's ``varerr`` constants."""

from __future__ import annotations

import numpy as np
import pytest

from gnss_cli.config import load_config
from gnss_cli.constants import C_M_S, OMEGA_E_RAD_S
from gnss_cli.gnss.broadcast import system_records
from gnss_cli.gnss.observables import select_pseudoranges
from gnss_cli.gnss.range_model import (
    COMPACT_ROW_STEP,
    SatelliteArrays,
    compact_width,
    corrected_pseudoranges,
    linearize,
    pseudorange_variance_m2,
    sagnac_range,
    satellites_at_transmit_time,
    width_groups,
)
from gnss_cli.io.rinex import read_nav, read_obs
from gnss_cli.pipeline import load_epochs


ULPS = 8 * np.finfo(float).eps
"""Relative tolerance of "the same value" computed in two layouts: a few units in the last place."""


@pytest.fixture(scope="module")
def kms3(rinex_dir):
    """KMS3, one hour of RINEX 4 multi-GNSS (five clocks: constraint rows), at its header position."""
    d = rinex_dir / "kms3-2022159-rinex4"
    cfg = load_config(overrides={"methods": "wls"})
    data = load_epochs(d / "KMS300DNK_R_20221591000_01H_30S_MO.crx", [d / "KMS300DNK_R_20221591000_01H_MN.rnx.gz"], cfg)
    return data, cfg


def test_compact_rows_are_the_dense_used_rows_in_satellite_order(kms3):
    data, cfg = kms3
    rows = np.arange(data.time_gps_s.size)
    x = np.repeat(data.approx_ecef_m[None, :], rows.size, axis=0)
    b = np.zeros((rows.size, len(data.systems)))
    dense = linearize(data, rows, x, b, cfg)
    width = int(compact_width(data.usable.sum(axis=1)).max())
    comp = linearize(data, rows, x, b, cfg, width=width)
    n, w = data.sv.size, comp.sat_rows
    used = dense.mask[:, :n]
    assert dense.sv_col is None and dense.sat_rows == n
    assert w == width
    assert w % COMPACT_ROW_STEP == 0 and w >= data.usable.sum(axis=1).max()
    for t in rows:
        sv = np.flatnonzero(used[t])  # the used satellites, ascending
        k = sv.size
        assert (comp.sv_col[t, :k] == sv).all() and (comp.sv_col[t, k:] == -1).all()
        assert comp.mask[t, :k].all() and not comp.mask[t, k:w].any()
        for name in ("A", "q", "var_m2", "unit", "range_m"):  # to rounding: numpy's SIMD and scalar loops
            # may round an element differently where the two layouts put it at different places
            np.testing.assert_allclose(getattr(comp, name)[t, :k], getattr(dense, name)[t, sv], rtol=ULPS, atol=0,
                                       err_msg=name)
            np.testing.assert_allclose(getattr(comp, name)[t, w:], getattr(dense, name)[t, n:], rtol=ULPS, atol=0,
                                       err_msg=name)
    np.testing.assert_array_equal(comp.mask[:, w:], dense.mask[:, n:])  # the clock constraint rows
    # back to the satellite columns: NaN where a satellite is not used
    back = comp.scatter(comp.q[:, :w], n)
    np.testing.assert_allclose(back[used], dense.q[:, :n][used], rtol=ULPS, atol=0)
    assert np.isnan(back[~used]).all()
    np.testing.assert_array_equal(comp.sv_index, comp.sv_col)
    np.testing.assert_array_equal(dense.sv_index[0], np.arange(n))


def test_an_epoch_gets_its_own_width_whatever_it_is_stacked_with(kms3):
    data, cfg = kms3
    usable = data.usable.copy()
    usable[0, :] = False  # an epoch without satellites still gets one step of rows
    groups = width_groups(usable, block=4)
    idx = np.concatenate([g for g, _ in groups])
    np.testing.assert_array_equal(np.sort(idx), np.arange(usable.shape[0]))  # every epoch once
    for g, width in groups:
        assert g.size <= 4 and (compact_width(usable[g].sum(axis=1)) == width).all()
    assert compact_width(np.array([0, 1, 8, 9, 16])).tolist() == [8, 8, 8, 16, 16]
    rows = np.arange(data.time_gps_s.size)
    x = np.repeat(data.approx_ecef_m[None, :], rows.size, axis=0)
    with pytest.raises(ValueError, match="width"):
        linearize(data, rows, x, np.zeros((rows.size, len(data.systems))), cfg, width=4)


def test_satellite_states_are_those_of_the_transmit_time(rinex_dir):
    """Each position is the broadcast state at ``t - P/c - dt_sv``, evaluated here directly. The
    model moves the state of ``t - P/c`` along the broadcast velocity, which is good to ~0.15 m/s
    here: 0.2 mm with ``|dt_sv| < 0.4 ms``. Receive time instead would be ~270 m off, no clock
    shift up to 1.5 m (v ~ 3.9 km/s)."""
    d = rinex_dir / "rtklib-0759"
    obs = read_obs(d / "07590920.05o", systems=["G"])
    prs = select_pseudoranges(obs, ["G"])
    records, _ = system_records(read_nav([d / "07590920.05n"], systems=["G"]), "G")
    asked: list[str] = []
    sats = satellites_at_transmit_time(prs, None, lambda s: asked.append(s) or records, ["G", "E"], True)
    assert asked == ["G"]  # a system without observations is not asked for its records
    ii, jj = np.nonzero(sats.usable)
    assert ii.size > 500
    idx = records.select(prs.sv, prs.time_gps_s, True)[ii, jj]
    t_flight = prs.time_gps_s[ii] - prs.pr_m[ii, jj] / C_M_S
    t_tx = t_flight - records.states(idx, t_flight).clock_s
    st = records.states(idx, t_tx)
    np.testing.assert_allclose(sats.sat[ii, jj], st.pos_ecef_m, rtol=0, atol=1e-3)
    np.testing.assert_allclose(sats.clk[ii, jj], st.clock_s, rtol=0, atol=1e-14)
    np.testing.assert_array_equal(sats.tgd[ii, jj], np.nan_to_num(st.tgd_s))
    assert np.abs(sats.clk[ii, jj]).max() * 3.0e3 > 0.1  # the clock shift moves some satellite > 10 cm


def test_clock_and_group_delay_corrections_follow_is_gps_200():
    """IS-GPS-200 20.3.3.3.3.2: the L1 C/A clock is ``dt_sv - TGD``; corrected ``P + c (dt_sv - TGD)``.
    Iono-free: the combination (group delays removed) ``+ c dt_sv``; NaN where not usable."""
    sats = SatelliteArrays.empty(1, 3)
    sats.clk[:] = [1e-4, -2e-4, 3e-4]
    sats.tgd[:] = [-1.1e-8, 4.7e-9, 0.0]
    sats.p_if[:] = [2.1e7, 2.2e7, 2.3e7]
    pr = np.array([[2.0e7, 2.1e7, 2.2e7]])
    usable = np.array([[True, True, False]])
    one = corrected_pseudoranges(pr, sats, usable, iono_free=False)
    np.testing.assert_allclose(one[0, :2], [2.0e7 + 29979.2458 + 3.2977, 2.1e7 - 59958.4916 - 1.4090], rtol=0, atol=1e-3)
    both = corrected_pseudoranges(pr, sats, usable, iono_free=True)
    np.testing.assert_allclose(both[0, :2], [2.1e7 + 29979.2458, 2.2e7 - 59958.4916], rtol=0, atol=1e-3)
    assert np.isnan(one[0, 2]) and np.isnan(both[0, 2])


def test_sagnac_term_is_the_earth_rotation_during_the_flight():
    """The first-order Sagnac range equals the range to the satellite position rotated with the
    Earth by ``omega_E tau`` during the flight time ``tau`` (to < 1 mm); the term is tens of metres."""
    rx = np.array([[-3976219.19, 3382371.60, 3652511.14]])  # rtklib-0759, Japan
    lat, lon = np.deg2rad(35.0), np.deg2rad(140.0)
    east = np.array([-np.sin(lon), np.cos(lon), 0.0])
    up = np.array([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)])
    sats = np.stack([rx[0] + 2.2e7 * (c * east + s * up) for c, s in ((0.9, 0.44), (-0.9, 0.44), (0.0, 1.0))])
    rng, unit = sagnac_range(sats[None], rx)
    exact = np.empty(3)
    for i, s in enumerate(sats):
        r = np.linalg.norm(s - rx[0])
        for _ in range(5):  # the flight time of the rotated position
            a = OMEGA_E_RAD_S * r / C_M_S
            rot = np.array([[np.cos(a), np.sin(a), 0.0], [-np.sin(a), np.cos(a), 0.0], [0.0, 0.0, 1.0]])
            r = np.linalg.norm(rot @ s - rx[0])
        exact[i] = r
    np.testing.assert_allclose(rng[0], exact, rtol=0, atol=1e-3)
    term = rng[0] - np.linalg.norm(sats - rx[0], axis=1)
    assert np.abs(term[:2]).min() > 10.0 and np.sign(term[0]) != np.sign(term[1])
    np.testing.assert_allclose(np.linalg.norm(unit[0], axis=1), 1.0, rtol=1e-15)


def test_variances_are_rtklib_varerr_plus_the_broadcast_and_atmosphere_terms():
    """RTKLIB 2.4.3 ``rescode``: ``varerr`` (err = [100, 0.003, 0.003]: 0.3^2 + 0.3^2 / sin el, x EFACT^2)
    + URA^2 + CODE_ERR^2 (0.3 m) + (ERR_BRDCI = 0.5 x iono)^2 + (ERR_SAAS = 0.3 m / (sin el + 0.1))^2;
    iono-free: varerr x 3^2 + URA^2 + the troposphere term."""
    cfg = load_config()
    el = np.deg2rad(np.array([30.0, 90.0, 10.0]))
    ura = np.array([2.4, 3.4, 2.4])
    iono = np.array([5.0, 2.0, 8.0])
    efact = np.array([1.0, 1.0, 1.5])
    se = np.sin(el)
    tropo = (0.3 / (se + 0.1)) ** 2
    varerr = (0.09 + 0.09 / se) * efact**2
    expected = varerr + ura**2 + 0.09 + (0.5 * iono) ** 2 + tropo
    np.testing.assert_allclose(pseudorange_variance_m2(cfg, el, ura, iono, efact), expected, rtol=1e-12)
    np.testing.assert_allclose(pseudorange_variance_m2(cfg, el[:1], ura[:1], iono[:1]), [0.09 + 0.18 + 5.76 + 0.09 + 6.25 + 0.25],
                               rtol=1e-12)
    free = load_config(overrides={"iono": "iono-free"})
    np.testing.assert_allclose(pseudorange_variance_m2(free, el, ura, iono, efact), varerr * 9.0 + ura**2 + tropo, rtol=1e-12)
