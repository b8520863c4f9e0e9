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
