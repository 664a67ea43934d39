"""avoidd's avoidance settings as MAVLink parameters (AVD_*), for QGroundControl and MAVProxy.

Answers ``PARAM_REQUEST_LIST``, ``PARAM_REQUEST_READ`` and ``PARAM_SET`` addressed to avoidd's
component with ``PARAM_VALUE`` (all ``MAV_PARAM_TYPE_REAL32``). A set outside a parameter's
range is refused: the answer is the unchanged value, as ground stations expect. Values set in
flight are kept in a JSON file (``avoidance.params_file``, in the state folder) and read back
at the next start.
"""

from __future__ import annotations

import json
import logging
import math
import os
from dataclasses import dataclass
from pathlib import Path

from avoidd.config import AvoidanceConfig

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class Param:
    """One parameter: its MAVLink name, the config field, and its range."""

    name: str
    field: str
    low: float
    high: float


PARAMS = (
    Param("AVD_ENABLE", "enabled", 0.0, 1.0),
    Param("AVD_RADIUS", "vehicle_radius_m", 0.05, 5.0),
    Param("AVD_MARGIN", "margin_m", 0.0, 10.0),
    Param("AVD_MAX_SPEED", "max_speed_m_s", 0.1, 20.0),
    Param("AVD_MAX_ACCEL", "max_accel_m_s2", 0.1, 10.0),
    Param("AVD_YAW_RATE", "max_yaw_rate_deg_s", 1.0, 360.0),
    Param("AVD_ACCEPT_RAD", "acceptance_radius_m", 0.1, 50.0),
)
BY_NAME = {p.name: p for p in PARAMS}


class ParamTable:
    """The current values (starting from the config, then the saved file).

    Args:
        config: The ``avoidance`` section.
        path: Where values set in flight are kept (None: not kept).
    """

    def __init__(self, config: AvoidanceConfig, path: Path | None) -> None:
        self.config = config
        self.path = path
        if path is not None and path.exists():
            self._load(path)

    def _load(self, path: Path) -> None:
        try:
            saved = json.loads(path.read_text())
        except (OSError, ValueError) as exc:
            logger.warning("avoidance parameters: %s unreadable (%s); using the config", path, exc)
            return
        if not isinstance(saved, dict):
            logger.warning("avoidance parameters: %s is not an object; using the config", path)
            return
        for name, value in saved.items():
            if not self.set(name, value, save=False):
                logger.warning("avoidance parameters: %s=%r in %s ignored", name, value, path)

    def value(self, name: str) -> float:
        """A parameter's current value."""
        return float(getattr(self.config, BY_NAME[name].field))

    def set(self, name: str, value: object, save: bool = True) -> bool:
        """Set a parameter if the name is known and the value in range; True when set."""
        param = BY_NAME.get(name)
        if param is None or not isinstance(value, (int, float)):
            return False
        number = float(value)
        if not math.isfinite(number) or not param.low <= number <= param.high:
            return False
        current = getattr(self.config, param.field)
        new: object = number
        if isinstance(current, bool):
            new = number >= 0.5
        elif isinstance(current, int):
            new = round(number)
        self.config = self.config.model_copy(update={param.field: new})
        if save:
            self._save()
        return True

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
