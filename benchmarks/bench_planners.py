"""Global planners per map: planned / shortest, planning time, driven / shortest.

Maps: the built-in ``turtlebot3_world``, ``warehouse`` (30 x 50 m) and ``depot``
(30 x 15 m), and the real ``map_saver`` maps ``tests/data/ros_maps/{turtlebot3_world,
aws_small_house}`` (skipped when missing). Each map has a tour; every planner plans
every leg (RRTConnect, RRTstar and BITstar with seeds 0..2, the deterministic planners
three times; on the two small maps every other planner OMPL's bindings expose, seed 0).
Robot radius 0.22 m (waffle) on the large worlds, 0.105 m (burger) elsewhere; inflation
0.3 m. OMPL plans are OMPL's own (the costmap's cost through OMPL's objective and its
path simplifier).

Keys ``planners.<map>.<planner>.<metric>``:

* ``planned_vs_shortest.p50`` / ``.max``: global path length / the shortest path at the
  same clearance (``grid_astar`` with ``cost_weight: 0`` over every cell, any-angle
  smoothed).
* ``time_ms.p50`` / ``time_ms.p90``: wall time of one plan. cost_grid reuses its coarse
  graph while the costmap is unchanged (as in a run); ``cold`` is a fresh planner each time.
* ``failures``: plans that raised PlanningError.
* ``drive.*``: a patrol of the tour in simulation (ground-truth localisation, MPC) with
  cost_grid, RRTConnect, RRTstar and BITstar: per leg planned / shortest and driven /
  shortest (the run's own shortest path per leg), their mean and worst over the legs,
  ``driven_vs_planned_max``, ``stops`` and ``succeeded``.

``planners.warehouse_50m.cost_grid.time_ms.p50``: the 50 m leg dock -> back of the
warehouse (target < 50 ms), planned again and again (the coarse graph reused); ``cold_time_ms``
with a fresh planner each time. ``plain_dijkstra.time_ms.p50``: scipy's Dijkstra over every
free cell, measured interleaved as a yardstick of the machine's speed; the ratio
``cost_grid_over_plain_dijkstra`` does not depend on how busy the machine is.
"""

from __future__ import annotations

import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import yaml
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra

from agv_mission.geometry import Pose2D
from agv_mission.maps.builtin_worlds import depot, turtlebot3_world, warehouse
from agv_mission.maps.costmap import Costmap, CostmapConfig
from agv_mission.maps.grid import OccupancyGrid
from agv_mission.planners.base import PlanningError
from agv_mission.planners.configs import CostGridConfig, available_planners
from agv_mission.planners.cost_grid import CostGridPlanner
from agv_mission.planners.grid_astar import GridAstarConfig, GridAstarPlanner
from agv_mission.planners.ompl_planner import OmplPlanner, OmplPlannerConfig

ROS_MAPS = Path(__file__).resolve().parents[1] / "tests/data/ros_maps"
OMPL_PLANNERS = ("RRTConnect", "RRTstar", "BITstar")
ALL_PLANNER_MAPS = ("turtlebot3_world", "aws_small_house")  # every bound planner there
DRIVE_PLANNERS = {
    "cost_grid": {"type": "cost_grid"},
    **{f"ompl_{n}": {"type": "ompl", "planner": n} for n in OMPL_PLANNERS},
}
SEEDS = range(3)
INFLATION = 0.3


def _ros(name: str) -> Callable[[], OccupancyGrid] | None:
    path = ROS_MAPS / name / "map.yaml"
    if not path.is_file():
        return None

    def load() -> OccupancyGrid:
        from agv_mission.maps.ros_map import load_ros_map

        return load_ros_map(path)

    return load


# name -> (world spec for a mission, map loader, robot, tour)
MAPS: dict[str, tuple[str, Callable[[], OccupancyGrid] | None, str, list[tuple[float, float]]]] = {
    "turtlebot3_world": (
        "turtlebot3_world",
        lambda: turtlebot3_world().map,
        "burger",
        [(-2.0, -0.5), (1.13, -1.6), (0.13, 1.93), (2.0, 0.0)],
    ),
    "tb3_real": (
        str(ROS_MAPS / "turtlebot3_world/map.yaml"),
        _ros("turtlebot3_world"),
        "burger",
        [(-2.0, -0.5), (1.13, -1.6), (0.13, 1.93), (-0.55, -0.55)],
    ),
    "aws_small_house": (
        str(ROS_MAPS / "aws_small_house/map.yaml"),
        _ros("aws_small_house"),
        "burger",
        [(3.83, -1.23), (-8.0, 0.0), (7.0, -3.0), (-6.0, -4.0), (4.0, 3.0), (0.0, -4.0)],
    ),
    "warehouse": (
        "warehouse",
        lambda: warehouse().map,
        "waffle",
        [(0.0, -22.0), (-9.0, -10.0), (5.4, 10.0), (13.2, -20.0), (-1.8, 17.0)],
    ),
    "depot": (
        "depot",
        lambda: depot().map,
        "waffle",
        [(-12.0, 0.0), (12.0, -4.5), (0.0, 4.0), (-12.0, -5.0)],
    ),
}
RADIUS = {"burger": 0.105, "waffle": 0.22}


def _stats(prefix: str, times: list[float], ratios: list[float], failures: int) -> dict:
    out = {f"{prefix}.failures": float(failures)}
    if times:
        out[f"{prefix}.time_ms.p50"] = float(np.percentile(times, 50) * 1e3)
        out[f"{prefix}.time_ms.p90"] = float(np.percentile(times, 90) * 1e3)
    if ratios:
        out[f"{prefix}.planned_vs_shortest.p50"] = float(np.median(ratios))
        out[f"{prefix}.planned_vs_shortest.max"] = float(np.max(ratios))
    return out


def _plans(
    costmap: Costmap, legs: list, reference: list[float], every_planner: bool
) -> dict[str, float]:
    out: dict[str, float] = {}
    planners: dict[str, tuple[Callable[[], object], range]] = {
        "cost_grid": (lambda: CostGridPlanner(CostGridConfig()), range(3)),
        "grid_astar": (lambda: GridAstarPlanner(GridAstarConfig()), range(1)),
    }
    names = available_planners() if every_planner else OMPL_PLANNERS
    for name in names:
        planners[f"ompl_{name}"] = (
            lambda name=name: OmplPlanner(OmplPlannerConfig(planner=name)),
            SEEDS if name in OMPL_PLANNERS else range(1),
        )
    for key, (make, seeds) in planners.items():
        planner = make()
        times, ratios, failures = [], [], 0
        for seed in seeds:
            for (a, b), ref in zip(legs, reference, strict=True):
                try:
                    path = planner.plan(costmap, a, b, seed=seed)  # type: ignore[attr-defined]
                except PlanningError:
                    failures += 1
                    continue
                times.append(path.planning_time)
                ratios.append(path.length / ref)
        out.update(_stats(key, times, ratios, failures))
    cold = []
    for a, b in legs:
        t0 = time.perf_counter()
        CostGridPlanner(CostGridConfig()).plan(costmap, a, b)
        cold.append(time.perf_counter() - t0)
    out["cost_grid.cold_time_ms.p50"] = float(np.median(cold) * 1e3)
    return out


def _drive(world: str, robot: str, tour: list, planner: dict) -> dict[str, float]:
    """Patrol the tour in simulation; the worst leg's ratios and the stops."""
    from agv_mission.missions.load.loader import load_mission
    from agv_mission.missions.run.runner import run_mission

    mission = {
        "name": "bench-drive",
        "world": world,
        "robot": robot,
        "start": {"x": tour[0][0], "y": tour[0][1], "yaw": 0.0},
        "seed": 1,
        "stack": {"localization": {"type": "ground_truth"}, "global_planner": planner},
        "tasks": [
            {
                "type": "patrol",
                "waypoints": [{"x": x, "y": y, "yaw": 0.0} for x, y in tour[1:]],
                "loops": 1,
            }
        ],
        "limits": {"time": 1500.0},
    }
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "mission.yaml"
        path.write_text(yaml.safe_dump(mission))
        record = run_mission(load_mission(path))
    nav = record.metrics["navigation"]
    out = {
        "drive.succeeded": float(record.status == "succeeded"),
        "drive.stops": float(nav["stops"]),
    }
    done = [leg for leg in nav["legs"] if leg["status"] == "succeeded"]
    for key in ("planned_vs_shortest", "driven_vs_shortest", "driven_vs_planned"):
        values = [leg[key] for leg in done if leg[key] is not None]
        if values:
            out[f"drive.{key}.mean"] = float(np.mean(values))
            out[f"drive.{key}.max"] = float(np.max(values))
    return out


def _plain_dijkstra_time(costmap: Costmap, start: Pose2D) -> float:
    """A yardstick for the machine's speed: scipy's Dijkstra over every free cell of the
    map (8-connected, unit costs, graph built with COO), as a first try would do it."""
    t0 = time.perf_counter()
    free = costmap.distance > costmap.robot_radius + 0.05
    h, w = free.shape
    index = np.arange(h * w).reshape(h, w)
    src, dst, wts = [], [], []
    for dr, dc, length in ((0, 1, 1.0), (1, 0, 1.0), (1, 1, 2**0.5), (1, -1, 2**0.5)):
        c0, c1 = max(0, -dc), w - max(0, dc)
        ok = free[: h - dr, c0:c1] & free[dr:, c0 + dc : c1 + dc]
        a = index[: h - dr, c0:c1][ok]
        src += [a, a + dr * w + dc]
        dst += [a + dr * w + dc, a]
        wts += [np.full(a.size, length)] * 2
    graph = coo_matrix(
        (np.concatenate(wts), (np.concatenate(src), np.concatenate(dst))), shape=(h * w, h * w)
    ).tocsr()
    row, col = costmap.grid.world_to_cell(np.array([start.x, start.y]))
    dijkstra(graph, indices=int(row) * w + int(col))
    return time.perf_counter() - t0


def run() -> dict[str, float]:
    out: dict[str, float] = {}
    for name, (world, load, robot, tour) in MAPS.items():
        if load is None:
            continue
        costmap = Costmap.from_grid(
            load(), RADIUS[robot], CostmapConfig(inflation_radius=INFLATION)
        )
        poses = [Pose2D(x, y) for x, y in tour]
        legs = list(zip(poses, poses[1:], strict=False))
        shortest = GridAstarPlanner(GridAstarConfig(cost_weight=0.0))
        reference = [shortest.plan(costmap, a, b).length for a, b in legs]
        plans = _plans(costmap, legs, reference, name in ALL_PLANNER_MAPS)
        out.update({f"planners.{name}.{k}": v for k, v in plans.items()})
        for key, planner in DRIVE_PLANNERS.items():
            for k, v in _drive(world, robot, tour, planner).items():
                out[f"planners.{name}.{key}.{k}"] = v
    # the 50 m leg on the 30 x 50 m warehouse
    costmap = Costmap.from_grid(warehouse().map, 0.22, CostmapConfig(inflation_radius=INFLATION))
    planner = CostGridPlanner(CostGridConfig())
    a, b = Pose2D(0.0, -22.0), Pose2D(5.4, 22.0)
    times, plain = [], []
    for i in range(15):  # interleaved with the yardstick: the machine's speed drifts
        times.append(planner.plan(costmap, a, b).planning_time)
        if i % 3 == 0:
            plain.append(_plain_dijkstra_time(costmap, a))
    out["planners.warehouse_50m.cost_grid.time_ms.p50"] = float(np.median(times) * 1e3)
    out["planners.warehouse_50m.plain_dijkstra.time_ms.p50"] = float(np.median(plain) * 1e3)
    out["planners.warehouse_50m.cost_grid_over_plain_dijkstra"] = float(
        np.median(times) / np.median(plain)
    )
    cold = []
    for _ in range(5):
        t0 = time.perf_counter()
        CostGridPlanner(CostGridConfig()).plan(costmap, a, b)
        cold.append(time.perf_counter() - t0)
    out["planners.warehouse_50m.cost_grid.cold_time_ms.p50"] = float(np.median(cold) * 1e3)
    out["planners.warehouse_50m.cost_grid.length_m"] = planner.plan(costmap, a, b).length
    return out


if __name__ == "__main__":
    for key, value in run().items():
        print(f"{key:60s} {value:10.4f}")
