"""amcl filter update cost: motion + likelihood field + KLD resample + cluster estimate.

One filter update (what amcl does after update_min_d / update_min_a of motion) on the
turtlebot3_world map with a 360-beam scan, for 500 / 1000 / 2000 particles (min = max, so
KLD keeps the count) and 60 / 180 beams. Also the sensor model alone, and the real-time
factor of the demo patrol with amcl.
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np

from agv_mission.geometry import Pose2D
from agv_mission.localization.beam_model import SensorParams
from agv_mission.localization.particle_filter import MotionNoise, ParticleFilter
from agv_mission.maps.builtin_worlds import turtlebot3_world
from agv_mission.maps.grid import OccupancyGrid
from agv_mission.sensor_msgs import LaserScan

PARTICLES = (500, 1000, 2000)
BEAMS = (60, 180)
REPEATS = 200


def cast_scan(grid: OccupancyGrid, pose: Pose2D, beams: int = 360, range_max: float = 3.5):
    """Ranges (float32, inf = no return) by marching rays through the grid."""
    a = pose.yaw + 2.0 * math.pi * np.arange(beams) / beams
    steps = np.arange(0.0, range_max, grid.resolution / 4.0)
    pts = np.stack(
        [pose.x + np.cos(a)[:, None] * steps, pose.y + np.sin(a)[:, None] * steps], axis=-1
    )
    occ = grid.value_at(pts) >= 65
    r = steps[occ.argmax(axis=1)]
    return np.where(occ.any(axis=1) & (r >= 0.12), r, np.inf).astype(np.float32)


def _percentiles(samples: list[float]) -> tuple[float, float]:
    ms = np.asarray(samples) * 1e3
    return float(np.percentile(ms, 50)), float(np.percentile(ms, 99))


def run() -> dict[str, float]:
    grid = turtlebot3_world().map
    truth = Pose2D(-2.0, -0.5, 0.3)
    ranges = cast_scan(grid, truth)
    scan = LaserScan(ranges, 0.0, 2.0 * math.pi / len(ranges), 0.12, 3.5, 0.0)
    out: dict[str, float] = {}
    for n in PARTICLES:
        for b in BEAMS:
            pf = ParticleFilter(
                grid,
                np.random.default_rng(0),
                min_particles=n,
                max_particles=n,
                motion=MotionNoise(),
                sensor=SensorParams(max_beams=b),
            )
            pf.init_gaussian(truth.as_array(), np.diag([0.01, 0.01, 0.003]))
            odom = np.zeros(3)
            full, sensor = [], []
            for k in range(REPEATS):
                new = np.array([0.2 * (k + 1), 0.0, 0.0])
                t0 = time.perf_counter()
                pf.motion_update(odom, new)
                t1 = time.perf_counter()
                pf.sensor_update(scan)
                t2 = time.perf_counter()
                pf.resample()
                pf.estimate()
                t3 = time.perf_counter()
                full.append(t3 - t0)
                sensor.append(t2 - t1)
                odom = new
                # keep the cloud where the scan was taken (undo the drive forward)
                pf.particles[:, :2] -= pf.particles[:, :2].mean(axis=0) - truth.as_array()[:2]
            p50, p99 = _percentiles(full)
            s50, _ = _percentiles(sensor)
            out[f"amcl.update_ms.p50.{n}x{b}"] = p50
            out[f"amcl.update_ms.p99.{n}x{b}"] = p99
            out[f"amcl.sensor_ms.p50.{n}x{b}"] = s50
    out["amcl.patrol.real_time_factor"] = patrol_real_time_factor()
    return out


def patrol_real_time_factor() -> float:
    """The demo patrol with amcl (TurtleBot3 defaults), start estimate 0.3 m / 0.2 rad off."""
    from agv_mission.missions.load.loader import load_mission
    from agv_mission.missions.run.runner import run_mission

    demo = Path(__file__).resolve().parents[1] / "missions" / "patrol.yaml"
    x, y = -2.0 + 0.3 * math.cos(2.0), -0.5 + 0.3 * math.sin(2.0)
    overrides = [
        "stack.localization.type=amcl",
        f"stack.localization.initial_pose={{x: {x:.5f}, y: {y:.5f}, yaw: 0.2}}",
    ]
    record = run_mission(load_mission(demo, overrides))
    return float(record.metrics["real_time_factor"])


if __name__ == "__main__":
    for key, value in run().items():
        print(f"{key:34s} {value:10.3f}")
