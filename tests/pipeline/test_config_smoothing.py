"""[smoothing] options: the TOML is the source of the defaults; invalid options are ConfigErrors."""

from __future__ import annotations

import dataclasses
import tomllib

import pytest

from gnss_cli.config import DEFAULT_CONFIG_PATH, ProcessingConfig, SmoothingConfig, WeightConfig, load_config
from gnss_cli.errors import ConfigError


def test_dataclass_defaults_equal_the_packaged_toml() -> None:
    toml = tomllib.loads(DEFAULT_CONFIG_PATH.read_text())
    assert dataclasses.asdict(SmoothingConfig()) == toml["smoothing"]
    assert dataclasses.asdict(WeightConfig()) == toml["weights"]
    proc = ProcessingConfig()
    assert proc.orbit_sigma_m == toml["stls"]["orbit_sigma_m"]
    assert proc.wtls_column_scaling == toml["wtls"]["column_scaling"]
    for key, value in toml["processing"].items():
        if key not in ("methods", "systems"):
            assert getattr(proc, key) == (tuple(value) if key == "exclude" else value), key
    assert load_config().smoothing == SmoothingConfig()


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"lag": 3, "kernel": "full", "order": 20}, "smoothing.order"),
        ({"lag": 3, "kernel": "full", "order": 6, "window": 15}, "infeasible"),
        ({"model": "pva"}, "needs smoothing.lag"),
        ({"lag": 3, "model": "kalman"}, "smoothing.model"),
        ({"lag": 3, "kernel": "diagonal"}, "smoothing.kernel"),
        ({"lag": 3, "window": 5}, "smoothing.window"),
        ({"lag": 1, "model": "pva", "window": 4}, "smoothing.window"),
        ({"lag": 1, "model": "static", "window": 2}, "smoothing.window"),
        ({"lag": -1}, "smoothing.lag"),
        ({"lag": 3, "order": 9}, "kernel = 'full' only"),
        ({"lag": 3, "tolerance": 0.0}, "smoothing.tolerance"),
        ({"lag": 3, "window": 2.5}, "integer"),
        ({"lag": 1, "model": "static", "window": "whole"}, "'auto'"),
        ({"lag": 1, "model": "static", "window_pfa": 0.0}, "smoothing.window_pfa"),
        ({"lag": 1, "model": "static", "window_pfa": 0.7}, "smoothing.window_pfa"),
        ({"lags": 3}, "unknown [smoothing]"),
    ],
)
def test_invalid_smoothing_options_are_config_errors(options: dict[str, object], message: str) -> None:
    with pytest.raises(ConfigError, match=message.replace("[", r"\[")):
        load_config(None, {f"smoothing.{k}": v for k, v in options.items()})


def test_valid_smoothing_options() -> None:
    cfg = load_config(None, {"smoothing.lag": 3, "smoothing.kernel": "full", "smoothing.window": 0,
                             "smoothing.order": 9})
    assert cfg.smoothing.full_order == 9 and cfg.smoothing.min_window() == 13
    assert load_config(None, {"smoothing.lag": 2, "smoothing.model": "pva"}).smoothing.effective_lag == 3


def test_auto_window_is_a_ladder_for_the_static_model_only() -> None:
    """``window = "auto"`` (the default; also ``"15"`` and ``"AUTO"`` from the command line)."""
    static = load_config(None, {"smoothing.lag": 1, "smoothing.model": "static", "smoothing.window": "AUTO"}).smoothing
    assert static.window == "auto" and static.window_ladder
    for model in ("pva", "identify", "auto"):
        s = load_config(None, {"smoothing.lag": 3, "smoothing.model": model}).smoothing
        assert s.window == "auto" and not s.window_ladder and s.window_epochs == 15
    fixed = load_config(None, {"smoothing.lag": 1, "smoothing.model": "static", "smoothing.window": "15"}).smoothing
    assert fixed.window == 15 and not fixed.window_ladder


def test_toml_section(tmp_path) -> None:  # type: ignore[no-untyped-def]
    path = tmp_path / "c.toml"
    path.write_text("[smoothing]\nlag = 3\nmodel = \"static\"\nwindow = 0\n")
    s = load_config(path).smoothing
    assert (s.lag, s.model, s.window, s.effective_lag) == (3, "static", 0, 1)
