"""Whole missions end to end: real-time factor (simulated seconds per wall second).

The demo patrol (amcl localisation, OMPL, MPC) and a map_area of small_house (grid SLAM,
frontier exploration), each once: the numbers include everything the runner does.
"""

from __future__ import annotations

from pathlib import Path

from agv_mission.missions.load.loader import load_mission
from agv_mission.missions.run.runner import run_mission

REPO = Path(__file__).resolve().parents[1]
DEMO = REPO / "missions" / "patrol.yaml"
MAP_HOUSE = REPO / "missions" / "map_house.yaml"


def _mission(key: str, path: Path, results: dict[str, float]) -> dict:
    record = run_mission(load_mission(path))
    results[f"mission.{key}.real_time_factor"] = round(record.sim_time / record.wall_time, 2)
    results[f"mission.{key}.sim_time_s"] = record.sim_time
    results[f"mission.{key}.succeeded"] = float(record.status == "succeeded")
    nav = record.metrics["navigation"]
    if nav["controller_solve_ms_p50"] is not None:
        results[f"mission.{key}.controller_ms.p50"] = nav["controller_solve_ms_p50"]
        results[f"mission.{key}.controller_ms.p99"] = nav["controller_solve_ms_p99"]
    return record.extras


def run() -> dict[str, float]:
    results: dict[str, float] = {}
    _mission("patrol", DEMO, results)
    extras = _mission("map_area_small_house", MAP_HOUSE, results)
    for m in extras.get("maps", []):
        for k in ("coverage", "free_iou", "slam_rmse"):
            results[f"mission.map_area_small_house.{k}"] = m[k]
    return results
