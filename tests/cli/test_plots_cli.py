"""``--plots DIR`` and ``--report FILE.html`` of gnss-solve and ``--plots`` of gnss-identify:
the files, the one-line refusal without matplotlib, and no partial output on interruption."""

from __future__ import annotations

import sys
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("matplotlib")

from matplotlib.image import imread  # noqa: E402

from gnss_cli.cli.exits import run_app  # noqa: E402
from gnss_cli.cli.identify import app as identify_app  # noqa: E402
from gnss_cli.cli.solve import app  # noqa: E402
from gnss_cli.plots import IDENTIFY_FIGURES, RUN_FIGURES  # noqa: E402

SAMPLE = Path(__file__).resolve().parents[2] / "sample_rinex" / "static"
REF_0759 = "-3976219.1879,3382371.6041,3652511.1428"


def invoke(args, capsys, application=app, prog="gnss-solve"):
    with pytest.raises(SystemExit) as exc:
        run_app(application, prog, [str(a) for a in args])
    out, err = capsys.readouterr()
    return exc.value.code, out, err


def sample_args(tmp_path: Path) -> list[object]:
    return [SAMPLE / "obs.rnx", SAMPLE / "nav.rnx", "--method", "ls,wls", "--reference-csv", SAMPLE / "truth.csv",
            "-o", tmp_path / "positions.csv", "-q"]


def assert_png(path: Path) -> None:
    pixels = imread(path)
    assert pixels.shape[0] > 200 and float(pixels[..., :3].var()) > 0.0


class _Images(HTMLParser):
    def __init__(self) -> None:
        super().__init__()
        self.images: list[str] = []
        self.tables = 0

    def handle_starttag(self, tag, attrs):
        self.images += [dict(attrs)["src"]] if tag == "img" else []
        self.tables += tag == "table"


def test_plots_and_report_written_with_the_csv(tmp_path, capsys):
    code, out, err = invoke([*sample_args(tmp_path), "--plots", tmp_path / "fig", "--report", tmp_path / "run.html"], capsys)
    assert code == 0, err
    assert sorted(p.name for p in (tmp_path / "fig").iterdir()) == sorted(f"{n}.png" for n in RUN_FIGURES)
    for p in (tmp_path / "fig").iterdir():
        assert_png(p)
    page = (tmp_path / "run.html").read_text(encoding="utf-8")
    parser = _Images()
    parser.feed(page)
    assert len(parser.images) == len(RUN_FIGURES) and parser.tables == 3  # settings, key columns, all (folded)
    assert all(src.startswith("data:image/png;base64,") for src in parser.images)
    assert "obs.rnx" in page and "truth.csv" in page and "rms_3d_m" in page
    assert (tmp_path / "positions.csv").is_file()


def test_without_matplotlib_one_line_and_nothing_written(tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "matplotlib", None)  # import matplotlib -> ImportError
    for option, target in (("--plots", tmp_path / "fig"), ("--report", tmp_path / "r.html")):
        code, out, err = invoke([*sample_args(tmp_path), option, target], capsys)
        assert code == 3
        assert err.count("\n") == 1 and option in err and "pip install 'gnss-solve[plot]' (from a clone: pip install -e '.[plot]')" in err
        assert list(tmp_path.iterdir()) == []


def test_interrupted_while_drawing_leaves_no_file(tmp_path, capsys, monkeypatch):
    import gnss_cli.plots.run

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(gnss_cli.plots.run, "run_figures", interrupted)
    code, _, err = invoke([*sample_args(tmp_path), "--plots", tmp_path / "fig", "--report", tmp_path / "r.html"], capsys)
    assert code == 130
    assert list(tmp_path.iterdir()) == []


def test_plots_folder_that_is_a_file(tmp_path, capsys):
    (tmp_path / "fig").write_text("x")
    code, _, err = invoke([*sample_args(tmp_path), "--plots", tmp_path / "fig"], capsys)
    assert code == 6 and "not a folder" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["fig"]


def test_identify_plots_the_fit_and_prediction(tmp_path, capsys):
    code, out, err = invoke([*sample_args(tmp_path)[:-1], "--method", "wls", "-q"], capsys)
    assert code == 0, err
    code, out, err = invoke([tmp_path / "positions.csv", "--lag", "1", "--train", "20", "--predict", "10",
                             "-o", tmp_path / "ident.csv", "--plots", tmp_path / "fig"], capsys, identify_app, "gnss-identify")
    assert code == 0, err
    assert sorted(p.name for p in (tmp_path / "fig").iterdir()) == [f"{n}.png" for n in IDENTIFY_FIGURES]
    assert_png(tmp_path / "fig" / "identification.png")


def test_identification_figure_content(tmp_path):
    from gnss_cli.io.trajectory import read_trajectory
    from gnss_cli.pipeline.identification import identify_trajectory
    from gnss_cli.plots.track import figure_identification

    t = np.arange(30.0)
    enu = np.column_stack([2.0 * t, 5.0 * np.sin(t / 5), 0.1 * t])
    from gnss_cli.gnss.frames import enu2ecef

    xyz = enu2ecef(enu, np.array([-3976219.0, 3382371.0, 3652511.0]))
    csv = tmp_path / "t.csv"
    csv.write_text("time,x_m,y_m,z_m\n" + "".join(f"{ti},{x},{y},{z}\n" for ti, (x, y, z) in zip(t, xyz)))
    traj = read_trajectory(csv, None)
    ident = identify_trajectory(traj, 2, None, "stls", "full", 20, 10)
    fig = figure_identification(ident, traj.t_s, traj.xyz_m)
    *series, track = fig.axes
    assert [ax.get_ylabel() for ax in series] == ["East (m)", "North (m)", "Up (m)"]
    for ax in series:
        assert [line.get_label() for line in ax.get_lines()][:3] == ["data", "identified (stls)", "predicted"]
    assert track.get_xlabel() == "East (m)" and track.get_aspect() == 1.0
    assert series[-1].get_xlabel() == "time since the first sample (s)"
