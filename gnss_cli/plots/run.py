"""Every figure of a ``gnss-solve`` run, from its :class:`~gnss_cli.pipeline.RunResult`."""

from __future__ import annotations

from collections.abc import Callable

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
                alert_limits_m: tuple[float, float] = (float("inf"), float("inf")),
                progress: Callable[[str, float], None] | None = None) -> dict[str, Figure]:
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
    progress : callable, optional
        ``progress("figures", fraction)`` after each figure: the drawing is the first half of
        the stage, the rendering (:func:`gnss_cli.cli.figures.stage_figures`) the second.
    """
    offsets = method_offsets(result, reference_ecef_m)
    makers: dict[str, Callable[[], Figure]] = {
        "enu_errors": lambda: figure_enu_errors(result, offsets),
        "horizontal_scatter": lambda: figure_horizontal_scatter(offsets),
        "error_statistics": lambda: figure_error_statistics(result, offsets),
        "gdop": lambda: figure_gdop(result),
        "track": lambda: figure_track(result, reference_ecef_m),
        "sky": lambda: figure_sky(result, elevation_mask_deg),
        "satellites": lambda: figure_satellite_count(result),
        "residuals": lambda: figure_residuals(result),
        "stanford": lambda: figure_stanford(result, offsets, alert_limits_m),
    }
    assert list(makers) == list(RUN_FIGURES)
    figures = {}
    for k, (name, make) in enumerate(makers.items()):
        if progress is not None:
            progress("figures", 0.5 * k / len(makers))
        figures[name] = make()
    if progress is not None:
        progress("figures", 0.5)
    return figures
