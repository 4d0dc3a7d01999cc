"""Fleets in the built-in 30 x 50 m warehouse (issue 24): real-time factor and CPU per
robot per simulated second for 1, 5, 10 and 30 robots (amcl + MPC each), and where the
time goes.

Every robot patrols its own 5 m stretch of a rack aisle (eight aisles, four stretches
each), so the figures measure the cost of many robots in one world rather than of their
traffic. The loop alone is timed (set-up aside), over the same simulated time for every
fleet size, on the process's CPU clock.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

from bench_breakdown import _Clock

from agv_mission.missions.loader import load_mission
from agv_mission.missions.runner import MissionRun

AISLES = (-13.2, -8.95, -5.35, -1.75, 1.85, 5.45, 9.05, 12.55)  # x of the rack aisles
STRETCHES = ((-20.0, -15.0), (-12.0, -7.0), (7.0, 12.0), (15.0, 20.0))  # y of a patrol
SIM_SECONDS = 30.0
SIZES = (1, 5, 10, 30)
COMPONENTS = (
    "physics",
    "lidar",
    "localisation",
    "obstacle_layer",
    "planning",
    "control",
    "tree",
    "traffic",
)


def fleet_mission(n: int, sim_seconds: float = SIM_SECONDS) -> str:
    """A warehouse mission of ``n`` burgers, each patrolling its own aisle stretch."""
    robots = []
    for k in range(n):
        x = AISLES[k % len(AISLES)]
        y0, y1 = STRETCHES[(k // len(AISLES)) % len(STRETCHES)]
        robots.append(
            f"  - name: agv{k + 1}\n"
            f"    start: {{x: {x}, y: {y0}, yaw: 1.5708}}\n"
            "    tasks:\n"
            "      - type: patrol\n"
            f"        waypoints: [{{x: {x}, y: {y1}, yaw: 1.5708}}, "
            f"{{x: {x}, y: {y0}, yaw: -1.5708}}]\n"
            "        loops: 100\n"
        )
    return (
        f"name: fleet-{n}\nworld: warehouse\nseed: 11\n"
        "stack: {localization: {type: amcl}, local_planner: {type: mpc}}\n"
        f"robots:\n{''.join(robots)}"
        f"limits: {{time: {sim_seconds}, collisions: 1000}}\n"
    )


def measure(n: int, sim_seconds: float = SIM_SECONDS, parts: bool = True) -> dict[str, float]:
    """The loop of an ``n``-robot fleet: wall and CPU per simulated second, per robot."""
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "fleet.yaml"
        path.write_text(fleet_mission(n, sim_seconds))
        run = MissionRun(load_mission(path), None)
    clock = _Clock()
    if parts:
        clock.wrap(run.world, "step", "physics")
        if run.coordinator is not None:
            clock.wrap(run.coordinator.traffic, "decide", "traffic")
        for r in run.robots:
            clock.wrap(r.sim, "scan", "lidar")
            clock.wrap(r.localizer, "update", "localisation")
            clock.wrap(r.navigator, "observe", "obstacle_layer")
            clock.wrap(r.navigator.global_planner, "plan", "planning")
            clock.wrap(r.navigator.local_planner, "compute", "control")
            clock.wrap(r.tree.root, "tick_once", "tree")
    wall0, cpu0 = time.perf_counter(), time.process_time()
    run.drive()
    wall, cpu = time.perf_counter() - wall0, time.process_time() - cpu0
    record = run.record()
    sim = record.sim_time
    out = {
        "real_time_factor": sim / wall,
        "cpu_ms_per_robot_per_sim_s": cpu * 1e3 / sim / n,
        "sim_time_s": sim,
        "collisions": float(record.metrics["collisions"]),
    }
    if parts:
        for c in COMPONENTS:
            out[f"{c}_ms_per_robot_per_sim_s"] = clock.total.get(c, 0.0) * 1e3 / sim / n
        out["other_ms_per_robot_per_sim_s"] = (cpu - sum(clock.total.values())) * 1e3 / sim / n
    return out


def run() -> dict[str, float]:
    results: dict[str, float] = {}
    for n in SIZES:
        for metric, value in measure(n).items():
            results[f"fleet.warehouse.{n}.{metric}"] = round(value, 3)
    one = results["fleet.warehouse.1.cpu_ms_per_robot_per_sim_s"]
    for n in SIZES[1:]:
        results[f"fleet.warehouse.{n}_over_1_cpu_per_robot"] = round(
            results[f"fleet.warehouse.{n}.cpu_ms_per_robot_per_sim_s"] / one, 3
        )
    return results


if __name__ == "__main__":
    import sys

    for n in map(int, sys.argv[1:] or ["1", "10"]):
        print(n, {k: round(v, 2) for k, v in measure(n).items()})
