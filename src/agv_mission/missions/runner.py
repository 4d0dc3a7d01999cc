"""The simulation-clock loop: sensors -> estimator -> behaviour tree -> robot, step by step.

One control step every ``CONTROL_PERIOD`` simulated seconds: read encoders and (when due)
the lidar, update odometry and the localiser, tick the tree once, smooth the command
within the robot's acceleration limits, and advance the physics. The wall clock is read
only to report speed.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from py_trees.common import Status

from agv_mission.geometry import wrap_angle
from agv_mission.maps.recorder import RECORDER_FILENAME, LocationRecorder
from agv_mission.missions.loader import LoadedMission
from agv_mission.missions.tree import MissionTree, build_tree
from agv_mission.navigation.handle import RobotHandle
from agv_mission.navigation.navigator import Navigator
from agv_mission.navigation.state import RobotState
from agv_mission.planners.base import VelocityLimits
from agv_mission.registry import registry
from agv_mission.robots.odometry import DiffDriveOdometry
from agv_mission.robots.simulation import DiffDriveSim

CONTROL_PERIOD = 0.1

TRAJECTORY_COLUMNS = ("t", "x", "y", "yaw", "est_x", "est_y", "est_yaw", "v", "w")

ProgressCallback = Callable[[float, float], None]


@dataclass
class RunRecord:
    """Everything a run produced, before it is written out."""

    status: str
    reason: str | None
    sim_time: float
    wall_time: float
    tasks: list[dict[str, Any]]
    metrics: dict[str, Any]
    trajectory: np.ndarray  # (steps, len(TRAJECTORY_COLUMNS))
    paths: list[np.ndarray]
    events: list[dict[str, Any]]
    tree_text: str
    extras: dict[str, Any] = field(default_factory=dict)  # more keys for result.json
    particle_snapshots: list[tuple[float, np.ndarray]] = field(default_factory=list)


class VelocitySmoother:
    """Limits command changes to the robot's accelerations, like a cmd_vel smoother."""

    def __init__(self, limits: VelocityLimits, period: float) -> None:
        self.limits, self.period = limits, period
        self.v = self.w = 0.0

    def __call__(self, v: float, w: float) -> tuple[float, float]:
        lim, dt = self.limits, self.period
        v = float(np.clip(v, -lim.max_v, lim.max_v))
        w = float(np.clip(w, -lim.max_w, lim.max_w))
        self.v = float(np.clip(v, self.v - lim.max_acc_v * dt, self.v + lim.max_acc_v * dt))
        self.w = float(np.clip(w, self.w - lim.max_acc_w * dt, self.w + lim.max_acc_w * dt))
        return self.v, self.w


def run_mission(
    loaded: LoadedMission,
    run_dir: Path | None = None,
    progress: ProgressCallback | None = None,
) -> RunRecord:
    """Run ``loaded`` in simulation until its tree finishes or its time limit passes.

    With ``run_dir``, recorded room poses go to ``run_dir/location_recorder.yaml`` as they
    are recorded (and to the mission's ``recorder`` file, when it names one).
    """
    mission, robot = loaded.mission, loaded.robot
    seeds = np.random.SeedSequence(mission.seed).spawn(3)
    sim_rng, loc_rng, planner_rng = (np.random.default_rng(s) for s in seeds)

    sim = DiffDriveSim(robot, loaded.world, loaded.start, mission.simulation, sim_rng)
    odometry = DiffDriveOdometry(robot.encoder.ticks_per_meter, robot.wheel_separation)
    localizer = registry.create(
        "localization", mission.stack.localization, grid=loaded.world.map, rng=loc_rng
    )
    limits = VelocityLimits(
        max_v=robot.max_linear_velocity,
        max_w=robot.max_angular_velocity,
        max_acc_v=robot.max_linear_acceleration,
        max_acc_w=robot.max_angular_acceleration,
    )
    global_planner = registry.create("global_planner", mission.stack.global_planner)
    local_planner = registry.create(
        "local_planner",
        mission.stack.local_planner,
        limits=limits,
        robot_radius=robot.footprint_radius,
        control_period=CONTROL_PERIOD,
    )
    navigator = Navigator(
        loaded.costmap,
        global_planner,
        local_planner,
        limits,
        mission.stack.navigation,
        CONTROL_PERIOD,
        seed=int(planner_rng.integers(0, 2**31 - 1)),
    )
    left, right = sim.encoder_ticks()
    odom_pose = odometry.update(left, right)
    localizer.reset(loaded.start, odom_pose)
    handle = RobotHandle(
        RobotState(time=0.0, estimate=loaded.start),
        navigator,
        rooms=loaded.rooms,
        recorders=_recorders(loaded, run_dir),
    )
    tree = build_tree(mission, handle, robot, loaded.room_goals)
    smoother = VelocitySmoother(limits, CONTROL_PERIOD)

    scan_period = 1.0 / robot.lidar.rate
    next_scan = 0.0
    rows: list[tuple[float, ...]] = []
    task_status = ["not_run"] * len(tree.tasks)
    collisions = 0
    in_contact = False
    min_clearance = math.inf
    limit = mission.limits.time
    wall_start = time.perf_counter()
    timed_out = False

    while True:
        now = sim.time
        odom_pose = odometry.update(*sim.encoder_ticks())
        scan = None
        if now >= next_scan - 1e-9:
            scan = sim.scan()
            next_scan += scan_period
        truth = sim.true_pose()
        estimate = localizer.update(odom_pose, scan, truth, now)
        state = handle.state
        state.time, state.estimate = now, estimate
        state.velocity = (smoother.v, smoother.w)
        if scan is not None:
            state.scan = scan
            state.obstacles = scan.points(estimate)

        handle.stop()
        tree.root.tick_once()
        for i, subtree in enumerate(tree.tasks):
            if subtree.status is not Status.INVALID:
                task_status[i] = _status_name(subtree.status)

        v, w = smoother(*handle.command)
        rows.append((now, truth.x, truth.y, truth.yaw, estimate.x, estimate.y, estimate.yaw, v, w))

        contacts = sim.contacts()
        if contacts and not in_contact:
            collisions += 1
        in_contact = contacts > 0
        clearance = (
            float(loaded.costmap.clearance(np.array([truth.x, truth.y]))) - robot.footprint_radius
        )
        min_clearance = min(min_clearance, clearance)

        if progress is not None:
            progress(now, limit)
        if tree.root.status in (Status.SUCCESS, Status.FAILURE):
            break
        if now >= limit - 1e-9:
            timed_out = True
            break
        sim.set_command(v, w)
        sim.advance(CONTROL_PERIOD)

    wall_time = time.perf_counter() - wall_start
    sim_time = sim.time
    trajectory = np.asarray(rows, dtype=float)
    tasks = _task_reports(mission, tree, task_status, handle.events)
    if tree.root.status is Status.SUCCESS:
        status, reason = "succeeded", None
    elif timed_out:
        running = next((i for i, s in enumerate(task_status) if s == "running"), None)
        where = (
            f" during task {running + 1} ({mission.tasks[running].type})"
            if running is not None
            else ""
        )
        status, reason = "failed", f"time limit of {limit:g} s reached{where}"
        if running is not None:
            task_status[running] = "failed"
            tasks[running]["status"] = "failed"
            tasks[running]["reason"] = "time limit reached"
    else:
        failed = next((t for t in tasks if t["status"] == "failed"), None)
        status = "failed"
        reason = (
            f"task {failed['index']} ({failed['type']}) failed: {failed['reason']}"
            if failed
            else "mission failed"
        )

    metrics = _metrics(trajectory, navigator, collisions, min_clearance, sim_time, wall_time)
    extras: dict[str, Any] = {}
    if handle.recorded:
        extras["rooms_recorded"] = {
            label: {"x": round(p.x, 4), "y": round(p.y, 4), "yaw": round(p.yaw, 4)}
            for label, p in handle.recorded.items()
        }
    counts = getattr(localizer, "particle_counts", None)
    if counts:
        c = np.asarray([n for _, n in counts])
        metrics["localization"]["particles"] = {
            "min": int(c.min()),
            "max": int(c.max()),
            "mean": round(float(c.mean()), 1),
        }
        extras["particle_counts"] = [[round(t, 3), int(n)] for t, n in counts]
    return RunRecord(
        status=status,
        reason=reason,
        sim_time=round(sim_time, 6),
        wall_time=round(wall_time, 3),
        tasks=tasks,
        metrics=metrics,
        trajectory=trajectory,
        paths=navigator.paths,
        events=handle.events,
        tree_text=tree.render(),
        extras=extras,
        particle_snapshots=list(getattr(localizer, "snapshots", [])),
    )


def _recorders(loaded: LoadedMission, run_dir: Path | None) -> list[LocationRecorder]:
    recorders = []
    if run_dir is not None:
        recorders.append(LocationRecorder(run_dir / RECORDER_FILENAME, initial=loaded.recorder))
    if loaded.recorder is not None:
        recorders.append(LocationRecorder(loaded.recorder, initial=loaded.recorder))
    return recorders


def _status_name(status: Status) -> str:
    return {Status.SUCCESS: "succeeded", Status.FAILURE: "failed", Status.RUNNING: "running"}.get(
        status, "not_run"
    )


def _task_reports(
    mission: Any, tree: MissionTree, task_status: list[str], events: list[dict[str, Any]]
) -> list[dict[str, Any]]:
    reports = []
    for i, (task, subtree) in enumerate(zip(mission.tasks, tree.tasks, strict=True)):
        report: dict[str, Any] = {
            "index": i + 1,
            "type": task.type,
            "status": task_status[i],
            "reason": None,
        }
        if task_status[i] == "failed":
            report["reason"] = _failure_reason(subtree)
        if task.type == "patrol":
            report["waypoints"] = [
                {k: e[k] for k in ("loop", "waypoint", "t", "x", "y", "yaw", "reason") if k in e}
                | {"status": "reached" if e["event"] == "goal_reached" else "failed"}
                for e in events
                if e.get("task") == i and e["event"] in ("goal_reached", "goal_failed")
            ]
        if task.type == "visit_rooms":
            mine = [e for e in events if e.get("task") == i]
            report["rooms"] = [
                {
                    "room": room,
                    "status": "reached"
                    if any(e["event"] == "goal_reached" and e.get("room") == room for e in mine)
                    else "not_reached",
                    "recorded": any(
                        e["event"] == "room_recorded" and e.get("room") == room for e in mine
                    ),
                }
                for room in task.rooms
            ]
        reports.append(report)
    return reports


def _failure_reason(subtree: Any) -> str:
    for node in subtree.iterate():
        if node.status is Status.FAILURE and not node.children and node.feedback_message:
            return node.feedback_message
    return subtree.feedback_message or "failed"


def _metrics(
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
        "localization": {
            "position_rmse": round(float(np.sqrt(np.mean(err**2))), 5),
            "position_max_error": round(float(err.max()), 5),
            "yaw_rmse": round(float(np.sqrt(np.mean(yaw_err**2))), 5),
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
