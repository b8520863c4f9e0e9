"""gnss-solve stls --lag with several systems: one receiver clock per system over several epochs too."""

from __future__ import annotations

import io

import numpy as np
import pandas as pd
import pytest

from gnss_cli.cli.exits import run_app
from gnss_cli.cli.solve import app

KMS3 = ("kms3-2022159-rinex4", "KMS300DNK_R_20221591000_01H_30S_MO.crx", "KMS300DNK_R_20221591000_01H_MN.rnx.gz")


def _invoke(args, capsys):
    with pytest.raises(SystemExit) as exc:
        run_app(app, "gnss-solve", [str(a) for a in args])
    out, err = capsys.readouterr()
    return exc.value.code, out, err


def test_lag_with_every_system_keeps_a_clock_per_system(rinex_dir, capsys):
    d = rinex_dir / KMS3[0]
    # lag 1 with the shared kernel's fixed root at z = 1: r(z) = z - 1, the static behavior
    code, out, err = _invoke([d / KMS3[1], d / KMS3[2], "--method", "wls,stls", "--lag", "1", "--window", "0", "-q"],
                             capsys)
    assert code == 0, err
    df = pd.read_csv(io.StringIO(out))
    tdop_cols = [c for c in df.columns if c.startswith("tdop_")]
    assert len(tdop_cols) >= 4  # G, E, C, R at least on this RINEX 4 file
    wls, stls = (df[df.method == m].reset_index(drop=True) for m in ("wls", "stls"))
    assert len(stls) == 19 and (stls.status == "ok").all()
    assert np.allclose(stls["tdop"], stls[f"tdop_{tdop_cols[0][-1]}"], equal_nan=True)
    # A static receiver over the whole hour is one point: every epoch gets the same position.
    xyz = stls[["x_m", "y_m", "z_m"]].to_numpy()
    assert np.ptp(xyz, axis=0).max() < 1e-6
    # Fixed model over 19 epochs: the multi-epoch DOPs are below the snapshot ones, clock by clock too.
    compared = 0
    for col in ("gdop", "pdop", "tdop", *tdop_cols):
        both = np.isfinite(stls[col]) & np.isfinite(wls[col])  # a system without satellites: empty cells
        assert (np.isfinite(stls[col]) == np.isfinite(wls[col])).all(), col
        assert (stls[col][both] < wls[col][both]).all(), col  # 19 epochs: strictly below
        compared += int(both.any())
    assert compared >= 7
    # The reference clock re-estimated at the (unchanged up to metres) position stays close to WLS's.
    assert np.all(np.abs(stls["clock_m"] - wls["clock_m"]) < 30.0)
