"""grid SLAM cost on real MuJoCo scans: scan integration, scan matching, frontier search.

A burger drives a fixed route through small_house (living room, bedroom door, bedroom)
with noisy encoders (encoder_noise 0.05, wheel_slip 0.1), feeding 5 Hz 360-beam scans
and odometry to the ``grid`` plugin exactly as the runner does; the plugin times each
integration and each match itself. Frontier search runs on the map at the end, as the
map_area task would call it.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

from agv_mission.mapping.frontiers import find_frontiers
from agv_mission.mapping.slam import trajectory_rmse
from agv_mission.maps.builtin_worlds import small_house
from agv_mission.robots.simulation import SimConfig

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from slam_drive import drive  # noqa: E402

ROUTE = ((3.0, -0.45), (-1.5, -0.45), (-1.5, -1.7), (-3.5, -1.7), (-5.5, -1.5), (-5.5, -3.5))
BOUNDS = (-9.5, 9.5, -5.5, 5.5)
NOISY = SimConfig(encoder_noise=0.05, wheel_slip=0.1)


def _percentile(samples: list[float], q: float) -> float:
    return float(np.percentile(np.asarray(samples) * 1e3, q))


def run() -> dict[str, float]:
    world = small_house()
    driven = drive(world, ROUTE, NOISY, bounds=BOUNDS, max_steps=3000)
    slam, est = driven.slam, driven.estimate
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
        "slam.ms_per_sim_s": 1e3 * driven.update_wall / driven.sim_time,
        "slam.frontiers_ms.p50": _percentile(frontier_times, 50),
        "slam.route_rmse_m": trajectory_rmse(est, driven.truth),
    }


if __name__ == "__main__":
    for key, value in run().items():
        print(f"{key:28s} {value:.3f}")
