"""A long file solved part by part (``[processing] chunk_epochs``) writes the bytes of the whole-file run.

Every case runs ``gnss-solve`` twice into ``--out-dir`` (with ``--model-out`` when smoothing):
once with ``chunk_epochs = 0`` (the whole file at once) and once in parts of 50 epochs
(``stream_above_epochs = 50``), and
compares every output file byte for byte. The parts really are parts: :class:`ChunkedRun`
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
from gnss_cli.pipeline.stream import RESTART, ChunkedRun, streamable
from gnss_cli.report import VELOCITY_COLUMNS
from gnss_cli.sim.scenario import ScenarioConfig, run_scenario, write_scenario

SAMPLE = Path(__file__).resolve().parents[2] / "sample_rinex" / "static"
CHUNK = 50


@pytest.fixture(scope="module")
def flight(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """10 min of a simulated flight at 1 Hz, GPS + Galileo, with Doppler."""
    out = tmp_path_factory.mktemp("flight")
    write_scenario(run_scenario(replace(ScenarioConfig(), trajectory="flight", duration_s=600.0, systems=("G", "E"),
                                        seed=3)), out)
    return out


@pytest.fixture(scope="module")
def gapped(flight: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The flight without the epochs 100-104, 200-202 and 206-208: three segments of the
    smoothing, one of them (203-205) too short for a window."""
    out = tmp_path_factory.mktemp("gapped")
    text = (flight / "obs.rnx").read_text()
    head, _, body = text.partition("END OF HEADER\n")
    records = [">" + r for r in body.split("\n>")]
    records[0] = records[0][1:]
    drop = set(range(100, 105)) | {200, 201, 202, 206, 207, 208}
    kept = [r for k, r in enumerate(records) if k not in drop]
    (out / "obs.rnx").write_text(head + "END OF HEADER\n" + "\n".join(kept))
    (out / "nav.rnx").write_bytes((flight / "nav.rnx").read_bytes())
    return out


def _solve(args: list[object], out: Path, chunk: int, capsys: pytest.CaptureFixture[str]) -> dict[str, bytes]:
    cfg = out.parent / f"{out.name}.toml"
    cfg.write_text(f"[processing]\nchunk_epochs = {chunk}\nstream_above_epochs = {chunk}\n")
    extra = ["--model-out", out / "models.json"] if "--lag" in args else []
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


def _same_numbers(name: str, a: bytes, b: bytes) -> None:
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
    for c in da.columns:
        if da[c].dtype.kind == "f":
            x, y = da[c].to_numpy(), db[c].to_numpy()
            rtol = 1e-6 + (2 * np.finfo(float).eps * np.nan_to_num(y) ** 2 if c.endswith("dop") else 0.0)
            with np.errstate(invalid="ignore"):  # (inf - inf)
                close = (x == y) | (np.isnan(x) & np.isnan(y)) | (np.abs(x - y) <= 2e-4 + rtol * np.abs(y))
            assert close.all(), f"{name}:{c}: {x[~close][:5]} against {y[~close][:5]}"
        else:
            assert (da[c].fillna("") == db[c].fillna("")).all(), f"{name}:{c}"


def same_outputs(got: dict[str, bytes], expected: dict[str, bytes], what: str) -> None:
    """The same output files: byte for byte with numpy 2, the same numbers with numpy 1.x."""
    assert sorted(got) == sorted(expected)
    for name in expected:
        if NUMPY_2:
            assert got[name] == expected[name], f"{name} differs: {what}"
        else:
            _same_numbers(name, got[name], expected[name])


def _same_bytes(args: list[object], tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> dict[str, bytes]:
    whole = _solve(args, tmp_path / "whole", 0, capsys)
    parts = _solve(args, tmp_path / "parts", CHUNK, capsys)
    same_outputs(parts, whole, f"the whole-file run against parts of {CHUNK} epochs")
    return whole


def _n_parts(obs: Path, nav: Path, **overrides: object) -> int:
    cfg = load_config(None, overrides)
    assert streamable(cfg)
    return sum(p is not RESTART for p in ChunkedRun(obs, [nav], cfg, CHUNK).parts())


@pytest.mark.parametrize("extra", [["--method", "wls"], ["--method", "stls", "--lag", "3"]], ids=["wls", "stls-lag3"])
def test_rtklib_0759_in_parts_is_the_whole_run(rinex_dir: Path, extra: list[str], tmp_path: Path, capsys) -> None:
    d = rinex_dir / "rtklib-0759"
    out = _same_bytes([d / "07590920.05o", d / "07590920.05n", *extra], tmp_path, capsys)
    assert out["positions.csv"].count(b"\n") == 121  # 120 epochs and the header
    assert _n_parts(d / "07590920.05o", d / "07590920.05n") == 3


def test_sample_in_parts_is_the_whole_run(tmp_path: Path, capsys) -> None:
    _same_bytes([SAMPLE / "obs.rnx", SAMPLE / "nav.rnx", "--method", "wls,stls", "--lag", "3"], tmp_path, capsys)


@pytest.mark.parametrize("extra", [["--method", "wls,tls"], ["--method", "ls,wls,stls", "--lag", "3", "--model", "identify"],
                                   ["--method", "stls", "--lag", "3", "--model", "pva"]], ids=["wls-tls", "stls-lag3", "pva"])
def test_simulated_flight_with_doppler_in_parts_is_the_whole_run(flight: Path, extra: list[str], tmp_path: Path,
                                                                 capsys) -> None:
    out = _same_bytes([flight / "obs.rnx", flight / "nav.rnx", "--reference-csv", flight / "truth.csv", *extra],
                      tmp_path, capsys)
    header = out["positions.csv"].split(b"\n", 1)[0].decode().split(",")
    rows = out["positions.csv"].split(b"\n")[1:3]
    velocity = [rows[0].decode().split(",")[header.index(c)] for c in VELOCITY_COLUMNS]
    assert all(velocity), "the simulated file has Doppler: the velocity columns are filled"
    assert {"errors.csv", "satellites.csv", "summary.csv"} <= set(out)
    assert _n_parts(flight / "obs.rnx", flight / "nav.rnx") == 12
    one = list(ChunkedRun(flight / "obs.rnx", [flight / "nav.rnx"], load_config(), CHUNK, whole_epochs=601).parts())
    assert len(one) == 1 and one[0].epochs.time_gps_s.size == 601  # not above the threshold: whole


def test_doppler_model_in_parts_is_the_whole_run_within_a_millimetre(flight: Path, tmp_path: Path, capsys) -> None:
    """The default --lag 3 on a file with Doppler (model doppler) goes in overlapping pieces with
    the whole file's variance factors: the same epochs, statuses and satellites, positions
    within 1 mm (measured on a 2 h flight in parts of 1200: 0.7 mm at most)."""
    import pandas as pd

    args = [flight / "obs.rnx", flight / "nav.rnx", "--method", "wls,stls", "--lag", "3"]
    whole = _solve(args, tmp_path / "whole", 0, capsys)
    parts = _solve(args, tmp_path / "parts", CHUNK, capsys)
    assert b'"model": "smoother"' in whole["models.json"] and b'"model": "smoother"' in parts["models.json"]
    w, p = (pd.read_csv(__import__("io").BytesIO(o["positions.csv"])) for o in (whole, parts))
    assert list(w.columns) == list(p.columns) and len(w) == len(p) == 2 * 601
    assert (w["status"] == p["status"]).all() and (w["n_sat"] == p["n_sat"]).all()
    np.testing.assert_array_equal(w["tow_s"], p["tow_s"])
    d = np.linalg.norm(w[["x_m", "y_m", "z_m"]].to_numpy() - p[["x_m", "y_m", "z_m"]].to_numpy(), axis=1)
    assert np.max(d) <= 1e-3
    # 12 parts of 50 read; a piece is handed out once 300 epochs follow it
    assert _n_parts(flight / "obs.rnx", flight / "nav.rnx", **{"methods": "stls", "smoothing.lag": 3}) == 7


def test_doppler_model_with_carrier_phase_in_parts(rinex_dir: Path, tmp_path: Path, capsys) -> None:
    """tst2 (986 epochs, 1 Hz, L1 phase) in parts of 300: the pieces carry their phase pairs. The
    phase ties a piece's epochs rigidly, so a piece averages its pseudoranges over itself and
    its margins instead of the whole segment: positions move by up to about half a metre
    (0.56 m measured), the same epochs and statuses, and no worse against the truth."""
    import pandas as pd

    d = rinex_dir / "tst2-2020155-urban-static"
    args = [d / "2020_06_03_TST_03.obs.gz", *sorted(d.glob("hksc155d.20?")), "--method", "stls", "--lag", "3"]
    whole = _solve(args, tmp_path / "whole", 0, capsys)
    parts = _solve(args, tmp_path / "parts", 300, capsys)
    w, p = (pd.read_csv(__import__("io").BytesIO(o["positions.csv"])) for o in (whole, parts))
    assert len(w) == len(p) == 986 and (w["status"] == p["status"]).all() and (w["status"] == "ok").all()
    xyz = ["x_m", "y_m", "z_m"]
    assert np.max(np.linalg.norm(w[xyz].to_numpy() - p[xyz].to_numpy(), axis=1)) < 1.0
    truth = np.array([-2418077.2710, 5386069.6872, 2405174.1252])
    rms = [float(np.sqrt(np.mean(np.sum((f[xyz].to_numpy() - truth) ** 2, axis=1)))) for f in (w, p)]
    assert rms[1] < 1.1 * rms[0], rms


@pytest.mark.parametrize("model", ["identify", "pva"])
def test_segments_and_short_segments_across_parts(gapped: Path, model: str, tmp_path: Path, capsys) -> None:
    out = _same_bytes([gapped / "obs.rnx", gapped / "nav.rnx", "--method", "stls", "--lag", "3", "--model", model],
                      tmp_path, capsys)
    text = out["positions.csv"].decode()
    assert "fallback_wls" in text  # the three epochs between the second and third gap
    assert b'"segment": 2' in out["models.json"]


def test_a_system_unusable_all_through_is_dropped_and_the_parts_restart(flight: Path, tmp_path: Path, capsys) -> None:
    galileo = sorted({s for s in read_obs(flight / "obs.rnx")["sv"].values.astype(str) if s.startswith("E")})
    args = [flight / "obs.rnx", flight / "nav.rnx", "--method", "wls,stls", "--lag", "3", "--model", "identify",
            "--exclude", ",".join(galileo)]
    out = _same_bytes(args, tmp_path, capsys)
    assert b"tdop_E" not in out["positions.csv"]  # one clock: the Galileo clock column is gone
    cfg = load_config(None, {"exclude": galileo})
    parts = list(ChunkedRun(flight / "obs.rnx", [flight / "nav.rnx"], cfg, CHUNK).parts())
    assert sum(p is RESTART for p in parts) == 1
    after = parts[parts.index(RESTART) + 1:]
    assert all(p.epochs.systems == ("G",) for p in after)


def test_kf_and_whole_segment_windows_need_the_whole_file() -> None:
    assert not streamable(load_config(None, {"methods": "wls,kf"}))
    assert not streamable(load_config(None, {"methods": "stls", "smoothing.lag": 3, "smoothing.window": 0}))
    assert streamable(load_config(None, {"methods": "stls", "smoothing.lag": 3}))
    # the static model's window ladder starts with the whole segment; a fixed length streams
    static = {"methods": "stls", "smoothing.lag": 1, "smoothing.model": "static"}
    assert not streamable(load_config(None, static))
    assert streamable(load_config(None, {**static, "smoothing.window": 15}))


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
    assert _solve(args, tmp_path / "one", 3600, capsys) == _solve(args, tmp_path / "whole", 0, capsys)
    printed = {}
    for chunk in (0, CHUNK):
        cfg = tmp_path / f"stdout{chunk}.toml"
        cfg.write_text(f"[processing]\nchunk_epochs = {chunk}\nstream_above_epochs = {chunk}\n")
        with pytest.raises(SystemExit) as exc:
            run_app(app, "gnss-solve", [str(a) for a in [*args, "--config", cfg, "-q"]])
        printed[chunk], _ = capsys.readouterr()
        assert exc.value.code == 0
    assert printed[CHUNK] == printed[0] and printed[0].count("\n") == 241
