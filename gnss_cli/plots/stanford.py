"""The Stanford diagram: each epoch's horizontal error against its HPL and vertical error
against its VPL, per method with protection levels, with the regions of
:mod:`gnss_cli.stanford` and the count of epochs in each."""

from __future__ import annotations

import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure

from gnss_cli.pipeline.results import RunResult
from gnss_cli.plots.common import F64, method_style, new_figure, no_data
from gnss_cli.plots.errors import Offsets
from gnss_cli.stanford import REGIONS, region_counts, regions

__all__ = ["figure_stanford"]

_REGION_COLORS = {"normal": "0.93", "misleading": "#f6c89f", "hazardous": "#f4a3a3", "unavailable": "#cfe2f3",
                  "unavailable_misleading": "#d9c3e9"}


def figure_stanford(result: RunResult, offsets: Offsets, alert_limits_m: tuple[float, float] = (np.inf, np.inf)) -> Figure:
    """Horizontal and vertical Stanford diagrams (two panels) of every method that writes
    protection levels; ``alert_limits_m``: (horizontal, vertical) alert limits, m."""
    fig = new_figure(10.0, 5.0)
    if not offsets.against_reference:
        return no_data(fig, "no reference: a Stanford diagram needs the position errors")
    methods = [m for m, s in result.solutions.items() if s.hpl_m is not None and np.isfinite(s.hpl_m).any()]
    if not methods:
        return no_data(fig, "no method of this run wrote protection levels")
    axes = fig.subplots(1, 2)
    for ax, component, k in ((axes[0], "horizontal", 0), (axes[1], "vertical", 1)):
        _panel(ax, result, offsets, methods, component, alert_limits_m[k])
    return fig


def _errors(enu_m: F64, component: str) -> F64:
    return np.hypot(enu_m[:, 0], enu_m[:, 1]) if component == "horizontal" else np.abs(enu_m[:, 2])


def _panel(ax: Axes, result: RunResult, offsets: Offsets, methods: list[str], component: str, alert_m: float) -> None:
    level = "HPL" if component == "horizontal" else "VPL"
    points = []
    for method in methods:
        s = result.solutions[method]
        pl = s.hpl_m if component == "horizontal" else s.vpl_m
        err = _errors(offsets.enu_m[method], component)
        labels = regions(err, pl if pl is not None else np.full(err.shape, np.nan), alert_m)
        have = labels != ""
        counts = region_counts(labels)
        text = ", ".join(f"{n} {name.replace('_', ' ')}" for name, n in counts.items() if n)
        ax.scatter(err[have], pl[have], s=6, label=f"{method}: {text}", color=method_style(method)["color"], zorder=3)
        points.append(np.concatenate((err[have], pl[have])))
    values = np.concatenate(points)
    values = values[np.isfinite(values) & (values > 0)]
    top = float(values.max()) * 1.5 if values.size else 10.0
    if np.isfinite(alert_m):
        top = max(top, 1.5 * alert_m)
    bottom = max(float(values.min()) / 1.5, top / 1e4) if values.size else top / 1e3
    _shade(ax, bottom, top, alert_m)
    ax.plot([bottom, top], [bottom, top], color="0.3", linewidth=0.8)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlim(bottom, top)
    ax.set_ylim(bottom, top)
    ax.set_xlabel(f"{component} error (m)")
    ax.set_ylabel(f"{level} (m)")
    limit = f", alert limit {alert_m:g} m" if np.isfinite(alert_m) else ", no alert limit"
    ax.set_title(f"{component.capitalize()}{limit}", fontsize=10)
    ax.legend(loc="upper left", fontsize=7, frameon=True)


def _shade(ax: Axes, low: float, high: float, alert_m: float) -> None:
    """The regions as filled polygons (below the diagonal: the level fails to bound the error)."""
    al = alert_m if np.isfinite(alert_m) else high
    polygons = {
        "normal": [(low, low), (al, al), (low, al)],
        "misleading": [(low, low), (al, low), (al, al)],
        "hazardous": [(al, low), (high, low), (high, al), (al, al)],
        "unavailable": [(low, al), (al, al), (high, high), (low, high)],
        "unavailable_misleading": [(al, al), (high, al), (high, high)],
    }
    for name in REGIONS:
        xs, ys = zip(*polygons[name])
        ax.fill(xs, ys, color=_REGION_COLORS[name], zorder=0, linewidth=0)
    if np.isfinite(alert_m):
        ax.axvline(alert_m, color="0.5", linewidth=0.6, linestyle="--")
        ax.axhline(alert_m, color="0.5", linewidth=0.6, linestyle="--")
