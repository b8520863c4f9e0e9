"""The compact layout of :func:`gnss_cli.gnss.range_model.linearize`: the dense layout's rows, moved."""

from __future__ import annotations

import numpy as np
import pytest

from gnss_cli.config import load_config
from gnss_cli.gnss.range_model import COMPACT_ROW_STEP, compact_width, linearize, width_groups
from gnss_cli.pipeline import load_epochs


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
        for name in ("A", "q", "var_m2", "unit", "range_m"):
            np.testing.assert_array_equal(getattr(comp, name)[t, :k], getattr(dense, name)[t, sv], err_msg=name)
            np.testing.assert_array_equal(getattr(comp, name)[t, w:], getattr(dense, name)[t, n:], err_msg=name)
    np.testing.assert_array_equal(comp.mask[:, w:], dense.mask[:, n:])  # the clock constraint rows
    # back to the satellite columns: NaN where a satellite is not used
    back = comp.scatter(comp.q[:, :w], n)
    np.testing.assert_array_equal(back[used], dense.q[:, :n][used])
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
