"""The shortest way (issue 32): plans and drives against the shortest free path.

The yardstick is the shortest free path (:mod:`agv_mission.planners.shortest_free`):
any-angle, in the robot's configuration space (free space shrunk by its radius, no
margin, no inflation cost). Two parts, each with the planner before and after side by
side in this one run:

* **Missions** (``shortest_way.<mission>.<variant>.*``): the demo (``missions/patrol.yaml``),
  ``missions/visit_rooms.yaml`` and a patrol of the real tb3 map (``tests/data/ros_maps/
  turtlebot3_world``, burger, default sensors, ``global_planner: {type: ompl, planner:
  RRTConnect}``), run whole. ``before``: RRTConnect as it was (one run, OMPL's own edge
  length, a fifth of the map's diagonal); ``after``: the defaults. Per leg
  ``leg<i>.planned_vs_shortest_free`` and ``leg<i>.driven_vs_shortest_free`` (the run's
  ``metrics.navigation.legs``), their ``max``, ``succeeded`` and ``planning_ms_mean``.
* **Plans** (``shortest_way.plans.<map>.<planner>.vs_shortest_free.p50`` / ``.max``,
  ``.time_ms.p50``): every leg of a tour on the built-in tb3 arena and the real tb3 and
  house maps, planned by each global planner (OMPL's with seeds 0..2), burger radius,
  inflation 0.3 m; ``ompl_RRTConnect_before`` as above.
* **Exploring** (``shortest_way.explore.<world>.<slam>.*``): ``map_area`` with the
  default sensors of the real AWS house (waffle), the real tb3 map (burger) and the
  built-in 30 x 15 m depot (burger), then a patrol on the saved map, with ``grid``
  SLAM (no loop closure) and ``graph`` SLAM (loop closure): ``succeeded`` (both tasks),
  ``rmse_m`` / ``max_error_m`` (the estimate, after the first 10 s, over the whole run),
  ``free_iou`` (the saved map's free cells against the real map), ``slam_rmse_m``,
  ``goals_cancelled`` (frontier goals given up for another) and ``real_time_factor``.

The plans are timed alone; the whole runs (missions and exploring, 12 runs and most of
this module's time) go two at a time in worker processes, one per core: their figures are
the same as run one by one (each run is reproducible from its seed), and their
``real_time_factor`` / ``planning_ms_mean`` are of a run sharing the machine with another.
"""

from __future__ import annotations

import math
import multiprocessing
import tempfile
from collections.abc import Callable
from concurrent.futures import Future, ProcessPoolExecutor
from pathlib import Path

import numpy as np
import yaml

from agv_mission.geometry import Pose2D
from agv_mission.maps.builtin_worlds import small_house, turtlebot3_world
from agv_mission.maps.costmap import Costmap, CostmapConfig
from agv_mission.maps.grid import OccupancyGrid
from agv_mission.maps.ros_map import load_ros_map
from agv_mission.planners.base import PlanningError
from agv_mission.planners.configs import CostGridConfig, GridAstarConfig, OmplPlannerConfig
from agv_mission.planners.cost_grid import CostGridPlanner
from agv_mission.planners.grid_astar import GridAstarPlanner
from agv_mission.planners.ompl_planner import OmplPlanner
from agv_mission.planners.shortest_free import ShortestFreePath

ROOT = Path(__file__).resolve().parents[1]
ROS_MAPS = ROOT / "tests/data/ros_maps"
TB3_REAL = ROS_MAPS / "turtlebot3_world/map.yaml"
HOUSE_REAL = ROS_MAPS / "aws_small_house/map.yaml"
SEEDS = range(3)
OMPL_DEFAULT_RANGE_SHARE = 0.2  # OMPL's default edge: a fifth of the space's extent


def ompl_default_range(grid: OccupancyGrid) -> float:
    """The edge length OMPL picks itself for a plan on ``grid`` (its bounds' diagonal / 5)."""
    return OMPL_DEFAULT_RANGE_SHARE * math.hypot(
        grid.width * grid.resolution, grid.height * grid.resolution
    )


def tb3_real_mission() -> dict:
    """A patrol of the real tb3 map with OMPL's RRTConnect (the issue's third target)."""
    tour = [(1.13, -1.6), (0.13, 1.93), (-0.55, -0.55), (1.8, 0.5)]
    return {
        "name": "tb3-real-rrtconnect",
        "world": str(TB3_REAL),
        "robot": "burger",
        "start": {"x": -2.0, "y": -0.5, "yaw": 0.0},
        "seed": 5,
        "stack": {"global_planner": {"type": "ompl", "planner": "RRTConnect"}},
        "tasks": [{"type": "patrol", "waypoints": [{"x": x, "y": y, "yaw": 0.0} for x, y in tour]}],
        "limits": {"time": 400.0},
    }


# mission -> (mission document, the map OMPL plans on, for its default edge)
MISSIONS: dict[str, tuple[Callable[[], dict], Callable[[], OccupancyGrid]]] = {
    "demo_patrol": (
        lambda: yaml.safe_load((ROOT / "missions/patrol.yaml").read_text()),
        lambda: turtlebot3_world().map,
    ),
    "visit_rooms": (
        lambda: yaml.safe_load((ROOT / "missions/visit_rooms.yaml").read_text()),
        lambda: small_house().map,
    ),
    "tb3_real_rrtconnect": (tb3_real_mission, lambda: load_ros_map(TB3_REAL)),
}


def _run(mission: dict) -> dict[str, float]:
    from agv_mission.missions.load.loader import load_mission
    from agv_mission.missions.run.runner import run_mission

    with tempfile.TemporaryDirectory() as tmp:
        mission = {**mission, "output": tmp}
        path = Path(tmp) / "mission.yaml"
        path.write_text(yaml.safe_dump(mission))
        record = run_mission(load_mission(path))
    nav = record.metrics["navigation"]
    out = {
        "succeeded": float(record.status == "succeeded"),
        "planning_ms_mean": float(nav["planning_time_ms_mean"] or 0.0),
    }
    legs = [leg for leg in nav["legs"] if leg["planned_vs_shortest_free"] is not None]
    for i, leg in enumerate(legs, 1):
        for key in ("planned_vs_shortest_free", "driven_vs_shortest_free"):
            if leg[key] is not None:
                out[f"leg{i}.{key}"] = float(leg[key])
    for key in ("planned_vs_shortest_free", "driven_vs_shortest_free"):
        values = [leg[key] for leg in legs if leg[key] is not None and leg["status"] == "succeeded"]
        if values:
            out[f"max.{key}"] = float(max(values))
    return out


def mission_variants() -> dict[str, dict]:
    """``<mission>.<variant>`` -> the mission document with its planner before or after."""
    out: dict[str, dict] = {}
    for name, (document, grid) in MISSIONS.items():
        base = document()
        planner = dict(base["stack"].get("global_planner") or {})
        before = {**planner, "restarts": 1, "range": ompl_default_range(grid())}
        for variant, config in (("before", before), ("after", planner)):
            out[f"{name}.{variant}"] = {
                **base,
                "stack": {**base["stack"], "global_planner": config},
            }
    return out


# map -> (grid, tour)
TOURS: dict[str, tuple[Callable[[], OccupancyGrid], list[tuple[float, float]]]] = {
    "turtlebot3_world": (
        lambda: turtlebot3_world().map,
        [(-2.0, -0.5), (1.13, -1.6), (0.13, 1.93), (2.0, 0.0), (-2.0, -0.5)],
    ),
    "tb3_real": (
        lambda: load_ros_map(TB3_REAL),
        [(-2.0, -0.5), (1.13, -1.6), (0.13, 1.93), (-0.55, -0.55), (1.8, 0.5)],
    ),
    "aws_small_house": (
        lambda: load_ros_map(HOUSE_REAL),
        [(3.83, -1.23), (-8.0, 0.0), (7.0, -3.0), (-6.0, -4.0), (4.0, 3.0), (0.0, -4.0)],
    ),
}


def plans() -> dict[str, float]:
    out: dict[str, float] = {}
    shortest = ShortestFreePath()
    for name, (load, tour) in TOURS.items():
        grid = load()
        costmap = Costmap.from_grid(grid, 0.105, CostmapConfig(inflation_radius=0.3))
        poses = [Pose2D(x, y) for x, y in tour]
        legs = list(zip(poses[:-1], poses[1:], strict=True))
        reference = [shortest.length(costmap, a, b) for a, b in legs]
        planners: dict[str, tuple[object, range]] = {
            "cost_grid": (CostGridPlanner(CostGridConfig()), range(1)),
            "grid_astar": (GridAstarPlanner(GridAstarConfig()), range(1)),
            "ompl_RRTConnect_before": (
                OmplPlanner(OmplPlannerConfig(restarts=1, range=ompl_default_range(grid))),
                SEEDS,
            ),
            **{
                f"ompl_{p}": (OmplPlanner(OmplPlannerConfig(planner=p)), SEEDS)
                for p in ("RRTConnect", "RRTstar", "BITstar")
            },
        }
        for key, (planner, seeds) in planners.items():
            ratios, times = [], []
            for seed in seeds:
                for (a, b), ref in zip(legs, reference, strict=True):
                    try:
                        path = planner.plan(costmap, a, b, seed=seed)  # type: ignore[attr-defined]
                    except PlanningError:
                        continue
                    if ref:
                        ratios.append(path.length / ref)
                    times.append(path.planning_time)
            prefix = f"shortest_way.plans.{name}.{key}"
            out[f"{prefix}.vs_shortest_free.p50"] = float(np.median(ratios))
            out[f"{prefix}.vs_shortest_free.max"] = float(np.max(ratios))
            out[f"{prefix}.time_ms.p50"] = float(np.median(times) * 1e3)
    return out


# world -> (world spec, robot, start, patrol on the saved map)
EXPLORE: dict[str, tuple[str, str, tuple[float, float], list[tuple[float, float]]]] = {
    "aws_small_house": (str(HOUSE_REAL), "waffle", (3.83, -1.23), [(-6.0, -1.0), (7.0, -3.0)]),
    "tb3_real": (str(TB3_REAL), "burger", (-2.0, -0.5), [(1.13, -1.6), (0.13, 1.93)]),
    "depot": ("depot", "burger", (-12.0, 0.0), [(12.0, -4.5), (0.0, 4.0)]),
}
EXPLORE_SLAM = ("grid", "graph")  # the map_area SLAM before (grid) and after (graph)


def explore_mission(world: str, slam: str) -> dict:
    """``map_area`` with the default sensors, then a patrol on the map it saved."""
    spec, robot, (x, y), patrol = EXPLORE[world]
    return {
        "name": f"explore-{world}-{slam}",
        "world": spec,
        "robot": robot,
        "start": {"x": x, "y": y, "yaw": 0.0},
        "seed": 1,
        "stack": {"slam": {"type": slam}, "localization": {"type": "amcl"}},
        "tasks": [
            {"type": "map_area", "save_map": "explored"},
            {"type": "patrol", "waypoints": [{"x": px, "y": py, "yaw": 0.0} for px, py in patrol]},
        ],
        "limits": {"time": 2400.0},
    }


def _explore_run(world: str, slam: str) -> dict[str, float]:
    from agv_mission.missions.load.loader import load_mission
    from agv_mission.missions.run.runner import run_mission

    with tempfile.TemporaryDirectory() as tmp:
        mission = {**explore_mission(world, slam), "output": tmp}
        path = Path(tmp) / "mission.yaml"
        path.write_text(yaml.safe_dump(mission))
        record = run_mission(load_mission(path))
    loc = record.metrics["localization"]
    legs = record.metrics["navigation"]["legs"]
    maps = record.extras.get("maps") or [{}]
    out = {
        "succeeded": float(record.status == "succeeded"),
        "rmse_m": float(loc.get("position_rmse_settled") or math.nan),
        "max_error_m": float(loc.get("position_max_error_settled") or math.nan),
        "free_iou": float(maps[0].get("free_iou", math.nan)),
        "slam_rmse_m": float(maps[0].get("slam_rmse", math.nan)),
        "goals_cancelled": float(sum(leg["status"] == "cancelled" for leg in legs)),
        "real_time_factor": float(record.metrics.get("real_time_factor") or math.nan),
    }
    return {k: v for k, v in out.items() if not math.isnan(v)}  # (no map saved: no IoU)


def whole_runs(workers: int = 2) -> dict[str, float]:
    """The missions (``shortest_way.<mission>.<variant>.*``) and each world mapped with
    each SLAM then patrolled (``shortest_way.explore.<world>.<slam>.*``), ``workers`` at
    a time, the longest (exploring) first."""
    context = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max_workers=workers, mp_context=context) as pool:
        futures: dict[str, Future[dict[str, float]]] = {
            f"explore.{world}.{slam}": pool.submit(_explore_run, world, slam)
            for world in EXPLORE
            for slam in EXPLORE_SLAM
        }
        for prefix, mission in mission_variants().items():
            futures[prefix] = pool.submit(_run, mission)
        return {
            f"shortest_way.{prefix}.{key}": value
            for prefix, future in sorted(futures.items())
            for key, value in future.result().items()
        }


def run() -> dict[str, float]:
    return {**plans(), **whole_runs()}


if __name__ == "__main__":
    for key, value in run().items():
        print(f"{key:75s} {value:10.4f}")
