"""The configuration files: the packaged defaults and every example in ``configs/``."""

from __future__ import annotations

import sys
from dataclasses import replace
from importlib.resources import files
from pathlib import Path

import pytest

from gnss_cli.config import DEFAULT_CONFIG_PATH, load_config

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = sorted((ROOT / "configs").glob("*.toml"))
PEER_CONF = ROOT.parent / "shared" / "peer" / "rnx2rtkp-spp.conf"


def test_defaults_are_package_data() -> None:
    """load_config reads the file inside the package, not one beside the checkout."""
    packaged = files("gnss_cli") / "configs" / "default.toml"
    assert packaged.is_file() and str(DEFAULT_CONFIG_PATH) == str(packaged)
    data = tomllib.loads(packaged.read_text(encoding="utf-8"))
    cfg = load_config()
    assert cfg.methods == tuple(data["processing"]["methods"])
    assert cfg.elevation_mask_deg == data["processing"]["elevation_mask_deg"]
    assert cfg.signals["G"] == tuple(data["signals"]["G"])
    assert cfg.signals_second["E"] == tuple(data["signals"]["second"]["E"])
    assert cfg.orbit_sigma_m == data["stls"]["orbit_sigma_m"]


def test_there_are_examples() -> None:
    assert ROOT / "configs" / "rtklib-peer.toml" in EXAMPLES


@pytest.mark.parametrize("path", EXAMPLES, ids=lambda p: p.name)
def test_every_example_loads(path: Path) -> None:
    cfg = load_config(path)
    assert cfg.validated() == cfg


def test_rtklib_peer_sets_what_it_claims() -> None:
    cfg = load_config(ROOT / "configs" / "rtklib-peer.toml")
    assert cfg.systems == ("G",)
    assert cfg.elevation_mask_deg == 10.0
    assert cfg.iono == "klobuchar" and cfg.tropo == "saastamoinen"
    assert cfg.weights.model == "rtklib"
    assert cfg.methods == ("wls",)
    assert cfg.healthy_only
    assert cfg.weights.cn0_model == "off" and cfg.nlos.detector == "off"  # pntpos.c has neither
    assert cfg.signals["G"][0] == "C1C" and all(code[1] == "1" for code in cfg.signals["G"])  # L1 only


def test_the_nlos_detector_is_off_by_default_and_on_in_the_urban_settings() -> None:
    """Off in the packaged settings (it costs accuracy away from street canyons); the urban
    environment (configs/urban.toml, or a file the default ``auto`` judges a canyon) turns it on
    beside its multi-satellite protection levels, with fixes that rest on suspected reflections not
    ok (``min_direct_dof`` 1), every other [nlos] key packaged."""
    from gnss_cli.pipeline.environment import judged

    default = load_config(None)
    assert default.nlos.detector == "off" and default.environment == "auto"
    given = load_config(ROOT / "configs" / "urban.toml")
    assert given == replace(default, environment="urban")  # the file names the environment, nothing else
    urban = judged(given, None)
    assert urban.nlos == replace(default.nlos, detector="arcs", min_direct_dof=1)
    assert urban.max_simultaneous_faults == 3 and urban.prior_fault_satellite == 1e-2


def test_rtklib_peer_matches_the_peer_options() -> None:
    """The example follows shared/peer/rnx2rtkp-spp.conf (when that file is beside the repository)."""
    if not PEER_CONF.is_file():
        pytest.skip(f"peer options {PEER_CONF} not found")
    opts = {}
    for line in PEER_CONF.read_text().splitlines():
        if "=" in line and not line.lstrip().startswith("#"):
            key, value = line.split("=", 1)
            opts[key.strip()] = value.split("#")[0].strip()
    cfg = load_config(ROOT / "configs" / "rtklib-peer.toml")
    assert opts["pos1-posmode"] == "single" and opts["pos1-frequency"] == "l1"
    assert {"1": ("G",)}[opts["pos1-navsys"]] == cfg.systems
    assert float(opts["pos1-elmask"]) == cfg.elevation_mask_deg
    assert {"brdc": "klobuchar", "off": "none"}[opts["pos1-ionoopt"]] == cfg.iono
    assert {"saas": "saastamoinen", "off": "none"}[opts["pos1-tropopt"]] == cfg.tropo
    assert float(opts["pos2-rejgdop"]) == cfg.max_gdop
    assert {"off": "check", "on": "fde"}[opts["pos1-posopt5"]] == cfg.integrity


def test_flags_override_config_file() -> None:
    cfg = load_config(ROOT / "configs" / "rtklib-peer.toml", overrides={"methods": "ls,wls", "elevation_mask_deg": 15.0})
    assert cfg.methods == ("ls", "wls") and cfg.elevation_mask_deg == 15.0 and cfg.systems == ("G",)
