"""The column-wise CSV writer writes what pandas writes once the floats are formatted."""

from __future__ import annotations

import numpy as np
import pandas as pd

from gnss_cli.report import _to_csv_pandas, to_csv_text


def _table(rng: np.random.Generator, n: int) -> pd.DataFrame:
    x = rng.normal(0.0, 1e6, n)
    x[rng.random(n) < 0.2] = np.nan
    x[:3] = [np.inf, -np.inf, -1e-9][:n]  # not finite -> empty; a tiny negative keeps its sign: "-0.0000"
    half = np.round(rng.normal(0.0, 50.0, n)) / 2 + 0.00005  # near the rounding boundary of 4 decimals
    names = rng.choice(["ok", "integrity_fail", 'say "hi"', "a,b", "", "line\nbreak"], n)
    text = pd.Series(names, dtype="str")
    text[rng.random(n) < 0.2] = np.nan
    return pd.DataFrame({
        "time": [f"2020-06-25T00:00:{k % 60:02d}" for k in range(n)],
        "x_m": x, "gdop": np.abs(x) / 1e5, "tdop_G": half, "hpl_m": half,
        "n_sat": rng.integers(-5, 40, n), "flag": rng.random(n) < 0.5,
        "status": text, "note": pd.Series(names, dtype=object),
    })


def test_fast_csv_matches_pandas_on_every_column_type() -> None:
    rng = np.random.default_rng(7)
    for n in (0, 3, 257):
        df = _table(rng, n)
        text = to_csv_text(df)
        assert text == _to_csv_pandas(df)
        assert text.count("\n") >= n + 1
    assert "-0.0000" in to_csv_text(_table(rng, 5))  # the sign of a value that rounds to zero stays


def test_other_column_types_go_through_pandas() -> None:
    df = pd.DataFrame({"t": pd.to_datetime(["2020-01-01", None]), "v": [1.23456, np.nan],
                       "k": pd.array([1, None], dtype="Int64")})
    assert to_csv_text(df) == "t,v,k\n2020-01-01,1.2346,1\n,,\n"
