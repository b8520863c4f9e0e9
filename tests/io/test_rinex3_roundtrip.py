"""Property test: observations written as RINEX 3 text by an independent little writer
(Python string formatting, one value at a time) are read back exactly."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gnss_cli.io.rinex3_obs import read_obs3

CODES = {
    "G": ["C1C", "L1C", "D1C", "S1C", "C2W", "L2W", "C5Q", "L5Q", "S5Q", "C1W", "L1W", "D5Q", "S2W", "C2L"],
    "E": ["C1C", "L1C", "C5Q", "L5Q"],
    "R": ["C1C", "C2P"],
}  # G has 14 types: the header needs a continuation line


def _header(version: str) -> str:
    lines = [f"{version:>9}           OBSERVATION DATA    M                   RINEX VERSION / TYPE"]
    for sys_char, codes in CODES.items():
        for i in range(0, len(codes), 13):
            chunk = " ".join(codes[i : i + 13])
            lead = f"{sys_char}  {len(codes):>3}" if i == 0 else " " * 6
            lines.append(f"{lead} {chunk:<53}SYS / # / OBS TYPES")
    lines.append(f"{'':60}END OF HEADER")
    return "\n".join(lines) + "\n"


def _write(
    path: Path,
    version: str,
    seconds: np.ndarray,
    present: np.ndarray,
    values: dict[str, np.ndarray],
    svs: list[str],
) -> None:
    out = [_header(version)]
    for t, sec in enumerate(seconds):
        visible = [j for j in range(len(svs)) if present[t, j]]
        minute, s = divmod(float(sec), 60.0)
        out.append(f"> 2021 03 04 05 {int(minute):02d}{s:11.7f}  0{len(visible):3d}\n")
        for j in visible:
            sv = svs[j]
            fields = []
            for code in CODES[sv[0]]:
                v = values[code][t, j]
                fields.append(" " * 16 if np.isnan(v) else f"{v:14.3f} 7")
            out.append((sv + "".join(fields)).rstrip() + "\n")
    path.write_text("".join(out))


@settings(max_examples=25, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    n_epochs=st.integers(1, 12),
    p_missing=st.sampled_from([0.0, 0.3, 0.9]),
    version=st.sampled_from(["3.05", "4.00"]),
)
def test_written_values_read_back_exactly(
    tmp_path_factory: pytest.TempPathFactory, seed: int, n_epochs: int, p_missing: float, version: str
) -> None:
    rng = np.random.default_rng(seed)
    svs = ["E05", "E11", "G01", "G07", "G32", "R02"]
    present = rng.random((n_epochs, len(svs))) < 0.8
    present[:, 2] = True  # G01 in every epoch, so every epoch is kept
    seconds = np.sort(rng.choice(np.arange(0, 3600, 0.5), size=n_epochs, replace=False))
    values: dict[str, np.ndarray] = {}
    for code in {c for codes in CODES.values() for c in codes}:
        milli = rng.integers(-99_999_999_999, 999_999_999_999, size=(n_epochs, len(svs)))
        v = milli / 1000.0
        v[rng.random(v.shape) < p_missing] = np.nan
        v[~present] = np.nan
        values[code] = v
    path = tmp_path_factory.mktemp("rt") / "rt.rnx"
    _write(path, version, seconds, present, values, svs)

    obs = read_obs3(path)
    seen = present.any(axis=0)
    assert list(obs.sv.values) == [s for s, k in zip(svs, seen) if k]
    expected_t = np.datetime64("2021-03-04T05:00:00", "ns") + (seconds * 1e9).astype("timedelta64[ns]")
    np.testing.assert_array_equal(obs.time.values, expected_t)
    cols = np.flatnonzero(seen)
    for code in obs.data_vars:
        expected = np.full((n_epochs, cols.size), np.nan)
        for k, j in enumerate(cols):
            if code in CODES[svs[j][0]]:
                text = [f"{x:14.3f}" for x in values[str(code)][:, j]]
                expected[:, k] = [float(x) if x.strip() != "nan" else np.nan for x in text]
        np.testing.assert_array_equal(obs[code].values, expected, err_msg=str(code))
    assert obs.attrs["obs_types"]["G"] == CODES["G"]
