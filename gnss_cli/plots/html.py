"""The one-page HTML report: figures embedded as base64 PNG, the summary table, the settings.

The page is self-contained (no external style sheet, script or image) so that it can be
mailed or archived as one file.
"""

from __future__ import annotations

import base64
import html
from collections.abc import Mapping

import numpy as np
import pandas as pd

_STYLE = """
body { font-family: sans-serif; margin: 1.5em auto; max-width: 1100px; color: #222; }
table { border-collapse: collapse; font-size: 0.85em; margin-bottom: 1.5em; }
th, td { border: 1px solid #bbb; padding: 0.2em 0.5em; text-align: right; }
th { background: #eee; }
td.key, th.key { text-align: left; }
figure { margin: 1.5em 0; }
figure img { max-width: 100%; }
figcaption { font-size: 0.9em; color: #444; }
.scroll { overflow-x: auto; }
"""


def _cell(value: object) -> str:
    if isinstance(value, (float, np.floating)):
        return "" if not np.isfinite(value) else f"{value:.4g}"
    return html.escape(str(value))


def table_html(df: pd.DataFrame, css_class: str) -> str:
    """A plain HTML table of ``df`` (numbers to four significant digits, empty when missing)."""
    head = "".join(f"<th>{html.escape(str(c))}</th>" for c in df.columns)
    rows = "".join("<tr>" + "".join(f"<td>{_cell(v)}</td>" for v in row) + "</tr>\n"
                   for row in df.itertuples(index=False))
    return f'<div class="scroll"><table class="{css_class}">\n<tr>{head}</tr>\n{rows}</table></div>'


KEY_COLUMNS = ["method", "epochs", "ok_%", "rms_3d_m", "rms_horizontal_m", "rms_vertical_m", "mean_gdop"]
"""The columns of the report's first summary table (:func:`key_summary`)."""


def key_summary(summary: pd.DataFrame) -> pd.DataFrame:
    """The key columns of a summary table, one row per method: ``method``, ``epochs``, ``ok_%``
    (epochs solved, per cent), the 3D, horizontal (``√(rms_e² + rms_n²)``) and vertical
    (``rms_u``) RMS errors in m (empty without a reference), ``mean_gdop``.

    >>> print(key_summary(pd.DataFrame({"method": ["wls"], "epochs": [4], "epochs_solved": [3], "rms_e_m": [3.0],
    ...       "rms_n_m": [4.0], "rms_u_m": [1.0], "rms_3d_m": [5.1], "mean_gdop": [2.0]})).to_string(index=False))
    method  epochs  ok_%  rms_3d_m  rms_horizontal_m  rms_vertical_m  mean_gdop
       wls       4  75.0       5.1               5.0             1.0        2.0
    """
    def col(name: str) -> pd.Series:
        return summary[name] if name in summary.columns else pd.Series(np.nan, index=summary.index)

    epochs = col("epochs")
    return pd.DataFrame({
        "method": col("method"), "epochs": epochs,
        "ok_%": 100.0 * col("epochs_solved") / epochs.where(epochs > 0),
        "rms_3d_m": col("rms_3d_m"), "rms_horizontal_m": np.hypot(col("rms_e_m"), col("rms_n_m")),
        "rms_vertical_m": col("rms_u_m"), "mean_gdop": col("mean_gdop"),
    })[KEY_COLUMNS]


def html_report(title: str, figures: Mapping[str, tuple[str, bytes]], summary: pd.DataFrame,
                settings: Mapping[str, object], key: pd.DataFrame | None = None) -> str:
    """The report page.

    Parameters
    ----------
    title : str
        Page title and heading.
    figures : mapping name -> (caption, PNG bytes)
        In page order; each becomes an ``<img>`` with a ``data:image/png;base64`` URI.
    summary : DataFrame
        The summary table (one row per method): its key columns (:func:`key_summary`) first,
        every column in a folded ``<details>`` block.
    settings : mapping
        The run's settings (input files, options), shown as a two-column table.
    key : DataFrame, optional
        The table shown first instead of :func:`key_summary` of ``summary`` (gnss-batch: one
        row per station).
    """
    settings_rows = "".join(f'<tr><td class="key">{html.escape(str(k))}</td><td class="key">{html.escape(str(v))}</td></tr>\n'
                            for k, v in settings.items())
    parts = [
        "<!DOCTYPE html>", '<html lang="en">', "<head>", '<meta charset="utf-8">',
        f"<title>{html.escape(title)}</title>", f"<style>{_STYLE}</style>", "</head>", "<body>",
        f"<h1>{html.escape(title)}</h1>",
        "<h2>Settings</h2>", f'<table class="settings">\n<tr><th class="key">setting</th><th class="key">value</th></tr>\n{settings_rows}</table>',
        "<h2>Summary</h2>", table_html(key_summary(summary) if key is None else key, "key-summary"),
        f"<details><summary>All {len(summary.columns)} summary columns (as summary.csv)</summary>",
        table_html(summary, "summary"), "</details>",
        "<h2>Figures</h2>",
    ]
    for name, (caption, png) in figures.items():
        data = base64.b64encode(png).decode("ascii")
        parts.append(f'<figure id="{html.escape(name)}"><img alt="{html.escape(caption)}" '
                     f'src="data:image/png;base64,{data}"><figcaption>{html.escape(caption)}</figcaption></figure>')
    parts += ["</body>", "</html>", ""]
    return "\n".join(parts)
