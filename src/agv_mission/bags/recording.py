"""What mapping needs from a robot's recording, whichever reader read it (a bag or a
CARMEN log), and the one error for a recording that cannot be mapped as given."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from agv_mission.geometry import Pose2D
from agv_mission.sensor_msgs import LaserScan


class BagError(Exception):
    """The bag cannot be mapped as given (invalid input: exit code 2)."""


@dataclass
class BagData:
    """What mapping needs from a bag, in the robot's base frame."""

    scans: list[LaserScan]  # as recorded (angles in the scan frame), nan = invalid
    scan_topic: str
    scan_frame: str
    odom: np.ndarray  # (m, 4) t, x, y, yaw of the base frame in the odometry frame
    odom_source: str  # the topic, or "/tf odom->base_footprint"
    base_frame: str
    mount: Pose2D  # the scan frame on the base frame (planar)
    flipped: bool  # the lidar is upside down
    mount_found: bool
    map_to_odom: np.ndarray | None = None  # (k, 4) t, x, y, yaw when the bag has map->odom
    truth: np.ndarray | None = None  # (k, 4) t, x, y, yaw
    truth_topic: str | None = None
    topics: dict[str, str] = field(default_factory=dict)  # topic -> type
    robot: str | None = None  # the robot's namespace, when its topics have one
    duration: float = 0.0
    notes: dict[str, Any] = field(default_factory=dict)  # what the report should say

    @property
    def timed(self) -> bool:
        """Whether the scans' stamps tell the recording's time: not when most had to be
        spread apart (:mod:`~agv_mission.bags.carmen`: a log printing its stamps to six
        digits, all one stamp, or wrapped past 2**32), where their span is a rounding's
        and a speed "x the duration" would mean nothing."""
        return 2 * int(self.notes.get("stamps_spread", 0)) <= len(self.scans)
