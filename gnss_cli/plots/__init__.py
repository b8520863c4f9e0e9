"""Figures of a run and of an identification (PNG through matplotlib's Agg renderer) and the
one-page HTML report.

matplotlib is an optional dependency (the ``plot`` extra: ``pip install 'gnss-solve[plot]'``).
This package's ``__init__`` imports nothing heavy: :func:`require_matplotlib` checks that
matplotlib can be imported (so a command can refuse ``--plots`` before it computes anything),
and the submodules import matplotlib when they are imported themselves:

- :mod:`gnss_cli.plots.run`: :func:`~gnss_cli.plots.run.run_figures`, every figure of a
  ``gnss-solve`` run (ENU errors, horizontal scatter with 95 % ellipses, error statistics,
  GDOP, track, sky plot, satellite count, residuals) as matplotlib ``Figure`` objects;
- :mod:`gnss_cli.plots.track`: the horizontal track of a run and, in
  :func:`~gnss_cli.plots.track.figure_identification`, the identified and predicted trajectory
  against the data;
- :mod:`gnss_cli.plots.common`: :func:`~gnss_cli.plots.common.png_bytes`;
- :mod:`gnss_cli.plots.html`: :func:`~gnss_cli.plots.html.html_report`.

No figure goes through ``pyplot``: every ``Figure`` is created directly, so nothing depends
on a display, a global backend or global state.

Modules, one job each::

    common      What every figure shares: method styles, the time axis, scale choices, PNG bytes.
    errors      Position errors: ENU errors over time, the horizontal scatter with 95 % ellipses, an...
    html        The one-page HTML report: figures embedded as base64 PNG, the summary table, the set...
    network     The figures of a gnss-batch network: per station its RMS errors and mean GDOP, a map.
    run         Every figure of a gnss-solve run, from its RunResult.
    satellites  Satellite geometry over the run: sky plot of used and excluded satellites, satellite...
    stanford    The Stanford diagram: each epoch's horizontal error against its HPL and vertical err...
    track       Tracks in a local East-North-Up frame: a run's positions per method with the referen...
"""

from __future__ import annotations

from gnss_cli.errors import ConfigError

__all__ = ["PLOT_EXTRA_HINT", "RUN_FIGURES", "IDENTIFY_FIGURES", "NETWORK_FIGURES", "require_matplotlib"]

RUN_FIGURES = {
    "enu_errors": "E, N and U errors over time per method (deviations from each method's mean without a reference)",
    "horizontal_scatter": "Horizontal errors per method with the mean and the 95 % error ellipse",
    "error_statistics": "Mean errors and error variances per method",
    "gdop": "GDOP per method over time",
    "track": "Horizontal track in local ENU with the reference",
    "sky": "Sky plot of used and excluded satellites",
    "satellites": "Satellites used per method over time",
    "residuals": "Post-fit pseudorange residuals per satellite",
    "stanford": "Stanford diagram: horizontal error against HPL, vertical against VPL, epochs per region",
}
"""The figures of a ``gnss-solve`` run: file stem (``<name>.png`` under ``--plots``) -> caption."""

IDENTIFY_FIGURES = {
    "identification": "Identified and predicted trajectory against the data (E, N, U and horizontal track)",
}
"""The figures of ``gnss-identify --plots``: file stem -> caption."""

NETWORK_FIGURES = {
    "stations": "Per station and method: 3D RMS error against the reference and mean GDOP",
    "station_map": "Mean positions of the stations",
}
"""The figures of ``gnss-batch --plots``: file stem -> caption."""

PLOT_EXTRA_HINT = "pip install 'gnss-solve[plot]' (from a clone: pip install -e '.[plot]')"
"""How to install the optional plotting dependency, for an installed package and for a clone."""


def require_matplotlib(option: str) -> None:
    """Raise :class:`~gnss_cli.errors.ConfigError` (exit 3) naming ``option`` when matplotlib
    cannot be imported (not installed, or broken)."""
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        raise ConfigError(f"{option}: needs matplotlib, which is not installed; install it with {PLOT_EXTRA_HINT}") from None
