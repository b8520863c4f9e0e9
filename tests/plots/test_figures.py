"""The figures of a run, checked by content (labels, titles, one line per method, ellipses)
and as PNG files (readable, not blank), and the HTML report (parses, embeds every figure)."""

from __future__ import annotations

import io
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("matplotlib")

from matplotlib.image import imread  # noqa: E402
from matplotlib.patches import Ellipse  # noqa: E402

from gnss_cli.config import load_config  # noqa: E402
from gnss_cli.io.reference import reference_from_csv  # noqa: E402
from gnss_cli.pipeline import process  # noqa: E402
from gnss_cli.plots import RUN_FIGURES  # noqa: E402
from gnss_cli.plots.common import png_bytes  # noqa: E402
from gnss_cli.plots.errors import CHI2_2D_95, method_offsets  # noqa: E402
from gnss_cli.plots.html import html_report  # noqa: E402
from gnss_cli.plots.run import run_figures  # noqa: E402
from gnss_cli.report import summary_table  # noqa: E402

SAMPLE = Path(__file__).resolve().parents[2] / "sample_rinex" / "static"


@pytest.fixture(scope="module")
def static_run():
    cfg = load_config(None, {"methods": "ls,wls"})
    result = process(SAMPLE / "obs.rnx", [SAMPLE / "nav.rnx"], cfg)
    ref = reference_from_csv(SAMPLE / "truth.csv", result.epochs.time_gps_s)
    return result, ref, cfg


@pytest.fixture(scope="module")
def figures(static_run):
    result, ref, cfg = static_run
    return run_figures(result, ref, cfg.elevation_mask_deg)


def _labels(ax) -> list[str]:
    return [line.get_label() for line in ax.get_lines() if not line.get_label().startswith("_")]


def suptitle(fig) -> str:
    """The figure's title (``Figure.get_suptitle`` is newer than matplotlib 3.7)."""
    return " ".join(t.get_text() for t in fig.texts)


def assert_png_not_blank(data: bytes) -> None:
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    pixels = imread(io.BytesIO(data), format="png")
    assert pixels.ndim == 3 and pixels.shape[0] > 200 and pixels.shape[1] > 200
    assert float(pixels[..., :3].var()) > 0.0


def test_every_figure_is_made_in_order(figures):
    assert list(figures) == list(RUN_FIGURES)


def test_enu_errors_one_line_per_method_with_units(figures):
    axes = figures["enu_errors"].axes
    assert len(axes) == 3  # ls and wls are within 10x: one linear column
    assert [ax.get_ylabel() for ax in axes] == ["East error (m)", "North error (m)", "Up error (m)"]
    for ax in axes:
        assert _labels(ax) == ["ls", "wls"]
    assert axes[-1].get_xlabel().startswith("time since 2024-03-01 00:00:00 GPST (")
    assert suptitle(figures["enu_errors"]) == "ENU errors against the reference"


def test_scatter_has_a_95_percent_ellipse_per_method(static_run, figures):
    result, ref, _ = static_run
    (ax,) = figures["horizontal_scatter"].axes
    ellipses = [p for p in ax.patches if isinstance(p, Ellipse)]
    assert [e.get_label().split(":")[0] for e in ellipses] == ["ls", "wls"]
    assert ax.get_xlabel() == "East error (m)" and ax.get_ylabel() == "North error (m)"
    assert ax.get_aspect() == 1.0
    # the ellipse's area is that of the 95 % region of the errors' covariance
    en = method_offsets(result, ref).enu_m["wls"][:, :2]
    cov = np.cov(en[np.isfinite(en).all(axis=1)].T, ddof=0)
    area = np.pi * ellipses[1].width * ellipses[1].height / 4
    assert area == pytest.approx(np.pi * CHI2_2D_95 * np.sqrt(np.linalg.det(cov)), rel=1e-9)


def test_statistics_gdop_satellites_residuals_content(static_run, figures):
    result, _, _ = static_run
    mean_ax, var_ax = figures["error_statistics"].axes
    assert mean_ax.get_ylabel() == "mean error (m)" and var_ax.get_ylabel().startswith("error variance (m²")
    assert len(mean_ax.patches) == 2 * 3 and [t.get_text() for t in mean_ax.get_xticklabels()] == ["ls", "wls"]
    (gdop,) = figures["gdop"].axes
    assert _labels(gdop) == ["ls", "wls"] and gdop.get_ylabel().startswith("GDOP (unitless")
    (sats,) = figures["satellites"].axes
    assert _labels(sats) == ["observed, usable ephemeris", "ls", "wls"] and sats.get_ylabel() == "satellites"
    (res,) = figures["residuals"].axes
    used = [str(sv) for j, sv in enumerate(result.epochs.sv) if np.isfinite(result.solutions["wls"].residuals_m[:, j]).any()]
    assert _labels(res) == used and res.get_ylabel() == "post-fit residual (m)"


def test_track_and_sky(figures):
    (track,) = figures["track"].axes
    assert _labels(track) == ["ls", "wls", "reference"]
    assert track.get_xlabel() == "East (m)" and track.get_ylabel() == "North (m)" and track.get_aspect() == 1.0
    (sky,) = figures["sky"].axes
    assert sky.name == "polar"
    used, excluded = sky.collections[:2]
    assert used.get_label() == "used by wls" and len(used.get_offsets()) > 0
    assert excluded.get_label().startswith("observed, not used")
    r = np.asarray(used.get_offsets())[:, 1]
    assert r.min() >= 0 and r.max() <= 90 - 10  # used satellites are above the 10 deg mask


def test_without_reference_deviations_are_labelled(static_run):
    result, _, _ = static_run
    figs = run_figures(result, None)
    assert figs["enu_errors"].axes[0].get_ylabel() == "East deviation from mean (m)"
    assert "no reference" in suptitle(figs["enu_errors"])
    assert _labels(figs["track"].axes[0]) == ["ls", "wls"]


def test_pngs_are_valid_and_not_blank(figures):
    for fig in figures.values():
        assert_png_not_blank(png_bytes(fig))


class _Page(HTMLParser):
    def __init__(self) -> None:
        super().__init__()
        self.images: list[str] = []
        self.tables: list[list[str]] = []
        self._in_table = False

    def handle_starttag(self, tag, attrs):
        if tag == "img":
            self.images.append(dict(attrs)["src"])
        if tag == "table":
            self.tables.append([])
            self._in_table = True

    def handle_endtag(self, tag):
        if tag == "table":
            self._in_table = False

    def handle_data(self, data):
        if self._in_table and data.strip():
            self.tables[-1].append(data.strip())


def test_html_report_embeds_figures_and_summary(static_run, figures):
    result, ref, _ = static_run
    summary = summary_table(result, ref)
    pngs = {name: (RUN_FIGURES[name], png_bytes(fig)) for name, fig in list(figures.items())[:2]}
    page = html_report("run <1>", pngs, summary, {"methods": "ls, wls"})
    parser = _Page()
    parser.feed(page)
    assert len(parser.images) == 2 and all(src.startswith("data:image/png;base64,") for src in parser.images)
    settings, key, table = parser.tables
    assert settings == ["setting", "value", "methods", "ls, wls"]
    assert key[:7] == ["method", "epochs", "ok_%", "rms_3d_m", "rms_horizontal_m", "rms_vertical_m", "mean_gdop"]
    assert table[: len(summary.columns)] == list(summary.columns) and "wls" in table
    assert "<title>run &lt;1&gt;</title>" in page


def test_every_method_has_a_colour_of_its_own():
    """Every method a run can plot, the multi-epoch ones included, is told apart by its colour
    (smoother and kf had none and were both grey in the Stanford diagram)."""
    from gnss_cli.constants import METHOD_KEYS, MULTI_EPOCH_METHOD_KEYS
    from gnss_cli.plots.common import method_style

    keys = METHOD_KEYS + MULTI_EPOCH_METHOD_KEYS
    assert len({str(method_style(m)["color"]) for m in keys}) == len(keys)
