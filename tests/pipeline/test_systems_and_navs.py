"""Default systems (every system in both files), ``--systems`` restriction, and several nav files."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import gnss_cli.io.rinex3_nav as rinex3_nav
from gnss_cli.config import load_config
from gnss_cli.errors import ConfigError
from gnss_cli.io.compression import open_bytes
from gnss_cli.pipeline import EpochStatus, load_epochs, solve_method

ESBC_OBS = "ESBC00DNK_R_20201770000_01D_30S_MO.crx.gz"
ESBC_NAV = "ESBC00DNK_R_20201770000_01D_MN.rnx.gz"


def test_default_systems_are_those_in_both_files(rinex_dir):
    cfg = load_config(overrides={"methods": "wls"})
    assert cfg.systems == ()  # "all"
    d = rinex_dir / "p433-2019"  # observations G, E, R, C, S; navigation GPS only
    data = load_epochs(d / "P43300USA_R_20190012056_17M_15S_MO.crx", [d / "brdc0010.19n"], cfg)
    assert data.systems == ("G",)
    assert not [w for w in data.warnings if "ephemeris" in w]  # absent systems are not warned about
    d = rinex_dir / "rtklib-0759"
    assert load_epochs(d / "07590920.05o", [d / "07590920.05n"], cfg).systems == ("G",)


def test_systems_option_restricts_and_orders(rinex_dir):
    d = rinex_dir / "kms3-2022159-rinex4"
    obs, nav = d / "KMS300DNK_R_20221591000_01H_30S_MO.crx", d / "KMS300DNK_R_20221591000_01H_MN.rnx.gz"
    every = load_epochs(obs, [nav], load_config(overrides={"systems": "all"}))
    assert every.systems[0] == "G" and set(every.systems) >= {"G", "E", "C", "R"}
    two = load_epochs(obs, [nav], load_config(overrides={"systems": ["R", "E"]}))
    assert two.systems == ("R", "E")
    assert {s[0] for s in two.sv} == {"R", "E"}


def _split_by_system(nav_text: str, out_dir: Path) -> list[Path]:
    """Per-system RINEX 3 navigation files (``_GN``, ``_EN``, ...) from a mixed one."""
    lines = nav_text.splitlines(keepends=True)
    end = next(i for i, line in enumerate(lines) if "END OF HEADER" in line) + 1
    records: dict[str, list[str]] = {}
    system = ""
    for line in lines[end:]:
        if line[:1].strip():
            system = line[0]
        records.setdefault(system, []).append(line)
    paths = []
    for system, body in sorted(records.items()):
        path = out_dir / f"nav_{system}N.rnx"
        path.write_text("".join(lines[:end] + body))
        paths.append(path)
    return paths


def test_per_system_nav_files_give_the_mixed_file_result_in_one_read(rinex_dir, tmp_path, monkeypatch):
    d = rinex_dir / "esbc-2020177"
    navs = _split_by_system(open_bytes(d / ESBC_NAV).decode("ascii", errors="replace"), tmp_path)
    assert len(navs) >= 5
    cfg = load_config(overrides={"methods": "wls"})
    mixed = load_epochs(d / ESBC_OBS, [d / ESBC_NAV], cfg)
    calls: list[object] = []
    real = rinex3_nav.read_nav3

    def counting(paths, *args, **kwargs):  # type: ignore[no-untyped-def]
        calls.append(paths)
        return real(paths, *args, **kwargs)

    monkeypatch.setattr(rinex3_nav, "read_nav3", counting)
    split = load_epochs(d / ESBC_OBS, navs, cfg)
    assert len(calls) == 1 and len(calls[0]) == len(navs)  # one pass over every file
    assert split.systems == mixed.systems
    assert np.array_equal(split.sv, mixed.sv)
    assert np.array_equal(split.usable, mixed.usable)
    np.testing.assert_array_equal(split.pr_corrected_m, mixed.pr_corrected_m)
    np.testing.assert_array_equal(split.sat_ecef_m, mixed.sat_ecef_m)
    sol = solve_method(split, "wls", cfg)
    assert (sol.status == EpochStatus.OK).sum() == 2880


@pytest.mark.parametrize("value", ["X", "G,G", ","])
def test_bad_systems_are_config_errors(value):
    with pytest.raises(ConfigError, match="systems"):
        load_config(overrides={"systems": value})
