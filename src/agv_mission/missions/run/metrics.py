"""What a run's record says: per-task reports (waypoints, rooms) and the metrics."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from agv_mission.behaviors.outcome import failure_reason
from agv_mission.geometry import wrap_angle
from agv_mission.missions.run.behaviour_tree import MissionTree
from agv_mission.navigation.legs import leg_report
from agv_mission.navigation.navigator import Navigator

#: Extra trajectory.csv columns after the contract's nine: the estimate's covariance.
COVARIANCE_COLUMNS = ("cov_xx", "cov_xy", "cov_yy", "cov_yawyaw")
#: Localisation errors are also summarised after the estimate has had this long to settle.
SETTLE_TIME = 10.0


def task_reports(
    tree: MissionTree, task_status: list[str], events: list[dict[str, Any]]
) -> list[dict[str, Any]]:
    """Per-task status and reason, with what each task node's ports model adds from its
    events (a patrol's waypoints, a visit's rooms)."""
    reports = []
    by_task: dict[int, list[dict[str, Any]]] = {}
    for e in events:
        if "task" in e:
            by_task.setdefault(e["task"], []).append(e)
    for i, (node, behaviour) in enumerate(zip(tree.task_nodes, tree.tasks, strict=True)):
        mine = by_task.get(i + 1, [])  # events number tasks from 1, as the reports do
        status = task_status[i]
        ports = node.ports or _started_ports(behaviour)
        extra = ports.report(status, mine) if ports is not None else {"status": status}
        report: dict[str, Any] = {
            "index": i + 1,
            "type": node.type,
            "status": extra.pop("status"),
            "reason": extra.pop("reason", None),
        }
        if status == "failed":
            report["reason"] = failure_reason(behaviour)
        report.update(extra)
        reports.append(report)
    return reports


def _started_ports(behaviour: Any) -> Any:
    """The ports a node bound to the blackboard started with last (None: never started)."""
    inner = getattr(behaviour, "inner", None)
    return getattr(inner, "ports_model", None)


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


def run_metrics(
    traj: np.ndarray,
    navigator: Navigator | None,
    collisions: int,
    min_clearance: float,
    sim_time: float,
    wall_time: float,
) -> dict[str, Any]:
    """Distance, safety, localisation error and navigation statistics; None where nothing
    was measured (no trajectory row yet, or no navigator: the run failed to set up)."""
    xy = traj[:, 1:3]
    distance = float(np.sum(np.linalg.norm(np.diff(xy, axis=0), axis=1))) if len(xy) > 1 else 0.0
    err = np.linalg.norm(traj[:, 4:6] - xy, axis=1)
    yaw_err = np.array([wrap_angle(a) for a in traj[:, 6] - traj[:, 3]])
    stats = navigator.stats if navigator is not None else None
    solve_ms = np.asarray(stats.solve_times if stats else []) * 1e3
    plan_ms = np.asarray(stats.planning_times if stats else []) * 1e3
    return {
        "distance_driven": round(distance, 4),
        "collisions": collisions,
        "min_clearance": round(min_clearance, 4) if math.isfinite(min_clearance) else None,
        "localization": {
            # None when the run ended before its first step (a very early Ctrl-C)
            "position_rmse": round(float(np.sqrt(np.mean(err**2))), 5) if err.size else None,
            "position_max_error": round(float(err.max()), 5) if err.size else None,
            "yaw_rmse": round(float(np.sqrt(np.mean(yaw_err**2))), 5) if err.size else None,
        },
        "navigation": {
            "plans": stats.plans if stats else 0,
            "replans": stats.replans if stats else 0,
            "planning_time_ms_mean": round(float(plan_ms.mean()), 3) if plan_ms.size else None,
            "controller_solve_ms_p50": round(float(np.percentile(solve_ms, 50)), 3)
            if solve_ms.size
            else None,
            "controller_solve_ms_p99": round(float(np.percentile(solve_ms, 99)), 3)
            if solve_ms.size
            else None,
            "controller_failures": stats.solver_failures if stats else 0,
            **(leg_report(stats.legs, traj[:, 0], xy, traj[:, 7], sim_time) if stats else {}),
        },
        "real_time_factor": round(sim_time / wall_time, 2) if wall_time > 0 else None,
    }


def covariance_metrics(traj: np.ndarray, cov: np.ndarray) -> dict[str, Any]:
    """Errors after SETTLE_TIME, and how far the reported covariance tells the true error.

    ``consistency_2sigma`` is the share of steps whose position error ``e`` has
    ``e^T C^-1 e <= 4`` under the reported position covariance ``C``; ``consistency`` says
    it again (``inside_2sigma``) beside ``radius_over_error``: the 2-sigma ellipse's mean
    radius (twice the root of the mean of its two variances) over the steps, divided by
    the mean true error. An honest covariance has ~0.86 inside (a Gaussian's share) and a
    ratio near 1.6; one much larger than the error says little.
    """
    out: dict[str, Any] = {}
    if not len(traj):
        return out
    err_xy = traj[:, 4:6] - traj[:, 1:3]
    err = np.linalg.norm(err_xy, axis=1)
    late = traj[:, 0] >= SETTLE_TIME
    if late.any():
        out["position_rmse_settled"] = round(float(np.sqrt(np.mean(err[late] ** 2))), 5)
        out["position_max_error_settled"] = round(float(err[late].max()), 5)
    have = np.isfinite(cov).all(axis=1) if len(cov) == len(traj) else np.zeros(len(traj), bool)
    if not have.any():
        return out
    xx, xy, yy = cov[have, 0], cov[have, 1], cov[have, 2]
    ex, ey = err_xy[have, 0], err_xy[have, 1]
    det = xx * yy - xy**2
    with np.errstate(divide="ignore", invalid="ignore"):
        d2 = (yy * ex**2 - 2.0 * xy * ex * ey + xx * ey**2) / det
    d2 = np.where(det > 0.0, d2, np.where(np.hypot(ex, ey) == 0.0, 0.0, np.inf))
    inside = round(float(np.mean(d2 <= 4.0)), 4)
    out["consistency_2sigma"] = inside
    radius = 2.0 * np.sqrt(np.maximum(0.5 * (xx + yy), 0.0))
    mean_error = float(np.mean(np.hypot(ex, ey)))
    ratio = float(np.mean(radius)) / mean_error if mean_error > 0.0 else None
    out["consistency"] = {
        "inside_2sigma": inside,
        "radius_over_error": round(ratio, 3) if ratio is not None else None,
        "mean_2sigma_radius": round(float(np.mean(radius)), 5),
        "mean_error": round(mean_error, 5),
    }
    last = cov[np.flatnonzero(have)[-1]]
    out["final_covariance"] = {
        k.removeprefix("cov_"): float(f"{v:.4g}")
        for k, v in zip(COVARIANCE_COLUMNS, last, strict=True)
    }
    return out


def covariance_row(cov: np.ndarray | None) -> tuple[float, float, float, float]:
    """(xx, xy, yy, yawyaw) of the estimate's covariance, NaN when there is none."""
    if cov is None:
        return (math.nan,) * 4
    c = np.asarray(cov, dtype=float)
    return float(c[0, 0]), float(c[0, 1]), float(c[1, 1]), float(c[2, 2])
