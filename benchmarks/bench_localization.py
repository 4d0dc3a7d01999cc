"""Localisation accuracy per map and robot: the whole stack, the estimate against the truth.

One patrol per (map, robot, amcl profile), with the sensors' default (realistic) errors:
the demo on the built-in turtlebot3_world and small_house, the real ROS maps
(turtlebot3_world, AWS small house) read from ``tests/data/ros_maps``, and the
30 x 50 m warehouse and 30 x 15 m depot of ``tests/worlds``. Per run: position RMSE and
maximum error after the first 10 s, the RMSE of odometry alone on the same run (the start
pose composed with the encoders' dead reckoning), the share of steps whose true error lies
in the reported 2-sigma ellipse, and the localiser's cost per scan (filter + refinement,
p50 / p99 ms of ``update`` calls that carry a scan). The ``turtlebot3`` rows are amcl alone.

The ``map_*`` rows give the robot a ``map:`` that is not the world: the house mapped by an
earlier ``map_area`` run (``tests/fixtures/maps``, made by ``make_small_house_slam.py``
there), the real AWS house mapped by ``agv-mission map`` from the bag of an earlier patrol
(``benchmarks/data/house_patrol.yaml``, bench_bags' round trip), and furniture moved
(boxes in the world the map lacks, and a box on the map the world lacks) in the house,
depot and warehouse.
"""

from __future__ import annotations

import math
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
from rich.table import Table

from agv_mission.bags.offline import default_slam, map_bag
from agv_mission.bags.writer import BagWriter
from agv_mission.geometry import Pose2D
from agv_mission.maps.ros_map import save_ros_map
from agv_mission.maps.world_loader import load_world
from agv_mission.missions.load.loader import load_mission
from agv_mission.missions.run.metrics import SETTLE_TIME
from agv_mission.missions.run.runner import MissionRun, run_mission

REPO = Path(__file__).resolve().parents[1]
ROS_MAPS = REPO / "tests" / "data" / "ros_maps"
WORLDS = REPO / "tests" / "worlds"
MAPS = REPO / "tests" / "fixtures" / "maps"

MISSION = """
name: bench-loc
world: {world}
{map}robot: {robot}
start: {{x: {sx}, y: {sy}, yaw: 0.0}}
seed: 3
stack:
  localization: {{type: amcl, profile: {profile}}}
  global_planner: {{type: grid_astar}}
  local_planner: {{type: mpc}}
tasks:
  - type: patrol
    waypoints: [{waypoints}]
    on_failure: skip
limits: {{time: 1200}}
{obstacles}"""

TB3 = ((-2.0, -0.5), [(1.13, -1.6, 0.333), (0.13, 1.93, 1.389)])  # the demo's goals
HOUSE = (
    (3.83, -1.23),
    [(6.5, -2.0, 0.0), (2.0, 1.0, 3.14), (-1.5, 2.5, 1.57), (-5.0, -3.0, 3.14), (-6.0, 0.0, 0)],
)
WAREHOUSE = ((2.0, 2.0), [(6.0, 24.0, 1.57), (6.0, 47.5, 0.0), (18.0, 47.5, -1.57), (26.0, 4.0, 0)])
DEPOT = ((2.0, 2.0), [(15.0, 7.5, 0.0), (27.0, 12.5, 1.57), (12.5, 7.5, 3.14), (3.0, 12.5, 1.57)])

# (key, world, route, robot, profile)
CASES: list[tuple[str, str, Any, str, str]] = [
    ("turtlebot3_world", "turtlebot3_world", TB3, "burger", "accurate"),
    ("turtlebot3_world", "turtlebot3_world", TB3, "burger", "turtlebot3"),
    ("small_house", "small_house", HOUSE, "burger", "accurate"),
    (
        "ros_turtlebot3_world",
        str(ROS_MAPS / "turtlebot3_world" / "map.yaml"),
        TB3,
        "burger",
        "accurate",
    ),
    (
        "ros_aws_small_house",
        str(ROS_MAPS / "aws_small_house" / "map.yaml"),
        HOUSE,
        "waffle",
        "accurate",
    ),
    (
        "ros_aws_small_house",
        str(ROS_MAPS / "aws_small_house" / "map.yaml"),
        HOUSE,
        "burger",
        "accurate",
    ),
    (
        "ros_aws_small_house",
        str(ROS_MAPS / "aws_small_house" / "map.yaml"),
        HOUSE,
        "waffle",
        "turtlebot3",
    ),
    ("warehouse_30x50", str(WORLDS / "loc_warehouse.yaml"), WAREHOUSE, "waffle", "accurate"),
    ("warehouse_30x50", str(WORLDS / "loc_warehouse.yaml"), WAREHOUSE, "waffle", "turtlebot3"),
    ("depot_30x15", str(WORLDS / "loc_depot.yaml"), DEPOT, "burger", "accurate"),
    ("depot_30x15", str(WORLDS / "loc_depot.yaml"), DEPOT, "burger", "turtlebot3"),
]

# Furniture moved since the map was made: (x, y, size_x, size_y) boxes the world has and
# the map lacks, and boxes on the map the world lacks (all off the routes' waypoints).
MOVED: dict[str, tuple[list[tuple[float, ...]], list[tuple[float, ...]]]] = {
    "small_house": ([(0.5, -3.5, 0.6, 0.6), (4.5, 2.0, 0.5, 0.8)], [(-3.0, -1.0, 0.6, 0.6)]),
    "depot": ([(8.0, 7.5, 1.0, 1.0), (18.0, 12.0, 0.8, 0.8)], [(12.5, 2.5, 1.0, 1.0)]),
    "warehouse": ([(4.0, 12.0, 0.8, 0.8), (12.0, 47.0, 1.0, 0.6)], [(8.0, 30.0, 1.0, 1.0)]),
}

# (key, world, map ("moved": the world's map with MOVED's map boxes; "bag": bag_map's),
# route, robot, moved)
MAP_CASES: list[tuple[str, str, str, Any, str, str | None]] = [
    ("map_slam_house", "small_house", str(MAPS / "small_house_slam.yaml"), HOUSE, "burger", None),
    ("map_bag_house", str(ROS_MAPS / "aws_small_house" / "map.yaml"), "bag", HOUSE, "burger", None),
    ("map_moved_house", "small_house", "moved", HOUSE, "burger", "small_house"),
    ("map_moved_depot", str(WORLDS / "loc_depot.yaml"), "moved", DEPOT, "burger", "depot"),
    (
        "map_moved_warehouse",
        str(WORLDS / "loc_warehouse.yaml"),
        "moved",
        WAREHOUSE,
        "waffle",
        "warehouse",
    ),
]

COLUMNS = (
    "rmse_m",
    "max_error_m",
    "odom_rmse_m",
    "consistency_2sigma",
    "update_ms_p50",
    "update_ms_p99",
)


def moved_map(world: str, boxes: list[tuple[float, ...]], out_dir: Path) -> Path:
    """The world's own map with ``boxes`` (x, y, size_x, size_y) drawn in, as a map_server
    YAML in ``out_dir``."""
    grid = load_world(world, REPO).map
    data = np.array(grid.data, copy=True)
    ys, xs = np.mgrid[0 : grid.height, 0 : grid.width]
    cx = grid.origin.x + (xs + 0.5) * grid.resolution
    cy = grid.origin.y + (ys + 0.5) * grid.resolution
    for x, y, sx, sy in boxes:
        data[(np.abs(cx - x) <= sx / 2) & (np.abs(cy - y) <= sy / 2)] = 100
    moved = type(grid)(data=data, resolution=grid.resolution, origin=grid.origin)
    return save_ros_map(moved, out_dir / "moved_map")[1]


def bag_map(out_dir: Path) -> Path:
    """The map ``agv-mission map`` makes of the house patrol's bag (a run of
    ``benchmarks/data/house_patrol.yaml`` recorded in ``out_dir``), as map_server files."""
    loaded = load_mission(REPO / "benchmarks" / "data" / "house_patrol.yaml")
    run_dir = out_dir / "house_patrol"
    run_dir.mkdir()
    run_mission(loaded, run_dir, observers=[BagWriter()])
    result = map_bag(run_dir / "bag", default_slam([]))
    return save_ros_map(result.grid, out_dir / "bag_map")[1]


def obstacles_yaml(boxes: list[tuple[float, ...]]) -> str:
    items = "".join(
        f"  - {{type: box, x: {x}, y: {y}, size_x: {sx}, size_y: {sy}}}\n" for x, y, sx, sy in boxes
    )
    return "obstacles:\n" + items if items else ""


def run_case(
    world: str,
    route: Any,
    robot: str,
    profile: str,
    map_path: str | None = None,
    obstacles: str = "",
) -> dict[str, float]:
    (sx, sy), waypoints = route
    wps = ", ".join(f"{{x: {x}, y: {y}, yaw: {yaw}}}" for x, y, yaw in waypoints)
    text = MISSION.format(
        world=world,
        map=f"map: {map_path}\n" if map_path else "",
        robot=robot,
        sx=sx,
        sy=sy,
        profile=profile,
        waypoints=wps,
        obstacles=obstacles,
    )
    run = MissionRun(load_mission(REPO / "bench.yaml", text=text), None)
    costs: list[float] = []
    update = run.localizer.update
    start = run.loaded.start
    odom0: list[Pose2D] = []
    odom_err: list[float] = []

    def timed(odom, scan, truth, now):  # noqa: ANN001, ANN202 - the Localizer signature
        if not odom0:
            odom0.append(odom)
        dead = start.compose(odom.relative_to(odom0[0]))
        if now >= SETTLE_TIME:
            odom_err.append(math.hypot(dead.x - truth.x, dead.y - truth.y))
        t0 = time.perf_counter()
        out = update(odom, scan, truth, now)
        if scan is not None:
            costs.append(time.perf_counter() - t0)
        return out

    run.localizer.update = timed
    while run.step():
        pass
    record = run.record()
    loc = record.metrics["localization"]
    ms = np.asarray(costs) * 1e3
    return {
        "rmse_m": loc["position_rmse_settled"],
        "max_error_m": loc["position_max_error_settled"],
        "odom_rmse_m": round(float(np.sqrt(np.mean(np.square(odom_err)))), 5),
        "consistency_2sigma": loc.get("consistency_2sigma", float("nan")),
        "update_ms_p50": round(float(np.percentile(ms, 50)), 3),
        "update_ms_p99": round(float(np.percentile(ms, 99)), 3),
        "succeeded": float(record.status == "succeeded"),
    }


def run() -> dict[str, float]:
    out: dict[str, float] = {}
    for key, world, route, robot, profile in CASES:
        if not world.endswith(".yaml") or Path(world).is_file():
            values = run_case(world, route, robot, profile)
            for name, value in values.items():
                out[f"localization.{key}.{robot}.{profile}.{name}"] = value
    with tempfile.TemporaryDirectory() as tmp:
        for key, world, map_spec, route, robot, moved in MAP_CASES:
            extra, gone = MOVED[moved] if moved else ([], [])
            if map_spec == "moved":
                map_spec = str(moved_map(world, gone, Path(tmp)))
            elif map_spec == "bag":
                map_spec = str(bag_map(Path(tmp)))
            values = run_case(world, route, robot, "accurate", map_spec, obstacles_yaml(extra))
            for name, value in values.items():
                out[f"localization.{key}.{robot}.accurate.{name}"] = value
    return out


def tables(results: dict[str, float]) -> list[Table]:
    """One table per map: a row per robot and profile."""
    out = []
    for key in dict.fromkeys([*(c[0] for c in CASES), *(c[0] for c in MAP_CASES)]):
        table = Table(title=f"localisation on {key}", header_style="bold")
        for col in ("robot", "profile", *COLUMNS):
            table.add_column(col, justify="right" if col in COLUMNS else "left")
        rows = [(c[3], c[4]) for c in CASES if c[0] == key]
        rows += [(c[4], "accurate") for c in MAP_CASES if c[0] == key]
        for robot, profile in rows:
            prefix = f"localization.{key}.{robot}.{profile}."
            if prefix + "rmse_m" in results:
                table.add_row(robot, profile, *(f"{results[prefix + c]:.4g}" for c in COLUMNS))
        out.append(table)
    return out


if __name__ == "__main__":
    from rich.console import Console

    results = run()
    for t in tables(results):
        Console().print(t)
