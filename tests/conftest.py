from __future__ import annotations

import os
from pathlib import Path

import pytest


@pytest.fixture
def data_dir() -> Path:
    """The shared public stereo data ($AVOIDD_DATA); tests that need it skip without it."""
    value = os.environ.get("AVOIDD_DATA")
    if not value:
        pytest.skip("AVOIDD_DATA is not set; real-data tests need ../shared/data")
    path = Path(value)
    if not path.is_dir():
        pytest.skip(f"AVOIDD_DATA={value} is not a folder")
    return path
