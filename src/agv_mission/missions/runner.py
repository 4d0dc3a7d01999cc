"""The simulation-clock loop: sensors -> estimator -> behaviour tree -> robot, step by step.

One control step every ``CONTROL_PERIOD`` simulated seconds: read encoders and (when due)
the lidar, update odometry and the localiser, tick the tree once, smooth the command
within the robot's acceleration limits, and advance the physics. The wall clock is read
only to report speed.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from py_trees.common import Status

from agv_mission.behaviors.outcome import failure_reason
from agv_mission.geometry import Pose2D, wrap_angle
from agv_mission.maps.costmap import Costmap
from agv_mission.maps.frontiers import map_quality
from agv_mission.maps.grid import OccupancyGrid
from agv_mission.maps.obstacle_layer import ObstacleLayer
from agv_mission.maps.recorder import RECORDER_FILENAME, LocationRecorder
from agv_mission.maps.ros_map import load_ros_map, save_ros_map
from agv_mission.missions.faults import FaultInjector
from agv_mission.missions.loader import LoadedMission
from agv_mission.missions.observe import (
    RunControl,
    RunObserver,
    RunStart,
    StepSample,
    TreeNode,
    tree_nodes,
)
from agv_mission.missions.tree import MissionTree, build_tree
from agv_mission.navigation.handle import RobotHandle
from agv_mission.navigation.mapping import MappingSession
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
    built_map: OccupancyGrid | None = None  # the last map a map_area task saved


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
    *,
    observers: Sequence[RunObserver] = (),
    control: RunControl | None = None,
) -> RunRecord:
    """Run ``loaded`` in simulation until its tree finishes or its time limit passes.

    With ``run_dir``, recorded room poses go to ``run_dir/location_recorder.yaml`` as they
    are recorded (and to the mission's ``recorder`` file, when it names one). Ctrl-C ends
    the run with status ``aborted``; an exception inside it with status ``error``: either
    way a record of what happened so far comes back.
    """
    run = MissionRun(loaded, run_dir)
    sampler = _Sampler(run, list(observers)) if observers else None
    try:
        if sampler is not None:
            sampler.start()
        while True:
            if control is not None:
                control.before_step(run)
            events_from = len(run.handle.events)
            going = run.step()
            if sampler is not None:
                sampler.step(events_from)
            if not going:
                break
            if progress is not None:
                progress(run.sim.time, loaded.mission.limits.time)
    except KeyboardInterrupt:
        run.end("aborted", "interrupted by the user (Ctrl-C)")
    except Exception as exc:  # the run directory must still say what happened
        run.end("error", f"{type(exc).__name__}: {exc}")
    record = run.record()
    for observer in observers:
        observer.on_end(record)
    return record


class MissionRun:
    """One mission in simulation: the components, the control loop's state, the outcome."""

    def __init__(self, loaded: LoadedMission, run_dir: Path | None) -> None:
        self.loaded = loaded
        mission, robot = loaded.mission, loaded.robot
        self.mission, self.robot = mission, robot
        seeds = np.random.SeedSequence(mission.seed).spawn(4)
        sim_rng, loc_rng, planner_rng, fault_rng = (np.random.default_rng(s) for s in seeds)
        self.sim = DiffDriveSim(robot, loaded.world, loaded.start, mission.simulation, sim_rng)
        self.odometry = DiffDriveOdometry(robot.encoder.ticks_per_meter, robot.wheel_separation)
        self.localizer = registry.create(
            "localization", mission.stack.localization, grid=loaded.world.map, rng=loc_rng
        )
        self.limits = VelocityLimits(
            max_v=robot.max_linear_velocity,
            max_w=robot.max_angular_velocity,
            max_acc_v=robot.max_linear_acceleration,
            max_acc_w=robot.max_angular_acceleration,
        )
        local_planner = registry.create(
            "local_planner",
            mission.stack.local_planner,
            limits=self.limits,
            robot_radius=robot.footprint_radius,
            control_period=CONTROL_PERIOD,
        )
        self.navigator = Navigator(
            ObstacleLayer(loaded.costmap, mission.stack.costmap.obstacles),
            registry.create("global_planner", mission.stack.global_planner),
            local_planner,
            self.limits,
            mission.stack.navigation,
            CONTROL_PERIOD,
            seed=int(planner_rng.integers(0, 2**31 - 1)),
        )
        self._odom = self.odometry.update(*self.sim.encoder_ticks())
        self._odom_start = self._odom
        self.localizer.reset(loaded.start, self._odom)
        self.handle = RobotHandle(
            RobotState(time=0.0, estimate=loaded.start),
            self.navigator,
            rooms=loaded.rooms,
            recorders=_recorders(loaded, run_dir),
        )
        self.handle.begin_mapping = self._begin_mapping
        self.handle.end_mapping = self._end_mapping
        self.run_dir = run_dir
        self.loc_rng = loc_rng
        self.maps: list[dict[str, Any]] = []
        self.built_map: OccupancyGrid | None = None
        self.tree = build_tree(mission, self.handle, robot, loaded.room_goals)
        self.smoother = VelocitySmoother(self.limits, CONTROL_PERIOD)
        self.faults = FaultInjector(mission.faults, self.sim, fault_rng)
        self.scan_period = 1.0 / robot.lidar.rate
        self.next_scan = 0.0
        self.rows: list[tuple[float, ...]] = []
        self.task_status = ["not_run"] * len(self.tree.tasks)
        self.collisions: list[dict[str, float]] = []
        self.in_contact = False
        self.min_clearance = math.inf
        self.wall_start = time.perf_counter()
        self.status: str | None = None
        self.reason: str | None = None

    def cancel(self, reason: str) -> None:
        """End the run with status ``aborted`` before the next control step."""
        self.end("aborted", reason)

    def step(self) -> bool:
        """One control step; False once the mission has ended."""
        if self.status is not None:
            return False
        sim, handle, state = self.sim, self.handle, self.handle.state
        now = sim.time
        state.time = now
        self.faults.apply(now, handle)
        odom_pose = self.odometry.update(*sim.encoder_ticks())
        scan = None
        if now >= self.next_scan - 1e-9:
            self.next_scan += self.scan_period
            scan = self.faults.filter_scan(now, sim.scan(), handle)
        truth = sim.true_pose()
        self._odom = odom_pose
        mapping = handle.mapping
        if mapping is not None:
            estimate = mapping.update(odom_pose, scan, truth, now)
            costmap = mapping.refreshed_costmap(now)
            if costmap is not None:
                self.navigator.layer = ObstacleLayer(costmap, costmap.config.obstacles)
        else:
            if handle.nomotion_update:  # the localiser holds it until a scan comes
                self.localizer.request_nomotion_update()
                handle.nomotion_update = False
            estimate = self.localizer.update(odom_pose, scan, truth, now)
        state.time, state.estimate = now, estimate
        state.velocity = (self.smoother.v, self.smoother.w)
        if scan is not None:
            state.scan = scan
            state.obstacles = scan.points(estimate)
            self.navigator.observe(estimate, scan)

        handle.stop()
        self.tree.root.tick_once()
        for i, subtree in enumerate(self.tree.tasks):
            if subtree.status is not Status.INVALID:
                self.task_status[i] = _status_name(subtree.status)
        v, w = self.smoother(*handle.command)
        self.rows.append(
            (now, truth.x, truth.y, truth.yaw, estimate.x, estimate.y, estimate.yaw, v, w)
        )
        self._watch_safety(now, truth)

        if self.status is not None:
            return False
        if self.tree.root.status is Status.SUCCESS:
            return self.end("succeeded", None)
        if self.tree.root.status is Status.FAILURE:
            return self.end("failed", self._failure())
        if now >= self.mission.limits.time - 1e-9:
            return self.end("failed", self._timeout())
        sim.set_command(v, w)
        sim.advance(CONTROL_PERIOD)
        return True

    def _begin_mapping(self, bounds: tuple[float, float, float, float] | None) -> MappingSession:
        """SLAM takes over pose and map, starting from the current estimate."""
        bounds = bounds or self.loaded.world.map.extent
        slam = registry.create("slam", self.mission.stack.slam, bounds=bounds, rng=self.loc_rng)
        session = MappingSession(
            slam, bounds, self.robot.footprint_radius, self.mission.stack.costmap
        )
        session.start(self._mapping_anchor(), self._odom)
        self.handle.mapping = session
        return session

    def _mapping_anchor(self) -> Pose2D:
        """The pose the new map is anchored at.

        A robot that has not moved since the start is where the mission said it is; a
        filter estimate there only adds its initial spread to every cell of the map.
        """
        moved = self._odom.relative_to(self._odom_start)
        if math.hypot(moved.x, moved.y) < 1e-3 and abs(moved.yaw) < 1e-3:
            return self.loaded.start
        return self.handle.state.estimate

    def _end_mapping(self, stem: str) -> dict[str, Any]:
        """Save the map, judge it against the world, and navigate on it from now on."""
        session = self.handle.mapping
        assert session is not None
        grid = session.grid
        summary: dict[str, Any] = {"map": stem}
        if self.run_dir is not None:
            save_ros_map(grid, self.run_dir / stem)
            grid = load_ros_map(self.run_dir / f"{stem}.yaml")  # navigate on what was saved
        quality = map_quality(
            grid,
            self.loaded.world.map,
            session.bounds,
            start=(self.loaded.start.x, self.loaded.start.y),
        )
        summary.update({k: round(v, 4) for k, v in quality.items()})
        summary["slam_rmse"] = round(self._slam_rmse(session), 4)
        summary["known_fraction"] = round(session.known_fraction(), 4)
        self.maps.append(summary)
        self.built_map = grid
        static = Costmap.from_grid(grid, self.robot.footprint_radius, self.mission.stack.costmap)
        self.navigator.layer = ObstacleLayer(static, self.mission.stack.costmap.obstacles)
        self.localizer = registry.create(
            "localization", self.mission.stack.localization, grid=grid, rng=self.loc_rng
        )
        self.localizer.reset(session.slam.pose, self._odom)
        self.handle.mapping = None
        return summary

    def _slam_rmse(self, session: MappingSession) -> float:
        """SLAM trajectory error against the true trajectory at the same times."""
        est = np.asarray(session.slam.trajectory, dtype=float).reshape(-1, 4)
        if not len(est) or not self.rows:
            return float("nan")
        rows = np.asarray(self.rows)
        idx = np.clip(np.searchsorted(rows[:, 0], est[:, 0] - 1e-9), 0, len(rows) - 1)
        err = np.hypot(est[:, 1] - rows[idx, 1], est[:, 2] - rows[idx, 2])
        return float(np.sqrt(np.mean(err**2)))

    def end(self, status: str, reason: str | None) -> bool:
        if self.status is None:
            fired = self.faults.describe_fired()
            if status == "failed" and fired:
                reason = f"{reason} (faults fired: {fired})"
            self.status, self.reason = status, reason
            self.sim.set_command(0.0, 0.0)
        return False

    def _watch_safety(self, now: float, truth: Pose2D) -> None:
        contacts = self.sim.contacts()
        if contacts and not self.in_contact:
            self.collisions.append(
                {"t": round(now, 3), "x": round(truth.x, 3), "y": round(truth.y, 3)}
            )
            if len(self.collisions) > self.mission.limits.collisions:
                self.end(
                    "failed", f"collision at t={now:.1f} s near ({truth.x:.2f}, {truth.y:.2f})"
                )
        self.in_contact = contacts > 0
        self.min_clearance = min(self.min_clearance, self.sim.min_clearance())

    def _failure(self) -> str:
        i = next((i for i, s in enumerate(self.task_status) if s == "failed"), None)
        if i is None:
            return "mission failed"
        return (
            f"task {i + 1} ({self.mission.tasks[i].type}) failed: "
            f"{failure_reason(self.tree.tasks[i])}"
        )

    def _timeout(self) -> str:
        i = next((i for i, s in enumerate(self.task_status) if s == "running"), None)
        limit = self.mission.limits.time
        if i is None:
            return f"time limit of {limit:g} s reached"
        self.task_status[i] = "failed"
        self.tree.tasks[i].feedback_message = "time limit reached"
        return (
            f"time limit of {limit:g} s reached during task {i + 1} ({self.mission.tasks[i].type})"
        )

    def record(self) -> RunRecord:
        """The outcome so far, as the run directory will hold it."""
        if self.status is None:
            self.end("error", "the run ended without an outcome")
        wall_time = time.perf_counter() - self.wall_start
        sim_time = self.sim.time
        trajectory = np.asarray(self.rows, dtype=float).reshape(-1, len(TRAJECTORY_COLUMNS))
        if self.status in ("aborted", "error"):
            self.task_status = ["aborted" if s == "running" else s for s in self.task_status]
        tasks = _task_reports(self.mission, self.tree, self.task_status, self.handle.events)
        _add_true_errors(tasks, trajectory)
        metrics = _metrics(
            trajectory,
            self.navigator,
            len(self.collisions),
            self.min_clearance,
            sim_time,
            wall_time,
        )
        recoveries: dict[str, int] = {}
        for e in self.handle.events:
            if e["event"] == "recovery":
                recoveries[e["kind"]] = recoveries.get(e["kind"], 0) + 1
        metrics["navigation"]["recoveries"] = recoveries
        extras: dict[str, Any] = {"collisions": self.collisions, "faults": self.faults.report()}
        if self.maps:
            extras["maps"] = self.maps
        if self.handle.recorded:
            extras["rooms_recorded"] = {
                label: {"x": round(p.x, 4), "y": round(p.y, 4), "yaw": round(p.yaw, 4)}
                for label, p in self.handle.recorded.items()
            }
        counts = getattr(self.localizer, "particle_counts", None)
        if counts:
            c = np.asarray([n for _, n in counts])
            metrics["localization"]["particles"] = {
                "min": int(c.min()),
                "max": int(c.max()),
                "mean": round(float(c.mean()), 1),
            }
            extras["particle_counts"] = [[round(t, 3), int(n)] for t, n in counts]
        return RunRecord(
            status=self.status or "error",
            reason=self.reason,
            sim_time=round(sim_time, 6),
            wall_time=round(wall_time, 3),
            tasks=tasks,
            metrics=metrics,
            trajectory=trajectory,
            paths=self.navigator.paths,
            events=self.handle.events,
            tree_text=self.tree.render(),
            extras=extras,
            particle_snapshots=list(getattr(self.localizer, "snapshots", [])),
            built_map=self.built_map,
        )


class _Sampler:
    """Builds a :class:`StepSample` per control step for the observers."""

    def __init__(self, run: MissionRun, observers: list[RunObserver]) -> None:
        self.run, self.observers = run, observers
        self.plans = 0
        self.filter_updates = -1
        self.nodes: list[TreeNode] = tree_nodes(run.tree.root)

    def start(self) -> None:
        run, loaded = self.run, self.run.loaded
        start = RunStart(
            run.run_dir,
            run.mission,
            run.robot,
            loaded.world.map,
            loaded.rooms,
            loaded.start,
            self.nodes,
        )
        for observer in self.observers:
            observer.on_start(start)

    def step(self, events_from: int) -> None:
        run = self.run
        if not run.rows:
            return
        t, x, y, yaw, ex, ey, eyaw, v, w = run.rows[-1]
        nav = run.navigator
        plan = None
        if len(nav.paths) != self.plans:
            self.plans = len(nav.paths)
            plan = nav.paths[-1]
        particles = None
        updates = getattr(run.localizer, "filter_updates", None)
        if updates is not None and updates != self.filter_updates:
            self.filter_updates = updates
            particles = run.localizer.particles
        nodes = tree_nodes(run.tree.root)
        changed = nodes != self.nodes
        self.nodes = nodes
        task = next((i for i, s in enumerate(run.task_status) if s == "running"), None)
        state = run.handle.state
        sample = StepSample(
            t=t,
            truth=Pose2D(x, y, yaw),
            estimate=Pose2D(ex, ey, eyaw),
            covariance=None,
            odom=run._odom,
            v=v,
            w=w,
            scan=state.scan if state.scan is not None and abs(state.scan.time - t) < 1e-6 else None,
            particles=particles,
            plan=plan,
            horizon=None,
            goal=nav.goal,
            grid=None,
            events=run.handle.events[events_from:],
            tree_nodes=nodes if changed else None,
            task_index=task,
            task_type=run.mission.tasks[task].type if task is not None else None,
        )
        for observer in self.observers:
            observer.on_step(sample)


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


_OUTCOMES = {"goal_reached": "reached", "goal_failed": "failed", "goal_skipped": "skipped"}


def _task_reports(
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


def _add_true_errors(tasks: list[dict[str, Any]], trajectory: np.ndarray) -> None:
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
