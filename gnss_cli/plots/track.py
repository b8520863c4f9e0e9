"""Tracks in a local East-North-Up frame: a run's positions per method with the reference,
and an identified trajectory (fit and prediction) against its data."""

from __future__ import annotations

import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure

from gnss_cli.gnss.frames import ecef2enu
from gnss_cli.pipeline.identification import Identification
from gnss_cli.pipeline.results import RunResult
from gnss_cli.plots.common import F64, elapsed_axis, method_style, new_figure, note, split_wide, spread_m


def track_origin(result: RunResult, reference_ecef_m: F64 | None) -> tuple[F64, str]:
    """ENU origin of the track: the (first finite) reference, else the mean of the first method."""
    if reference_ecef_m is not None:
        ref = np.atleast_2d(reference_ecef_m)
        ok = np.isfinite(ref).all(axis=1)
        if ok.any():
            return ref[np.argmax(ok)], "reference" if ref.shape[0] == 1 else "first reference epoch"
    method = next(iter(result.solutions))
    x = result.solutions[method].x_ecef_m
    ok = np.isfinite(x).all(axis=1)
    return (x[ok].mean(axis=0) if ok.any() else np.zeros(3)), f"mean {method} position"


def _limits(ax: Axes, points: list[F64], margin: float = 0.08) -> None:
    """Axis limits around ``points`` (the methods on the main scale and the reference)."""
    pts = np.vstack([p[np.isfinite(p).all(axis=1)] for p in points if p.size]) if points else np.zeros((0, 2))
    if not pts.shape[0]:
        return
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    centre, half = (lo + hi) / 2.0, max(float((hi - lo).max()) * (0.5 + margin), 0.5)
    ax.set_xlim(centre[0] - half, centre[0] + half)  # a square: equal aspect without moving the limits
    ax.set_ylim(centre[1] - half, centre[1] + half)


def figure_track(result: RunResult, reference_ecef_m: F64 | None) -> Figure:
    """Horizontal track per method in local ENU with the reference; methods whose spread is
    more than ten times the smallest are left out (a note names them)."""
    origin, origin_name = track_origin(result, reference_ecef_m)
    fig = new_figure(9, 8)
    ax = fig.add_subplot()
    enu = {m: ecef2enu(s.x_ecef_m, origin) for m, s in result.solutions.items()}
    ref_en = None
    if reference_ecef_m is not None:
        ref = np.atleast_2d(reference_ecef_m)
        ref_en = ecef2enu(ref, origin)[:, :2]
    center = ref_en if ref_en is not None else np.zeros((1, 2))
    spreads = {}
    for m, v in enu.items():
        d = v[:, :2] - (center if center.shape[0] == v.shape[0] else center[:1])
        spreads[m] = spread_m(np.hypot(d[:, 0], d[:, 1]))
    near, wide = split_wide(spreads)
    static = ref_en is not None and ref_en.shape[0] == 1  # a fixed station: the fixes are a cloud, not a path
    for m in near:
        style = method_style(m)
        if static:
            style["linestyle"] = "none"
        ax.plot(enu[m][:, 0], enu[m][:, 1], marker=".", markersize=4 if static else 3, linewidth=0.6, alpha=0.8,
                label=m, **style)
    if ref_en is not None:
        if ref_en.shape[0] == 1:
            ax.plot(ref_en[0, 0], ref_en[0, 1], marker="*", markersize=16, color="black", linestyle="none",
                    label="reference", zorder=5)
        else:
            ax.plot(ref_en[:, 0], ref_en[:, 1], color="black", linewidth=1.6, label="reference", zorder=5)
    _limits(ax, [enu[m][:, :2] for m in near] + ([ref_en] if ref_en is not None else []))
    ax.set_aspect("equal", adjustable="box")
    if wide:
        note(ax, f"not drawn: {', '.join(wide)} (spread more than 10× that of {', '.join(near)}; see the error figures)")
    ax.set_xlabel("East (m)")
    ax.set_ylabel("North (m)")
    ax.set_title(f"Horizontal track in local ENU (origin: {origin_name})")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, frameon=False)
    return fig


def figure_identification(ident: Identification, data_t_s: F64, data_ecef_m: F64) -> Figure:
    """The identified (fit) and predicted trajectory against the data: E, N, U over time and
    the horizontal track, in the identification's ENU frame (origin: the first sample)."""
    data = ecef2enu(data_ecef_m, ident.origin_ecef_m)
    t0 = float(data_t_s[0])
    t_data, t_label = elapsed_axis(np.asarray(data_t_s, dtype=np.float64))
    scale = (float(data_t_s[-1]) - t0) / t_data[-1] if t_data.size > 1 and t_data[-1] else 1.0
    t_rows = (ident.t_s - t0) / scale
    kinds = np.asarray(ident.kinds)
    fit, pred = kinds == "fit", kinds == "predicted"
    if not ident.is_gps_time:
        t_label = t_label.split(" since")[0] + " since the first sample" + t_label[t_label.rfind(" ("):]
    fig = new_figure(13, 8)
    grid = fig.add_gridspec(3, 2, width_ratios=(1.4, 1.0))
    axes = [fig.add_subplot(grid[0, 0])]
    axes += [fig.add_subplot(grid[k, 0], sharex=axes[0]) for k in (1, 2)]
    for k, (ax, name) in enumerate(zip(axes, ("East", "North", "Up"))):
        ax.plot(t_data, data[:, k], linestyle="none", marker=".", markersize=4, color="0.5", label="data")
        ax.plot(t_rows[fit], ident.enu_m[fit, k], color="tab:blue", linewidth=1.4, label=f"identified ({ident.method})")
        if pred.any():
            ax.plot(t_rows[pred], ident.enu_m[pred, k], color="tab:orange", linewidth=1.4, linestyle="--",
                    label="predicted")
            ax.axvline(t_rows[fit][-1], color="0.3", linewidth=0.8, linestyle=":")
        ax.set_ylabel(f"{name} (m)")
        ax.grid(True, alpha=0.3)
    axes[-1].set_xlabel(t_label)
    axes[0].legend(fontsize=8, loc="best")
    ax = fig.add_subplot(grid[:, 1])
    ax.plot(data[:, 0], data[:, 1], linestyle="none", marker=".", markersize=4, color="0.5", label="data")
    ax.plot(ident.enu_m[fit, 0], ident.enu_m[fit, 1], color="tab:blue", linewidth=1.4, label="identified")
    if pred.any():
        ax.plot(ident.enu_m[pred, 0], ident.enu_m[pred, 1], color="tab:orange", linewidth=1.4, linestyle="--",
                label="predicted")
    ax.plot(0.0, 0.0, marker="o", color="black", linestyle="none", label="origin (first sample)")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("East (m)")
    ax.set_ylabel("North (m)")
    ax.set_title("Horizontal track", fontsize=10)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8, loc="best")
    res = ident.result
    fig.suptitle(f"Identified lag-{res.kernel.lag} kernel ({ident.method}, {ident.structure}): {ident.train} training "
                 f"samples, {ident.predicted} predicted; misfit {res.misfit:.3g} m²")
    return fig
