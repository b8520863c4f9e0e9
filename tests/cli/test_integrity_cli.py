"""--integrity, --exclude, --snr-mask, satellites.csv, and the simulator's random outliers."""

from __future__ import annotations

import pandas as pd
import pytest

from gnss_cli.cli.exits import run_app
from gnss_cli.cli.simulate import app as simulate_app
from gnss_cli.cli.solve import app
from gnss_cli.report import SATELLITE_COLUMNS


def invoke(application, name, args, capsys):
    with pytest.raises(SystemExit) as exc:
        run_app(application, name, [str(a) for a in args])
    out, err = capsys.readouterr()
    return exc.value.code, out, err


@pytest.fixture(scope="module")
def sim_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("sim")
    with pytest.raises(SystemExit) as exc:
        run_app(simulate_app, "gnss-simulate", ["--out-dir", str(d), "--duration", "120", "--systems", "G,E", "--seed", "4",
                                                 "--errors", "noise,outliers", "--outlier-rate", "0.2", "--outlier-m", "50,500",
                                                 "--quiet"])
    assert exc.value.code == 0
    return d


def test_simulate_writes_the_random_faults(sim_dir):
    faults = pd.read_csv(sim_dir / "faults.csv")
    assert list(faults.columns) == ["time", "satellite", "bias_m"]
    assert 10 <= len(faults) <= 45 and faults["bias_m"].between(50, 500).all()
    assert faults["time"].is_unique


def test_satellites_csv_explains_every_unused_satellite(sim_dir, capsys):
    out = sim_dir / "out"
    sv = "G01"
    code, _, err = invoke(app, "gnss-solve", [sim_dir / "obs.rnx", sim_dir / "nav.rnx", "--out-dir", out, "--exclude", "G1",
                                             "--snr-mask", "38", "-q"], capsys)
    assert code == 0, err
    sats = pd.read_csv(out / "satellites.csv", keep_default_na=False)
    assert list(sats.columns) == SATELLITE_COLUMNS
    assert set(sats["method"]) == {"wls"}
    assert (sats.loc[sats["satellite"] == sv, "reason"] == "excluded_by_user").all()
    low = sats[sats["reason"] == "snr_mask"]
    assert len(low) and (low["snr_dbhz"].astype(float) < 38.05).all()  # printed with one decimal
    used = sats[sats["used"] == 1]
    assert (used["reason"] == "").all() and (used["snr_dbhz"].astype(float) >= 38).all()
    assert set(sats["reason"]) <= {"", "excluded_by_user", "snr_mask", "excluded_fde", "below_mask"}
    faults = pd.read_csv(sim_dir / "faults.csv")
    fde = sats[sats["reason"] == "excluded_fde"]
    found = set(zip(fde["time"], fde["satellite"]))
    masked = set(zip(sats.loc[sats["reason"] != "", "time"], sats.loc[sats["reason"] != "", "satellite"])) - found
    usable = [(t, s) for t, s in zip(faults["time"], faults["satellite"]) if (t, s) not in masked]  # not excluded before
    assert len(usable) >= 10 and sum(f in found for f in usable) >= 0.9 * len(usable)
    pos = pd.read_csv(out / "positions.csv", keep_default_na=False)
    assert list(pos.columns[-10:-5]) == ["n_excluded", "excluded", "test_stat", "hpl_m", "vpl_m"]
    assert pos["n_excluded"].sum() == len(fde)


def test_unknown_integrity_mode_is_a_configuration_error(sim_dir, capsys):
    code, _, err = invoke(app, "gnss-solve", [sim_dir / "obs.rnx", sim_dir / "nav.rnx", "--integrity", "maybe"], capsys)
    assert code == 3 and "integrity: expected one of fde, check, off" in err


def test_robust_weights_in_satellites_csv(sim_dir, capsys):
    """--robust cauchy --integrity off: the faults stay used but get tiny weights (reason
    ``downweighted``); without --robust every used satellite has weight 1."""
    plain, robust = sim_dir / "plain", sim_dir / "robust"
    for out, extra in ((plain, []), (robust, ["--robust", "cauchy"])):
        code, _, err = invoke(app, "gnss-solve", [sim_dir / "obs.rnx", sim_dir / "nav.rnx", "--out-dir", out,
                                                 "--integrity", "off", "-q", *extra], capsys)
        assert code == 0, err
    sats = {k: pd.read_csv(d / "satellites.csv", keep_default_na=False) for k, d in (("plain", plain), ("robust", robust))}
    used = sats["plain"][sats["plain"]["used"] == 1]
    assert (used["weight"].astype(float) == 1.0).all() and (sats["plain"]["reason"] != "downweighted").all()
    r = sats["robust"]
    low = r[r["reason"] == "downweighted"]
    assert (low["used"] == 1).all() and (low["weight"].astype(float) < 0.1).all()
    assert (r.loc[r["used"] == 0, "weight"] == "").all()
    faults = set(zip(*pd.read_csv(sim_dir / "faults.csv")[["time", "satellite"]].to_numpy().T))
    flagged = set(zip(low["time"], low["satellite"]))
    assert len(flagged) >= 10 and len(flagged & faults) >= 0.9 * len(flagged)  # the down-weighted are the faults
    assert len(flagged & faults) >= 0.9 * len(faults & set(zip(r.loc[r["used"] == 1, "time"], r.loc[r["used"] == 1, "satellite"])))


def test_unknown_robust_estimator_is_a_configuration_error(sim_dir, capsys):
    code, _, err = invoke(app, "gnss-solve", [sim_dir / "obs.rnx", sim_dir / "nav.rnx", "--robust", "tukey"], capsys)
    assert code == 3 and "robust: expected one of off, huber, cauchy" in err
