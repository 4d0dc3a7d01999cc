"""A robot description as the shape the world builds its body from
(:mod:`agv_mission.world.body`)."""

from __future__ import annotations

from agv_mission.geometry import Pose2D
from agv_mission.robots.description import RobotDescription
from agv_mission.world.body import DiffDriveShape


def diff_drive_shape(robot: RobotDescription) -> DiffDriveShape:
    """What the world needs of ``robot`` to build its body."""
    mount = robot.lidar.mount
    return DiffDriveShape(
        wheel_radius=robot.wheel_radius,
        wheel_separation=robot.wheel_separation,
        footprint_radius=robot.footprint_radius,
        outline=robot.outline,
        mass=robot.mass,
        max_linear_acceleration=robot.max_linear_acceleration,
        lidar_height=robot.lidar.height,
        lidar_mount=Pose2D(mount.x, mount.y, mount.yaw),
        lidar_range=robot.lidar.range_max,
    )
