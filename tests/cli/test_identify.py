"""gnss-identify through typer's CliRunner and through the console entry point."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from gnss_cli.cli.identify import app, main
from gnss_cli.report import IDENTIFICATION_COLUMNS as CSV_COLUMNS
from gnss_cli.gnss.frames import ecef2enu, enu2ecef

ORIGIN_ECEF_M = np.array([4.0e6, 1.0e6, 4.8e6])


def write_track(path: Path, n_t: int = 20, methods: tuple[str, ...] = ("ls",), step_s: float = 1.0,
                names: tuple[str, str, str] = ("x_m", "y_m", "z_m")) -> np.ndarray:
    t = np.arange(n_t, dtype=float)
    enu = np.stack([100 * np.cos(0.1 * t), 100 * np.sin(0.1 * t), 5.0 + 0.0 * t], axis=1)
    xyz = enu2ecef(enu, ORIGIN_ECEF_M)
    stamps = (pd.Timestamp("2005-04-02T00:00:30") + pd.to_timedelta(t * step_s, unit="s")).strftime("%Y-%m-%dT%H:%M:%S.%f")
    frames = [pd.DataFrame({"time": stamps, "method": m, names[0]: xyz[:, 0], names[1]: xyz[:, 1], names[2]: xyz[:, 2]}) for m in methods]
    pd.concat(frames).to_csv(path, index=False)
    return xyz


def test_identify_writes_fit_and_prediction(tmp_path: Path) -> None:
    src = tmp_path / "track.csv"
    xyz = write_track(src, 20)
    model_path = tmp_path / "model.json"
    result = CliRunner().invoke(app, [str(src), "--lag", "3", "--structure", "shared", "--train", "10",
                                      "--model-out", str(model_path)])
    assert result.exit_code == 0, result.output
    lines = result.stdout.splitlines()
    assert lines[0] == ",".join(CSV_COLUMNS)
    table = pd.read_csv(pd.io.common.StringIO(result.stdout))
    assert list(table["kind"]) == ["fit"] * 10 + ["predicted"] * 10
    # exact circular track: the fit and the prediction reproduce it (CSV has 0.1 mm resolution)
    np.testing.assert_allclose(table[["x_m", "y_m", "z_m"]].to_numpy(), xyz, atol=2e-3)
    enu = ecef2enu(xyz, xyz[0])  # the ENU origin is the first sample
    np.testing.assert_allclose(table[["e_m", "n_m", "u_m"]].to_numpy(), enu, atol=2e-3)
    model = json.loads(model_path.read_text())
    assert model["lag"] == 3 and model["order"] == 9 and model["structure"] == "shared"
    assert len(model["poles"]) == 9 and model["status"] in ("converged", "exact", "no_further_decrease")
    assert np.allclose(model["enu_origin_ecef_m"], xyz[0])


def test_accepts_plain_xyz_columns_and_wtls(tmp_path: Path) -> None:
    src = tmp_path / "plain.csv"
    write_track(src, 15, names=("x", "y", "z"))
    result = CliRunner().invoke(app, [str(src), "--lag", "3", "--structure", "shared", "--method", "wtls"])
    assert result.exit_code == 0, result.output
    assert result.stdout.count("\n") == 16


def test_several_methods_need_a_choice(tmp_path: Path) -> None:
    src = tmp_path / "multi.csv"
    write_track(src, 12, methods=("ls", "tls"))
    bad = CliRunner().invoke(app, [str(src), "--lag", "2"])
    assert bad.exit_code != 0
    good = CliRunner().invoke(app, [str(src), "--lag", "2", "--source-method", "tls"])
    assert good.exit_code == 0, good.output


def _run_main(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str]:
    with pytest.raises(SystemExit) as info:
        main(argv)
    return int(info.value.code or 0), capsys.readouterr().err


def test_main_too_few_samples(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    src = tmp_path / "short.csv"
    write_track(src, 4)
    code, err = _run_main([str(src), "--lag", "3"], capsys)
    assert code == 4 and err.startswith("gnss-identify: error: too few samples for lag 3")


def test_main_non_uniform_steps(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    src = tmp_path / "gap.csv"
    write_track(src, 12)
    frame = pd.read_csv(src).drop(index=5)
    frame.to_csv(src, index=False)
    code, err = _run_main([str(src), "--lag", "2"], capsys)
    assert code == 4 and "non-uniform time steps" in err


def test_main_nan_positions(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    src = tmp_path / "nan.csv"
    write_track(src, 12)
    frame = pd.read_csv(src)
    frame.loc[3, "y_m"] = np.nan
    frame.to_csv(src, index=False)
    code, err = _run_main([str(src), "--lag", "2"], capsys)
    assert code == 4 and "NaN" in err


def test_main_missing_columns_and_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    src = tmp_path / "cols.csv"
    pd.DataFrame({"time": [0.0, 1.0], "lat_deg": [1.0, 2.0]}).to_csv(src, index=False)
    code, err = _run_main([str(src)], capsys)
    assert code == 4 and "x_m,y_m,z_m" in err
    code, err = _run_main([str(tmp_path / "absent.csv")], capsys)
    assert code == 4 and "no such file" in err


def test_main_bad_option_value_is_a_configuration_error(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    src = tmp_path / "track.csv"
    write_track(src, 12)
    code, err = _run_main([str(src), "--method", "svd"], capsys)
    assert code == 3 and "--method" in err
