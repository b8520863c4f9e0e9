"""Position errors: ENU errors over time, the horizontal scatter with 95 % ellipses, and the
mean errors and error variances per method (the paper's figures 2-5 and 8-10).

With a reference the offsets are errors against it (local ENU at the reference). Without
one, the time series and the scatter show each method's deviations from its own mean
position, and the statistics figure shows each method's mean position relative to the
mean position of the first method of the run; every label says which.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from matplotlib.patches import Ellipse

from gnss_cli.plots.common import (
    F64, elapsed_axis, method_style, new_figure, note, set_symlog, split_wide, spread_m, symlog_threshold_m,
)
from gnss_cli.report import enu_errors
from gnss_cli.pipeline.results import RunResult

CHI2_2D_95 = -2.0 * np.log(0.05)
"""95 % quantile of the chi-square distribution with 2 degrees of freedom (5.991)."""


@dataclass(frozen=True)
class Offsets:
    """Per-method E/N/U offsets ``(T, 3)`` (m) and what they are measured from."""

    enu_m: dict[str, F64]
    against_reference: bool

    @property
    def word(self) -> str:
        return "error" if self.against_reference else "deviation from mean"


def method_offsets(result: RunResult, reference_ecef_m: F64 | None) -> Offsets:
    """E/N/U errors against the reference, or deviations from each method's mean position."""
    out = {}
    for method, s in result.solutions.items():
        x = s.x_ecef_m
        if reference_ecef_m is not None:
            out[method] = enu_errors(x, reference_ecef_m)
        else:
            ok = np.isfinite(x).all(axis=1)
            mean = x[ok].mean(axis=0) if ok.any() else np.zeros(3)
            out[method] = enu_errors(x, mean) if ok.any() else np.full_like(x, np.nan)
    return Offsets(out, reference_ecef_m is not None)


def _enu_column(axes: list[Axes], t: F64, offsets: Offsets, methods: list[str], symlog: bool) -> None:
    for k, (ax, name) in enumerate(zip(axes, ("East", "North", "Up"))):
        for method in methods:
            ax.plot(t, offsets.enu_m[method][:, k], label=method, linewidth=1.0, **method_style(method))
        threshold = symlog_threshold_m({m: spread_m(offsets.enu_m[m][:, k]) for m in methods}) if symlog else None
        set_symlog(ax, threshold)
        ax.set_ylabel(f"{name} {offsets.word} ({'m, symlog' if threshold is not None else 'm'})")
        ax.axhline(0.0, color="0.3", linewidth=0.6)
        ax.grid(True, alpha=0.3)
        if threshold is not None:
            note(ax, f"linear within ±{threshold:g} m (shaded), logarithmic beyond")


def figure_enu_errors(result: RunResult, offsets: Offsets) -> Figure:
    """E, N and U offsets over time, one line per method. When some methods' errors are more
    than ten times larger than the others', the others get their own linear column and the
    second column shows every method on symlog axes."""
    spreads = {m: spread_m(np.linalg.norm(v, axis=1)) for m, v in offsets.enu_m.items()}
    near, wide = split_wide(spreads)
    fig = new_figure(15 if wide else 10, 8)
    axes = fig.subplots(3, 2 if wide else 1, sharex=True, squeeze=False)
    t, t_label = elapsed_axis(result.epochs.time_gps_s)
    _enu_column(list(axes[:, 0]), t, offsets, near, symlog=False)
    if wide:
        _enu_column(list(axes[:, 1]), t, offsets, near + wide, symlog=True)
        axes[0, 0].set_title(f"{', '.join(near)} (linear)", fontsize=10)
        axes[0, 1].set_title(f"all methods ({', '.join(wide)}: >10× larger errors)", fontsize=10)
    for ax in axes[-1]:
        ax.set_xlabel(t_label)
    axes[0, -1].legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, title="method", frameon=False)
    title = ("ENU errors against the reference" if offsets.against_reference
             else "ENU deviations from each method's mean position (no reference given)")
    fig.suptitle(title)
    return fig


def ellipse_95(ax: Axes, enu: F64, method: str) -> tuple[F64, F64] | None:
    """Scatter of one method's horizontal offsets with its mean and 95 % covariance ellipse."""
    en = enu[:, :2][np.isfinite(enu[:, :2]).all(axis=1)]
    if en.shape[0] < 2:
        return None
    style = method_style(method)
    mean = en.mean(axis=0)
    cov = np.cov(en.T, ddof=0)
    vals, vecs = np.linalg.eigh(cov)
    vals = np.clip(vals, 0.0, None)
    angle = float(np.degrees(np.arctan2(vecs[1, 1], vecs[0, 1])))
    width, height = 2.0 * np.sqrt(CHI2_2D_95 * vals[::-1])
    label = f"{method}: mean E {mean[0]:.2f} N {mean[1]:.2f} m, 95 % semi-axes {width / 2:.2f} / {height / 2:.2f} m"
    ax.scatter(en[:, 0], en[:, 1], s=6, alpha=0.45, color=style["color"], linewidths=0)
    ax.add_patch(Ellipse(tuple(mean), width, height, angle=angle, fill=False, linewidth=1.6,
                         edgecolor=style["color"], linestyle=style["linestyle"], label=label))
    ax.plot(*mean, marker="+", markersize=12, markeredgewidth=2, color=style["color"])
    return mean, cov


def _scatter_axes(ax: Axes, offsets: Offsets, methods: list[str], title: str) -> None:
    for method in methods:
        ellipse_95(ax, offsets.enu_m[method], method)
    ax.axhline(0.0, color="0.3", linewidth=0.6)
    ax.axvline(0.0, color="0.3", linewidth=0.6)
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel(f"East {offsets.word} (m)")
    ax.set_ylabel(f"North {offsets.word} (m)")
    ax.set_title(title, fontsize=10)
    ax.grid(True, alpha=0.3)
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.14), fontsize=7, frameon=False)


def figure_horizontal_scatter(offsets: Offsets) -> Figure:
    """Horizontal offsets per method with the mean (+) and the 95 % error ellipse; methods
    whose spread is more than ten times the smallest get a second, wider panel."""
    spreads = {m: spread_m(np.hypot(v[:, 0], v[:, 1])) for m, v in offsets.enu_m.items()}
    near, wide = split_wide(spreads)
    fig = new_figure(13 if wide else 8, 8)
    axes = fig.subplots(1, 2 if wide else 1, squeeze=False)[0]
    _scatter_axes(axes[0], offsets, near, ", ".join(near) if wide else "")
    if wide:
        _scatter_axes(axes[1], offsets, near + wide, f"all methods ({', '.join(wide)}: >{10:g}× wider)")
    what = "errors against the reference" if offsets.against_reference else "deviations from each method's mean"
    fig.suptitle(f"Horizontal {what}: mean (+) and 95 % error ellipse per method")
    return fig


def _grouped_bars(ax: Axes, methods: list[str], values: F64, labels: tuple[str, ...]) -> None:
    width = 0.8 / len(labels)
    x = np.arange(len(methods))
    colors = ("tab:blue", "tab:orange", "tab:green")
    for j, label in enumerate(labels):
        ax.bar(x + (j - (len(labels) - 1) / 2) * width, values[:, j], width, label=label, color=colors[j % 3])
    ax.set_xticks(x)
    ax.set_xticklabels(methods)
    ax.grid(True, axis="y", alpha=0.3)
    ax.legend(fontsize=8)


def figure_error_statistics(result: RunResult, offsets: Offsets) -> Figure:
    """Mean E/N/U error and the E/N/U error variances per method (grouped bars; symlog and
    log axes when the methods differ by more than a factor of ten)."""
    methods = list(offsets.enu_m)
    means = np.full((len(methods), 3), np.nan)
    variances = np.full((len(methods), 3), np.nan)
    first = None
    for i, m in enumerate(methods):
        enu = offsets.enu_m[m]
        if not offsets.against_reference:  # relative to the first method's mean position
            x = result.solutions[m].x_ecef_m
            ok = np.isfinite(x).all(axis=1)
            if first is None and ok.any():
                first = x[ok].mean(axis=0)
            if first is not None and ok.any():
                means[i] = enu_errors(x[ok].mean(axis=0)[None, :], first)[0]
        enu = enu[np.isfinite(enu).all(axis=1)]
        if enu.shape[0]:
            if offsets.against_reference:
                means[i] = enu.mean(axis=0)
            variances[i] = enu.var(axis=0)
    fig = new_figure(10, 7.5)
    ax_mean, ax_var = fig.subplots(2, 1)
    _grouped_bars(ax_mean, methods, means, ("East", "North", "Up"))
    set_symlog(ax_mean, symlog_threshold_m({m: float(np.nanmax(np.abs(means[i]))) for i, m in enumerate(methods)}))
    ax_mean.axhline(0.0, color="0.3", linewidth=0.6)
    if offsets.against_reference:
        ax_mean.set_ylabel("mean error (m)")
        ax_mean.set_title("Mean estimation errors", fontsize=10)
    else:
        ax_mean.set_ylabel(f"mean position − {methods[0]} mean (m)")
        ax_mean.set_title(f"Mean positions relative to the {methods[0]} mean (no reference given)", fontsize=10)
    _grouped_bars(ax_var, methods, variances, ("var E", "var N", "var U"))
    finite = variances[np.isfinite(variances) & (variances > 0)]
    what = "error variance" if offsets.against_reference else "position variance"
    if finite.size and finite.max() > 100 * finite.min():
        ax_var.set_yscale("log")
        ax_var.set_ylabel(f"{what} (m², log scale)")
    else:
        ax_var.set_ylabel(f"{what} (m²)")
    ax_var.set_title("Error covariances: the E/N/U variances (the full covariance is in the summary table)", fontsize=10)
    fig.suptitle("Error statistics per method")
    return fig
