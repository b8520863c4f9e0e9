"""The effective configuration as TOML (``gnss-solve --print-config``).

The text has the tables and keys of the packaged ``default.toml``, so it can be saved and given
back with ``--config`` (:func:`gnss_cli.config.load_config` reads it into the same
configuration: a test checks the round trip).
"""

from __future__ import annotations

import math
from dataclasses import fields
from typing import Any

from gnss_cli.config import _OWN_TABLES, ProcessingConfig

__all__ = ["config_toml"]


def config_toml(config: ProcessingConfig) -> str:
    """Every key of ``config`` in its ``default.toml`` table, as TOML text.

    >>> from gnss_cli.config import load_config
    >>> "methods = [\\"wls\\"]" in config_toml(load_config())
    True
    """
    processing = {f.name: getattr(config, f.name) for f in fields(config) if f.name not in _OWN_TABLES}
    processing["systems"] = list(config.systems) or "all"
    processing["measurements"] = list(config.measurements) or "all"
    tables: list[tuple[str, dict[str, Any]]] = [
        ("processing", processing),
        ("weights", _fields(config.weights)),
        ("signals", {k: list(v) for k, v in config.signals.items()}),
        ("signals.second", {k: list(v) for k, v in config.signals_second.items()}),
        ("stls", {"orbit_sigma_m": config.orbit_sigma_m, **_fields(config.stls)}),
        ("wtls", {"column_scaling": config.wtls_column_scaling}),
        ("smoother", _fields(config.smoother)),
        ("kalman", _fields(config.kalman)),
        ("nlos", _fields(config.nlos)),
        ("urban", _fields(config.urban)),
    ]
    lines = ["# gnss-solve effective configuration (packaged defaults < --config < flags)"]
    for name, table in tables:
        lines += ["", f"[{name}]"] + [f"{key} = {_value(value)}" for key, value in table.items()]
    return "\n".join(lines) + "\n"


def _fields(section: Any) -> dict[str, Any]:
    return {f.name: getattr(section, f.name) for f in fields(section)}


def _value(value: Any) -> str:
    """One TOML value: string, boolean, integer, float (``inf``, ``nan``) or array of those."""
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_value(v) for v in value) + "]"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if math.isnan(value):
            return "nan"
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
        return repr(value)
    text = str(value).replace("\\", "\\\\").replace('"', '\\"')
    return f'"{text}"'
