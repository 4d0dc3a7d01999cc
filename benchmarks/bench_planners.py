"""Global planners: planning time and path length on the real aws small house map.

A tour of seven legs across the rooms of the ``aws_small_house`` ROS map (the
synthetic built-in ``small_house`` world when the shared map is missing), robot radius
0.105 m, inflation 0.3 m, default planner configs (time_limit 1 s, clearance 0.05 m).
Each OMPL planner plans every leg with seeds 0..4.

* ``<planner>.time_ms``: median wall time of one plan (all legs and seeds).
* ``<planner>.length_ratio``: median over plans of length / reference length, the
  reference being the shortest smoothed grid path (``grid_astar`` with
  ``cost_weight: 0``); ``grid_astar.length_ratio`` is the default, cost-aware
  grid_astar (it keeps away from walls, so it is a little longer).
* ``<planner>.length_ratio_p90``: 90th percentile of the same ratio.
* ``<planner>.failures``: plans that raised PlanningError (failures are left out of
  the medians).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from agv_mission.geometry import Pose2D
from agv_mission.maps.costmap import Costmap, CostmapConfig
from agv_mission.planners.base import PlanningError
from agv_mission.planners.grid_astar import GridAstarConfig, GridAstarPlanner
from agv_mission.planners.ompl_planner import OmplPlanner, OmplPlannerConfig

ROS_MAP = Path(__file__).resolve().parents[2] / "shared/data/ros_maps/aws_small_house/map.yaml"
PLANNERS = ("RRTConnect", "RRTstar", "PRMstar", "BITstar", "InformedRRTstar")
SEEDS = range(5)
# Living room (spawn) -> bedroom -> kitchen -> bedroom corner -> recreation room -> ...
TOUR = [
    (3.83, -1.23),
    (-8.0, 0.0),
    (7.0, -3.0),
    (-6.0, -4.0),
    (4.0, 3.0),
    (-8.5, -4.5),
    (0.0, -4.0),
]
SYNTHETIC_TOUR = [(3.83, -1.23), (-5.5, -1.5), (7.0, -2.0), (-0.5, 1.8), (-8.5, 2.0), (8.5, 2.0)]


def _setting() -> tuple[Costmap, list[tuple[Pose2D, Pose2D]]]:
    if ROS_MAP.is_file():
        from agv_mission.maps.ros_map import load_ros_map

        grid, tour = load_ros_map(ROS_MAP), TOUR
    else:
        from agv_mission.maps.builtin_worlds import small_house

        grid, tour = small_house().map, SYNTHETIC_TOUR
    costmap = Costmap.from_grid(grid, 0.105, CostmapConfig(inflation_radius=0.3))
    poses = [Pose2D(x, y) for x, y in tour]
    return costmap, list(zip(poses, poses[1:] + poses[:1], strict=True))


def _summary(prefix: str, times: list[float], ratios: list[float], failures: int) -> dict:
    return {
        f"{prefix}.time_ms": float(np.median(times) * 1e3) if times else float("nan"),
        f"{prefix}.length_ratio": float(np.median(ratios)) if ratios else float("nan"),
        f"{prefix}.length_ratio_p90": float(np.percentile(ratios, 90)) if ratios else float("nan"),
        f"{prefix}.failures": float(failures),
    }


def run() -> dict[str, float]:
    costmap, legs = _setting()
    shortest = GridAstarPlanner(GridAstarConfig(cost_weight=0.0))
    reference = [shortest.plan(costmap, a, b).length for a, b in legs]

    out: dict[str, float] = {}
    grid = GridAstarPlanner(GridAstarConfig())
    times, ratios = [], []
    for _ in range(3):
        for (a, b), ref in zip(legs, reference, strict=True):
            path = grid.plan(costmap, a, b)
            times.append(path.planning_time)
            ratios.append(path.length / ref)
    out.update(_summary("grid_astar", times, ratios, 0))

    for name in PLANNERS:
        planner = OmplPlanner(OmplPlannerConfig(planner=name))
        times, ratios, failures = [], [], 0
        for seed in SEEDS:
            for (a, b), ref in zip(legs, reference, strict=True):
                try:
                    path = planner.plan(costmap, a, b, seed=seed)
                except PlanningError:
                    failures += 1
                    continue
                times.append(path.planning_time)
                ratios.append(path.length / ref)
        out.update(_summary(f"ompl.{name}", times, ratios, failures))
    return out


if __name__ == "__main__":
    for key, value in run().items():
        print(f"{key:36s} {value:10.3f}")
