"""[stls], [smoother], [kalman] and measurements: the TOML is the source of the defaults, invalid
options are ConfigErrors, old spellings name the new ones, and --print-config round-trips."""

from __future__ import annotations

import dataclasses
import math
import tomllib

import pytest

from gnss_cli.config import (
    DEFAULT_CONFIG_PATH, KalmanConfig, ProcessingConfig, SmootherConfig, StlsConfig, WeightConfig, load_config,
)
from gnss_cli.config.toml import config_toml
from gnss_cli.errors import ConfigError


def test_dataclass_defaults_equal_the_packaged_toml() -> None:
    toml = tomllib.loads(DEFAULT_CONFIG_PATH.read_text())
    stls = dict(toml["stls"])
    assert ProcessingConfig().orbit_sigma_m == stls.pop("orbit_sigma_m")
    assert dataclasses.asdict(StlsConfig()) == stls
    assert dataclasses.asdict(SmootherConfig()) == toml["smoother"]
    assert dataclasses.asdict(KalmanConfig()) == toml["kalman"]
    assert dataclasses.asdict(WeightConfig()) == toml["weights"]
    proc = ProcessingConfig()
    assert proc.wtls_column_scaling == toml["wtls"]["column_scaling"]
    for key, value in toml["processing"].items():
        if key not in ("methods", "systems", "measurements"):
            assert getattr(proc, key) == (tuple(value) if key == "exclude" else value), key
    assert toml["processing"]["measurements"] == "all" and proc.measurements == ()
    cfg = load_config()
    assert (cfg.stls, cfg.smoother, cfg.kalman) == (StlsConfig(), SmootherConfig(), KalmanConfig())


@pytest.mark.parametrize(
    ("key", "value", "message"),
    [
        ("stls.order", 20, "stls.order"),
        ("stls.kernel", "diagonal", "stls.kernel"),
        ("stls.window", 5, "stls.window"),
        ("stls.lag", -1, "stls.lag"),
        ("stls.tolerance", 0.0, "stls.tolerance"),
        ("stls.window", 2.5, "integer"),
        ("smoother.motion", "pva", "smoother.motion"),
        ("smoother.lag", 4, "smoother.lag"),
        ("kalman.output", "rts", "kalman.output"),
        ("measurements", "doppler", "add pseudorange"),
        ("measurements", "pseudorange,carrier", "measurements"),
        ("phase_sigma_m", 0.0, "phase_sigma_m"),
        ("stls.lags", 3, "unknown [stls]"),
    ],
)
def test_invalid_options_are_config_errors(key: str, value: object, message: str) -> None:
    overrides: dict[str, object] = {key: value}
    if key.startswith("stls.") and key != "stls.lag":
        overrides["stls.lag"] = 3
    if key.startswith("smoother."):
        overrides["methods"] = "smoother"
    with pytest.raises(ConfigError, match=message.replace("[", r"\[")):
        load_config(None, overrides)


def test_full_kernel_orders() -> None:
    cfg = load_config(None, {"stls.lag": 3, "stls.kernel": "full", "stls.window": 0, "stls.order": 9})
    assert cfg.stls.full_order == 9 and cfg.stls.min_window() == 13
    with pytest.raises(ConfigError, match="infeasible"):
        load_config(None, {"stls.lag": 3, "stls.kernel": "full", "stls.order": 6, "stls.window": 15})
    with pytest.raises(ConfigError, match="kernel = 'full' only"):
        load_config(None, {"stls.lag": 3, "stls.order": 9})


def test_multi_epoch_methods_and_measurements() -> None:
    assert load_config(None, {"methods": "ls,wls,stls"}).multi_epoch_methods == ()
    cfg = load_config(None, {"methods": "wls,stls,smoother,kf", "stls.lag": 3})
    assert cfg.multi_epoch_methods == ("stls", "smoother", "kf")
    assert cfg.uses("phase") and not cfg.uses("phase", present=False)
    some = load_config(None, {"measurements": "pseudorange, Doppler"})
    assert some.measurements == ("pseudorange", "doppler") and some.uses("doppler") and not some.uses("phase")


@pytest.mark.parametrize(("toml", "new"), [
    ("[smoothing]\nlag = 3\n", "[stls] keys"),
    ("[kalman]\ndoppler = true\n", "measurements"),
    ("[kalman]\nsmoother = \"rts\"\n", "kalman.output"),
])
def test_old_spellings_name_the_new_ones(tmp_path, toml: str, new: str) -> None:  # type: ignore[no-untyped-def]
    path = tmp_path / "old.toml"
    path.write_text(toml)
    with pytest.raises(ConfigError, match=new.replace("[", r"\[")):
        load_config(path)


def test_a_mistyped_processing_key_gets_the_closest_valid_one() -> None:
    with pytest.raises(ConfigError, match="did you mean 'methods'"):
        load_config(None, {"method": "wls"})


def test_toml_sections(tmp_path) -> None:  # type: ignore[no-untyped-def]
    path = tmp_path / "c.toml"
    path.write_text("[processing]\nmethods = ['stls', 'smoother']\nmeasurements = ['pseudorange']\n"
                    "[stls]\nlag = 2\nwindow = 0\n[smoother]\nmotion = \"cv\"\n")
    cfg = load_config(path)
    assert (cfg.stls.lag, cfg.stls.window, cfg.smoother.motion, cfg.measurements) == (2, 0, "cv", ("pseudorange",))


def test_print_config_round_trips(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """The printed TOML, given back as --config, is the same configuration (non-default values too)."""
    cfg = load_config(None, {"methods": "wls,smoother,kf", "systems": "G,E", "measurements": "pseudorange,doppler",
                             "smoother.motion": "ca", "stls.lag": 2, "kalman.model": "ca", "exclude": "G07",
                             "weights.a_m": 0.5})
    path = tmp_path / "printed.toml"
    path.write_text(config_toml(cfg))
    again = load_config(path)
    assert again == cfg
    assert math.isinf(again.alert_limit_h_m)
