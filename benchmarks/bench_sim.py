"""Simulator cost: physics step, lidar scan, and real-time factor in a ~50-box world."""

from __future__ import annotations

import math
import time

import numpy as np

from agv_mission.geometry import Pose2D
from agv_mission.maps.grid import OccupancyGrid
from agv_mission.maps.worlds import Box, Cylinder, World
from agv_mission.robots.builtin_robots import BUILTIN_ROBOTS
from agv_mission.robots.diff_drive import DiffDriveBody, SimConfig


def bench_world(n_boxes: int = 50) -> World:
    """A 10 x 10 m room (4 walls) with interior wall segments and a few pillars."""
    rng = np.random.default_rng(7)
    boxes = [
        Box(0.0, 5.0, 5.0, 0.05),
        Box(0.0, -5.0, 5.0, 0.05),
        Box(5.0, 0.0, 0.05, 5.0),
        Box(-5.0, 0.0, 0.05, 5.0),
    ]
    while len(boxes) < n_boxes:
        x, y = rng.uniform(-4.5, 4.5, size=2)
        if math.hypot(x, y) < 1.0:  # keep the robot's track clear
            continue
        boxes.append(Box(x, y, rng.uniform(0.05, 0.6), 0.05, rng.uniform(-math.pi, math.pi)))
    pillars = [Cylinder(2.5, 2.5, 0.1), Cylinder(-2.5, -2.5, 0.15)]
    grid = OccupancyGrid(np.zeros((200, 200), dtype=np.int8), 0.05, Pose2D(-5.0, -5.0))
    return World("bench", boxes, pillars, grid, Pose2D(0.0, 0.0))


def run() -> dict[str, float]:
    robot = BUILTIN_ROBOTS["burger"]
    world = bench_world()
    sim = DiffDriveBody.alone(robot, world, Pose2D(0.0, 0.0), SimConfig(), np.random.default_rng(0))
    sim.set_command(0.1, 0.4)  # circle of radius 0.25 m around the start

    steps = 5000
    t0 = time.perf_counter()
    sim.advance(steps * sim.dt)
    step_us = (time.perf_counter() - t0) / steps * 1e6

    scans = 200
    t0 = time.perf_counter()
    for _ in range(scans):
        sim.scan()
    scan_ms = (time.perf_counter() - t0) / scans * 1e3

    # Physics at the default rate (SimConfig.physics_dt) with a 5 Hz lidar and 20 Hz
    # encoder reads, 20 simulated seconds.
    sim_seconds = 20.0
    t0 = time.perf_counter()
    for k in range(int(sim_seconds * 20)):
        sim.advance(0.05)
        sim.encoder_ticks()
        if k % 4 == 0:
            sim.scan()
    rtf = sim_seconds / (time.perf_counter() - t0)

    return {
        "sim_geoms": float(sim.world.model.ngeom),
        "physics_hz": 1.0 / sim.dt,
        "physics_step_us": step_us,
        "physics_ms_per_sim_s": step_us / sim.dt * 1e-3,
        "lidar_scan_360_ms": scan_ms,
        "realtime_factor_lidar5hz": rtf,
    }


if __name__ == "__main__":
    for key, value in run().items():
        print(f"{key:34s} {value:10.3f}")
