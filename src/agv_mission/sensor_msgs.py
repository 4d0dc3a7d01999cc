"""Sensor messages passed between layers (the ROS message types this project needs)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from agv_mission.geometry import Pose2D


@dataclass
class LaserScan:
    """One planar scan, like ``sensor_msgs/LaserScan``.

    ``ranges[i]`` is the range of the beam at ``angle_min + i * angle_increment`` in the
    robot frame; ``inf`` means no valid return (beyond ``range_max``, closer than
    ``range_min``, or dropped).
    """

    ranges: np.ndarray  # float32 (n,)
    angle_min: float
    angle_increment: float
    range_min: float
    range_max: float
    time: float

    @property
    def angles(self) -> np.ndarray:
        return self.angle_min + self.angle_increment * np.arange(len(self.ranges))

    def valid(self) -> np.ndarray:
        return np.isfinite(self.ranges)

    def points(self, pose: Pose2D) -> np.ndarray:
        """Map-frame end points (M, 2) of the valid returns, seen from ``pose``."""
        ok = self.valid()
        r = self.ranges[ok].astype(float)
        a = self.angles[ok] + pose.yaw
        return np.stack([pose.x + r * np.cos(a), pose.y + r * np.sin(a)], axis=1)


def json_default(value: Any) -> Any:
    """numpy scalars and arrays as plain JSON values (``json.dumps(..., default=...)``), so
    every file and message the project writes turns numpy into JSON the same way."""
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    raise TypeError(f"not JSON serialisable: {type(value).__name__}")


def finite(value: Any) -> Any:
    """``value`` with NaN and infinities as None and numpy scalars as Python numbers: what
    strict JSON (a browser's JSON.parse) accepts."""
    if isinstance(value, dict):
        return {str(k): finite(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [finite(v) for v in value]
    if isinstance(value, np.ndarray):
        return finite(value.tolist())
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value
