"""avoidd's avoidance settings as MAVLink parameters (AVD_*), for QGroundControl and MAVProxy.

Answers ``PARAM_REQUEST_LIST``, ``PARAM_REQUEST_READ`` and ``PARAM_SET`` addressed to avoidd's
component with ``PARAM_VALUE`` (all ``MAV_PARAM_TYPE_REAL32``). A set that is refused is
answered with the unchanged value, as ground stations expect: outside a parameter's range,
or making avoidd less cautious from a message that may not (see :mod:`avoidd.mavlink.trust`).
The safety settings have floors: the radius never goes below the configured airframe's
(``avoidance.vehicle_radius_m``), the margin never below ``avoidance.min_margin_m``. Values
set in flight are kept in a JSON file (``avoidance.params_file``, in the state folder) and
read back at the next start within the same bounds, except that a saved ``AVD_ENABLE`` never
switches avoidance on: only the configuration does.
"""

from __future__ import annotations

import enum
import json
import logging
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

from avoidd.config import AvoidanceConfig
from avoidd.fileread import UnreadableFile, read_bounded

logger = logging.getLogger(__name__)

_MAX_PARAMS_FILE_BYTES = 64_000
"""The saved parameters are a dozen numbers; a larger file is not ours."""


@dataclass(frozen=True)
class Param:
    """One parameter: its MAVLink name, the config field, its range, and which way is safer.

    Attributes:
        name: The MAVLink name.
        field: The ``avoidance`` field it sets.
        low: Smallest value.
        high: Largest value.
        safer: Which way the value makes avoidd more cautious (``lower``, ``higher``), or
            None when neither does.
    """

    name: str
    field: str
    low: float
    high: float
    safer: Literal["lower", "higher"] | None


PARAMS = (
    Param("AVD_ENABLE", "enabled", 0.0, 1.0, "lower"),
    Param("AVD_RADIUS", "vehicle_radius_m", 0.05, 5.0, "higher"),
    Param("AVD_MARGIN", "margin_m", 0.0, 10.0, "higher"),
    Param("AVD_MAX_SPEED", "max_speed_m_s", 0.1, 20.0, "lower"),
    Param("AVD_MAX_ACCEL", "max_accel_m_s2", 0.1, 10.0, "lower"),
    Param("AVD_YAW_RATE", "max_yaw_rate_deg_s", 1.0, 360.0, "lower"),
    Param("AVD_ACCEPT_RAD", "acceptance_radius_m", 0.1, 50.0, None),
)
BY_NAME = {p.name: p for p in PARAMS}


class Outcome(enum.Enum):
    """What became of a parameter set."""

    SET = "set"
    UNKNOWN = "no such parameter"
    RANGE = "out of range"
    WEAKENS = "less cautious, not allowed from this sender"


class ParamTable:
    """The current values (starting from the config, then the saved file).

    Args:
        config: The ``avoidance`` section.
        path: Where values set in flight are kept (None: not kept).
    """

    def __init__(self, config: AvoidanceConfig, path: Path | None) -> None:
        self.base = config
        """The configuration as loaded: its radius is the floor of ``AVD_RADIUS``."""
        self.config = config
        self.path = path
        if path is not None and path.exists():
            self._load(path)

    def _load(self, path: Path) -> None:
        try:
            saved = json.loads(read_bounded(path, _MAX_PARAMS_FILE_BYTES))
        except (OSError, ValueError, UnreadableFile) as exc:
            logger.warning("avoidance parameters: %s unreadable (%s); using the config", path, exc)
            return
        if not isinstance(saved, dict):
            logger.warning("avoidance parameters: %s is not an object; using the config", path)
            return
        for name, value in saved.items():
            if name == "AVD_ENABLE" and value != 0 and not self.base.enabled:
                logger.warning(
                    "avoidance parameters: AVD_ENABLE=%r in %s ignored: a saved value never "
                    "switches avoidance on (set avoidance.enabled: true in the config)",
                    value,
                    path,
                )
                continue
            outcome = self.set(name, value, may_weaken=True, save=False)
            if outcome is not Outcome.SET:
                low, high = self.bounds(name) if name in BY_NAME else (math.nan, math.nan)
                logger.warning(
                    "avoidance parameters: %s=%r in %s ignored (%s; %g..%g)",
                    name,
                    value,
                    path,
                    outcome.value,
                    low,
                    high,
                )

    def value(self, name: str) -> float:
        """A parameter's current value."""
        return float(getattr(self.config, BY_NAME[name].field))

    def bounds(self, name: str) -> tuple[float, float]:
        """The range a parameter may be set to (floors from the configuration included)."""
        param = BY_NAME[name]
        low = param.low
        if name == "AVD_RADIUS":
            low = max(low, self.base.vehicle_radius_m)
        elif name == "AVD_MARGIN":
            low = max(low, self.base.min_margin_m)
        return low, param.high

    def set(self, name: str, value: object, may_weaken: bool, save: bool = True) -> Outcome:
        """Set a parameter if the name is known, the value in range and the change allowed.

        Args:
            name: The parameter.
            value: Its new value.
            may_weaken: The change may make avoidd less cautious.
            save: Write the values to the file when set.
        """
        param = BY_NAME.get(name)
        if param is None:
            return Outcome.UNKNOWN
        if not isinstance(value, (int, float)) or isinstance(value, bool):
            return Outcome.RANGE
        number = float(value)
        low, high = self.bounds(name)
        if not math.isfinite(number) or not low <= number <= high:
            return Outcome.RANGE
        current = getattr(self.config, param.field)
        new: float | int | bool = number
        if isinstance(current, bool):
            new = number >= 0.5
        elif isinstance(current, int):
            new = round(number)
        if not may_weaken and _weakens(param, float(current), float(new)):
            return Outcome.WEAKENS
        self.config = self.config.model_copy(update={param.field: new})
        if save:
            self._save()
        return Outcome.SET

    def _save(self) -> None:
        if self.path is None:
            return
        values = {p.name: self.value(p.name) for p in PARAMS}
        temporary = self.path.with_suffix(".tmp")
        try:
            temporary.write_text(json.dumps(values, indent=2) + "\n")
            os.replace(temporary, self.path)
        except OSError as exc:
            logger.error("avoidance parameters: cannot write %s (%s)", self.path, exc)


def _weakens(param: Param, current: float, new: float) -> bool:
    """Whether going from ``current`` to ``new`` makes avoidd less cautious."""
    if param.safer == "lower":
        return new > current
    if param.safer == "higher":
        return new < current
    return False
