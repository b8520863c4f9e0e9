"""Fixtures of the behavioral tests."""

from __future__ import annotations

from pathlib import Path

import pytest

from behavior_trajectories import ANCHOR_DIR


@pytest.fixture
def anchor_dir() -> Path:
    if not ANCHOR_DIR.is_dir():
        pytest.skip(f"anchor data folder {ANCHOR_DIR} is missing (it lives outside the repository)")
    return ANCHOR_DIR
