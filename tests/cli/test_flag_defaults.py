"""Every processing default lives in the packaged TOML: a flag that sets a configuration key
has no default of its own (None, so ``--config`` and the packaged file decide) and its
``--help`` shows the packaged value."""

from __future__ import annotations

import typer

from gnss_cli.cli import simulate as simulate_cli
from gnss_cli.cli import solve as solve_cli
from gnss_cli.config import load_config, packaged_defaults

# flag -> (TOML table, key) of gnss-solve
SOLVE_KEYS = {
    "--method": ("processing", "methods"), "--systems": ("processing", "systems"), "--iono": ("processing", "iono"),
    "--tropo": ("processing", "tropo"), "--elevation-mask": ("processing", "elevation_mask_deg"),
    "--kernel": ("stls", "kernel"), "--order": ("stls", "order"), "--window": ("stls", "window"),
    "--motion": ("smoother", "motion"), "--measurements": ("processing", "measurements"),
    "--time-system": ("processing", "time_system"),
    "--integrity": ("processing", "integrity"), "--snr-mask": ("processing", "snr_mask_dbhz"),
    "--robust": ("processing", "robust"),
    "--kf-model": ("kalman", "model"), "--kf-output": ("kalman", "output"),
}
SIMULATE_KEYS = {
    "--trajectory": ("simulate", "trajectory"), "--duration": ("simulate", "duration_s"),
    "--interval": ("simulate", "interval_s"), "--systems": ("simulate", "systems"), "--seed": ("simulate", "seed"),
    "--errors": ("simulate", "errors"), "--noise-sigma": ("errors", "noise_sigma_m"),
    "--elevation-mask": ("simulate", "elevation_mask_deg"), "--rinex-version": ("simulate", "rinex_version"),
}


def _options(app: typer.Typer) -> dict[str, object]:
    command = typer.main.get_command(app)
    return {opt: p for p in command.params for opt in getattr(p, "opts", [])}


def _as_flag(value: object) -> str:
    return ",".join(str(v) for v in value) if isinstance(value, (list, tuple)) else str(value)


def test_solve_flags_defer_to_the_packaged_configuration() -> None:
    options, toml = _options(solve_cli.app), packaged_defaults()
    for flag, (table, key) in SOLVE_KEYS.items():
        param = options[flag]
        assert param.default is None, flag  # type: ignore[attr-defined]
        assert param.show_default == _as_flag(toml[table][key]), flag  # type: ignore[attr-defined]
    lag = options["--lag"]  # one flag for two keys: stls.lag and smoother.lag
    assert lag.default is None  # type: ignore[attr-defined]
    assert lag.show_default == f"stls {toml['stls']['lag']}, smoother {toml['smoother']['lag']}"  # type: ignore[attr-defined]


def test_packaged_values_are_what_a_run_uses() -> None:
    cfg, toml = load_config(), packaged_defaults()
    assert cfg.methods == tuple(toml["processing"]["methods"])
    assert cfg.elevation_mask_deg == toml["processing"]["elevation_mask_deg"]
    assert cfg.iono == toml["processing"]["iono"] and cfg.tropo == toml["processing"]["tropo"]
    for key in ("lag", "kernel", "order", "window", "tolerance", "max_iterations"):
        assert getattr(cfg.stls, key) == toml["stls"][key], key
    for key in ("motion", "lag"):
        assert getattr(cfg.smoother, key) == toml["smoother"][key], key
    assert cfg.doppler_sigma_m_s == toml["processing"]["doppler_sigma_m_s"]
    for key, value in toml["kalman"].items():
        assert getattr(cfg.kalman, key) == value, key


def test_simulate_flags_show_the_packaged_simulate_defaults() -> None:
    from gnss_cli.sim.scenario import ScenarioConfig

    options, toml, built_in = _options(simulate_cli.app), packaged_defaults("simulate.toml"), ScenarioConfig()
    for flag, (table, key) in SIMULATE_KEYS.items():
        param = options[flag]
        assert param.default is None, flag  # type: ignore[attr-defined]
        assert param.show_default == _as_flag(toml[table][key]), flag  # type: ignore[attr-defined]
    assert built_in.duration_s == toml["simulate"]["duration_s"] and built_in.seed == toml["simulate"]["seed"]
