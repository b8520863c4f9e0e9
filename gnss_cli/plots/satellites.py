"""Satellite geometry over the run: sky plot of used and excluded satellites, satellite count,
GDOP per method, and the post-fit residuals per satellite.

"Used" is a row with a finite post-fit residual in the solution of the geometry method (WLS
when the run has it, else the first method); "excluded" is an observation with a usable
ephemeris that the solution did not use (below the elevation mask, a failed epoch, ...).
"""

from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

from gnss_cli.gnss.frames import satellite_azimuth_elevation_deg
from gnss_cli.io.rinex3_header import SYSTEM_NAMES
from gnss_cli.pipeline.results import MethodSolution, RunResult
from gnss_cli.plots.common import F64, elapsed_axis, legend_outside, method_style, new_figure, no_data

SATELLITE_COLORS = [f"C{i}" for i in range(10)]
SATELLITE_STYLES = ["-", "--", ":", "-."]


def geometry_method(result: RunResult) -> str:
    """The method whose residuals define "used": ``wls`` when present, else the first."""
    return "wls" if "wls" in result.solutions else next(iter(result.solutions))


def receiver_positions(sol: MethodSolution) -> F64:
    """Per-epoch receiver positions ``(T, 3)``; failed epochs take the median of the others."""
    x = sol.x_ecef_m.copy()
    ok = np.isfinite(x).all(axis=1)
    if ok.any():
        x[~ok] = np.median(x[ok], axis=0)
    return x


def azimuth_elevation_deg(result: RunResult, sol: MethodSolution) -> tuple[F64, F64]:
    """Azimuth and elevation ``(T, n)`` (deg) of every satellite seen from the solution (failed
    epochs: from the median solved position, so their observed satellites are drawn too)."""
    return satellite_azimuth_elevation_deg(result.epochs.sat_ecef_m, receiver_positions(sol))


def figure_sky(result: RunResult, elevation_mask_deg: float | None = None) -> Figure:
    """Polar sky plot (north up, azimuth clockwise, zenith at the centre) of used and
    excluded satellite observations, labelled with the satellite id."""
    method = geometry_method(result)
    sol = result.solutions[method]
    fig = new_figure(8, 8)
    ax = fig.add_subplot(projection="polar")
    if not np.isfinite(sol.x_ecef_m).any():
        return no_data(fig, f"{method}: no epoch solved")
    az, el = azimuth_elevation_deg(result, sol)
    used = np.isfinite(sol.residuals_m)
    seen = result.epochs.usable & np.isfinite(el) & (el >= 0)
    excluded = seen & ~used
    used &= seen
    ax.set_theta_zero_location("N")
    ax.set_theta_direction(-1)
    r = 90.0 - el
    ax.scatter(np.radians(az[used]), r[used], s=5, color="tab:blue", label=f"used by {method}", linewidths=0)
    ax.scatter(np.radians(az[excluded]), r[excluded], s=10, marker="x", color="tab:red", linewidths=0.8,
               label="observed, not used (below mask, failed epoch, ...)")
    for j, sv in enumerate(result.epochs.sv):
        k = np.flatnonzero(seen[:, j])
        if k.size:
            ax.annotate(str(sv), (np.radians(az[k[-1], j]), r[k[-1], j]), fontsize=7, ha="left", va="bottom")
    if elevation_mask_deg is not None:
        theta = np.linspace(0, 2 * np.pi, 361)
        ax.plot(theta, np.full_like(theta, 90.0 - elevation_mask_deg), color="0.4", linestyle="--", linewidth=1,
                label=f"elevation mask {elevation_mask_deg:g}°")
    ax.set_rlim(0, 90)
    ax.set_rticks([0, 15, 30, 45, 60, 75, 90])
    ax.set_yticklabels(["90°", "75°", "60°", "45°", "30°", "15°", "0°"], fontsize=7)
    ax.set_rlabel_position(22.5)
    ax.set_xticks(np.radians(np.arange(0, 360, 45)))
    ax.set_xticklabels(["N", "NE", "E", "SE", "S", "SW", "W", "NW"])
    ax.set_title("Sky plot: azimuth (clockwise from north) and elevation (deg, zenith at the centre)", fontsize=10)
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.04), fontsize=8, frameon=False)
    return fig


def figure_satellite_count(result: RunResult) -> Figure:
    """Satellites used per method over time, and the observations with a usable ephemeris."""
    fig = new_figure(10, 4.5)
    ax = fig.add_subplot()
    t, t_label = elapsed_axis(result.epochs.time_gps_s)
    ax.step(t, result.epochs.usable.sum(axis=1), where="mid", color="black", linewidth=1.2, linestyle="--",
            label="observed, usable ephemeris")
    for method, s in result.solutions.items():
        ax.step(t, s.n_sat, where="mid", linewidth=1.0, label=method, **method_style(method))
    ax.yaxis.set_major_locator(MaxNLocator(integer=True))
    ax.set_ylim(bottom=0)
    ax.set_xlabel(t_label)
    ax.set_ylabel("satellites")
    ax.set_title("Satellites used per method")
    ax.grid(True, alpha=0.3)
    legend_outside(ax, len(result.solutions) + 1)
    return fig


def figure_gdop(result: RunResult) -> Figure:
    """GDOP per method over time (log axis when the methods differ by more than 30×)."""
    fig = new_figure(10, 4.5)
    ax = fig.add_subplot()
    t, t_label = elapsed_axis(result.epochs.time_gps_s)
    for method, s in result.solutions.items():
        ax.plot(t, s.gdop, linewidth=1.0, label=method, **method_style(method))
    values = np.concatenate([s.gdop for s in result.solutions.values()])
    values = values[np.isfinite(values) & (values > 0)]
    log = values.size > 0 and values.max() > 30 * values.min()
    if log:
        ax.set_yscale("log")
    ax.set_xlabel(t_label)
    ax.set_ylabel("GDOP (unitless" + (", log scale)" if log else ")"))
    title = "GDOP per method"
    if result.models:
        title += " (stls: multi-epoch GDOP of the smoothing windows)"
    ax.set_title(title)
    ax.grid(True, which="both", alpha=0.3)
    legend_outside(ax, len(result.solutions), "method")
    return fig


SYSTEM_COLORS = {"G": "tab:blue", "E": "tab:orange", "C": "tab:red", "J": "tab:purple", "R": "tab:green"}
MAX_SATELLITE_LEGEND = 32
"""Above this many satellites the residual lines are coloured by system, one legend entry each."""


def figure_residuals(result: RunResult) -> Figure:
    """Post-fit pseudorange residuals of the geometry method, one line per satellite
    (coloured per satellite, or per system when there are many satellites)."""
    method = geometry_method(result)
    res = result.solutions[method].residuals_m
    fig = new_figure(11, 5)
    ax = fig.add_subplot()
    t, t_label = elapsed_axis(result.epochs.time_gps_s)
    shown = [j for j in range(res.shape[1]) if np.isfinite(res[:, j]).any()]
    if not shown:
        return no_data(fig, f"{method}: no residuals")
    by_system = len(shown) > MAX_SATELLITE_LEGEND
    counts: dict[str, int] = {}
    for drawn, j in enumerate(shown):
        sv = str(result.epochs.sv[j])
        if by_system:
            counts[sv[0]] = counts.get(sv[0], 0) + 1
            style = {"color": SYSTEM_COLORS.get(sv[0], "tab:gray"), "linestyle": "-", "alpha": 0.6, "label": "_" + sv}
        else:
            style = {"color": SATELLITE_COLORS[drawn % 10], "linestyle": SATELLITE_STYLES[(drawn // 10) % 4], "label": sv}
        ax.plot(t, res[:, j], linewidth=0.9, marker=".", markersize=2, **style)
    if by_system:
        for system, n in counts.items():
            ax.plot([], [], color=SYSTEM_COLORS.get(system, "tab:gray"), label=f"{SYSTEM_NAMES.get(system, system)} ({n} satellites)")
    ax.axhline(0.0, color="0.3", linewidth=0.6)
    ax.set_xlabel(t_label)
    ax.set_ylabel("post-fit residual (m)")
    ax.set_title(f"Pseudorange residuals per satellite ({method})")
    ax.grid(True, alpha=0.3)
    legend_outside(ax, len(counts) if by_system else len(shown), "system" if by_system else "satellite")
    return fig
