"""Every figure of a ``gnss-solve`` run, from its :class:`~gnss_cli.pipeline.RunResult`."""

from __future__ import annotations

from matplotlib.figure import Figure

from gnss_cli.pipeline.results import RunResult
from gnss_cli.plots import RUN_FIGURES
from gnss_cli.plots.common import F64
from gnss_cli.plots.errors import (
    figure_enu_errors, figure_error_statistics, figure_horizontal_scatter, method_offsets,
)
from gnss_cli.plots.satellites import figure_gdop, figure_residuals, figure_satellite_count, figure_sky
from gnss_cli.plots.stanford import figure_stanford
from gnss_cli.plots.track import figure_track

__all__ = ["run_figures"]


def run_figures(result: RunResult, reference_ecef_m: F64 | None = None,
                elevation_mask_deg: float | None = None,
                alert_limits_m: tuple[float, float] = (float("inf"), float("inf"))) -> dict[str, Figure]:
    """The figures of :data:`~gnss_cli.plots.RUN_FIGURES`, in that order.

    Parameters
    ----------
    result : RunResult
        The run (:func:`gnss_cli.pipeline.process`).
    reference_ecef_m : ndarray (3,) or (T, 3), optional
        Reference position(s), ECEF m; without it the error figures show deviations from
        each method's mean position.
    elevation_mask_deg : float, optional
        Drawn as a circle on the sky plot.
    alert_limits_m : (float, float)
        Horizontal and vertical alert limits, m, drawn on the Stanford diagram.
    """
    offsets = method_offsets(result, reference_ecef_m)
    figures = {
        "enu_errors": figure_enu_errors(result, offsets),
        "horizontal_scatter": figure_horizontal_scatter(offsets),
        "error_statistics": figure_error_statistics(result, offsets),
        "gdop": figure_gdop(result),
        "track": figure_track(result, reference_ecef_m),
        "sky": figure_sky(result, elevation_mask_deg),
        "satellites": figure_satellite_count(result),
        "residuals": figure_residuals(result),
        "stanford": figure_stanford(result, offsets, alert_limits_m),
    }
    assert list(figures) == list(RUN_FIGURES)
    return figures
