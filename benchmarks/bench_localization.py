"""Localisation accuracy per map and robot: the whole stack, the estimate against the truth.

One patrol per (map, robot, amcl profile): the demo on the built-in turtlebot3_world, the
real ROS maps (turtlebot3_world, AWS small house) read from ``tests/data/ros_maps``,
and the 30 x 50 m warehouse and 30 x 15 m depot of ``tests/worlds``. Per run: position
RMSE and maximum error after the first 10 s, the share of steps whose true error lies in
the reported 2-sigma ellipse, and the localiser's cost per scan (filter + refinement,
p50 / p99 ms of ``update`` calls that carry a scan). The ``turtlebot3`` rows are amcl alone.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np
from rich.table import Table

from agv_mission.missions.loader import load_mission
from agv_mission.missions.runner import MissionRun

REPO = Path(__file__).resolve().parents[1]
ROS_MAPS = REPO / "tests" / "data" / "ros_maps"
WORLDS = REPO / "tests" / "worlds"

MISSION = """
name: bench-loc
world: {world}
robot: {robot}
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
"""

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

COLUMNS = ("rmse_m", "max_error_m", "consistency_2sigma", "update_ms_p50", "update_ms_p99")


def run_case(world: str, route: Any, robot: str, profile: str) -> dict[str, float]:
    (sx, sy), waypoints = route
    wps = ", ".join(f"{{x: {x}, y: {y}, yaw: {yaw}}}" for x, y, yaw in waypoints)
    text = MISSION.format(world=world, robot=robot, sx=sx, sy=sy, profile=profile, waypoints=wps)
    run = MissionRun(load_mission(REPO / "bench.yaml", text=text), None)
    costs: list[float] = []
    update = run.localizer.update

    def timed(odom, scan, truth, now):  # noqa: ANN001, ANN202 - the Localizer signature
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
    return out


def tables(results: dict[str, float]) -> list[Table]:
    """One table per map: a row per robot and profile."""
    out = []
    for key in dict.fromkeys(case[0] for case in CASES):
        table = Table(title=f"localisation on {key}", header_style="bold")
        for col in ("robot", "profile", *COLUMNS):
            table.add_column(col, justify="right" if col in COLUMNS else "left")
        for _, _, _, robot, profile in (c for c in CASES if c[0] == key):
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
