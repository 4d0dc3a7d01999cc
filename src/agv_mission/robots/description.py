"""Robot descriptions: the numbers that define a differential-drive AGV and its sensors."""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import yaml
from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    ValidationError,
    field_validator,
    model_validator,
)

from agv_mission.atomic import InputFileError, input_path, read_input_text
from agv_mission.geometry import Footprint, Pose2D
from agv_mission.robots.battery import BatterySpec
from agv_mission.suggest import unknown_key

MAX_BEAMS = 8192  # more than any planar lidar sold; each beam is a ray cast per scan


@functools.lru_cache(maxsize=64)
def _outline(points: tuple[tuple[float, float], ...] | None, radius: float) -> Footprint:
    """A robot's footprint, built once per polygon or radius."""
    return Footprint.from_points(points) if points is not None else Footprint.circle(radius)


class LidarMount(BaseModel):
    """Where the scan's frame sits on the robot (TF ``base_link -> laser``), planar."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    x: float = Field(0.0, ge=-5.0, le=5.0, description="metres ahead of the robot's origin")
    y: float = Field(0.0, ge=-5.0, le=5.0, description="metres to the left")
    yaw: float = Field(0.0, ge=-math.pi, le=math.pi, description="rad, counter-clockwise")


class LidarSpec(BaseModel):
    """A planar laser scanner (``sensor_msgs/LaserScan`` conventions): a full turn unless
    ``angle_min`` / ``angle_max`` say otherwise."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

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

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

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

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

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

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    name: str
    wheel_radius: float = Field(..., gt=0, description="metres")
    wheel_separation: float = Field(..., gt=0, description="distance between wheel contacts, m")
    footprint_radius: float = Field(
        None,
        gt=0,
        description="radius of a circular footprint, m; with a footprint polygon: the "
        "circle round the polygon (derived)",
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


# TurtleBot3 burger and waffle (pi): ROBOTIS' e-Manual specification table, "Battery:
# Lithium polymer 11.1V 1800mAh / 19.98Wh 5C" and "Expected operating time: 2h 30m"
# (burger) / "2h" (waffle pi). The idle load is that mean power (19.98 Wh / 2.5 h = 8.0 W,
# / 2 h = 10.0 W) less what the motion model draws at full speed (0.1 W, 0.3 W); the
# charger delivers 1C (1.8 A at 11.1 V), the usual limit for charging a LiPo.
TB3_BATTERY_WH = 11.1 * 1.8


def _ticks_per_meter(ticks_per_rev: float, wheel_radius: float) -> float:
    return ticks_per_rev / (2.0 * math.pi * wheel_radius)


#: ROBOTIS LDS-01 (TurtleBot3 burger and waffle), from its datasheet: range 0.12-3.5 m,
#: 1 degree resolution, 5 Hz; precision +-10 mm at 0.12-0.499 m and +-3.5 % at 0.5-3.5 m
#: (accuracy +-15 mm and +-5 %), read as two standard deviations. Dropouts (no return from
#: dark, glossy or grazing surfaces) are our estimate.
LDS_01: dict[str, Any] = {
    "beams": 360,
    "range_min": 0.12,
    "range_max": 3.5,
    "rate": 5.0,
    "noise_std": 0.005,
    "noise_fraction": 0.0175,
    "dropout": 0.01,
}
#: Slamtec RPLIDAR A1 (the seed's rosbots): range 0.15-12 m, 1 degree, 5.5 Hz; accuracy
#: 1 % of the range up to 3 m, 2.5 % beyond 5 m (datasheet), taken as 1 % std.
RPLIDAR_A1: dict[str, Any] = {
    "beams": 360,
    "range_min": 0.15,
    "range_max": 12.0,
    "rate": 5.5,
    "noise_std": 0.005,
    "noise_fraction": 0.01,
    "dropout": 0.01,
}
#: The TurtleBot3's wheel odometry: the XL430's 4096 ticks per revolution (quantisation),
#: 0.5 % random error per read and +-0.5 % slip (rubber tyres on a hard floor), and a
#: systematic scale error of 0.2 % per wheel (tyre wear and load; Borenstein and Feng's
#: UMBmark finds wheel-diameter mismatches of this order on uncalibrated robots). Measured
#: on 2 m straight runs (six seeds): 0.7-10 cm off, median 2 cm; heading 0.1-5.6 degrees.
TB3_ENCODER: dict[str, Any] = {"noise": 0.005, "slip": 0.005, "scale_error": 0.002}
#: The OpenCR 1.0 board's InvenSense MPU-9250 (TurtleBot3 burger and waffle), from its
#: product specification (PS-MPU-9250A-01 rev 1.1): gyro rate noise spectral density
#: 0.01 deg/s/sqrt(Hz), accelerometer noise power spectral density 300 ug/sqrt(Hz);
#: published at 200 Hz (the firmware's IMU_PUBLISH_FREQUENCY, turtlebot3_core_config.h).
#: The datasheet gives no bias instability: 10 deg/h, what Allan-variance measurements of
#: consumer MEMS gyros of its class find once the start-up calibration (the OpenCR's
#: calibrationGyro) has taken the turn-on bias out. See docs/imu-and-localisation.md.
MPU_9250: dict[str, Any] = {
    "rate": 200.0,
    "gyro_noise_density": math.radians(0.01),
    "gyro_bias_instability": math.radians(10.0 / 3600.0),
    "accel_noise_density": 300e-6 * 9.80665,
}
#: InvenSense MPU-6050 (the GY-521 breakout of hobby kits; our choice for rosbots, whose
#: seed names no IMU), from its product specification (PS-MPU-6000A-00 rev 3.4): gyro
#: rate noise spectral density 0.005 deg/s/sqrt(Hz), accelerometer 400 ug/sqrt(Hz); read
#: at 100 Hz over I2C; bias instability as the MPU-9250's (not in the datasheet).
MPU_6050: dict[str, Any] = {
    "rate": 100.0,
    "gyro_noise_density": math.radians(0.005),
    "gyro_bias_instability": math.radians(10.0 / 3600.0),
    "accel_noise_density": 400e-6 * 9.80665,
}
#: The Jackal's IMU as BARN simulates it: ``jackal_description``'s ``jackal.gazebo`` runs
#: hector_gazebo_plugins' IMU at 50 Hz with rateGaussianNoise and accelGaussianNoise of
#: 0.005 (rad/s, m/s^2 per sample: densities of 0.005/sqrt(50)) and a rateDrift of
#: 0.005 rad/s, a Gauss-Markov bias with a 1 h time constant that starts at zero: its
#: spread after a minute's run, 0.005 sqrt(2 * 60 / 3600) = 0.9 mrad/s, is the bias drawn.
JACKAL_IMU: dict[str, Any] = {
    "rate": 50.0,
    "gyro_noise_density": 0.005 / math.sqrt(50.0),
    "gyro_bias_instability": 0.005 * math.sqrt(2.0 * 60.0 / 3600.0),
    "accel_noise_density": 0.005 / math.sqrt(50.0),
}

#: Hokuyo UST-10LX (the Jackal's laser in BARN: ``JACKAL_LASER_MODEL=ust10``), from its
#: datasheet: 270 degrees at 0.25 degree steps (1081 beams), 25 ms a scan (40 Hz), range
#: 0.06-10 m, accuracy +-40 mm (read as two standard deviations). Dropouts: our estimate.
UST_10LX: dict[str, Any] = {
    "beams": 1081,
    "angle_min": -math.radians(135.0),
    "angle_max": math.radians(135.0),
    "range_min": 0.06,
    "range_max": 10.0,
    "rate": 40.0,
    "noise_std": 0.02,
    "noise_fraction": 0.0,
    "dropout": 0.01,
}
#: Clearpath Jackal's outline: 508 x 430 mm (its datasheet's external dimensions), centred
#: on the robot's origin (the axle midpoint of its four wheels).
JACKAL_FOOTPRINT = [(0.254, 0.215), (-0.254, 0.215), (-0.254, -0.215), (0.254, -0.215)]

BUILTIN_ROBOTS: dict[str, RobotDescription] = {
    "burger": RobotDescription(
        name="burger",
        wheel_radius=0.033,
        wheel_separation=0.160,
        footprint_radius=0.105,
        max_linear_velocity=0.22,
        max_angular_velocity=2.84,
        max_linear_acceleration=1.0,
        max_angular_acceleration=4.0,
        mass=1.0,
        # Dynamixel XL430: 4096 ticks per revolution; errors: see TB3_ENCODER
        encoder=EncoderSpec(ticks_per_meter=_ticks_per_meter(4096, 0.033), **TB3_ENCODER),
        lidar=LidarSpec(height=0.17, **LDS_01),
        battery=BatterySpec(
            capacity=TB3_BATTERY_WH,
            voltage=11.1,
            initial_level=1.0,
            idle_power=7.9,
            charge_power=19.98,
        ),
        imu=ImuSpec(**MPU_9250),
    ),
    "waffle": RobotDescription(
        name="waffle",
        wheel_radius=0.033,
        wheel_separation=0.287,
        footprint_radius=0.22,
        max_linear_velocity=0.26,
        max_angular_velocity=1.82,
        max_linear_acceleration=1.0,
        max_angular_acceleration=3.0,
        mass=1.8,
        encoder=EncoderSpec(ticks_per_meter=_ticks_per_meter(4096, 0.033), **TB3_ENCODER),
        lidar=LidarSpec(height=0.12, **LDS_01),
        battery=BatterySpec(
            capacity=TB3_BATTERY_WH,
            voltage=11.1,
            initial_level=1.0,
            idle_power=9.7,
            charge_power=19.98,
        ),
        imu=ImuSpec(**MPU_9250),
    ),
    # The seed's home-built robot: RPLidar A1 (12 m), 190 encoder ticks per metre.
    "rosbots": RobotDescription(
        name="rosbots",
        wheel_radius=0.0325,
        wheel_separation=0.11,
        footprint_radius=0.09,
        max_linear_velocity=0.3,
        max_angular_velocity=2.0,
        max_linear_acceleration=0.8,
        max_angular_acceleration=3.0,
        mass=0.8,
        # Hobby gear motors with magnetic encoders: coarser and slipperier than a Dynamixel.
        encoder=EncoderSpec(ticks_per_meter=190.0, noise=0.02, slip=0.02, scale_error=0.005),
        lidar=LidarSpec(height=0.15, **RPLIDAR_A1),
        # The seed names no battery: a 2S LiPo of 7.4 V 2200 mAh (16.3 Wh), the common pack
        # of such kits; idle: a Raspberry Pi 3 (~2.5 W) and an RPLidar A1 (5 V, ~0.5 A);
        # charged at 1C.
        battery=BatterySpec(
            capacity=7.4 * 2.2, voltage=7.4, initial_level=1.0, idle_power=5.0, charge_power=16.28
        ),
        imu=ImuSpec(**MPU_6050),
    ),
    # Clearpath Jackal as BARN runs it (docs/robots.md gives each figure's source).
    "jackal": RobotDescription(
        name="jackal",
        wheel_radius=0.098,
        wheel_separation=0.37559,
        footprint=JACKAL_FOOTPRINT,
        max_linear_velocity=2.0,
        max_angular_velocity=4.0,
        max_linear_acceleration=2.0,
        max_angular_acceleration=8.0,
        mass=17.0,
        # 78,000 quadrature pulses per metre (datasheet); Clearpath publishes no error
        # figures: the TurtleBot3's (BARN's Jackal fuses its wheels with its IMU's gyro).
        encoder=EncoderSpec(ticks_per_meter=78000.0, **TB3_ENCODER),
        # On the front mount (0.12 m ahead of the mid mount) moved by BARN's
        # JACKAL_LASER_OFFSET "-0.065 0 0.01": 0.055 m ahead of the origin.
        lidar=LidarSpec(height=0.29, mount=LidarMount(x=0.055), **UST_10LX),
        imu=ImuSpec(**JACKAL_IMU),
    ),
}


class RobotFileError(ValueError):
    """A robot file that cannot be used; names the file, the line and the field."""

    def __init__(
        self,
        path: Path,
        line: int | None,
        field: str,
        message: str,
        more: Sequence[tuple[int | None, str, str]] = (),
    ) -> None:
        self.path, self.line, self.field, self.message = path, line, field, message
        self.problems = [(line, field, message), *more]  # every (line, field, message)
        super().__init__(
            "\n".join(
                (f"line {ln}: " if ln is not None else "") + (f"{f}: " if f else "") + m
                for ln, f, m in self.problems
            )
        )


def load_robot(spec: str, base_dir: Path | None = None) -> RobotDescription:
    """A built-in robot by name, or a robot YAML file (a :class:`RobotDescription` document).

    Raises ``FileNotFoundError`` for a name that is neither, and :class:`RobotFileError`
    (file, line, field) for a file that is not a valid robot description.
    """
    if spec in BUILTIN_ROBOTS:
        return BUILTIN_ROBOTS[spec]
    path = input_path(spec, base_dir) if base_dir is not None else Path(spec).expanduser()
    try:
        text = read_input_text(path)
    except InputFileError as exc:
        if exc.missing:
            raise FileNotFoundError(str(path)) from None
        raise RobotFileError(path, None, "", str(exc)) from None
    except UnicodeDecodeError:
        raise RobotFileError(path, None, "", "not a UTF-8 text file") from None
    try:
        doc = yaml.safe_load(text)
        root = yaml.compose(text, Loader=yaml.SafeLoader)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise RobotFileError(
            path, mark.line + 1 if mark else None, "", f"invalid YAML: {problem}"
        ) from None
    if doc is None:
        doc = {}
    if not isinstance(doc, dict):
        raise RobotFileError(path, 1, "", "expected a mapping of robot parameters")
    doc.setdefault("name", path.stem)
    try:
        return RobotDescription.model_validate(doc)
    except ValidationError as exc:
        problems = [_robot_problem(root, err) for err in exc.errors(include_url=False)]
        raise RobotFileError(path, *problems[0], more=problems[1:]) from None


def _robot_problem(root: Any, err: Any) -> tuple[int | None, str, str]:
    """One validation error as (line, field, message)."""
    loc = tuple(err["loc"])
    msg = "field required" if err["type"] == "missing" else err["msg"]
    if err["type"] == "extra_forbidden":
        msg = unknown_key(RobotDescription, loc)
    elif "input" in err and not isinstance(err["input"], (dict, list)):
        msg = f"{msg} (got {err['input']!r})"
    return _line_of(root, loc), ".".join(map(str, loc)), msg.removeprefix("Value error, ")


def _line_of(node: Any, loc: tuple[Any, ...]) -> int | None:
    """1-based line of the deepest part of ``loc`` the document holds."""
    line = node.start_mark.line + 1 if node is not None else None
    for part in loc:
        if isinstance(node, yaml.MappingNode):
            hit = next(((k, v) for k, v in node.value if k.value == str(part)), None)
            if hit is None:
                return line
            line, node = hit[0].start_mark.line + 1, hit[1]
        elif isinstance(node, yaml.SequenceNode) and isinstance(part, int):
            if not 0 <= part < len(node.value):
                return line
            node = node.value[part]
            line = node.start_mark.line + 1
        else:
            return line
    return line


def robot_json_schema() -> dict[str, Any]:
    """The JSON Schema of a robot file (``name`` may be left out: the file's stem)."""
    schema = RobotDescription.model_json_schema()
    schema["required"] = [k for k in schema.get("required", []) if k != "name"]
    schema["properties"]["name"]["description"] = "default: the file's stem"
    return {"$schema": "https://json-schema.org/draft/2020-12/schema", **schema}
