"""gnss-batch on a small simulated network: four stations over two days, one corrupt file,
one file without a navigation file. Each file must come out exactly as gnss-solve makes it,
navigation files must be matched by time, failures must be reported without stopping the
others, and a Dask cluster must give the same positions as the local processes."""

from __future__ import annotations

import io
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow.parquet as pq
import pytest

from gnss_cli.cli.exits import run_app

SIM = [  # (station file name, start, systems, seed): GPS day 2024-03-01 = day of year 061
    ("AAAA00DNK_R_20240610000_01H_30S_MO.rnx", "2024-03-01T00:00:00", "G,E", 1),
    ("BBBB00DNK_R_20240610600_01H_30S_MO.rnx", "2024-03-01T06:00:00", "G", 2),
    ("CCCC00DNK_R_20240620000_01H_30S_MO.rnx", "2024-03-02T00:00:00", "G,E", 3),
    ("DDDD00DNK_R_20240650000_01H_30S_MO.rnx", "2024-03-05T00:00:00", "G,E", 4),  # its nav is not given
]


def _python(module: str, args: list[str], cwd: Path, **kw: object) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "PYTHONWARNINGS": "ignore"}
    return subprocess.run([sys.executable, "-m", module, *map(str, args)], cwd=cwd, capture_output=True, text=True,
                          timeout=600, env=env, **kw)  # type: ignore[call-overload]


@pytest.fixture(scope="module")
def network(tmp_path_factory: pytest.TempPathFactory) -> dict[str, object]:
    """Simulated observation files under station names, their navigation files, a corrupt copy."""
    root = tmp_path_factory.mktemp("network")
    data = root / "data"
    data.mkdir()
    navs = []
    for name, start, systems, seed in SIM:
        sim = root / f"sim{seed}"
        proc = _python("gnss_cli.cli.simulate", ["--out-dir", sim, "--start", start, "--duration", "600", "--interval",
                                                 "30", "--systems", systems, "--seed", seed, "--quiet"], root)
        assert proc.returncode == 0, proc.stderr
        (data / name).write_bytes((sim / "obs.rnx").read_bytes())
        if seed != 4:
            navs.append(data / f"nav{seed}.rnx")
            navs[-1].write_bytes((sim / "nav.rnx").read_bytes())
    truth = pd.read_csv(root / "sim1" / "truth.csv")
    text = (data / SIM[0][0]).read_text().splitlines(keepends=True)
    epoch_lines = [i for i, line in enumerate(text) if line.startswith(">")]
    text[epoch_lines[5]] = "> 2024 03 01 00 02 xx.0000000  0 12\n"  # a bad epoch line in the middle
    corrupt = data / "EEEE00DNK_R_20240610000_01H_30S_MO.rnx"
    corrupt.write_text("".join(text))
    obs = [data / SIM[0][0], data / SIM[1][0], corrupt, data / SIM[2][0], data / SIM[3][0]]
    reference = ",".join(f"{truth[c].iloc[0]:.4f}" for c in ("x_m", "y_m", "z_m"))
    return {"root": root, "obs": obs, "navs": navs, "reference": reference}


def _batch_args(network: dict, out: Path) -> list[object]:
    return [*network["obs"], "--nav", str(Path(network["navs"][0]).parent / "nav*.rnx"), "--out", out,
            "--method", "ls,wls", "--reference", network["reference"]]


@pytest.fixture(scope="module")
def local_run(network: dict) -> tuple[subprocess.CompletedProcess[str], Path]:
    out = Path(network["root"]) / "out-local"
    return _python("gnss_cli.cli.batch", [*_batch_args(network, out), "--jobs", "2"], Path(network["root"])), out


def _files(out: Path) -> pd.DataFrame:
    text = {"nav_paths": "", "error": "", "warnings": "", "environment": ""}
    return pd.read_csv(out / "files.csv", dtype={k: str for k in text}).fillna(text)


def _solve_csv(obs: Path, navs: list[str], reference: str, capsys: pytest.CaptureFixture[str]) -> pd.DataFrame:
    from gnss_cli.cli.solve import app

    with pytest.raises(SystemExit) as exc:
        run_app(app, "gnss-solve", [str(obs), *navs, "--method", "ls,wls", "--reference", reference, "-q"])
    out, err = capsys.readouterr()
    assert exc.value.code == 0, err
    return pd.read_csv(io.StringIO(out))


def test_files_csv_reports_every_input_in_order(local_run, network) -> None:
    proc, out = local_run
    assert proc.returncode == 4, proc.stderr  # the first failure is the corrupt file: bad input
    files = _files(out)
    assert list(files["obs_path"]) == [str(p) for p in network["obs"]]
    assert list(files["status"]) == ["ok", "ok", "failed", "ok", "failed"]
    assert list(files["exit_code"]) == [0, 0, 4, 0, 4]
    assert list(files["station"]) == ["AAAA00DNK", "BBBB00DNK", "EEEE00DNK", "CCCC00DNK", "DDDD00DNK"]
    assert "EEEE00DNK_R_20240610000_01H_30S_MO.rnx" in files.loc[2, "error"]
    assert "no navigation file covers its epochs 2024-03-05 00:00:00 to 2024-03-05 00:10:00" in files.loc[4, "error"]
    ok = files[files["status"] == "ok"]
    assert (ok["epochs"] == 21).all() and (ok["solved"] == 21).all() and (ok["method"] == "ls").all()
    assert (ok["rms_3d_m"] > 0).all() and (ok["rms_3d_m"] < 20).all() and (ok["seconds"] > 0).all()
    # each file judged on its own epochs: open sky, though BBBB's 21 epochs of GPS alone, 5-6 degrees of
    # freedom each, measure 0.51 against 0.28 for its neighbours (docs/integrity.md, "The environment")
    assert ok["environment"].str.match(r"open \(auto: variance factor \d\.\d\d <= 0\.6\)$").all()
    # progress: one line per finished file, then the closing line
    lines = [ln for ln in proc.stderr.splitlines() if ln.startswith("gnss-batch: [")]
    assert len(lines) == 5 and sum("failed (exit 4)" in ln for ln in lines) == 2
    closing = [k for k, ln in enumerate(proc.stderr.splitlines()) if ln.startswith("gnss-batch: 3 of 5 files solved, 2 failed")]
    assert len(closing) == 1  # then the outputs written
    assert [ln.split(" (")[0] for ln in proc.stderr.splitlines()[closing[0] + 1:]] == [
        f"gnss-batch: wrote {out / name}" for name in ("positions", "files.csv", "summary.csv")]
    assert "Traceback" not in proc.stderr


def test_navigation_files_are_matched_by_time(local_run, network) -> None:
    _, out = local_run
    files = _files(out)
    navs = [str(p) for p in network["navs"]]
    # the two day-1 files each get the nav of their own hours, the day-2 file the day-2 nav
    assert list(files["nav_paths"][[0, 1, 3]]) == [navs[0], navs[1], navs[2]]
    assert files.loc[2, "nav_paths"] == navs[0]  # the corrupt copy of AAAA: matched, then failed reading


def test_dataset_positions_equal_gnss_solve(local_run, network, capsys) -> None:
    _, out = local_run
    data = pd.read_parquet(out / "positions")
    files = _files(out)
    assert set(data["station"].astype(str)) == {"AAAA00DNK", "BBBB00DNK", "CCCC00DNK"}
    days = data.groupby(data["station"].astype(str))["day"].agg(lambda d: set(d.astype(str)))
    assert days.to_dict() == {"AAAA00DNK": {"2024-03-01"}, "BBBB00DNK": {"2024-03-01"}, "CCCC00DNK": {"2024-03-02"}}
    for _, row in files[files["status"] == "ok"].iterrows():
        csv = _solve_csv(Path(row["obs_path"]), row["nav_paths"].split(";"), network["reference"], capsys)
        mine = data[data["obs_file"] == Path(row["obs_path"]).name].sort_values(["method", "time"]).reset_index(drop=True)
        csv = csv.sort_values(["method", "time"]).reset_index(drop=True)
        assert len(mine) == len(csv) == 42
        assert list(mine["status"].astype(str)) == list(csv["status"])
        assert list(mine["time"].dt.strftime("%Y-%m-%dT%H:%M:%S.%f").str[:-3]) == list(csv["time"])
        for col in ("x_m", "y_m", "z_m", "clock_m", "err_3d_m"):
            np.testing.assert_allclose(mine[col], csv[col], atol=6e-5, rtol=0, err_msg=col)  # CSV: 4 decimals
        np.testing.assert_allclose(mine["gdop"], csv["gdop"], atol=6e-4, rtol=0)
        summary = pd.read_csv(out / "summary.csv")
        mine_rms = summary[(summary["obs_path"] == row["obs_path"]) & (summary["method"] == "ls")]["rms_3d_m"]
        err = csv[csv["method"] == "ls"]["err_3d_m"]
        assert float(mine_rms.iloc[0]) == pytest.approx(float(np.sqrt(np.mean(err**2))), abs=2e-4)
        assert row["rms_3d_m"] == pytest.approx(float(mine_rms.iloc[0]), abs=1e-4)


def test_every_parquet_file_has_every_column(local_run) -> None:
    """BBBB is GPS only (no tdop_G / tdop_E columns of its own): its files get them as nulls."""
    _, out = local_run
    parts = sorted((out / "positions").rglob("*.parquet"))
    assert len(parts) == 3
    schemas = [pq.read_schema(p) for p in parts]
    assert all(s.equals(schemas[0]) for s in schemas)
    assert {"tdop_G", "tdop_E", "obs_file", "x_m", "err_3d_m"} <= set(schemas[0].names)
    gps_only = pq.read_table(next(p for p in parts if "BBBB" in str(p))).to_pandas()
    assert gps_only["tdop_E"].isna().all() and gps_only["tdop"].notna().all()
    assert not [p for p in out.rglob("*") if p.name.startswith(".")]  # no staging left


def test_dask_scheduler_gives_identical_positions(local_run, network) -> None:
    distributed = pytest.importorskip("distributed")
    _, local_out = local_run
    out = Path(network["root"]) / "out-dask"
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        proc = _python("gnss_cli.cli.batch", [*_batch_args(network, out), "--scheduler", cluster.scheduler_address],
                       Path(network["root"]))
    assert proc.returncode == 4, proc.stderr
    key = ["obs_file", "method", "time"]
    local = pd.read_parquet(local_out / "positions").sort_values(key).reset_index(drop=True)
    remote = pd.read_parquet(out / "positions").sort_values(key).reset_index(drop=True)
    pd.testing.assert_frame_equal(local, remote)
    a, b = (_files(d) for d in (local_out, out))
    pd.testing.assert_frame_equal(a.drop(columns="seconds"), b.drop(columns="seconds"))


def test_a_second_run_replaces_the_dataset(network, tmp_path) -> None:
    """Only the first (good) file, in process: the old dataset with its three stations is replaced whole."""
    out = tmp_path / "out"
    (out / "positions" / "OLD").mkdir(parents=True)
    (out / "positions" / "OLD" / "x.parquet").write_bytes(b"old")
    with pytest.raises(SystemExit) as exc:
        from gnss_cli.cli.batch import app

        run_app(app, "gnss-batch", [str(network["obs"][0]), "--nav", str(network["navs"][0]), "--out", str(out), "-q",
                                    "--jobs", "1"])
    assert exc.value.code == 0
    assert [p.name for p in (out / "positions").iterdir()] == ["AAAA00DNK"]
    assert sorted(p.name for p in out.iterdir()) == ["files.csv", "positions", "summary.csv"]


def test_gnss_batch_offers_every_processing_option_of_gnss_solve() -> None:
    import typer

    from gnss_cli.cli import batch, solve

    def options(app: typer.Typer) -> dict[str, object]:
        return {p.opts[0]: p for p in typer.main.get_command(app).params if p.param_type_name == "option"}

    mine, theirs = options(batch.app), options(solve.app)
    output_only = {"-o", "--out-dir", "--format", "--model-out"}
    # gnss-batch spreads the files over the cores (--jobs); gnss-solve the parts of its one file
    one_file = {"--processes"}
    assert set(theirs) - set(mine) == output_only | one_file
    network = {"--plots", "--report"}  # the same flags; gnss-batch's draw the network
    for flag in set(theirs) - output_only - one_file - network - {"--version"}:
        a, b = mine[flag], theirs[flag]
        assert (a.help, a.show_default, a.default, a.opts) == (b.help, b.show_default, b.default, b.opts), flag
