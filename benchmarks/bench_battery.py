"""The battery model's cost (issue 23): one ``Battery.step`` per control step, in the run's
hot loop.

* ``battery.step_us``: one step of the model (mean over 200 000 calls), and what it costs
  per simulated second at the 10 Hz control rate;
* the demo patrol (amcl, OMPL, MPC) with the burger's battery and with none: the CPU-time
  ratio (the battery's whole cost in a run: the model, the level column, the metrics),
  the two runs stepped side by side (``side_by_side.py``), the median of three pairings;
  and each kind's CPU per simulated second and real-time factor as whole runs.
"""

from __future__ import annotations

import statistics
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

from side_by_side import paired_ratio

from agv_mission.missions.load.loader import load_mission
from agv_mission.missions.run.runner import MissionRun, run_mission
from agv_mission.missions.run.stack import CONTROL_PERIOD
from agv_mission.robots.battery import battery_for
from agv_mission.robots.builtin_robots import BUILTIN_ROBOTS

REPO = Path(__file__).resolve().parents[1]
DEMO = REPO / "missions" / "patrol.yaml"
CALLS = 200_000
PAIRS = 3


def _step_us() -> float:
    robot = BUILTIN_ROBOTS["burger"]
    assert robot.battery is not None
    battery = battery_for(robot.battery, robot.mass, robot.footprint_radius, 0.16)
    step = battery.step
    t0 = time.perf_counter()
    for i in range(CALLS):
        step(0.2 if i & 1 else 0.18, 0.1, CONTROL_PERIOD)
    return (time.perf_counter() - t0) / CALLS * 1e6


def _demo(with_battery: bool) -> Any:
    loaded = load_mission(DEMO)
    if not with_battery:
        robot = loaded.lead.robot.model_copy(update={"battery": None})
        loaded.robots = [replace(loaded.lead, robot=robot)]
    return loaded


def _patrol_cpu_per_sim_s(with_battery: bool) -> tuple[float, float]:
    loaded = _demo(with_battery)
    cpu0 = time.process_time()
    record = run_mission(loaded)
    cpu = time.process_time() - cpu0
    assert (record.metrics["battery"] is not None) == with_battery
    return cpu / record.sim_time, record.sim_time / record.wall_time


def run() -> dict[str, float]:
    step_us = _step_us()
    results = {
        "battery.step_us": round(step_us, 3),
        "battery.model_us_per_sim_s": round(step_us / CONTROL_PERIOD, 2),
    }
    with_cost, without_cost, with_rtf, without_rtf = [], [], [], []
    for _ in range(PAIRS):
        cost, rtf = _patrol_cpu_per_sim_s(True)
        with_cost.append(cost)
        with_rtf.append(rtf)
        cost, rtf = _patrol_cpu_per_sim_s(False)
        without_cost.append(cost)
        without_rtf.append(rtf)
    ratio = paired_ratio(
        lambda: MissionRun(_demo(False), None), lambda: MissionRun(_demo(True), None)
    )
    results.update(
        {
            "battery.patrol.cpu_ms_per_sim_s.with": round(statistics.median(with_cost) * 1e3, 3),
            "battery.patrol.cpu_ms_per_sim_s.without": round(
                statistics.median(without_cost) * 1e3, 3
            ),
            "battery.patrol.cost_ratio_with_over_without": round(ratio, 4),
            "battery.patrol.real_time_factor.with": round(statistics.median(with_rtf), 2),
            "battery.patrol.real_time_factor.without": round(statistics.median(without_rtf), 2),
        }
    )
    return results
