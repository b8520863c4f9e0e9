"""gnss-solve --method kf, --kf-model, --kf-output and the velocity columns."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from gnss_cli.cli.exits import run_app
from gnss_cli.cli.solve import app
from gnss_cli.report import VELOCITY_COLUMNS

SAMPLE = Path(__file__).resolve().parents[2] / "sample_rinex" / "static"


def invoke(args, capsys):  # type: ignore[no-untyped-def]
    with pytest.raises(SystemExit) as exc:
        run_app(app, "gnss-solve", [str(a) for a in args])
    out, err = capsys.readouterr()
    return exc.value.code, out, err


def _csv(out: str) -> pd.DataFrame:
    return pd.read_csv(io.StringIO(out))


def test_kf_rows_with_velocity_on_a_static_sample(capsys):
    code, out, err = invoke([SAMPLE / "obs.rnx", SAMPLE / "nav.rnx", "--method", "wls,kf", "--reference-csv",
                             SAMPLE / "truth.csv"], capsys)
    assert code == 0, err
    df = _csv(out)
    assert list(df.columns[-5:]) == VELOCITY_COLUMNS
    kf, wls = df[df["method"] == "kf"], df[df["method"] == "wls"]
    assert len(kf) == len(wls) and (kf["status"] == "ok").all()
    speed = np.hypot(np.hypot(kf["vx_m_s"], kf["vy_m_s"]), kf["vz_m_s"])
    assert speed.max() < 0.2  # a static receiver (the filter's velocity)
    assert np.sqrt((kf["err_3d_m"] ** 2).mean()) < np.sqrt((wls["err_3d_m"] ** 2).mean())
    assert "kf: " in err and "epochs solved" in err


def test_kf_model_and_output_flags(capsys):
    base = [SAMPLE / "obs.rnx", SAMPLE / "nav.rnx", "--method", "kf", "-q"]
    rows = {}
    for flags in ([], ["--kf-output", "filtered"], ["--kf-model", "ca"]):
        code, out, err = invoke(base + flags, capsys)
        assert code == 0, err
        rows[" ".join(flags)] = _csv(out)[["x_m", "y_m", "z_m"]].to_numpy()
    assert not np.allclose(rows[""], rows["--kf-output filtered"], atol=1e-3, rtol=0)
    assert not np.allclose(rows[""], rows["--kf-model ca"], atol=1e-6, rtol=0)  # (30 s steps: ca and cv differ by ~0.1 mm)


def test_kf_flags_need_the_kf_method(capsys):
    code, _, err = invoke([SAMPLE / "obs.rnx", SAMPLE / "nav.rnx", "--kf-output", "filtered"], capsys)
    assert code == 2 and "--kf-output: only with --method kf" in err


def test_all_is_the_single_epoch_family(capsys):
    code, out, err = invoke([SAMPLE / "obs.rnx", SAMPLE / "nav.rnx", "--method", "all", "-q"], capsys)
    assert code == 0, err
    assert list(dict.fromkeys(_csv(out)["method"])) == ["ls", "wls", "tls", "dls", "mtls", "stls", "wtls"]


def test_bad_kalman_settings_are_configuration_errors(tmp_path, capsys):
    cfg = tmp_path / "kf.toml"
    cfg.write_text('[kalman]\nmodel = "imm"\n')
    code, _, err = invoke([SAMPLE / "obs.rnx", SAMPLE / "nav.rnx", "--method", "kf", "--config", cfg], capsys)
    assert code == 3 and "kalman.model: expected one of cv, ca; received 'imm'" in err
    cfg.write_text("[kalman]\naccel_psd_m2_s3 = -1\n")
    code, _, err = invoke([SAMPLE / "obs.rnx", SAMPLE / "nav.rnx", "--method", "kf", "--config", cfg], capsys)
    assert code == 3 and "kalman.accel_psd_m2_s3: expected > 0" in err
