"""What a run's record says: per-task reports (waypoints, rooms) and the metrics."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from agv_mission.behaviors.outcome import failure_reason
from agv_mission.geometry import wrap_angle
from agv_mission.missions.tree import MissionTree
from agv_mission.navigation.navigator import Navigator

_OUTCOMES = {"goal_reached": "reached", "goal_failed": "failed", "goal_skipped": "skipped"}


def task_reports(
    mission: Any, tree: MissionTree, task_status: list[str], events: list[dict[str, Any]]
) -> list[dict[str, Any]]:
    """Per-task status and reason, with per-waypoint and per-room outcomes."""
    reports = []
    for i, (task, subtree) in enumerate(zip(mission.tasks, tree.tasks, strict=True)):
        mine = [e for e in events if e.get("task") == i]
        status = task_status[i]
        skips = [e for e in mine if e["event"] == "goal_skipped"]
        if status == "succeeded" and skips:
            status = "skipped" if task.type == "go_to" else "partial"
        report: dict[str, Any] = {
            "index": i + 1,
            "type": task.type,
            "status": status,
            "reason": None,
        }
        if status == "failed":
            report["reason"] = failure_reason(subtree)
        elif skips:
            report["reason"] = "; ".join(sorted({e["reason"] for e in skips}))
        if task.type == "patrol":
            report["waypoints"] = [
                {k: e[k] for k in ("loop", "waypoint", "t", "x", "y", "yaw", "reason") if k in e}
                | {"status": _OUTCOMES[e["event"]]}
                for e in mine
                if e["event"] in _OUTCOMES
            ]
        if task.type == "visit_rooms":
            report["rooms"] = [_room_report(room, mine) for room in task.rooms]
        reports.append(report)
    return reports


def add_true_errors(tasks: list[dict[str, Any]], trajectory: np.ndarray) -> None:
    """Where the robot truly was when it believed a waypoint reached (simulation only)."""
    if not len(trajectory):
        return
    for task in tasks:
        for wp in task.get("waypoints", []):
            if wp["status"] != "reached":
                continue
            row = trajectory[int(np.argmin(np.abs(trajectory[:, 0] - wp["t"])))]
            wp["true_x"], wp["true_y"] = round(float(row[1]), 4), round(float(row[2]), 4)
            wp["estimate_error"] = round(float(np.hypot(row[1] - wp["x"], row[2] - wp["y"])), 4)


def _room_report(room: str, events: list[dict[str, Any]]) -> dict[str, Any]:
    outcome = next(
        (
            e
            for e in events
            if e.get("room") == room and e["event"] in ("goal_failed", "goal_skipped")
        ),
        None,
    )
    reached = any(e["event"] == "goal_reached" and e.get("room") == room for e in events)
    report: dict[str, Any] = {
        "room": room,
        "status": _OUTCOMES[outcome["event"]] if outcome else ("reached" if reached else "not_run"),
        "recorded": any(e["event"] == "room_recorded" and e.get("room") == room for e in events),
    }
    if outcome:
        report["reason"] = outcome["reason"]
    return report


def run_metrics(
    traj: np.ndarray,
    navigator: Navigator,
    collisions: int,
    min_clearance: float,
    sim_time: float,
    wall_time: float,
) -> dict[str, Any]:
    xy = traj[:, 1:3]
    distance = float(np.sum(np.linalg.norm(np.diff(xy, axis=0), axis=1))) if len(xy) > 1 else 0.0
    err = np.linalg.norm(traj[:, 4:6] - xy, axis=1)
    yaw_err = np.array([wrap_angle(a) for a in traj[:, 6] - traj[:, 3]])
    stats = navigator.stats
    solve_ms = np.asarray(stats.solve_times) * 1e3
    plan_ms = np.asarray(stats.planning_times) * 1e3
    return {
        "distance_driven": round(distance, 4),
        "collisions": collisions,
        "min_clearance": round(min_clearance, 4) if math.isfinite(min_clearance) else None,
        "localization": {  # a run stopped before its first step has no errors to show
            "position_rmse": round(float(np.sqrt(np.mean(err**2))), 5) if err.size else 0.0,
            "position_max_error": round(float(err.max()), 5) if err.size else 0.0,
            "yaw_rmse": round(float(np.sqrt(np.mean(yaw_err**2))), 5) if err.size else 0.0,
        },
        "navigation": {
            "plans": stats.plans,
            "replans": stats.replans,
            "planning_time_ms_mean": round(float(plan_ms.mean()), 3) if plan_ms.size else None,
            "path_length_total": round(float(np.sum(stats.path_lengths)), 4),
            "controller_solve_ms_p50": round(float(np.percentile(solve_ms, 50)), 3)
            if solve_ms.size
            else None,
            "controller_solve_ms_p99": round(float(np.percentile(solve_ms, 99)), 3)
            if solve_ms.size
            else None,
            "controller_failures": stats.solver_failures,
        },
        "real_time_factor": round(sim_time / wall_time, 2) if wall_time > 0 else None,
    }
