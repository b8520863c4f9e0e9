"""The public Python API: the README example runs and gives the numbers the CLI prints."""

from __future__ import annotations

import io
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from gnss_cli.cli.solve import app
from gnss_cli.report import FLOAT_FORMATS

REPO = Path(__file__).resolve().parents[2]


def _readme_example() -> str:
    text = (REPO / "README.md").read_text()
    section = text.split("**From Python.**", 1)[1].split("\n**", 1)[0]
    blocks = re.findall(r"```python\n(.*?)```", section, flags=re.S)
    assert len(blocks) == 1, "the README's Python example is one block"
    return blocks[0]


@pytest.fixture(scope="module")
def readme_namespace(monkeypatch_module: pytest.MonkeyPatch) -> dict[str, object]:
    monkeypatch_module.chdir(REPO)
    namespace: dict[str, object] = {}
    exec(compile(_readme_example(), "README.md", "exec"), namespace)  # noqa: S102 - the documented example
    return namespace


@pytest.fixture(scope="module")
def monkeypatch_module():  # type: ignore[no-untyped-def]
    mp = pytest.MonkeyPatch()
    yield mp
    mp.undo()


def test_readme_example_matches_the_cli_csv(readme_namespace: dict[str, object]) -> None:
    ds = readme_namespace["ds"]
    d = REPO / "sample_rinex" / "static"
    res = CliRunner().invoke(app, [str(d / "obs.rnx"), str(d / "nav.rnx"), "--method", "ls,wls", "-q"])
    assert res.exit_code == 0, res.output
    csv = pd.read_csv(io.StringIO(res.stdout), dtype=str, keep_default_na=False)
    assert list(ds["method"].values) == ["ls", "wls"]
    assert ds["time"].attrs["time_scale"] == "GPS" and ds["time"].dtype == np.dtype("datetime64[ns]")
    for method, rows in csv.groupby("method", sort=False):
        sel = ds.sel({"method": method})
        assert list(np.datetime_as_string(sel["time"].values, unit="ms")) == list(rows["time"])
        for col in ("x_m", "y_m", "z_m", "lat_deg", "lon_deg", "height_m", "clock_m", "gdop", "pdop", "hdop", "vdop", "tdop"):
            fmt = FLOAT_FORMATS.get(col, "{:.3f}")
            api = [fmt.format(v) if np.isfinite(v) else "" for v in sel[col].values]
            assert api == list(rows[col]), (method, col)
            assert sel[col].attrs["units"]
        assert [str(v) for v in sel["n_sat"].values] == list(rows["n_sat"])
        assert list(sel["status"].values) == list(rows["status"])
    table = readme_namespace["table"]
    assert len(table) == len(csv)


def test_reference_gives_error_variables() -> None:
    import gnss_cli

    d = REPO / "sample_rinex" / "static"
    ds = gnss_cli.solve(d / "obs.rnx", [d / "nav.rnx"], methods="wls", reference=d / "truth.csv")
    assert {"e_err_m", "n_err_m", "u_err_m", "err_3d_m"} <= set(ds.data_vars)
    assert float(ds["err_3d_m"].max()) < 50.0


def test_unknown_option_is_a_config_error() -> None:
    import gnss_cli
    from gnss_cli.errors import ConfigError

    d = REPO / "sample_rinex" / "static"
    with pytest.raises(ConfigError, match="elevation_mask"):
        gnss_cli.solve(d / "obs.rnx", d / "nav.rnx", elevation_mask=5)


def test_import_gnss_cli_is_cheap() -> None:
    code = ("import sys, gnss_cli; heavy = {'numpy', 'scipy', 'xarray', 'pandas'} & set(sys.modules); "
            "assert not heavy, heavy; assert callable(gnss_cli.solve); assert 'xarray' in sys.modules")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO,
                       env={"PYTHONPATH": str(REPO), "PATH": ""})
    assert r.returncode == 0, r.stderr
