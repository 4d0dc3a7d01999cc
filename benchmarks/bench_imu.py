"""The IMU (issue 32): odometry and localisation with the gyro fused and without, side by
side in one run.

Nav2's depot (the built-in ``depot``, 30 x 15 m with columns), burger, default sensors,
two routes (round the columns, and through the open middle where the LDS-01's 3.5 m sees
nothing), each with ``stack.odometry.imu`` true and false: the localiser's (amcl,
``accurate``) position RMSE and maximum after the first 10 s, the same run's odometry
alone (start pose composed with the odometry: wheels, or wheels + gyro), and the
consistency of the reported covariance (share of steps inside the 2-sigma ellipse, its
mean radius over the mean error). Then the odometry localiser (``type: odometry``: the
robot drives on dead reckoning) on the same routes. Last, the demo patrol's cost per
simulated second with the bag written, IMU on and off, alternated (the machine's speed
moves within seconds): ``demo_real_time_factor`` is simulated seconds per CPU second.

And the covariance's honesty (issue 32): the demo patrol and patrols on the real ROS maps
(turtlebot3_world, AWS small house) with amcl's refinement flooring its covariance at the
fit's residual RMS (before: ``refine_split_scale: 0, refine_floor_xy: 0.01``) and at the
disagreement of the scan's halves (after, the defaults): the share of steps inside the
2-sigma ellipse and its mean radius over the mean error.
"""

from __future__ import annotations

import math
import tempfile
import time
from pathlib import Path
from typing import Any

import bench_localization as bl
import numpy as np
from rich.table import Table

from agv_mission.bags.writer import BagWriter
from agv_mission.geometry import Pose2D
from agv_mission.missions.load.loader import load_mission
from agv_mission.missions.run.metrics import SETTLE_TIME
from agv_mission.missions.run.runner import MissionRun, run_mission

REPO = Path(__file__).resolve().parents[1]

MISSION = """
name: bench-imu
world: depot
robot: burger
start: {{x: -12.0, y: 0.0, yaw: 0.0}}
seed: {seed}
stack:
  localization: {localization}
  odometry: {{imu: {imu}}}
tasks:
  - type: patrol
    waypoints: [{waypoints}]
    on_failure: skip
limits: {{time: 900}}
"""

ROUTES = {
    # the regression scenario's patrol (tests/scenarios/slow/depot_patrol_burger_amcl.yaml)
    "columns": [(12.0, -4.5, 0.0), (0.0, 4.0, 3.14), (-12.0, -5.0, 3.14)],
    # down the middle of the hall, out to the walls and back
    "open": [(12.0, 0.0, 0.0), (0.0, -5.0, 3.14), (-6.0, 5.0, 3.14), (-12.0, 0.0, 3.14)],
}
SEED = 1
LOCALIZERS = {"amcl": "{type: amcl, profile: accurate}", "odometry": "{type: odometry}"}
COLUMNS = ("rmse_m", "max_error_m", "odom_rmse_m", "inside_2sigma", "radius_over_error")


def run_route(route: str, localizer: str, imu: bool) -> dict[str, float]:
    wps = ", ".join(f"{{x: {x}, y: {y}, yaw: {a}}}" for x, y, a in ROUTES[route])
    text = MISSION.format(
        seed=SEED,
        localization=LOCALIZERS[localizer],
        imu=str(imu).lower(),
        waypoints=wps,
    )
    run = MissionRun(load_mission(REPO / "bench_imu.yaml", text=text), None)
    update = run.localizer.update
    start = run.loaded.start
    odom0: list[Pose2D] = []
    odom_err: list[float] = []

    def watched(odom, scan, truth, now):  # noqa: ANN001, ANN202 - the Localizer signature
        if not odom0:
            odom0.append(odom)
        dead = start.compose(odom.relative_to(odom0[0]))
        if now >= SETTLE_TIME:
            odom_err.append(math.hypot(dead.x - truth.x, dead.y - truth.y))
        return update(odom, scan, truth, now)

    run.localizer.update = watched
    while run.step():
        pass
    record = run.record()
    loc = record.metrics["localization"]
    consistency = loc.get("consistency") or {}
    nan = float("nan")
    return {
        "rmse_m": loc["position_rmse_settled"],
        "max_error_m": loc["position_max_error_settled"],
        "odom_rmse_m": round(float(np.sqrt(np.mean(np.square(odom_err)))), 5),
        "inside_2sigma": consistency.get("inside_2sigma", nan),
        "radius_over_error": consistency.get("radius_over_error") or nan,
        "succeeded": float(record.status == "succeeded"),
    }


def demo_cost(imu: bool, tmp: Path) -> float:
    """The demo patrol with its bag written: simulated seconds per CPU second."""
    loaded = load_mission(REPO / "missions" / "patrol.yaml", [f"stack.odometry.imu={imu}"])
    run_dir = tmp / f"demo-{imu}-{time.monotonic_ns()}"
    run_dir.mkdir()
    t0 = time.process_time()
    record = run_mission(loaded, run_dir, observers=[BagWriter().prepare()])
    return record.sim_time / (time.process_time() - t0)


BEFORE = {"refine_split_scale": 0.0, "refine_floor_xy": 0.01}
CONSISTENCY = {
    "demo": None,
    "ros_turtlebot3_world": (str(bl.ROS_MAPS / "turtlebot3_world" / "map.yaml"), bl.TB3, "burger"),
    "ros_aws_small_house": (str(bl.ROS_MAPS / "aws_small_house" / "map.yaml"), bl.HOUSE, "waffle"),
}


def consistency(case: str, before: bool) -> dict[str, float]:
    overrides = [f"stack.localization.{k}={v}" for k, v in BEFORE.items()] if before else []
    if CONSISTENCY[case] is None:
        loaded = load_mission(REPO / "missions" / "patrol.yaml", overrides)
    else:
        world, ((sx, sy), wps), robot = CONSISTENCY[case]
        text = bl.MISSION.format(
            world=world,
            map="",
            robot=robot,
            sx=sx,
            sy=sy,
            profile="accurate",
            waypoints=", ".join(f"{{x: {x}, y: {y}, yaw: {a}}}" for x, y, a in wps),
            obstacles="",
        )
        loaded = load_mission(REPO / "bench_imu.yaml", overrides, text=text)
    run = MissionRun(loaded, None)
    while run.step():
        pass
    loc = run.record().metrics["localization"]
    c = loc["consistency"]
    return {
        "rmse_m": loc["position_rmse"],
        "inside_2sigma": c["inside_2sigma"],
        "radius_over_error": c["radius_over_error"],
    }


def run() -> dict[str, float]:
    out: dict[str, float] = {}
    for case in CONSISTENCY:
        for before in (True, False):
            for name, value in consistency(case, before).items():
                out[f"imu.consistency.{case}.{'before' if before else 'after'}.{name}"] = value
    for route in ROUTES:
        for localizer in LOCALIZERS:
            for imu in (False, True):
                values = run_route(route, localizer, imu)
                key = f"imu.depot_{route}.{localizer}.{'imu' if imu else 'wheels'}"
                for name, value in values.items():
                    out[f"{key}.{name}"] = value
    factors: dict[bool, list[float]] = {False: [], True: []}
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(2):
            for imu in (False, True):
                factors[imu].append(demo_cost(imu, Path(tmp)))
    for imu, values in factors.items():
        out[f"imu.demo_real_time_factor.{'imu' if imu else 'wheels'}"] = round(max(values), 1)
    out["imu.demo_cost_ratio_imu_over_wheels"] = round(max(factors[False]) / max(factors[True]), 3)
    return out


def tables(results: dict[str, Any]) -> list[Table]:
    table = Table(title="IMU: depot, burger (before: wheels, after: wheels + gyro)")
    for col in ("route", "localiser", "odometry", *COLUMNS):
        table.add_column(col, justify="right" if col in COLUMNS else "left")
    for route in ROUTES:
        for localizer in LOCALIZERS:
            for odometry in ("wheels", "imu"):
                prefix = f"imu.depot_{route}.{localizer}.{odometry}."
                if prefix + "rmse_m" in results:
                    cells = [f"{results[prefix + c]:.4g}" for c in COLUMNS]
                    table.add_row(route, localizer, odometry, *cells)
    speed = Table(title="IMU: the demo patrol with its bag (simulated s per CPU s)")
    for col in ("wheels", "imu", "wheels / imu cost"):
        speed.add_column(col, justify="right")
    speed.add_row(
        str(results.get("imu.demo_real_time_factor.wheels")),
        str(results.get("imu.demo_real_time_factor.imu")),
        str(results.get("imu.demo_cost_ratio_imu_over_wheels")),
    )
    honest = Table(title="covariance: residual-RMS floor (before) vs half-scan floor (after)")
    for col in ("mission", "floor", "rmse_m", "inside_2sigma", "radius_over_error"):
        honest.add_column(col, justify="left" if col in ("mission", "floor") else "right")
    for case in CONSISTENCY:
        for when in ("before", "after"):
            prefix = f"imu.consistency.{case}.{when}."
            if prefix + "rmse_m" in results:
                cells = [
                    f"{results[prefix + c]:.4g}"
                    for c in ("rmse_m", "inside_2sigma", "radius_over_error")
                ]
                honest.add_row(case, when, *cells)
    return [table, speed, honest]


if __name__ == "__main__":
    from rich.console import Console

    results = run()
    for t in tables(results):
        Console().print(t)
