"""A scripted drive that feeds a SLAM plugin as the runner does, for the SLAM tests and
``benchmarks/bench_slam.py`` (which puts ``tests/`` on its path)."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from agv_mission.geometry import Pose2D, wrap_angle
from agv_mission.mapping.slam import GridSlam, GridSlamConfig
from agv_mission.maps.worlds import World
from agv_mission.robots.builtin_robots import BUILTIN_ROBOTS
from agv_mission.robots.diff_drive import DiffDriveBody, SimConfig
from agv_mission.robots.odometry import DiffDriveOdometry

BURGER = BUILTIN_ROBOTS["burger"]
TB3_BOUNDS = (-3.0, 3.0, -3.0, 3.0)
GARBAGE = Pose2D(-99.0, 99.0, 0.0)  # passed as the "true pose": SLAM must not use it


@dataclass
class Drive:
    slam: GridSlam
    truth: np.ndarray  # (steps, 3)
    estimate: np.ndarray  # (steps, 3)
    odometry: np.ndarray  # (steps, 3), dead reckoning anchored at the start
    sim_time: float  # simulated seconds driven
    update_wall: float  # wall seconds spent in the plugin's update, for benchmarks


def drive(
    world: World,
    waypoints,
    config: SimConfig,
    slam_config: GridSlamConfig | None = None,
    bounds=TB3_BOUNDS,
    seed: int = 0,
    max_steps: int = 5000,
) -> Drive:
    """Follow ``waypoints`` (steering on the true pose, as a scripted test driver), feeding
    encoder odometry and 5 Hz scans to the SLAM plugin every 0.1 s like the runner does."""
    sim = DiffDriveBody.alone(BURGER, world, world.spawn, config, np.random.default_rng(seed))
    odometry = DiffDriveOdometry(BURGER.encoder.ticks_per_meter, BURGER.wheel_separation)
    odom0 = odometry.update(*sim.encoder_ticks())
    slam = GridSlam(slam_config or GridSlamConfig(), bounds=bounds)
    slam.reset(world.spawn, odom0)
    truth, est, dead = [], [], []
    target, step = 0, 0
    wall = 0.0
    while target < len(waypoints) and step < max_steps:
        odom = odometry.update(*sim.encoder_ticks())
        scan = sim.scan() if step % 2 == 0 else None
        pose = sim.true_pose()
        t0 = time.perf_counter()
        estimate = slam.update(odom, scan, GARBAGE, sim.time)
        wall += time.perf_counter() - t0
        truth.append(pose.as_array())
        est.append(estimate.as_array())
        dead.append(world.spawn.compose(odom.relative_to(odom0)).as_array())
        tx, ty = waypoints[target]
        dist = math.hypot(tx - pose.x, ty - pose.y)
        if dist < 0.05:
            target += 1
            continue
        err = wrap_angle(math.atan2(ty - pose.y, tx - pose.x) - pose.yaw)
        v = min(0.2, 0.5 * dist + 0.02) if abs(err) < 0.3 else 0.0
        sim.set_command(v, max(-1.5, min(1.5, 3.0 * err)))
        sim.advance(0.1)
        step += 1
    return Drive(slam, np.array(truth), np.array(est), np.array(dead), sim.time, wall)
