from __future__ import annotations

import os
from pathlib import Path

import pytest


def _shared_folder(variable: str, what: str, needs: str) -> Path:
    """The folder an environment variable names: unset skips, set but missing fails.

    A checkout whose CI sets the variable to a wrong path must not go green by skipping
    every test that needs the folder.
    """
    value = os.environ.get(variable)
    if not value:
        pytest.skip(f"{variable} is not set; {what} tests need {needs}")
    path = Path(value)
    if not path.is_dir():
        pytest.fail(
            f"{variable}={value} is set but {path.resolve()} is not a folder; fix the path "
            f"(relative to {Path.cwd()}) or unset it to skip the {what} tests",
            pytrace=False,
        )
    return path


@pytest.fixture
def data_dir() -> Path:
    """The shared public stereo data ($AVOIDD_DATA)."""
    return _shared_folder("AVOIDD_DATA", "real-data", "../shared/data")


@pytest.fixture
def sitl_dir() -> Path:
    """The prebuilt ArduCopter SITL ($AVOIDD_SITL_DIR)."""
    path = _shared_folder("AVOIDD_SITL_DIR", "ArduPilot SITL", "../shared/sitl/ardupilot")
    if not os.access(path / "arducopter", os.X_OK):
        pytest.fail(f"AVOIDD_SITL_DIR={path}: no executable 'arducopter' in it", pytrace=False)
    return path


@pytest.fixture
def px4_sitl_dir() -> Path:
    """The prebuilt PX4 SITL ($AVOIDD_PX4_SITL_DIR)."""
    path = _shared_folder("AVOIDD_PX4_SITL_DIR", "PX4 SITL", "../shared/sitl/px4")
    if not os.access(path / "bin" / "px4", os.X_OK):
        pytest.fail(f"AVOIDD_PX4_SITL_DIR={path}: no executable 'bin/px4' in it", pytrace=False)
    return path
