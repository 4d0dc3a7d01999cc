"""Robot descriptions: the numbers that define a differential-drive AGV and its sensors."""

from __future__ import annotations

from pathlib import Path

import yaml
from pydantic import BaseModel, ConfigDict, Field


class LidarSpec(BaseModel):
    """A planar 360-degree laser scanner (``sensor_msgs/LaserScan`` conventions)."""

    model_config = ConfigDict(extra="forbid")

    beams: int = Field(360, ge=4, description="beams per scan, evenly spread over 360 degrees")
    range_min: float = Field(0.12, gt=0, description="metres; closer returns read as invalid")
    range_max: float = Field(3.5, gt=0, description="metres; no return beyond this")
    rate: float = Field(5.0, gt=0, description="scans per second")
    noise_std: float = Field(0.01, ge=0, description="Gaussian range noise, metres")
    height: float = Field(0.17, gt=0, description="height of the scan plane above the floor")


class EncoderSpec(BaseModel):
    """Incremental wheel encoders, read as integer ticks."""

    model_config = ConfigDict(extra="forbid")

    ticks_per_meter: float = Field(
        ..., gt=0, description="ticks per metre of wheel travel (diff_tf's ticks_meter)"
    )


class RobotDescription(BaseModel):
    """A differential-drive robot: geometry, limits and sensors."""

    model_config = ConfigDict(extra="forbid")

    name: str
    wheel_radius: float = Field(..., gt=0, description="metres")
    wheel_separation: float = Field(..., gt=0, description="distance between wheel contacts, m")
    footprint_radius: float = Field(..., gt=0, description="radius of the circular footprint, m")
    max_linear_velocity: float = Field(..., gt=0, description="m/s")
    max_angular_velocity: float = Field(..., gt=0, description="rad/s")
    max_linear_acceleration: float = Field(1.0, gt=0, description="m/s^2")
    max_angular_acceleration: float = Field(4.0, gt=0, description="rad/s^2")
    mass: float = Field(1.0, gt=0, description="kg")
    encoder: EncoderSpec
    lidar: LidarSpec = LidarSpec()


def _ticks_per_meter(ticks_per_rev: float, wheel_radius: float) -> float:
    import math

    return ticks_per_rev / (2.0 * math.pi * wheel_radius)


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
        # Dynamixel XL430: 4096 ticks per revolution
        encoder=EncoderSpec(ticks_per_meter=_ticks_per_meter(4096, 0.033)),
        lidar=LidarSpec(beams=360, range_min=0.12, range_max=3.5, rate=5.0, height=0.17),
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
        encoder=EncoderSpec(ticks_per_meter=_ticks_per_meter(4096, 0.033)),
        lidar=LidarSpec(beams=360, range_min=0.12, range_max=3.5, rate=5.0, height=0.12),
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
        encoder=EncoderSpec(ticks_per_meter=190.0),
        lidar=LidarSpec(beams=360, range_min=0.15, range_max=12.0, rate=5.5, height=0.15),
    ),
}


def load_robot(spec: str, base_dir: Path | None = None) -> RobotDescription:
    """A built-in robot by name, or a robot YAML file (a :class:`RobotDescription` document)."""
    if spec in BUILTIN_ROBOTS:
        return BUILTIN_ROBOTS[spec]
    path = Path(spec)
    if base_dir is not None and not path.is_absolute():
        path = base_dir / path
    with open(path, encoding="utf-8") as f:
        doc = yaml.safe_load(f) or {}
    doc.setdefault("name", path.stem)
    return RobotDescription.model_validate(doc)
