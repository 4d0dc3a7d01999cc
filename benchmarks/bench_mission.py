"""The demo patrol's real-time factor (simulated seconds per wall second), end to end."""

from __future__ import annotations

from pathlib import Path

from agv_mission.missions.loader import load_mission
from agv_mission.missions.runner import run_mission

DEMO = Path(__file__).resolve().parents[1] / "missions" / "patrol.yaml"


def run() -> dict[str, float]:
    results: dict[str, float] = {}
    loaded = load_mission(DEMO)
    record = run_mission(loaded)
    results["mission.patrol.real_time_factor"] = round(record.sim_time / record.wall_time, 2)
    results["mission.patrol.sim_time_s"] = record.sim_time
    results["mission.patrol.succeeded"] = float(record.status == "succeeded")
    nav = record.metrics["navigation"]
    if nav["controller_solve_ms_p50"] is not None:
        results["mission.patrol.controller_ms.p50"] = nav["controller_solve_ms_p50"]
        results["mission.patrol.controller_ms.p99"] = nav["controller_solve_ms_p99"]
    return results
