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


class GyroFusedOdometry(DiffDriveOdometry):
    """Wheel odometry whose heading comes from the wheels and the gyro together, as a
    TurtleBot3's or a Jackal's ``robot_localization`` EKF fuses the wheels' and the IMU's
    yaw rate: each update's two measurements of the same turn, weighted by the inverse of
    their variances (the EKF's update with both rates measured).

    The wheels' turn variance grows with each wheel's travel (``wheel_noise``: the relative
    error of a wheel's travel, encoder noise, slip and scale error together); the gyro's is
    its angle random walk over the update and its bias: ``gyro_noise_density^2 * dt +
    (bias * dt)^2``. Rolling on, the gyro wins by orders of magnitude (a wheel's slip
    turns the robot on paper, not on the floor); standing still, the wheels' zero turn
    wins, so the gyro's bias does not turn a robot at rest. Translation stays the wheels'.
    """

    def __init__(
        self,
        ticks_per_meter: float,
        base_width: float,
        wheel_noise: float,
        gyro_noise_density: float,
        gyro_bias: float,
        start: Pose2D = Pose2D(0.0, 0.0, 0.0),  # noqa: B008 (frozen dataclass)
        initial_ticks: tuple[int, int] | None = None,
    ) -> None:
        super().__init__(ticks_per_meter, base_width, start, initial_ticks)
        # a floor of a thousandth of a tick's turn: the wheels at rest are not infinitely sure
        self._wheel_floor = (1e-3 / (ticks_per_meter * base_width)) ** 2
        self._wheel_var = (wheel_noise / base_width) ** 2
        self._gyro_density2 = gyro_noise_density**2
        self._gyro_bias2 = gyro_bias**2
        self.gyro_weight = 0.0  # the gyro's share of the last update's turn

    def update_fused(
        self, left_ticks: int, right_ticks: int, gyro_turn: float, duration: float
    ) -> Pose2D:
        """Integrate the encoders' travel with the turn fused from the wheels' and the
        gyro's ``gyro_turn`` (rad, measured over ``duration`` seconds)."""
        if self._ticks is None or duration <= 0.0:
            return self.update(left_ticks, right_ticks)
        dl = (left_ticks - self._ticks[0]) / self.ticks_per_meter
        dr = (right_ticks - self._ticks[1]) / self.ticks_per_meter
        self._ticks = (int(left_ticks), int(right_ticks))
        d = (dl + dr) / 2.0
        wheel_turn = (dr - dl) / self.base_width
        var_wheel = self._wheel_var * (dl * dl + dr * dr) + self._wheel_floor
        var_gyro = self._gyro_density2 * duration + self._gyro_bias2 * duration * duration
        weight = var_wheel / (var_wheel + var_gyro) if var_wheel + var_gyro > 0.0 else 0.0
        dth = wheel_turn + weight * (gyro_turn - wheel_turn)
        self.gyro_weight = weight
        self._x, self._y, self._yaw = arc_step(self._x, self._y, self._yaw, d, dth)
        self.distance += abs(d)
        self.last_delta = (d, dth)
        return self.pose
