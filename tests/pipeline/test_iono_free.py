"""Dual-frequency (``iono = "iono-free"``) positioning against RTKLIB's ``pos1-ionoopt=dual-freq``.

rnx2rtkp runs on plain copies of the ESBC 24 h files with the peer configuration and the
ionosphere-free option; both programs' positions are compared epoch by epoch and against
the station's reference position.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from gnss_cli.cli.exits import run_app
from gnss_cli.cli.solve import app
from gnss_cli.config import load_config
from gnss_cli.errors import ConfigError
from gnss_cli.gnss.time import gps_s2week_tow
from gnss_cli.io.compression import open_bytes
from gnss_cli.pipeline import EpochStatus, load_epochs, solve_method
from gnss_cli.report import enu_errors

REF_ESBC = np.array([3582104.922, 532590.196, 5232755.366])
ESBC_OBS = "ESBC00DNK_R_20201770000_01D_30S_MO.crx.gz"
ESBC_NAV = "ESBC00DNK_R_20201770000_01D_MN.rnx.gz"
NAVSYS = {"G": "1", "all": "61"}


def _rms(x: np.ndarray) -> float:
    e = enu_errors(x, REF_ESBC)
    return float(np.sqrt(np.nanmean(np.sum(e**2, axis=1))))


@pytest.fixture(scope="module")
def esbc_plain(rinex_dir, tmp_path_factory) -> tuple[Path, Path]:
    """Plain copies of the ESBC observation and navigation files (rnx2rtkp reads no .crx/.gz)."""
    d = rinex_dir / "esbc-2020177"
    out = tmp_path_factory.mktemp("esbc_plain")
    obs, nav = out / "esbc.obs", out / "esbc.nav"
    obs.write_bytes(open_bytes(d / ESBC_OBS))
    nav.write_bytes(open_bytes(d / ESBC_NAV))
    return obs, nav


def _ours(rinex_dir, systems: list[str] | None, config: Path | None = None):
    d = rinex_dir / "esbc-2020177"
    overrides: dict[str, object] = {"methods": "wls", "iono": "iono-free", "weights.cn0_model": "off"}  # the peer's weights
    if systems:
        overrides["systems"] = systems
    cfg = load_config(config, overrides)
    data = load_epochs(d / ESBC_OBS, [d / ESBC_NAV], cfg)
    return data, solve_method(data, "wls", cfg)


def _distance_to_peer(data, sol, tow_peer: np.ndarray, xyz_peer: np.ndarray) -> np.ndarray:
    _, tow = gps_s2week_tow(data.time_gps_s)
    # rnx2rtkp tags solutions with the receiver-clock-corrected time (sub-millisecond shift)
    k = np.clip(np.searchsorted(tow, tow_peer - 0.5), 0, tow.size - 1)
    assert np.all(np.abs(tow[k] - tow_peer) < 0.01)
    return np.linalg.norm(sol.x_ecef_m[k] - xyz_peer, axis=1)


def test_esbc_gps_iono_free_equals_rnx2rtkp(rinex_dir, peer, esbc_plain, tmp_path):
    data, sol = _ours(rinex_dir, ["G"])
    assert (sol.status == EpochStatus.OK).sum() == 2880
    tow, xyz = peer(esbc_plain[0], [esbc_plain[1]], tmp_path, pos1_ionoopt="dual-freq", pos1_navsys=NAVSYS["G"])
    assert tow.size == 2880
    dist = _distance_to_peer(data, sol, tow, xyz)
    # same observables (C1C/C2W), same weights (code noise x 3^2, no code-bias or iono term)
    assert np.median(dist) < 0.01, np.median(dist)
    assert np.percentile(dist, 90) < 0.05
    assert _rms(sol.x_ecef_m) <= 1.02 * _rms(xyz)  # measured 2.347 m and 2.348 m


def test_esbc_all_systems_iono_free_with_rtklib_pairs_close_to_rnx2rtkp(rinex_dir, peer, esbc_plain, tmp_path):
    """RTKLIB pairs BeiDou B1I with B2I only; the same choice in our configuration."""
    cfg = tmp_path / "b2i.toml"
    cfg.write_text('[signals.second]\nC = ["C7I"]\n')
    data, sol = _ours(rinex_dir, ["G", "E", "C", "R", "J"], cfg)
    assert (sol.status == EpochStatus.OK).sum() == 2880
    tow, xyz = peer(esbc_plain[0], [esbc_plain[1]], tmp_path, pos1_ionoopt="dual-freq", pos1_navsys=NAVSYS["all"])
    dist = _distance_to_peer(data, sol, tow, xyz)
    assert np.median(dist) < 0.10, np.median(dist)  # measured 0.04 m (Galileo SISA and record choice differ)
    assert _rms(sol.x_ecef_m) <= 1.05 * _rms(xyz)  # measured 1.58 m and 1.56 m


def test_esbc_all_systems_iono_free_default_pairs(rinex_dir):
    data, sol = _ours(rinex_dir, None)
    assert data.systems == ("G", "E", "C", "R")  # the clock columns: QZSS shares the GPS clock
    assert (sol.status == EpochStatus.OK).sum() == 2880
    assert _rms(sol.x_ecef_m) <= 1.05 * 1.56  # RTKLIB dual-freq, all systems: 1.56 m; measured 1.53 m
    # satellites without a second frequency (BeiDou-3 without B3I, GLONASS without G2) are dropped
    assert any("without a usable second frequency" in w for w in data.warnings)
    warning = next(w for w in data.warnings if "without a usable second frequency" in w)
    dropped = warning.split(": ")[-1].split()
    cols = np.isin(data.sv, dropped)
    assert cols.any() and not data.usable[:, cols].any()


def test_iono_free_on_single_frequency_file_is_a_one_line_input_error(capsys):
    static = Path(__file__).resolve().parents[2] / "sample_rinex" / "static"
    obs = next(static.glob("*obs*"), None)
    nav = next(static.glob("*nav*"), None)
    if obs is None or nav is None:
        pytest.skip("sample_rinex/static is missing")
    with pytest.raises(SystemExit) as exc:
        run_app(app, "gnss-solve", [str(obs), str(nav), "--iono", "iono-free"])
    err = capsys.readouterr().err
    assert exc.value.code == 4
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "second-frequency" in lines[0], err


@pytest.mark.parametrize(
    "text",
    ['[signals.second]\nG = ["C5Q"]\n', '[signals.second]\nC = ["C7D"]\n', '[signals.second]\nX = ["C2W"]\n'],
)
def test_second_frequency_codes_without_a_broadcast_group_delay_are_rejected(tmp_path, text):
    cfg = tmp_path / "c.toml"
    cfg.write_text(text)
    with pytest.raises(ConfigError, match="signals.second"):
        load_config(cfg)
