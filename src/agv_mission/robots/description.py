"""Robot descriptions: the numbers that define a differential-drive AGV and its sensors
(the built-in robots are in :mod:`~agv_mission.robots.builtin_robots`, robot files are read
by :mod:`~agv_mission.robots.robot_files`)."""

from __future__ import annotations

import functools
import math

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    field_validator,
    model_validator,
)

from agv_mission.geometry import Footprint, Pose2D
from agv_mission.robots.battery import BatterySpec

MAX_BEAMS = 8192  # more than any planar lidar sold; each beam is a ray cast per scan


@functools.lru_cache(maxsize=64)
def _outline(points: tuple[tuple[float, float], ...] | None, radius: float) -> Footprint:
    """A robot's footprint, built once per polygon or radius."""
    return Footprint.from_points(points) if points is not None else Footprint.circle(radius)


class LidarMount(BaseModel):
    """Where the scan's frame sits on the robot (TF ``base_link -> laser``), planar."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, defer_build=True)

    x: float = Field(0.0, ge=-5.0, le=5.0, description="metres ahead of the robot's origin")
    y: float = Field(0.0, ge=-5.0, le=5.0, description="metres to the left")
    yaw: float = Field(0.0, ge=-math.pi, le=math.pi, description="rad, counter-clockwise")


class LidarSpec(BaseModel):
    """A planar laser scanner (``sensor_msgs/LaserScan`` conventions): a full turn unless
    ``angle_min`` / ``angle_max`` say otherwise."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, defer_build=True)

    beams: int = Field(
        360,
        ge=4,
        le=MAX_BEAMS,
        description="beams per scan, evenly spread over a full turn, or from angle_min to "
        "angle_max (both included)",
    )
    angle_min: float | None = Field(
        None, ge=-math.pi, le=math.pi, description="rad, the first beam; default: a full turn"
    )
    angle_max: float | None = Field(
        None, ge=-math.pi, le=math.pi, description="rad, the last beam; default: a full turn"
    )
    mount: LidarMount = Field(
        default_factory=LidarMount, description="the scan's frame on the robot"
    )
    range_min: float = Field(0.12, gt=0, description="metres; closer returns read as invalid")
    range_max: float = Field(3.5, gt=0, le=1000.0, description="metres; no return beyond this")
    rate: float = Field(5.0, gt=0, le=100.0, description="scans per second")
    noise_std: float = Field(
        0.005, ge=0, description="Gaussian range noise std at short range, metres"
    )
    noise_fraction: float = Field(
        0.0175,
        ge=0,
        le=0.5,
        description="range noise std as a fraction of the range, where larger than noise_std",
    )
    dropout: float = Field(
        0.01, ge=0, le=1, description="probability that a beam returns nothing (reads inf)"
    )
    height: float = Field(0.17, gt=0, description="height of the scan plane above the floor")

    @model_validator(mode="after")
    def check_field_of_view(self) -> LidarSpec:
        if (self.angle_min is None) != (self.angle_max is None):
            raise ValueError("angle_min and angle_max go together (neither: a full turn)")
        if self.angle_min is not None and not self.angle_min < self.angle_max:
            raise ValueError(f"angle_min {self.angle_min} is not below angle_max {self.angle_max}")
        if not self.range_min < self.range_max:  # a lidar that could never return anything
            raise ValueError(f"range_min {self.range_min} is not below range_max {self.range_max}")
        return self

    @property
    def full_turn(self) -> bool:
        return self.angle_min is None

    def scan_pose(self, pose: Pose2D) -> Pose2D:
        """The scan frame's pose for the robot at ``pose`` (the mount composed on)."""
        m = self.mount
        if m.x == 0.0 and m.y == 0.0 and m.yaw == 0.0:
            return pose
        return pose.compose(Pose2D(m.x, m.y, m.yaw))

    def beam_angles(self) -> tuple[float, float]:
        """(angle of beam 0, increment), as ``LaserScan`` gives them."""
        if self.angle_min is None or self.angle_max is None:
            return 0.0, 2.0 * math.pi / self.beams
        return self.angle_min, (self.angle_max - self.angle_min) / (self.beams - 1)


class EncoderSpec(BaseModel):
    """Incremental wheel encoders, read as integer ticks."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, defer_build=True)

    ticks_per_meter: float = Field(
        ..., gt=0, description="ticks per metre of wheel travel (diff_tf's ticks_meter)"
    )
    noise: float = Field(
        0.01, ge=0, description="std of the relative tick error of each read (10 Hz)"
    )
    slip: float = Field(
        0.01, ge=0, le=1, description="each read's travel is scaled by 1 + U(-slip, slip)"
    )
    scale_error: float = Field(
        0.002,
        ge=0,
        le=0.1,
        description="std of each wheel's systematic scale error (tyre wear, load), drawn per run",
    )


class ImuSpec(BaseModel):
    """A MEMS IMU on the robot's base: the gyro's z rate and the accelerometer's x, y,
    published as ``sensor_msgs/Imu`` (noise densities as datasheets give them)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, defer_build=True)

    rate: float = Field(100.0, gt=0, le=1000.0, description="samples per second, Hz")
    gyro_noise_density: float = Field(
        ..., ge=0, le=0.1, description="gyro rate noise density, rad/s/sqrt(Hz)"
    )
    gyro_bias_instability: float = Field(
        ..., ge=0, le=0.1, description="gyro bias left after the start-up calibration, rad/s"
    )
    accel_noise_density: float = Field(
        ..., ge=0, le=10.0, description="accelerometer noise density, m/s^2/sqrt(Hz)"
    )


class RobotDescription(BaseModel):
    """A differential-drive robot: geometry, limits and sensors."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, defer_build=True)

    name: str
    wheel_radius: float = Field(
        ...,
        ge=0.005,
        le=2.0,
        description="metres, 5 mm to 2 m (a wheel of 1e-12 m has no mass the physics "
        "engine can move)",
    )
    wheel_separation: float = Field(..., gt=0, description="distance between wheel contacts, m")
    footprint_radius: float = Field(
        None,
        gt=0,
        le=10.0,
        description="radius of a circular footprint, m, at most 10 (as a footprint polygon's "
        "reach: a radius of 1e6 m overflows the costmap's inflation); with a footprint "
        "polygon: the circle round the polygon (derived)",
    )
    footprint: list[tuple[float, float]] | None = Field(
        None,
        min_length=3,
        max_length=64,
        description="the outline, robot frame (Nav2's convention: [[x, y], ...], m); "
        "replaces footprint_radius where given",
    )
    max_linear_velocity: float = Field(..., gt=0, description="m/s")
    max_angular_velocity: float = Field(..., gt=0, description="rad/s")
    max_linear_acceleration: float = Field(1.0, gt=0, description="m/s^2")
    max_angular_acceleration: float = Field(4.0, gt=0, description="rad/s^2")
    mass: float = Field(1.0, gt=0, description="kg")
    encoder: EncoderSpec
    lidar: LidarSpec = LidarSpec()
    battery: BatterySpec | None = Field(
        None, description="capacity, level, idle and charge power; none: not modelled"
    )
    imu: ImuSpec | None = Field(
        None, description="gyro and accelerometer; odometry fuses the gyro; none: no IMU"
    )

    @field_validator("footprint")
    @classmethod
    def check_footprint(
        cls, value: list[tuple[float, float]] | None
    ) -> list[tuple[float, float]] | None:
        if value is None:
            return None
        from shapely.geometry import Point, Polygon

        poly = Polygon(value)
        if not poly.is_valid or poly.area <= 0.0:
            raise ValueError("the footprint is not a simple polygon (edges cross or it is flat)")
        if not poly.contains(Point(0.0, 0.0)):
            raise ValueError("the footprint does not hold the robot's origin (0, 0)")
        if max(math.hypot(x, y) for x, y in value) > 10.0:
            raise ValueError("the footprint reaches more than 10 m from the origin")
        return value

    @model_validator(mode="after")
    def derive_radius(self) -> RobotDescription:
        if self.footprint is not None:
            self.footprint_radius = self.outline.circumscribed
        elif self.footprint_radius is None:
            raise ValueError("give footprint_radius (a round robot) or footprint (a polygon)")
        return self

    @property
    def outline(self) -> Footprint:
        """The footprint: the polygon where one is given, else the circle."""
        points = tuple(map(tuple, self.footprint)) if self.footprint is not None else None
        return _outline(points, self.footprint_radius)

    @property
    def polygon(self) -> Footprint | None:
        """The footprint where a polygon is given (None: a round robot)."""
        return self.outline if self.footprint is not None else None

    @property
    def inscribed_radius(self) -> float:
        """The largest circle round the origin inside the footprint (costmap, planners)."""
        return self.outline.inscribed
