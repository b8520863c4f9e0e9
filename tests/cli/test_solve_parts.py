"""A long file solved part by part (``[processing] chunk_epochs``): the single-epoch rows are the
bytes of the whole-file run; the multi-epoch methods, solved in overlapping pieces, are within a
millimetre to decimetres of it (their margins, :data:`~gnss_cli.pipeline.run.MARGIN_EPOCHS`).

Every case runs ``gnss-solve`` twice into ``--out-dir`` (with ``--model-out`` for multi-epoch
methods): once with ``chunk_epochs = 0`` (the whole file at once) and once in parts of 50 epochs
(``stream_above_epochs = 50``). The parts really are parts: :class:`~gnss_cli.pipeline.run.Run`
yields several of them for the same configuration.
"""

from __future__ import annotations

import gzip
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from gnss_cli.cli.exits import run_app
from gnss_cli.cli.solve import app
from gnss_cli.config import load_config
from gnss_cli.errors import RinexFormatError
from gnss_cli.io.obs_chunks import iter_obs_chunks
from gnss_cli.io.rinex import read_obs
from gnss_cli.pipeline.run import RESTART, Run
from gnss_cli.report import VELOCITY_COLUMNS
from gnss_cli.sim.scenario import ScenarioConfig, run_scenario, write_scenario

SAMPLE = Path(__file__).resolve().parents[2] / "sample_rinex" / "static"
CHUNK = 50


@pytest.fixture(scope="module")
def flight(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """10 min of a simulated flight at 1 Hz, GPS + Galileo, with Doppler."""
    out = tmp_path_factory.mktemp("flight")
    write_scenario(run_scenario(replace(ScenarioConfig(), trajectory="standard-flight", duration_s=600.0, systems=("G", "E"),
                                        seed=3)), out)
    return out


@pytest.fixture(scope="module")
def gapped(flight: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The flight without the epochs 100-104, 150, 194-202 and 206-214: a missed epoch the
    smoothing bridges (150), three segments, one of them (203-205) too short for a window and
    between gaps too long to bridge (ten seconds)."""
    out = tmp_path_factory.mktemp("gapped")
    text = (flight / "obs.rnx").read_text()
    head, _, body = text.partition("END OF HEADER\n")
    records = [">" + r for r in body.split("\n>")]
    records[0] = records[0][1:]
    drop = set(range(100, 105)) | {150} | set(range(194, 203)) | set(range(206, 215))
    kept = [r for k, r in enumerate(records) if k not in drop]
    (out / "obs.rnx").write_text(head + "END OF HEADER\n" + "\n".join(kept))
    (out / "nav.rnx").write_bytes((flight / "nav.rnx").read_bytes())
    return out


def _solve(args: list[object], out: Path, chunk: int, capsys: pytest.CaptureFixture[str]) -> dict[str, bytes]:
    cfg = out.parent / f"{out.name}.toml"
    cfg.write_text(f"[processing]\nchunk_epochs = {chunk}\nstream_above_epochs = {chunk}\n")
    extra = ["--model-out", out / "models.json"] if {"--lag", "smoother", "kf"} & set(map(str, args)) else []
    with pytest.raises(SystemExit) as exc:
        run_app(app, "gnss-solve", [str(a) for a in [*args, "--out-dir", out, "--config", cfg, "-q", *extra]])
    _, err = capsys.readouterr()
    assert exc.value.code == 0, err
    return {p.name: p.read_bytes() for p in sorted(out.iterdir())}


NUMPY_2 = int(np.__version__.split(".")[0]) >= 2
"""numpy 1.x's vectorized sums depend on the arrays' memory alignment, so its last bits differ
from run to run (seen with numpy 1.25, the lowest version allowed); there the parts are held
to the whole run's numbers within 1e-6 relative, the same cells and words otherwise. A DOP is
held within 1e-6 + 2 eps DOP^2: an inverse's first-order sensitivity to last-bit changes of the
normal matrix, which a near-singular epoch (a simulated flight's HDOP of 9e6) magnifies."""


def _same_numbers(name: str, a: bytes, b: bytes, flipped_rows: float = 0.0) -> None:
    """The same numbers (module note on numpy 1.x) and words; CSV rows that differ may make up at most
    ``flipped_rows`` of the rows (a decision at its threshold that last bits flipped)."""
    import io
    import json

    import pandas as pd

    if name.endswith(".json"):
        def flat(x: object) -> list[object]:
            if isinstance(x, dict):
                return [k for k in x] + [v for y in x.values() for v in flat(y)]
            if isinstance(x, list):
                return [v for y in x for v in flat(y)]
            return [x]
        fa, fb = flat(json.loads(a)), flat(json.loads(b))
        assert len(fa) == len(fb)
        for u, v in zip(fa, fb):
            assert u == v or (isinstance(u, float) and u == pytest.approx(v, rel=1e-6, abs=1e-9)), (name, u, v)
        return
    da, db = (pd.read_csv(io.BytesIO(x)) for x in (a, b))
    assert list(da.columns) == list(db.columns) and da.shape == db.shape, name
    bad = np.zeros(len(da), dtype=bool)
    first: dict[str, str] = {}
    for c in da.columns:
        if da[c].dtype.kind == "f":
            x, y = da[c].to_numpy(), db[c].to_numpy()
            # a DOP (gdop, gdop_paper, ...) carries its epoch's conditioning squared: a TLS GDOP
            # of ~800 keeps ~6 digits
            rtol = 1e-6 + (1e-9 * np.nan_to_num(y) ** 2 if "dop" in c else 0.0)
            with np.errstate(invalid="ignore"):  # (inf - inf)
                close = (x == y) | (np.isnan(x) & np.isnan(y)) | (np.abs(x - y) <= 2e-4 + rtol * np.abs(y))
            if not close.all():
                first.setdefault(c, f"{name}:{c}: {x[~close][:5]} against {y[~close][:5]}")
        else:
            close = (da[c].fillna("") == db[c].fillna("")).to_numpy()
            if not close.all():
                first.setdefault(c, f"{name}:{c}")
        bad |= ~close
    assert bad.mean() <= flipped_rows, f"{bad.sum()} of {bad.size} rows differ; " + "; ".join(first.values())


def _without_command(text: bytes) -> bytes:
    """summary.csv without its first column, the command line (the runs compared differ in their
    output and config paths); every other cell as written."""
    import csv
    import io

    rows = list(csv.reader(io.StringIO(text.decode())))
    assert rows[0][0] == "command"
    buf = io.StringIO()
    csv.writer(buf, lineterminator="\n").writerows(r[1:] for r in rows)
    return buf.getvalue().encode()


def same_outputs(got: dict[str, bytes], expected: dict[str, bytes], what: str, flipped_rows: float = 0.0) -> None:
    """The same output files: byte for byte with numpy 2, the same numbers with numpy 1.x
    (summary.csv without the command line), where ``flipped_rows`` of a CSV's rows may differ."""
    assert sorted(got) == sorted(expected)
    got, expected = dict(got), dict(expected)
    for name in ("summary.csv",):
        if name in expected:
            got[name], expected[name] = _without_command(got[name]), _without_command(expected[name])
    for name in expected:
        if NUMPY_2:
            assert got[name] == expected[name], f"{name} differs: {what}"
        else:
            _same_numbers(name, got[name], expected[name], flipped_rows)


def _same_bytes(args: list[object], tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> dict[str, bytes]:
    whole = _solve(args, tmp_path / "whole", 0, capsys)
    parts = _solve(args, tmp_path / "parts", CHUNK, capsys)
    same_outputs(parts, whole, f"the whole-file run against parts of {CHUNK} epochs")
    return whole


def _run(obs: Path, nav: Path, chunk: int = CHUNK, **overrides: object) -> Run:
    return Run(obs, [nav], replace(load_config(None, overrides), chunk_epochs=chunk, stream_above_epochs=chunk))


def _n_parts(obs: Path, nav: Path, **overrides: object) -> int:
    return sum(p is not RESTART for p in _run(obs, nav, **overrides).parts())


def _positions(out: dict[str, bytes]):  # type: ignore[no-untyped-def]
    import io

    import pandas as pd

    return pd.read_csv(io.BytesIO(out["positions.csv"]))


def _close_to_whole(args: list[object], tmp_path: Path, capsys: pytest.CaptureFixture[str], tol_m: float,
                    chunk: int = CHUNK) -> tuple[object, object]:
    """The multi-epoch rows in parts: the same epochs, statuses and satellites; positions within ``tol_m``."""
    tmp_path.mkdir(exist_ok=True)
    whole = _positions(_solve(args, tmp_path / "whole", 0, capsys))
    parts = _positions(_solve(args, tmp_path / "parts", chunk, capsys))
    assert list(whole.columns) == list(parts.columns) and len(whole) == len(parts)
    assert (whole["status"] == parts["status"]).all() and (whole["method"] == parts["method"]).all()
    np.testing.assert_array_equal(whole["tow_s"], parts["tow_s"])
    xyz = ["x_m", "y_m", "z_m"]
    d = np.linalg.norm(whole[xyz].to_numpy() - parts[xyz].to_numpy(), axis=1)
    assert np.nanmax(d) <= tol_m, (np.nanmax(d), tol_m)
    return whole, parts


@pytest.mark.parametrize("extra", [["--method", "wls"], ["--method", "ls,wls,tls"]], ids=["wls", "ls-wls-tls"])
def test_rtklib_0759_in_parts_is_the_whole_run(rinex_dir: Path, extra: list[str], tmp_path: Path, capsys) -> None:
    d = rinex_dir / "rtklib-0759"
    out = _same_bytes([d / "07590920.05o", d / "07590920.05n", *extra], tmp_path, capsys)
    assert out["positions.csv"].count(b"\n") == 120 * len(extra[1].split(",")) + 1  # 120 epochs per method, the header
    assert _n_parts(d / "07590920.05o", d / "07590920.05n") == 3


def test_sample_in_parts_is_the_whole_run(tmp_path: Path, capsys) -> None:
    _same_bytes([SAMPLE / "obs.rnx", SAMPLE / "nav.rnx", "--method", "wls,stls,dls"], tmp_path, capsys)


def test_simulated_flight_with_doppler_in_parts_is_the_whole_run(flight: Path, tmp_path: Path, capsys) -> None:
    out = _same_bytes([flight / "obs.rnx", flight / "nav.rnx", "--reference-csv", flight / "truth.csv", "--method",
                       "wls,tls"], tmp_path, capsys)
    header = out["positions.csv"].split(b"\n", 1)[0].decode().split(",")
    rows = out["positions.csv"].split(b"\n")[1:3]
    velocity = [rows[0].decode().split(",")[header.index(c)] for c in VELOCITY_COLUMNS]
    assert all(velocity), "the simulated file has Doppler: the velocity columns are filled"
    assert {"errors.csv", "satellites.csv", "summary.csv"} <= set(out)
    assert _n_parts(flight / "obs.rnx", flight / "nav.rnx") == 12
    one = list(_run(flight / "obs.rnx", flight / "nav.rnx", chunk=601).parts())
    assert len(one) == 1 and one[0].epochs.time_gps_s.size == 601  # not above the threshold: whole


def test_multi_epoch_methods_in_parts_are_near_the_whole_run(flight: Path, tmp_path: Path, capsys) -> None:
    """smoother and kf in overlapping pieces with the whole file's variance factors: within 1 mm
    of the whole run (every epoch has 300 epochs of margin or the file's end on either side);
    the identified STLS windows start where the piece starts, so their alignment changes: within
    the noise, and no worse against the truth."""
    args = [flight / "obs.rnx", flight / "nav.rnx", "--method", "wls,smoother,kf"]
    _close_to_whole(args, tmp_path / "fixed", capsys, 1e-3)
    whole, parts = _close_to_whole([flight / "obs.rnx", flight / "nav.rnx", "--method", "stls", "--lag", "3",
                                    "--reference-csv", flight / "truth.csv"], tmp_path / "stls", capsys, 1.0)
    rms = [float(np.sqrt(np.mean(f["err_3d_m"] ** 2))) for f in (whole, parts)]
    assert rms[1] < 1.1 * rms[0], rms
    # 12 parts of 50 read; a piece is handed out once 300 epochs follow it (parts 7 to 11), the
    # rest with the last part
    assert _n_parts(flight / "obs.rnx", flight / "nav.rnx", methods="smoother") == 6


def test_smoother_with_carrier_phase_in_parts(rinex_dir: Path, tmp_path: Path, capsys) -> None:
    """tst2 (986 epochs, 1 Hz, L1 phase) in parts of 300: the pieces carry their phase pairs. The
    phase ties a piece's epochs rigidly, so a piece averages its pseudoranges over itself and
    its margins instead of the whole segment: positions move by up to about half a metre
    (0.59 m measured), the same epochs and statuses, and no worse against the truth."""
    d = rinex_dir / "tst2-2020155-urban-static"
    args = [d / "2020_06_03_TST_03.obs.gz", *sorted(d.glob("hksc155d.20?")), "--method", "smoother",
            "--environment", "open"]  # the parts' phase pairs, not the canyon settings (measured so)
    w, p = _close_to_whole(args, tmp_path, capsys, 1.0, chunk=300)
    assert len(w) == 986 and (w["status"] == "ok").all()
    xyz = ["x_m", "y_m", "z_m"]
    truth = np.array([-2418077.2710, 5386069.6872, 2405174.1252])
    rms = [float(np.sqrt(np.mean(np.sum((f[xyz].to_numpy() - truth) ** 2, axis=1)))) for f in (w, p)]
    assert rms[1] < 1.1 * rms[0], rms


def test_segments_and_short_segments_across_parts(gapped: Path, tmp_path: Path, capsys) -> None:
    args = [gapped / "obs.rnx", gapped / "nav.rnx", "--method", "stls", "--lag", "3"]
    _close_to_whole(args, tmp_path, capsys, 1.0)
    out = {f.name: f.read_bytes() for f in (tmp_path / "parts").iterdir()}  # the run in parts it just made
    assert "fallback_wls" in out["positions.csv"].decode()  # the three epochs between the second and third gap
    assert b"across 1 gap of missed epochs" in out["models.json"]  # epoch 150
    assert b'"segment": 2' in out["models.json"] and b'"method": "stls"' in out["models.json"]


def test_a_system_unusable_all_through_is_dropped_and_the_parts_restart(flight: Path, tmp_path: Path, capsys) -> None:
    galileo = sorted({s for s in read_obs(flight / "obs.rnx")["sv"].values.astype(str) if s.startswith("E")})
    args = [flight / "obs.rnx", flight / "nav.rnx", "--method", "wls,tls", "--exclude", ",".join(galileo)]
    out = _same_bytes(args, tmp_path, capsys)
    assert b"tdop_E" not in out["positions.csv"]  # one clock: the Galileo clock column is gone
    parts = list(_run(flight / "obs.rnx", flight / "nav.rnx", exclude=galileo).parts())
    assert sum(p is RESTART for p in parts) == 1
    after = parts[parts.index(RESTART) + 1:]
    assert all(p.epochs.systems == ("G",) for p in after)
    one = list(_run(flight / "obs.rnx", flight / "nav.rnx", chunk=0, exclude=galileo, methods="wls,smoother").parts())
    assert one.count(RESTART) == 1 and one[-1].epochs.systems == ("G",)  # a file of one part restarts too


def _concat_equal(path: Path, codes: list[str]) -> int:
    whole = read_obs(path, codes=codes)
    parts = list(iter_obs_chunks(path, None, codes, CHUNK))
    t = np.concatenate([p["time"].values for p in parts])
    assert np.array_equal(t, whole["time"].values)
    for code in whole.data_vars:
        joined = np.concatenate([p[code].reindex(sv=whole["sv"].values).values for p in parts])
        assert np.array_equal(joined, whole[code].values, equal_nan=True), code
    return len(parts)


def test_chunks_of_a_file_are_its_epochs(rinex_dir: Path, flight: Path, tmp_path: Path) -> None:
    assert _concat_equal(rinex_dir / "rtklib-0759" / "07590920.05o", ["C1", "P2"]) == 3
    gz = tmp_path / "obs.rnx.gz"
    gz.write_bytes(gzip.compress((flight / "obs.rnx").read_bytes()))
    assert _concat_equal(gz, ["C1C", "D1C"]) == 12  # 601 epochs: the last one joins the 12th part


def test_a_bad_line_in_a_later_part_names_the_file_line(flight: Path, tmp_path: Path) -> None:
    lines = (flight / "obs.rnx").read_text().splitlines(keepends=True)
    k = [i for i, line in enumerate(lines) if line.startswith(">")][437] + 2
    lines[k] = lines[k][:3] + "  12ab5678.901" + lines[k][17:]
    bad = tmp_path / "bad.rnx"
    bad.write_text("".join(lines))
    with pytest.raises(RinexFormatError) as whole:
        read_obs(bad)
    with pytest.raises(RinexFormatError) as parts:
        list(iter_obs_chunks(bad, None, None, CHUNK))
    assert str(parts.value) == str(whole.value) and f"line {k + 1}" in str(whole.value)


def test_a_file_of_one_part_and_stdout_are_the_whole_run(rinex_dir: Path, tmp_path: Path, capsys) -> None:
    d = rinex_dir / "rtklib-0759"
    args = [d / "07590920.05o", d / "07590920.05n", "--method", "ls,wls"]
    same_outputs(_solve(args, tmp_path / "one", 3600, capsys), _solve(args, tmp_path / "whole", 0, capsys),
                 "one part against the whole run")
    printed = {}
    for chunk in (0, CHUNK):
        cfg = tmp_path / f"stdout{chunk}.toml"
        cfg.write_text(f"[processing]\nchunk_epochs = {chunk}\nstream_above_epochs = {chunk}\n")
        with pytest.raises(SystemExit) as exc:
            run_app(app, "gnss-solve", [str(a) for a in [*args, "--config", cfg, "-q"]])
        printed[chunk], _ = capsys.readouterr()
        assert exc.value.code == 0
    assert printed[CHUNK] == printed[0] and printed[0].count("\n") == 241
