"""gnss-solve with several systems: --lag keeps one receiver clock (warning or usage error)."""

from __future__ import annotations

import pytest

from gnss_cli.cli.exits import run_app
from gnss_cli.cli.solve import app

KMS3 = ("kms3-2022159-rinex4", "KMS300DNK_R_20221591000_01H_30S_MO.crx", "KMS300DNK_R_20221591000_01H_MN.rnx.gz")


def _invoke(args, capsys):
    with pytest.raises(SystemExit) as exc:
        run_app(app, "gnss-solve", [str(a) for a in args])
    out, err = capsys.readouterr()
    return exc.value.code, out, err


def test_lag_with_all_systems_uses_the_reference_system_and_says_so(rinex_dir, capsys):
    d = rinex_dir / KMS3[0]
    code, out, err = _invoke([d / KMS3[1], d / KMS3[2], "--method", "stls", "--lag", "1", "--model", "static"], capsys)
    assert code == 0, err
    assert "only system G is used" in err
    header = out.splitlines()[0].split(",")
    assert not [c for c in header if c.startswith("tdop_")]
    assert len(out.splitlines()) == 1 + 19


def test_lag_with_several_explicit_systems_is_a_usage_error(rinex_dir, capsys):
    d = rinex_dir / KMS3[0]
    code, out, err = _invoke([d / KMS3[1], d / KMS3[2], "--method", "stls", "--lag", "1", "--systems", "G,E"], capsys)
    assert code == 2 and out == ""
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("gnss-solve: error: --lag") and "G,E" in lines[0]
