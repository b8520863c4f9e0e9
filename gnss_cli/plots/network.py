"""The figures of a gnss-batch network: per station its RMS errors (or, without a reference, its
position scatter) and mean GDOP, and a map of the stations' mean positions."""

from __future__ import annotations

import numpy as np
import pandas as pd
from matplotlib.figure import Figure

from gnss_cli.plots.common import method_style, new_figure, no_data

__all__ = ["network_figures"]


def network_figures(table: pd.DataFrame) -> dict[str, Figure]:
    """The figures of :data:`~gnss_cli.plots.NETWORK_FIGURES` from the network table
    (:func:`gnss_cli.cli.batch_output.network_table`: one row per station and method)."""
    return {"stations": figure_stations(table), "station_map": figure_station_map(table)}


def figure_stations(table: pd.DataFrame) -> Figure:
    """Grouped bars per station: 3D, horizontal and vertical RMS of each method (m), and the
    mean GDOP; stations in the table's order."""
    fig = new_figure(max(7.0, 1.0 + 0.6 * table["station"].nunique()), 6.5)
    if table.empty:
        return no_data(fig, "no station was solved")
    stations = list(dict.fromkeys(table["station"]))
    methods = list(dict.fromkeys(table["method"]))
    ax_rms, ax_gdop = fig.subplots(2, 1, sharex=True)
    x = np.arange(len(stations))
    width = 0.8 / len(methods)
    with_reference = bool(np.isfinite(table["rms_3d_m"].to_numpy(dtype=np.float64)).any())
    for k, method in enumerate(methods):
        rows = table[table["method"] == method].set_index("station").reindex(stations)
        style = method_style(method)
        offset = (k - (len(methods) - 1) / 2) * width
        ax_rms.bar(x + offset, rows["rms_3d_m"] if with_reference else np.zeros(len(stations)), width,
                   color=style["color"], label=method)
        ax_gdop.bar(x + offset, rows["mean_gdop"], width, color=style["color"], label=method)
    ax_rms.set_ylabel("3D RMS error (m)" if with_reference else "no reference given")
    ax_rms.set_title("Per station: 3D RMS error against the reference" if with_reference
                     else "Per station (no reference given: no errors)", fontsize=10)
    ax_rms.legend(fontsize=8)
    ax_gdop.set_ylabel("mean GDOP")
    ax_gdop.set_xticks(x, stations, rotation=45 if len(stations) > 8 else 0, ha="right" if len(stations) > 8 else "center")
    ax_gdop.set_xlabel("station")
    return fig


def figure_station_map(table: pd.DataFrame) -> Figure:
    """The stations' mean positions (longitude, latitude in degrees) of the first method, labelled."""
    fig = new_figure(7.0, 6.0)
    if table.empty or not np.isfinite(table["mean_lat_deg"].to_numpy(dtype=np.float64)).any():
        return no_data(fig, "no station position")
    first = table[table["method"] == table["method"].iloc[0]]
    ax = fig.subplots()
    ax.scatter(first["mean_lon_deg"], first["mean_lat_deg"], color="black", zorder=3)
    for _, row in first.iterrows():
        ax.annotate(str(row["station"]), (row["mean_lon_deg"], row["mean_lat_deg"]), textcoords="offset points",
                    xytext=(4, 4), fontsize=8)
    ax.set_xlabel("longitude (deg)")
    ax.set_ylabel("latitude (deg)")
    ax.set_title(f"Station mean positions ({first['method'].iloc[0]})", fontsize=10)
    ax.grid(True, alpha=0.3)
    return fig
