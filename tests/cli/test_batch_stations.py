"""gnss-batch keeps station names as strings: a station named 0759 stays 0759 in the dataset's
folders and its ``station`` column (read back with pandas and Dask), in files.csv and summary.csv."""

from __future__ import annotations

import shutil
from pathlib import Path

import pandas as pd
import pytest

from gnss_cli.cli.batch import app
from gnss_cli.cli.exits import run_app

SAMPLE = Path(__file__).resolve().parents[2] / "sample_rinex" / "static"


@pytest.fixture(scope="module")
def numeric_station(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The simulated sample under RINEX 2 short names of two stations whose names are digits."""
    root = tmp_path_factory.mktemp("stations")
    for name in ("07590610.24o", "00420610.24o"):  # 2024-03-01 is day 061
        shutil.copy(SAMPLE / "obs.rnx", root / name)
    out = root / "out"
    with pytest.raises(SystemExit) as exc:
        run_app(app, "gnss-batch", [str(root / "07590610.24o"), str(root / "00420610.24o"), "--nav", str(SAMPLE / "nav.rnx"),
                                    "--out", str(out), "--jobs", "1", "--method", "wls", "-q"])
    assert exc.value.code == 0
    return out


def test_station_folders_and_column_keep_leading_zeros(numeric_station: Path) -> None:
    out = numeric_station
    assert sorted(p.name for p in (out / "positions").iterdir()) == ["0042", "0759"]
    df = pd.read_parquet(out / "positions")
    assert sorted(set(df["station"])) == ["0042", "0759"]
    assert all(isinstance(v, str) for v in df["station"])
    one = pd.read_parquet(out / "positions", filters=[("station", "==", "0759")])
    assert len(one) == 121 and set(one["station"]) == {"0759"}
    assert set(df["day"].astype(str)) == {"2024-03-01"}


def test_dask_reads_the_station_names(numeric_station: Path) -> None:
    dd = pytest.importorskip("dask.dataframe")
    ddf = dd.read_parquet(numeric_station / "positions")
    means = ddf.groupby("station")["x_m"].mean().compute()
    assert sorted(means.index) == ["0042", "0759"] and means.notna().all()


def test_csv_tables_write_the_names_as_given(numeric_station: Path) -> None:
    for name in ("files.csv", "summary.csv"):
        text = (numeric_station / name).read_text()
        assert ",0759," in text and ",0042," in text, name
        table = pd.read_csv(numeric_station / name, dtype={"station": str})  # as docs/outputs.md says
        assert list(table["station"]) == ["0759", "0042"], name


def test_network_table_pools_the_files_of_a_station() -> None:
    from gnss_cli.cli.batch_output import network_table

    summary = pd.DataFrame({
        "station": ["0759", "0759", "0042"], "method": ["wls"] * 3, "epochs": [10, 30, 5], "epochs_solved": [10, 20, 5],
        "epochs_with_reference": [10, 20, 0], "rms_3d_m": [1.0, 2.0, float("nan")], "rms_e_m": [0.6, 1.2, float("nan")],
        "rms_n_m": [0.8, 1.6, float("nan")], "rms_u_m": [0.5, 1.0, float("nan")], "mean_gdop": [2.0, 3.0, 1.5],
        "mean_lat_deg": [55.0, 55.0, 56.0], "mean_lon_deg": [8.0, 8.0, 9.0], "mean_height_m": [10.0, 13.0, 1.0]})
    table = network_table(summary).set_index("station")
    assert list(table.index) == ["0759", "0042"]
    row = table.loc["0759"]
    assert row["files"] == 2 and row["epochs"] == 40 and row["ok_%"] == pytest.approx(75.0)
    assert row["rms_3d_m"] == pytest.approx(((10 * 1.0 + 20 * 4.0) / 30) ** 0.5)
    assert row["rms_horizontal_m"] == pytest.approx(((10 * 1.0 + 20 * 4.0) / 30) ** 0.5)  # e, n: 3-4-5 of 1 and 2
    assert row["rms_vertical_m"] == pytest.approx(((10 * 0.25 + 20 * 1.0) / 30) ** 0.5)
    assert row["mean_gdop"] == pytest.approx((10 * 2.0 + 20 * 3.0) / 30)
    assert row["mean_height_m"] == pytest.approx((10 * 10.0 + 20 * 13.0) / 30)
    assert pd.isna(table.loc["0042", "rms_3d_m"]) and table.loc["0042", "mean_gdop"] == 1.5


def test_batch_report_is_one_page_with_a_row_per_station(numeric_station: Path, tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    pytest.importorskip("matplotlib")
    root = numeric_station.parent
    page, figs = tmp_path / "network.html", tmp_path / "figs"
    with pytest.raises(SystemExit) as exc:
        run_app(app, "gnss-batch", [str(root / "07590610.24o"), str(root / "00420610.24o"), "--nav", str(SAMPLE / "nav.rnx"),
                                    "--out", str(tmp_path / "out"), "--jobs", "1", "--method", "wls",
                                    "--reference", "geodetic:55.5,8.5,50", "--plots", str(figs), "--report", str(page)])
    err = capsys.readouterr().err
    assert exc.value.code == 0, err
    assert sorted(p.name for p in figs.iterdir()) == ["station_map.png", "stations.png"]
    assert f"gnss-batch: wrote {page} (HTML report, 2 figures)" in err
    text = page.read_text()
    key = text[text.index('<table class="key-summary">'):text.index("</table>", text.index('<table class="key-summary">'))]
    rows = [r for r in key.split("<tr>")[2:]]
    assert len(rows) == 2 and rows[0].startswith("<td>0759</td><td>wls</td>") and rows[1].startswith("<td>0042</td><td>wls</td>")
    summary = pd.read_csv(tmp_path / "out" / "summary.csv", dtype={"station": str}).set_index("station")
    rms = float(rows[0].split("</td><td>")[5])
    assert rms == pytest.approx(summary.loc["0759", "rms_3d_m"], rel=1e-3)
    assert "<details>" in text and text.index("gnss-batch ") < text.index("<h2>Summary</h2>")
