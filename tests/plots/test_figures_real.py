"""Figures of real runs (skipped without ../shared/rinex): all seven methods on rtklib-0759,
where TLS, DLS and MTLS err by tens of metres against ~2 m for the others, and the lag-3
smoothing of the Yamatogawa walk against its RTK trajectory."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("matplotlib")

from matplotlib.image import imread  # noqa: E402
from matplotlib.patches import Ellipse  # noqa: E402

from gnss_cli.config import load_config  # noqa: E402
from gnss_cli.io.reference import parse_reference  # noqa: E402
from gnss_cli.pipeline import process  # noqa: E402
from gnss_cli.plots.common import png_bytes  # noqa: E402
from gnss_cli.plots.run import run_figures  # noqa: E402

REF_0759 = "-3976219.1879,3382371.6041,3652511.1428"
ALL = ["ls", "wls", "tls", "dls", "mtls", "stls", "wtls"]


def _labels(ax) -> list[str]:
    return [line.get_label() for line in ax.get_lines() if not line.get_label().startswith("_")]


@pytest.fixture(scope="module")
def figures_0759(rinex_dir):
    d = rinex_dir / "rtklib-0759"
    cfg = load_config(None, {"methods": "all"})
    result = process(d / "07590920.05o", [d / "07590920.05n"], cfg)
    return run_figures(result, parse_reference(REF_0759), cfg.elevation_mask_deg)


def test_0759_wide_methods_get_their_own_scale(figures_0759):
    enu = figures_0759["enu_errors"].axes
    assert len(enu) == 6  # a linear column for the ~2 m methods, a symlog column for all seven
    assert _labels(enu[0]) == ["ls", "wls", "stls", "wtls"] and enu[0].get_yscale() == "linear"
    assert sorted(_labels(enu[1])) == sorted(ALL) and enu[1].get_yscale() == "symlog"
    near, every = figures_0759["horizontal_scatter"].axes
    assert len([p for p in near.patches if isinstance(p, Ellipse)]) == 4
    assert len([p for p in every.patches if isinstance(p, Ellipse)]) == 7
    assert figures_0759["error_statistics"].axes[1].get_yscale() == "log"
    assert figures_0759["gdop"].axes[0].get_yscale() == "log" and sorted(_labels(figures_0759["gdop"].axes[0])) == sorted(ALL)
    track = figures_0759["track"].axes[0]
    assert _labels(track) == ["ls", "wls", "stls", "wtls", "reference"]
    assert any("not drawn: tls, dls, mtls" in t.get_text() for t in track.texts)


def test_0759_pngs_readable(figures_0759):
    for fig in figures_0759.values():
        pixels = imread(io.BytesIO(png_bytes(fig)), format="png")
        assert float(pixels[..., :3].var()) > 0.0


def _rtklib_pos(path: Path, t_gps_s):
    rows = [line.split() for line in path.read_text().splitlines() if line.strip() and not line.startswith("%")]
    t = np.array([int(r[0]) * 604800.0 + float(r[1]) for r in rows])
    x = np.array([[float(v) for v in r[2:5]] for r in rows])
    k = np.clip(np.searchsorted(t, t_gps_s), 0, t.size - 1)
    return np.where((np.abs(t[k] - t_gps_s) < 0.5)[:, None], x[k], np.nan)


def test_yamatogawa_lag3_track_follows_the_reference(rinex_dir):
    d = rinex_dir / "yamatogawa-2010006-kinematic"
    if not d.is_dir():
        pytest.skip("yamatogawa-2010006-kinematic missing")
    cfg = load_config(None, {"methods": "stls", "stls.lag": 3})
    result = process(d / "yamatogawa_rover.obs", [d / "brdc0060.10n"], cfg)
    ref = _rtklib_pos(d / "rtk_ref_rover.pos", result.epochs.time_gps_s)
    figs = run_figures(result, ref, cfg.elevation_mask_deg)
    track = figs["track"].axes[0]
    assert _labels(track) == ["stls", "reference"]
    reference_line = track.get_lines()[-1]
    assert reference_line.get_xydata().shape[0] == result.epochs.time_gps_s.size
    # a walk of ~40 m by ~30 m: the axes hold it, with equal scales
    (x0, x1), (y0, y1) = track.get_xlim(), track.get_ylim()
    assert 30 < x1 - x0 < 80 and x1 - x0 == pytest.approx(y1 - y0)
    assert "multi-epoch" in figs["gdop"].axes[0].get_title()
    sky = figs["sky"].axes[0]
    assert sky.collections[0].get_label() == "used by stls" and len(sky.collections[0].get_offsets()) > 1000


def test_many_satellites_residuals_coloured_by_system(rinex_dir, monkeypatch):
    d = rinex_dir / "kms3-2022159-rinex4"
    if not d.is_dir():
        pytest.skip("kms3-2022159-rinex4 missing")
    import gnss_cli.plots.satellites as satellites

    monkeypatch.setattr(satellites, "MAX_SATELLITE_LEGEND", 20)  # kms3 has 30 satellites, five systems
    MAX_SATELLITE_LEGEND, figure_residuals = 20, satellites.figure_residuals

    cfg = load_config(None, {"methods": "wls"})
    result = process(d / "KMS300DNK_R_20221591000_01H_30S_MO.crx", [d / "KMS300DNK_R_20221591000_01H_MN.rnx.gz"], cfg)
    (ax,) = figure_residuals(result).axes
    used = np.isfinite(result.solutions["wls"].residuals_m).any(axis=0)
    assert used.sum() > MAX_SATELLITE_LEGEND
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    systems = sorted({str(sv)[0] for sv in result.epochs.sv[used]})
    assert len(labels) == len(systems) and all("satellites)" in label for label in labels)
    assert sum(int(label.split("(")[1].split()[0]) for label in labels) == used.sum()
