"""Fleets in the built-in 30 x 50 m warehouse (issue 24): real-time factor and CPU per
robot per simulated second for 1, 5, 10 and 30 robots (amcl + MPC each), and where the
time goes.

Every robot patrols its own 5 m stretch of a rack aisle (eight aisles, four stretches
each), so the figures measure the cost of many robots in one world rather than of their
traffic. The loop alone is timed (set-up aside), over the same simulated time for every
fleet size. Each size runs twice, each time in a fresh interpreter as ``agv-mission run``
would: with what the default ``simulation.processes: auto`` picks on an idle machine (the
robots decide in one process per core, :mod:`agv_mission.missions.run.team`; CPU counts every
process), the headline figures; and in one process (``_serial``), with the breakdown of
where the time goes.
"""

from __future__ import annotations

import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from bench_breakdown import _Clock

from agv_mission.missions.load.loader import load_mission
from agv_mission.missions.run.runner import MissionRun
from agv_mission.missions.run.team import AUTO_FROM, usable_cores

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


def _children_cpu() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def measure(
    n: int, sim_seconds: float = SIM_SECONDS, parts: bool = True, processes: str = "auto"
) -> dict[str, float]:
    """The loop of an ``n``-robot fleet: wall and CPU (of every process) per simulated
    second, per robot; with ``parts`` (one process only) where the time goes."""
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "fleet.yaml"
        path.write_text(fleet_mission(n, sim_seconds))
        run = MissionRun(load_mission(path, [f"simulation.processes={processes}"]), None)
    parts = parts and processes == "1"
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
    wall0, cpu0, kids0 = time.perf_counter(), time.process_time(), _children_cpu()
    run.drive()
    wall = time.perf_counter() - wall0
    record = run.record()  # gathers (and reaps) the robot processes
    cpu = time.process_time() - cpu0 + _children_cpu() - kids0
    sim = record.sim_time
    out = {
        "real_time_factor": sim / wall,
        "cpu_ms_per_robot_per_sim_s": cpu * 1e3 / sim / n,
        "sim_time_s": sim,
        "collisions": float(record.metrics["collisions"]),
        "processes": float(run.team.processes),
    }
    if parts:
        for c in COMPONENTS:
            out[f"{c}_ms_per_robot_per_sim_s"] = clock.total.get(c, 0.0) * 1e3 / sim / n
        out["other_ms_per_robot_per_sim_s"] = (cpu - sum(clock.total.values())) * 1e3 / sim / n
    return out


def measure_fresh(n: int, processes: str) -> dict[str, float]:
    """:func:`measure` in a fresh interpreter (one thread, not a worker: what ``auto``
    sees in ``agv-mission run``)."""
    out = subprocess.run(
        [sys.executable, __file__, "--json", str(n), processes],
        capture_output=True,
        text=True,
        check=True,
    )
    return json.loads(out.stdout.strip().splitlines()[-1])


def run() -> dict[str, float]:
    results: dict[str, float] = {}
    for n in SIZES:
        # what auto picks on an idle machine (one process per core from AUTO_FROM robots),
        # named, so a busy moment does not change what is measured
        picked = str(min(usable_cores(), n)) if n >= AUTO_FROM else "1"
        runs = [(picked, "")] + ([("1", "_serial")] if picked != "1" else [])
        for processes, suffix in runs:
            measured = measure_fresh(n, processes)
            if picked == "1":  # one process is the default here: one run stands for both
                measured.update({f"{k}_serial": v for k, v in measured.items() if "cpu" in k})
                measured["real_time_factor_serial"] = measured["real_time_factor"]
            for metric, value in measured.items():
                if suffix and metric in ("sim_time_s", "collisions", "processes"):
                    continue
                key = (
                    metric
                    if suffix
                    and metric.endswith("_per_robot_per_sim_s")
                    and (metric != "cpu_ms_per_robot_per_sim_s")
                    else f"{metric}{suffix}"
                )
                results[f"fleet.warehouse.{n}.{key}"] = round(value, 3)
    one = results["fleet.warehouse.1.cpu_ms_per_robot_per_sim_s"]
    one_serial = results["fleet.warehouse.1.cpu_ms_per_robot_per_sim_s_serial"]
    for n in SIZES[1:]:
        at = f"fleet.warehouse.{n}"
        results[f"{at}_over_1_cpu_per_robot"] = round(
            results[f"{at}.cpu_ms_per_robot_per_sim_s"] / one, 3
        )
        results[f"{at}_over_1_cpu_per_robot_serial"] = round(
            results[f"{at}.cpu_ms_per_robot_per_sim_s_serial"] / one_serial, 3
        )
        results[f"{at}.speed_over_serial"] = round(
            results[f"{at}.real_time_factor"] / results[f"{at}.real_time_factor_serial"], 3
        )
    return results


if __name__ == "__main__":
    if sys.argv[1:2] == ["--json"]:
        print(json.dumps(measure(int(sys.argv[2]), processes=sys.argv[3])))
    else:
        for n in map(int, sys.argv[1:] or ["1", "10"]):
            for processes in ("auto", "1"):
                print(
                    n,
                    processes,
                    {k: round(v, 2) for k, v in measure(n, processes=processes).items()},
                )
