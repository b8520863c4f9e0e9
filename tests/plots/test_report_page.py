"""The report page of a gnss-solve run: the key columns first, checked against summary.csv;
every column folded below them; the command line at the top."""

from __future__ import annotations

import re
import shlex
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

pytest.importorskip("matplotlib")

from gnss_cli.cli.exits import run_app  # noqa: E402
from gnss_cli.cli.solve import app  # noqa: E402

SAMPLE = Path(__file__).resolve().parents[2] / "sample_rinex" / "static"


class _Tables(HTMLParser):
    """Every table's rows of cells, and whether the table sits inside ``<details>``."""

    def __init__(self) -> None:
        super().__init__()
        self.tables: list[tuple[str, bool, list[list[str]]]] = []
        self._details = 0
        self._cell: list[str] | None = None

    def handle_starttag(self, tag, attrs):  # type: ignore[no-untyped-def]
        if tag == "details":
            self._details += 1
        elif tag == "table":
            self.tables.append((dict(attrs).get("class", ""), self._details > 0, []))
        elif tag == "tr":
            self.tables[-1][2].append([])
        elif tag in ("td", "th"):
            self._cell = []

    def handle_endtag(self, tag):  # type: ignore[no-untyped-def]
        if tag == "details":
            self._details -= 1
        elif tag in ("td", "th") and self._cell is not None:
            self.tables[-1][2][-1].append("".join(self._cell).strip())
            self._cell = None

    def handle_data(self, data):  # type: ignore[no-untyped-def]
        if self._cell is not None:
            self._cell.append(data)


def test_report_key_columns_agree_with_summary_csv(tmp_path, capsys) -> None:  # type: ignore[no-untyped-def]
    page_path, out = tmp_path / "run.html", tmp_path / "out"
    args = [SAMPLE / "obs.rnx", SAMPLE / "nav.rnx", "--method", "ls,wls,tls", "--reference-csv", SAMPLE / "truth.csv",
            "--report", page_path, "--out-dir", out]
    with pytest.raises(SystemExit) as exc:
        run_app(app, "gnss-solve", [str(a) for a in args])
    assert exc.value.code == 0, capsys.readouterr().err
    parser = _Tables()
    parser.feed(page_path.read_text())
    by_class = {cls: (folded, rows) for cls, folded, rows in parser.tables}
    settings = dict(by_class["settings"][1][1:])
    assert list(settings)[0] == "command"
    assert shlex.split(settings["command"]) == ["gnss-solve", *map(str, args)]
    folded, key_rows = by_class["key-summary"]
    assert not folded and key_rows[0] == ["method", "epochs", "ok_%", "rms_3d_m", "rms_horizontal_m", "rms_vertical_m",
                                          "mean_gdop"]
    assert by_class["summary"][0]  # every column, folded
    summary = pd.read_csv(out / "summary.csv").set_index("method")
    assert [r[0] for r in key_rows[1:]] == list(summary.index)
    for method, epochs, *cells in key_rows[1:]:
        ok, rms3, rmsh, rmsv, gdop = (float(c) if c else np.nan for c in cells)  # empty: missing
        row = summary.loc[method]
        assert int(epochs) == row["epochs"]
        assert ok == pytest.approx(100.0 * row["epochs_solved"] / row["epochs"], rel=1e-3)
        assert rms3 == pytest.approx(row["rms_3d_m"], rel=1e-3, nan_ok=True)
        assert rmsh == pytest.approx(np.hypot(row["rms_e_m"], row["rms_n_m"]), rel=1e-3, nan_ok=True)
        assert rmsv == pytest.approx(row["rms_u_m"], rel=1e-3, nan_ok=True)
        assert gdop == pytest.approx(row["mean_gdop"], rel=1e-3, nan_ok=True)
    assert np.isfinite(summary.loc["wls", "rms_3d_m"]) and float(key_rows[2][3]) > 0  # a row with numbers
    assert re.search(r"<details><summary>All \d+ summary columns", page_path.read_text())
