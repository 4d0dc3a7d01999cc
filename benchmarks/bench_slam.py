"""grid SLAM cost on real MuJoCo scans: scan integration, scan matching, frontier search.

A burger drives a fixed route through small_house (living room, bedroom door, bedroom)
with noisy encoders (encoder_noise 0.05, wheel_slip 0.1), feeding 5 Hz 360-beam scans
and odometry to the ``grid`` plugin exactly as the runner does; the plugin times each
integration and each match itself. Frontier search runs on the map at the end, as the
map_area task would call it.
"""

from __future__ import annotations

import math
import time

import numpy as np

from agv_mission.geometry import Pose2D, wrap_angle
from agv_mission.mapping.frontiers import find_frontiers
from agv_mission.mapping.slam import GridSlam, GridSlamConfig, trajectory_rmse
from agv_mission.maps.builtin_worlds import small_house
from agv_mission.robots.description import BUILTIN_ROBOTS
from agv_mission.robots.odometry import DiffDriveOdometry
from agv_mission.robots.simulation import DiffDriveSim, SimConfig

ROUTE = ((3.0, -0.45), (-1.5, -0.45), (-1.5, -1.7), (-3.5, -1.7), (-5.5, -1.5), (-5.5, -3.5))
BOUNDS = (-9.5, 9.5, -5.5, 5.5)


def _percentile(samples: list[float], q: float) -> float:
    return float(np.percentile(np.asarray(samples) * 1e3, q))


def run() -> dict[str, float]:
    world = small_house()
    robot = BUILTIN_ROBOTS["burger"]
    sim = DiffDriveSim(
        robot, world, world.spawn, SimConfig(encoder_noise=0.05, wheel_slip=0.1),
        np.random.default_rng(0),
    )  # fmt: skip
    odometry = DiffDriveOdometry(robot.encoder.ticks_per_meter, robot.wheel_separation)
    odom0 = odometry.update(*sim.encoder_ticks())
    slam = GridSlam(GridSlamConfig(), bounds=BOUNDS)
    slam.reset(world.spawn, odom0)
    truth, est = [], []
    target, step = 0, 0
    slam_wall = 0.0
    while target < len(ROUTE) and step < 3000:
        odom = odometry.update(*sim.encoder_ticks())
        scan = sim.scan() if step % 2 == 0 else None
        pose = sim.true_pose()
        t0 = time.perf_counter()
        estimate = slam.update(odom, scan, Pose2D(0.0, 0.0, 0.0), sim.time)
        slam_wall += time.perf_counter() - t0
        truth.append(pose.as_array())
        est.append(estimate.as_array())
        tx, ty = ROUTE[target]
        dist = math.hypot(tx - pose.x, ty - pose.y)
        if dist < 0.05:
            target += 1
            continue
        err = wrap_angle(math.atan2(ty - pose.y, tx - pose.x) - pose.yaw)
        v = min(0.2, 0.5 * dist + 0.02) if abs(err) < 0.3 else 0.0
        sim.set_command(v, max(-1.5, min(1.5, 3.0 * err)))
        sim.advance(0.1)
        step += 1

    grid = slam.occupancy_grid()
    frontier_times = []
    for _ in range(10):
        t0 = time.perf_counter()
        find_frontiers(grid, BOUNDS, robot=(est[-1][0], est[-1][1]))
        frontier_times.append(time.perf_counter() - t0)
    return {
        "slam.integrate_ms.p50": _percentile(slam.integrate_times, 50),
        "slam.integrate_ms.p99": _percentile(slam.integrate_times, 99),
        "slam.match_ms.p50": _percentile(slam.match_times, 50),
        "slam.match_ms.p99": _percentile(slam.match_times, 99),
        "slam.ms_per_sim_s": 1e3 * slam_wall / sim.time,
        "slam.frontiers_ms.p50": _percentile(frontier_times, 50),
        "slam.route_rmse_m": trajectory_rmse(np.array(est), np.array(truth)),
    }


if __name__ == "__main__":
    for key, value in run().items():
        print(f"{key:28s} {value:.3f}")
