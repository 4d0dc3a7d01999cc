"""A robot's drive base as its driver sees it, built in one call: the body in the world
with its encoders, lidar and IMU, and the odometry they feed (ROS's base driver with
``diff_tf``, or the gyro fused in as ``robot_localization`` would)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from agv_mission.geometry import Pose2D
from agv_mission.maps.worlds import World
from agv_mission.robots.body import diff_drive_shape
from agv_mission.robots.description import RobotDescription
from agv_mission.robots.diff_drive import DiffDriveBody
from agv_mission.robots.odometry import DiffDriveOdometry, GyroFusedOdometry
from agv_mission.robots.sensors import ImuSamples
from agv_mission.robots.sim_config import SimConfig
from agv_mission.world.body import diff_drive_world
from agv_mission.world.simulation import SimulatedWorld, WorldBuilder


def robots_world(
    world: World, robots: list[tuple[str, RobotDescription, Pose2D]], config: SimConfig
) -> WorldBuilder:
    """A builder of ``world`` with every robot's body in it (``robots``: name,
    description, start), each lidar seeing over the tallest hull."""
    bodies = [(name, diff_drive_shape(robot), start) for name, robot, start in robots]
    return diff_drive_world(world, config.physics_dt, bodies)


def new_odometry(robot: RobotDescription, use_imu: bool = True) -> DiffDriveOdometry:
    """The robot's odometry: wheels and gyro fused when it has an IMU and ``use_imu``,
    else the wheels alone."""
    enc = robot.encoder
    if robot.imu is None or not use_imu:
        return DiffDriveOdometry(enc.ticks_per_meter, robot.wheel_separation)
    # a wheel's relative travel error: per-read noise, slip (uniform), scale error
    wheel_noise = math.sqrt(enc.noise**2 + enc.slip**2 / 3.0 + enc.scale_error**2)
    return GyroFusedOdometry(
        enc.ticks_per_meter,
        robot.wheel_separation,
        wheel_noise,
        robot.imu.gyro_noise_density,
        robot.imu.gyro_bias_instability,
    )


@dataclass
class DriveBase:
    """A robot's body in the world and the odometry its encoders (and gyro) feed."""

    body: DiffDriveBody
    odometry: DiffDriveOdometry

    @classmethod
    def build(
        cls,
        world: SimulatedWorld,
        name: str,
        robot: RobotDescription,
        config: SimConfig,
        seed: np.random.SeedSequence,
        use_imu: bool = True,
    ) -> DriveBase:
        """Take hold of body ``name`` of ``world``; its sensors draw from ``seed``'s
        stream, its IMU from a stream spawned from it."""
        odometry = new_odometry(robot, use_imu)
        body = DiffDriveBody(
            world,
            name,
            robot,
            config,
            np.random.default_rng(seed),
            imu_rng=np.random.default_rng(seed.spawn(1)[0]),
        )
        return cls(body, odometry)

    def read(self) -> tuple[Pose2D, ImuSamples | None]:
        """The encoders (and the IMU, when the robot has one) read into the odometry."""
        body, odometry = self.body, self.odometry
        ticks = body.encoder_ticks()
        imu = body.imu_samples()
        if imu is not None and isinstance(odometry, GyroFusedOdometry):
            return odometry.update_fused(*ticks, imu.turn, len(imu) * imu.period), imu
        return odometry.update(*ticks), imu
