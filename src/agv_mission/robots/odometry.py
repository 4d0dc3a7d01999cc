"""Wheel odometry from encoder ticks, as the ROS ``differential_drive`` ``diff_tf.py`` node.

diff_tf computes, per update, ``d = (dl + dr) / 2`` and ``dth = (dr - dl) / base_width`` from
the tick deltas and integrates them. This version integrates the exact circular arc (with
the midpoint-heading formula for nearly straight motion), so the result does not depend on
the update rate for constant wheel speeds.
"""

from __future__ import annotations

from agv_mission.geometry import Pose2D, arc_step, wrap_angle


class DiffDriveOdometry:
    """Dead reckoning from cumulative left/right encoder ticks.

    The first :meth:`update` only records the tick baseline (like diff_tf, which starts from
    whatever the encoders read), unless ``initial_ticks`` is given.
    """

    def __init__(
        self,
        ticks_per_meter: float,
        base_width: float,
        start: Pose2D = Pose2D(0.0, 0.0, 0.0),  # noqa: B008 (frozen dataclass)
        initial_ticks: tuple[int, int] | None = None,
    ) -> None:
        if ticks_per_meter <= 0 or base_width <= 0:
            raise ValueError("ticks_per_meter and base_width must be positive")
        self.ticks_per_meter = float(ticks_per_meter)
        self.base_width = float(base_width)
        self._x, self._y, self._yaw = start.x, start.y, start.yaw
        self._ticks = initial_ticks
        self.distance = 0.0  # total |d| travelled, m
        self.last_delta = (0.0, 0.0)  # (d, dth) of the last update

    @property
    def pose(self) -> Pose2D:
        return Pose2D(self._x, self._y, wrap_angle(self._yaw))

    def reset(self, pose: Pose2D) -> None:
        """Set the pose estimate; the tick baseline is kept."""
        self._x, self._y, self._yaw = pose.x, pose.y, pose.yaw

    def update(self, left_ticks: int, right_ticks: int) -> Pose2D:
        if self._ticks is None:
            self._ticks = (int(left_ticks), int(right_ticks))
            return self.pose
        dl = (left_ticks - self._ticks[0]) / self.ticks_per_meter
        dr = (right_ticks - self._ticks[1]) / self.ticks_per_meter
        self._ticks = (int(left_ticks), int(right_ticks))
        d = (dl + dr) / 2.0
        dth = (dr - dl) / self.base_width
        self._x, self._y, self._yaw = arc_step(self._x, self._y, self._yaw, d, dth)
        self.distance += abs(d)
        self.last_delta = (d, dth)
        return self.pose
