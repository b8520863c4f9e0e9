"""The navigation files of a run: read, or kept from the run before in a long-lived worker.

Reading files is this package's job: the dataset comes from :func:`~gnss_cli.io.rinex.read_nav`,
the kept copy is keyed by the files' real paths, modification times and sizes. The per-system
record tables (:mod:`gnss_cli.gnss.broadcast`) are kept with it, in a dictionary the run fills.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import xarray as xr

from gnss_cli.io.rinex import nav_leap_seconds, read_nav

__all__ = ["keep_navigation", "navigation_files"]

_KEPT: dict[tuple[object, ...], tuple[xr.Dataset, float | None, dict[str, Any]]] | None = None
"""The navigation data last read, by :func:`_nav_key` (None: nothing is kept, the default)."""


def keep_navigation() -> None:
    """Keep the navigation data last read for the next runs of this process (``gnss-batch``'s
    workers: the stations of a network share one day's navigation files, 0.12 s of reading and
    record tables per run of a 24 h multi-GNSS file). Nothing is changed in what is kept."""
    global _KEPT
    if _KEPT is None:
        _KEPT = {}


def _nav_key(paths: Sequence[str | Path], systems: Sequence[str]) -> tuple[object, ...] | None:
    """The files (real path, modification time, size) and the systems; None when a file cannot be stat'ed."""
    try:
        files = tuple((os.path.realpath(p), os.stat(p).st_mtime_ns, os.stat(p).st_size) for p in paths)
    except OSError:
        return None
    return files, tuple(systems)


def navigation_files(paths: Sequence[str | Path], systems: Sequence[str]) -> tuple[xr.Dataset, float | None, dict[str, Any]]:
    """The navigation dataset of ``paths`` (``read_nav``), their leap seconds, and the dictionary
    of per-system record tables the run fills (the kept ones after :func:`keep_navigation`, while
    the files are unchanged; only the last set is kept, so a campaign of many days reads each
    day's files once)."""
    key = _nav_key(paths, systems) if _KEPT is not None else None
    if _KEPT is not None and key is not None and key in _KEPT:
        return _KEPT[key]
    kept = (read_nav(list(paths), systems=systems), nav_leap_seconds(paths), {})
    if _KEPT is not None and key is not None:
        _KEPT.clear()
        _KEPT[key] = kept
    return kept
