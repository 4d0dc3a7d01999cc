"""The navigator: pursue one goal by planning, following, checking progress and replanning.

It plays move_base's part: a global plan on the costmap, a local planner that tracks it,
an in-place rotation to the goal's yaw at the end, and replanning when the robot strays
from its path or stops making progress. Time is the simulation clock in ``RobotState``.
"""

from __future__ import annotations

import inspect
import math
from enum import Enum
from typing import Any

import numpy as np

from agv_mission.geometry import Pose2D, wrap_angle
from agv_mission.maps.costmap import Costmap
from agv_mission.maps.obstacle_layer import ObstacleLayer
from agv_mission.maps.rooms import reachable_cells
from agv_mission.maps.zones import ZoneFilters
from agv_mission.messages import LaserScan
from agv_mission.navigation.config import NavigationConfig
from agv_mission.navigation.legs import Leg, NavigationStats
from agv_mission.navigation.state import RobotState
from agv_mission.planners.base import (
    GlobalPlanner,
    LocalPlanner,
    PlannedPath,
    PlanningError,
    VelocityCommand,
    VelocityLimits,
)
from agv_mission.planners.cost_grid import CostGridPlanner
from agv_mission.planners.path_tracking import Projection, Segments, closest_point


class NavStatus(Enum):
    IDLE = "idle"
    RUNNING = "running"
    SUCCEEDED = "succeeded"
    FAILED = "failed"


class _Phase(Enum):
    FOLLOW = "follow"
    ROTATE = "rotate"


PERSON_TOLERANCE = 0.15  # m beyond a tracked person's radius: a lidar return is theirs
STANDING = 0.2  # m/s: a person slower than this stands (the costmap marks them)
PEOPLE_REACH = 5.0  # m beyond the obstacle range: people farther cannot matter this horizon


def on_people(points: np.ndarray, people: np.ndarray) -> np.ndarray:
    """Which of ``points`` (n, 2) lie on a tracked person (rows x, y, radius, ...)."""
    pts = np.asarray(points, dtype=float).reshape(-1, 2)
    rows = np.asarray(people, dtype=float)
    d2 = (pts[:, None, 0] - rows[None, :, 0]) ** 2 + (pts[:, None, 1] - rows[None, :, 1]) ** 2
    reach = rows[:, 2] + PERSON_TOLERANCE
    return (d2 <= (reach * reach)[None, :]).any(axis=1)


def beams_on_people(scan: LaserScan, pose: Pose2D, people: np.ndarray) -> np.ndarray | None:
    """Which beams of ``scan`` seen from ``pose`` end on a tracked person (rows x, y,
    radius, ...); None when no person is within the lidar's reach."""
    if not len(people):
        return None
    reach = scan.range_max + people[:, 2] + PERSON_TOLERANCE
    people = people[np.hypot(people[:, 0] - pose.x, people[:, 1] - pose.y) <= reach]
    if not len(people):
        return None
    r = scan.ranges.astype(float)
    a = scan.angles + pose.yaw
    with np.errstate(invalid="ignore"):  # no-return beams: inf or nan, on nobody
        ends = np.stack([pose.x + r * np.cos(a), pose.y + r * np.sin(a)], axis=1)
        return on_people(ends, people)


class Navigator:
    """Drives the robot to one goal at a time."""

    def __init__(
        self,
        layer: ObstacleLayer,
        global_planner: GlobalPlanner,
        local_planner: LocalPlanner,
        limits: VelocityLimits,
        config: NavigationConfig,
        control_period: float,
        seed: int = 0,
        zones: ZoneFilters | None = None,
    ) -> None:
        self.layer = layer
        self.zones = zones if zones is not None and not zones.empty else None
        self.global_planner = global_planner
        self.local_planner = local_planner
        self.limits = limits
        self.config = config
        self.control_period = control_period
        self.seed = seed
        self.status = NavStatus.IDLE
        self.reason: str | None = None
        self.goal: Pose2D | None = None
        self.path: PlannedPath | None = None
        self._segments: Segments | None = None  # the path's, for _projection
        self.paths: list[np.ndarray] = []  # every plan, for the run plot
        self.horizon: np.ndarray | None = None  # the local planner's last predicted path
        self.stats = NavigationStats()
        self._phase = _Phase.FOLLOW
        self._xy_tol = config.xy_goal_tolerance
        self._yaw_tol = config.yaw_goal_tolerance
        self._replans_for_goal = 0
        self._best_distance = math.inf
        self._last_progress_time = 0.0
        self._now = 0.0
        self._takes_prior = "prior" in inspect.signature(global_planner.plan).parameters
        self._shortest = CostGridPlanner.shortest(float(global_planner.clearance))

    @property
    def costmap(self) -> Costmap:
        """The static map with the obstacles the lidar marked."""
        return self.layer.costmap

    def observe(self, pose: Pose2D, scan: LaserScan, people: np.ndarray | None = None) -> None:
        """Mark and clear unmapped obstacles from a new scan; returns on tracked
        ``people`` walking by (rows x, y, radius, vx, vy) are not obstacles of the costmap
        (the controller avoids them where they go; a plan does not swerve round where they
        were), though their beams still clear what they pass. Someone standing still is
        an obstacle like any other until they walk on."""
        ignore = None
        if people is not None and len(people):
            people = np.asarray(people, dtype=float)
            walking = people[np.hypot(people[:, 3], people[:, 4]) >= STANDING]
            ignore = beams_on_people(scan, pose, walking)
        if ignore is None:
            self.layer.update(pose, scan)
        else:
            self.layer.update(pose, scan, ignore)

    def clear_costmap(self) -> None:
        self.layer.clear()

    def start(
        self,
        goal: Pose2D,
        state: RobotState,
        xy_tolerance: float | None = None,
        yaw_tolerance: float | None = None,
    ) -> None:
        """Begin pursuing ``goal``: plan a path from the current estimate.

        Tolerances default to the configuration's; exploration passes looser ones.
        """
        self.goal = goal
        self._xy_tol = xy_tolerance or self.config.xy_goal_tolerance
        self._yaw_tol = yaw_tolerance or self.config.yaw_goal_tolerance
        self.status = NavStatus.RUNNING
        self.reason = None
        self._phase = _Phase.FOLLOW
        self._replans_for_goal = 0
        self._best_distance = state.estimate.distance_to(goal)
        self._last_progress_time = state.time
        self.local_planner.reset()
        self._now = state.time
        self._end_leg("cancelled")
        self.stats.legs.append(Leg(goal, state.time, state.estimate))
        self.path = None
        if self._plan(state):
            leg = self.stats.legs[-1]
            leg.planned = self.path.length if self.path is not None else None
            leg.shortest = self._shortest_length(state.estimate, goal)

    def _shortest_length(self, start: Pose2D, goal: Pose2D) -> float | None:
        """The shortest path's length at the planner's clearance (None if there is none)."""
        try:
            return self._shortest.plan(self.costmap, start, goal).length
        except PlanningError:
            return None

    def _end_leg(self, status: str) -> None:
        if self.stats.legs and self.stats.legs[-1].t_end is None:
            self.stats.legs[-1].status, self.stats.legs[-1].t_end = status, self._now

    def cancel(self) -> None:
        self._end_leg("cancelled")
        self.status = NavStatus.IDLE
        self.goal = None
        self.path = None

    def update(self, state: RobotState) -> VelocityCommand:
        """One control step towards the goal; read ``status`` afterwards."""
        self._now = state.time
        self.horizon = None
        if self.status is not NavStatus.RUNNING or self.goal is None:
            return VelocityCommand(0.0, 0.0)
        pose, goal = state.estimate, self.goal
        distance = pose.distance_to(goal)
        if self._phase is _Phase.FOLLOW and distance <= self._xy_tol:
            self._phase = _Phase.ROTATE
        elif self._phase is _Phase.ROTATE and distance > 3.0 * self._xy_tol:
            self._phase = _Phase.FOLLOW
        if self._phase is _Phase.ROTATE:
            return self._rotate(state)
        return self._follow(state, distance)

    def _follow(self, state: RobotState, distance: float) -> VelocityCommand:
        assert self.goal is not None
        if distance < self._best_distance - self.config.progress_distance:
            self._best_distance = distance
            self._last_progress_time = state.time
        elif state.time - self._last_progress_time > self.config.progress_timeout and not (
            self._replan(state, f"no progress for {self.config.progress_timeout:g} s")
        ):
            return VelocityCommand(0.0, 0.0)
        here = None if self.path is None else self._projection(state.estimate)
        if here is None or here.distance > self.config.replan_distance:
            reason = "strayed from the path" if self.path is not None else "no path"
            if not self._replan(state, reason):
                return VelocityCommand(0.0, 0.0)
            here = self._projection(state.estimate)
        assert self.path is not None
        if self._path_blocked(here) and not self._replan(state, "path blocked"):
            return VelocityCommand(0.0, 0.0)
        near = state.obstacles
        if len(near):
            d = np.hypot(near[:, 0] - state.estimate.x, near[:, 1] - state.estimate.y)
            near = near[d <= self.config.obstacle_range]
        moving = None
        people = state.people
        if len(people) and getattr(self.local_planner, "predicts_moving", False):
            # a controller that predicts people gets them as people, not as the points
            # where they are now (those who could come within its reach this horizon)
            est = state.estimate
            gap = np.hypot(people[:, 0] - est.x, people[:, 1] - est.y) - people[:, 2]
            moving = people[gap <= self.config.obstacle_range + PEOPLE_REACH]
            if len(near) and len(moving):
                near = near[~on_people(near, moving)]
        if self.zones is not None:  # keepout edges are walls to the controller too
            edge = self.zones.boundary_near(
                state.estimate.x, state.estimate.y, self.config.obstacle_range
            )
            if len(edge):
                near = np.vstack([near.reshape(-1, 2), edge])
        if moving is not None:
            cmd = self.local_planner.compute(
                state.estimate, state.velocity, self.path.points, self.goal, near, moving
            )
        else:
            cmd = self.local_planner.compute(
                state.estimate, state.velocity, self.path.points, self.goal, near
            )
        self.stats.solve_times.append(cmd.solve_time)
        self.horizon = cmd.predicted
        if not cmd.ok:
            self.stats.solver_failures += 1
        return cmd

    def _rotate(self, state: RobotState) -> VelocityCommand:
        assert self.goal is not None
        error = wrap_angle(self.goal.yaw - state.estimate.yaw)
        v0, w0 = state.velocity
        dt = self.control_period
        v = (
            max(0.0, v0 - self.limits.max_acc_v * dt)
            if v0 > 0
            else min(0.0, v0 + self.limits.max_acc_v * dt)
        )
        if abs(error) <= self._yaw_tol and abs(v) < 1e-3:
            self.status = NavStatus.SUCCEEDED
            self._end_leg("succeeded")
            return VelocityCommand(0.0, 0.0)
        # P control, capped so the robot can still stop within the remaining angle.
        speed = min(
            self.config.rotate_gain * abs(error),
            math.sqrt(2.0 * self.limits.max_acc_w * abs(error)),
            self.limits.max_w,
        )
        w = math.copysign(speed, error)
        w = float(np.clip(w, w0 - self.limits.max_acc_w * dt, w0 + self.limits.max_acc_w * dt))
        return VelocityCommand(v, w)

    def _projection(self, pose: Pose2D) -> Projection:
        """The path's closest point to ``pose`` (the path's segments are kept while it
        stays the same)."""
        assert self.path is not None
        pts = self.path.points
        if len(pts) == 0:
            return Projection(0.0, np.array([pose.x, pose.y]), 0, 0.0)
        if self._segments is None or self._segments.path is not pts:
            self._segments = Segments.of(pts) if len(pts) > 1 else None
        return closest_point(pts, (pose.x, pose.y), segments=self._segments)

    def _path_blocked(self, here: Projection) -> bool:
        """Whether a marked obstacle stands on the path within ``lookahead`` of the robot
        (``here``: the robot's projection on the path)."""
        if not self.layer.has_marks or self.path is None or len(self.path.points) < 2:
            return False
        ahead = np.vstack([here.point, self.path.points[here.segment + 1 :]])
        seg = np.diff(ahead, axis=0)
        lengths = np.linalg.norm(seg, axis=1)
        cum = np.concatenate([[0.0], np.cumsum(lengths)])
        s = np.arange(0.0, min(cum[-1], self.config.blocked_lookahead), self.costmap.resolution)
        if s.size == 0:
            return False
        xy = np.stack([np.interp(s, cum, ahead[:, 0]), np.interp(s, cum, ahead[:, 1])], axis=1)
        return bool(np.any(self.costmap.clearance(xy) <= self.costmap.robot_radius))

    def _replan(self, state: RobotState, why: str) -> bool:
        if self._replans_for_goal >= self.config.max_replans:
            self._fail(
                f"goal ({self.goal.x:.2f}, {self.goal.y:.2f}) not reached: {why} "
                f"after {self._replans_for_goal} replans"
            )
            return False
        self._replans_for_goal += 1
        self.stats.replans += 1
        if self.stats.legs:
            self.stats.legs[-1].replans += 1
        self._best_distance = state.estimate.distance_to(self.goal)
        self._last_progress_time = state.time
        return self._plan(state)

    def _plan(self, state: RobotState) -> bool:
        """Plan from the current estimate; a replan hands the planner the old path, so
        planners that can (``cost_grid``) keep its way round obstacles unless blocked."""
        assert self.goal is not None
        seed = self.seed + self.stats.plans
        self.stats.plans += 1
        start = state.estimate
        goal = self.goal
        if self.zones is not None and self.zones.in_keepout(goal.x, goal.y):
            self._fail(f"goal ({goal.x:.2f}, {goal.y:.2f}) lies in a keepout zone")
            return False
        exit_point = self._keepout_exit(start)
        escape = exit_point or self._escape_point(start)
        if not self._connected(escape or start, self.goal):
            self._fail(
                f"goal ({self.goal.x:.2f}, {self.goal.y:.2f}) is unreachable: no free corridor "
                f"leads there from ({start.x:.2f}, {start.y:.2f}) on the map and the obstacles seen"
            )
            return False
        extra: dict[str, Any] = {}
        if self._takes_prior and self.path is not None:
            extra["prior"] = self.path.points
        try:
            path = self.global_planner.plan(
                self.costmap, escape or start, self.goal, seed=seed, **extra
            )
        except PlanningError as exc:
            self._fail(f"no path to ({self.goal.x:.2f}, {self.goal.y:.2f}): {exc}")
            return False
        if exit_point is not None:  # out of the keepout zone first, on the map without it
            lead = self._lead_out(start, exit_point, seed)
            path = PlannedPath(np.vstack([lead, path.points]), path.planning_time)
        elif escape is not None:  # leave the inflated margin the shortest way first
            path = PlannedPath(np.vstack([[start.x, start.y], path.points]), path.planning_time)
        self.path = path
        self.paths.append(path.points.copy())
        self.stats.planning_times.append(path.planning_time)
        return True

    def _connected(self, start: Pose2D, goal: Pose2D) -> bool:
        """Whether free space (with the planners' margin) joins start and goal: a cheap
        check that spares a sampling planner its whole time budget on a hopeless query."""
        margin = self.global_planner.clearance
        cells = reachable_cells(self.costmap, start, margin)
        rows, cols = self.costmap.grid.world_to_cell(np.array([goal.x, goal.y]))
        if not self.costmap.grid.in_bounds(rows, cols) or not cells.any():
            return True  # let the planner report what is wrong with start or goal
        return bool(cells[int(rows), int(cols)]) or not bool(
            self.costmap.is_free(np.array([goal.x, goal.y]), margin)
        )

    def _keepout_exit(self, pose: Pose2D) -> Pose2D | None:
        """Where a robot inside (or at the margin of) a keepout zone leaves it: the nearest
        point clear of it, reached straight, so it drives out instead of freezing."""
        if self.zones is None:
            return None
        out = self.zones.exit_point(pose.x, pose.y, self.global_planner.clearance + 0.02)
        return None if out is None else Pose2D(out[0], out[1], pose.yaw)

    def _lead_out(self, start: Pose2D, exit_point: Pose2D, seed: int) -> np.ndarray:
        """The way from inside a keepout zone to its exit point, planned on the map without
        the zones (around walls); straight when even that finds none."""
        assert self.zones is not None
        try:
            lead = self.global_planner.plan(self.zones.base, start, exit_point, seed=seed)
        except PlanningError:
            return np.array([[start.x, start.y]])
        return lead.points[:-1]

    def _escape_point(self, pose: Pose2D) -> Pose2D | None:
        """The nearest comfortably free point when the robot stands inside the margin the
        planners require (it drifted close to a wall); ``None`` when it is free already."""
        margin = self.global_planner.clearance + 0.01
        here = np.array([pose.x, pose.y])
        if bool(self.costmap.is_free(here, margin)):
            return None
        grid = self.costmap.grid
        rows, cols = grid.world_to_cell(here)
        reach = int(np.ceil(self.config.escape_distance / grid.resolution))
        r0, r1 = max(int(rows) - reach, 0), min(int(rows) + reach + 1, grid.height)
        c0, c1 = max(int(cols) - reach, 0), min(int(cols) + reach + 1, grid.width)
        rr, cc = np.mgrid[r0:r1, c0:c1]
        centres = grid.cell_to_world(rr.ravel(), cc.ravel())
        ok = self.costmap.is_free(centres, margin)
        if not ok.any():
            return None
        candidates = centres[ok]
        nearest = candidates[np.argmin(np.linalg.norm(candidates - here, axis=1))]
        if np.linalg.norm(nearest - here) > self.config.escape_distance:
            return None
        return Pose2D(float(nearest[0]), float(nearest[1]), pose.yaw)

    def _fail(self, reason: str) -> None:
        self.status = NavStatus.FAILED
        self.reason = reason
        self.path = None
        self._end_leg("failed")
