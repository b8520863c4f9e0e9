"""What every figure shares: method styles, the time axis, scale choices, PNG bytes."""

from __future__ import annotations

import io
from collections.abc import Mapping

import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from numpy.typing import NDArray

from gnss_cli.gnss.time import gps_s2datetime

F64 = NDArray[np.float64]

# One colour and line style per method; the methods that coincide on real data (wls, stls,
# wtls) differ in style so that each stays visible on top of the others.
METHOD_STYLES: dict[str, dict[str, object]] = {
    "ls": {"color": "tab:blue", "linestyle": "-"},
    "wls": {"color": "tab:orange", "linestyle": "-"},
    "tls": {"color": "tab:red", "linestyle": "-"},
    "dls": {"color": "tab:purple", "linestyle": "-"},
    "mtls": {"color": "tab:brown", "linestyle": "-"},
    "stls": {"color": "tab:green", "linestyle": "--"},
    "wtls": {"color": "tab:cyan", "linestyle": ":"},
    "smoother": {"color": "tab:pink", "linestyle": "-."},
    "kf": {"color": "tab:olive", "linestyle": "-."},
}

WIDE_FACTOR = 10.0
"""A method whose spread exceeds this many times the smallest spread of the run is drawn on
its own scale (a second panel, a symlog axis, or off the axes with a note)."""


def method_style(method: str) -> dict[str, object]:
    """Line colour and style of a method (grey for an unknown key)."""
    return dict(METHOD_STYLES.get(method, {"color": "tab:gray", "linestyle": "-"}))


def new_figure(width_in: float = 9.0, height_in: float = 5.5) -> Figure:
    """A figure outside pyplot (no global state), laid out without overlaps."""
    return Figure(figsize=(width_in, height_in), layout="constrained")


def png_bytes(fig: Figure, dpi: int = 100) -> bytes:
    """The figure as PNG bytes (Agg renderer)."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    return buf.getvalue()


def elapsed_axis(t_gps_s: F64) -> tuple[F64, str]:
    """Time since the first epoch in s, min or h (by the span) and its axis label with the start."""
    t = np.asarray(t_gps_s, dtype=np.float64)
    t0 = float(t[0]) if t.size else 0.0
    span = float(t[-1] - t0) if t.size else 0.0
    unit, scale = ("s", 1.0) if span <= 600 else (("min", 60.0) if span <= 3 * 3600 else ("h", 3600.0))
    start = np.datetime_as_string(gps_s2datetime(np.array([t0]))[0], unit="s").replace("T", " ")
    return (t - t0) / scale, f"time since {start} GPST ({unit})"


def spread_m(values: F64) -> float:
    """95th percentile of the absolute finite values (a robust size of an error cloud), m."""
    v = np.abs(np.asarray(values, dtype=np.float64))
    v = v[np.isfinite(v)]
    return float(np.percentile(v, 95)) if v.size else float("nan")


def split_wide(spreads: Mapping[str, float]) -> tuple[list[str], list[str]]:
    """Methods within :data:`WIDE_FACTOR` of the smallest spread, and the others."""
    finite = [s for s in spreads.values() if np.isfinite(s)]
    if not finite:
        return list(spreads), []
    limit = WIDE_FACTOR * max(min(finite), 1e-3)
    near = [m for m, s in spreads.items() if np.isfinite(s) and s <= limit]
    wide = [m for m, s in spreads.items() if m not in near]
    return near, wide


def symlog_threshold_m(spreads: Mapping[str, float]) -> float | None:
    """The linear range of a symlog axis when the spreads differ by more than
    :data:`WIDE_FACTOR` (a power of ten at or above the smallest spread), else None."""
    finite = [s for s in spreads.values() if np.isfinite(s) and s > 0]
    if len(finite) < 2 or max(finite) <= WIDE_FACTOR * min(finite):
        return None
    return float(10.0 ** np.ceil(np.log10(min(finite))))


def set_symlog(ax: Axes, threshold: float | None) -> None:
    """A symlog y axis (linear within ``±threshold``) when ``threshold`` is given."""
    if threshold is not None:
        ax.set_yscale("symlog", linthresh=threshold)
        ax.axhspan(-threshold, threshold, color="0.95", zorder=0)


def note(ax: Axes, text: str) -> None:
    """A small note in the lower left corner of the axes."""
    ax.text(0.01, 0.01, text, transform=ax.transAxes, fontsize=8, va="bottom", ha="left",
            bbox={"boxstyle": "round", "facecolor": "white", "alpha": 0.8, "edgecolor": "0.7"})


def legend_outside(ax: Axes, n_entries: int, title: str | None = None) -> None:
    """A legend to the right of the axes, in several columns when it is long."""
    if n_entries:
        ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, title=title,
                  ncol=1 + (n_entries - 1) // 16, frameon=False)


def no_data(fig: Figure, message: str) -> Figure:
    """Mark a figure that has nothing to draw (keeps the set of output files fixed)."""
    ax = fig.axes[0] if fig.axes else fig.add_subplot()
    ax.text(0.5, 0.5, message, transform=ax.transAxes, ha="center", va="center")
    return fig

