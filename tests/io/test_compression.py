"""Streamed reading (``iter_bytes``) and the input prefetch of :mod:`gnss_cli.io.compression`."""

from __future__ import annotations

import gzip
from pathlib import Path

import pytest

from gnss_cli.io import compression
from gnss_cli.io.compression import iter_bytes, open_bytes, prefetch

SAMPLE_OBS = Path(__file__).resolve().parents[2] / "sample_rinex" / "static" / "obs.rnx"


@pytest.fixture()
def gz_copy(tmp_path: Path) -> tuple[Path, bytes]:
    text = SAMPLE_OBS.read_bytes()
    path = tmp_path / "obs.rnx.gz"
    path.write_bytes(gzip.compress(text))
    return path, text


def test_gzip_is_streamed_in_blocks(gz_copy: tuple[Path, bytes]) -> None:
    path, text = gz_copy
    blocks = list(iter_bytes(path, block_bytes=4096))
    assert len(blocks) > 10 and max(len(b) for b in blocks) <= 4096
    assert b"".join(blocks) == text


def test_a_prefetched_file_is_taken_once_then_streamed(gz_copy: tuple[Path, bytes]) -> None:
    path, text = gz_copy
    prefetch(path)
    key = compression._file_key(path)
    assert key in compression._PENDING
    assert b"".join(iter_bytes(path, block_bytes=4096)) == text
    assert key not in compression._PENDING  # the text is let go, not held for the rest of the run
    assert b"".join(iter_bytes(path, block_bytes=4096)) == text  # a second reading streams
    assert open_bytes(path) == text


def test_files_above_the_limit_are_not_prefetched(gz_copy: tuple[Path, bytes], monkeypatch: pytest.MonkeyPatch) -> None:
    path, _ = gz_copy
    monkeypatch.setattr(compression, "PREFETCH_MAX_BYTES", path.stat().st_size - 1)
    prefetch(path)
    assert compression._file_key(path) not in compression._PENDING
