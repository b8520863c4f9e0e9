"""The CSV writer: fixed float formats per column, empty cells for missing values, header always."""

from __future__ import annotations

import numpy as np
import pandas as pd

from gnss_cli.report import to_csv_text


def test_floats_have_the_column_format_and_missing_values_are_empty() -> None:
    df = pd.DataFrame({
        "time": ["2020-06-25T00:00:00", "2020-06-25T00:00:30", "2020-06-25T00:01:00"],
        "tow_s": [345600.0, 345630.00049, 345660.0],  # 3 decimals
        "x_m": [3512345.123456, np.nan, -1e-9],  # 4 decimals; the sign of a value that rounds to zero stays
        "lat_deg": [55.123456789012, np.inf, -np.inf],  # 9 decimals; not finite -> empty
        "gdop": [1.23456, 2.0, np.nan],  # DOPs 3 decimals
        "n_sat": [9, 10, 11],
        "status": pd.Series(["ok", 'say "hi", twice', None], dtype="str"),
    })
    assert to_csv_text(df) == (
        "time,tow_s,x_m,lat_deg,gdop,n_sat,status\n"
        "2020-06-25T00:00:00,345600.000,3512345.1235,55.123456789,1.235,9,ok\n"
        '2020-06-25T00:00:30,345630.000,,,2.000,10,"say ""hi"", twice"\n'
        "2020-06-25T00:01:00,345660.000,-0.0000,,,11,\n"
    )


def test_empty_table_has_its_header() -> None:
    assert to_csv_text(pd.DataFrame({"time": pd.Series([], dtype=object), "x_m": np.zeros(0)})) == "time,x_m\n"


def test_other_column_types_are_written_by_pandas() -> None:
    df = pd.DataFrame({"t": pd.to_datetime(["2020-01-01", None]), "v": [1.23456, np.nan],
                       "k": pd.array([1, None], dtype="Int64"), "f": pd.array([0.5, None], dtype="Float64")})
    assert to_csv_text(df) == "t,v,k,f\n2020-01-01,1.2346,1,0.5000\n,,,\n"
