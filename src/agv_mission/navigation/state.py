"""What the navigation stack and the behaviours know about the robot at a control step."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from agv_mission.geometry import Pose2D, wrap_angles
from agv_mission.sensor_msgs import LaserScan

#: The columns of a tracked person's row (:attr:`RobotState.people`).
TRACKED_PERSON = ("x", "y", "radius", "vx", "vy", "still")
#: m/s: a tracked person slower than this stands (their ``still`` counts up).
STANDING = 0.1


@dataclass
class RobotState:
    """The robot as its software sees it (estimated, never true, pose)."""

    time: float
    estimate: Pose2D
    velocity: tuple[float, float] = (0.0, 0.0)  # the last command (v, w)
    scan: LaserScan | None = None  # the newest scan
    obstacles: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))  # map-frame points
    # People the robot tracks, rows (x, y, radius, vx, vy, still) in the map frame (still:
    # seconds the person has stood, slower than STANDING; 0 while walking), refreshed by the
    # run each step (a perfect tracker, as HuNavSim gives its robots); none: (0, 6).
    people: np.ndarray = field(default_factory=lambda: np.zeros((0, len(TRACKED_PERSON))))
    # range_ahead's last answer (scan, half width, range): a tree asks every tick (10 Hz),
    # the lidar answers at its rate (a TurtleBot3's 5 Hz)
    _ahead: tuple[LaserScan, float, float] | None = field(default=None, repr=False)

    def path_ahead_blocked(self, length: float, half_width: float, margin: float) -> bool:
        """Whether a scan point lies in the corridor the robot would sweep driving
        ``length`` metres straight on: ``|y| <= half_width + margin`` (the robot's half
        width and a safety margin), ``0 < x <= length + half_width``, robot frame."""
        if self.scan is None:
            return False
        ok = np.isfinite(self.scan.ranges)
        r = self.scan.ranges[ok].astype(float)
        a = self.scan.angles[ok]
        x, y = r * np.cos(a), r * np.sin(a)
        inside = (x > 0.0) & (x <= length + half_width) & (np.abs(y) <= half_width + margin)
        return bool(np.any(inside))

    def range_ahead(self, half_width: float) -> float:
        """Smallest valid range within +-``half_width`` radians of straight ahead."""
        scan = self.scan
        if scan is None:
            return float("inf")
        if self._ahead is not None and self._ahead[0] is scan and self._ahead[1] == half_width:
            return self._ahead[2]
        angles = np.abs(wrap_angles(scan.angles))
        sector = scan.ranges[angles <= half_width]
        finite = sector[np.isfinite(sector)]
        nearest = float(finite.min()) if finite.size else float("inf")
        self._ahead = (scan, half_width, nearest)
        return nearest
