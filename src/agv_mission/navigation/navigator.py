"""The navigator: pursue one goal by planning, following, checking progress and replanning.

It plays move_base's part: a global plan on the costmap, a local planner that tracks it,
an in-place rotation to the goal's yaw at the end, and replanning when the robot strays
from its path or stops making progress. Time is the simulation clock in ``RobotState``.

In a fleet it obeys the traffic layer's decision every control step
(:mod:`~agv_mission.navigation.traffic_orders`). The other robots' bodies
(``fleet_bodies``) are not obstacles to mark: the traffic layer keeps robots apart, and a
robot marked as a wall would make a narrow aisle unreachable
(:mod:`~agv_mission.navigation.scan_filter`).
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
from agv_mission.maps.zones import ZoneFilters
from agv_mission.navigation.config import NavigationConfig
from agv_mission.navigation.legs import Leg, NavigationStats
from agv_mission.navigation.reachability import FreeRegions, escape_point, keepout_exit
from agv_mission.navigation.scan_filter import (
    PEOPLE_REACH,
    PERSON_TOLERANCE,
    beams_on_people,
    on_people,
    standing_people,
    without_bodies,
)
from agv_mission.navigation.state import RobotState
from agv_mission.navigation.traffic_orders import ObeysTraffic, TrafficOrder
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
from agv_mission.planners.shortest_free import ShortestFreePath
from agv_mission.sensor_msgs import LaserScan


class NavStatus(Enum):
    IDLE = "idle"
    RUNNING = "running"
    SUCCEEDED = "succeeded"
    FAILED = "failed"


class NoPlan(Exception):
    """No plan to the goal: why, and the name of Nav2's error code for it."""

    def __init__(self, reason: str, code: str = "NO_VALID_PATH") -> None:
        super().__init__(reason)
        self.code = code


class _Phase(Enum):
    FOLLOW = "follow"
    ROTATE = "rotate"


class Navigator(ObeysTraffic):
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
        self._regions = FreeRegions()
        self.zones = zones if zones is not None and not zones.empty else None
        self.global_planner = global_planner
        self.local_planner = local_planner
        self.limits = limits
        self.config = config
        self.control_period = control_period
        self.seed = seed
        self.status = NavStatus.IDLE
        self.reason: str | None = None
        self.error_code: str | None = None  # Nav2's name for why it failed
        self.external = False  # following a path the tree planned (Nav2's FollowPath)
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
        self._advanced = False  # progress made since the last plan
        self._best_distance = math.inf
        self._last_progress_time = 0.0
        self._now = 0.0
        self._takes_prior = "prior" in inspect.signature(global_planner.plan).parameters
        self._shortest = CostGridPlanner.shortest(float(global_planner.clearance))
        self._shortest_free = ShortestFreePath()
        # Fleet traffic: this step's order, the detour being driven to, the other bodies.
        self.order: TrafficOrder | None = None
        self.detour: Pose2D | None = None
        self.detour_path: PlannedPath | None = None
        self.fleet_bodies: np.ndarray = np.zeros((0, 3))  # (x, y, radius) of the others
        self._updated_at = -math.inf

    def updated_at(self, now: float) -> bool:
        """Whether something (a behaviour) called :meth:`update` at time ``now``."""
        return self._updated_at == now

    @property
    def running(self) -> bool:
        """Driving to a goal."""
        return self.status is NavStatus.RUNNING

    @property
    def costmap(self) -> Costmap:
        """The static map with the obstacles the lidar marked."""
        return self.layer.costmap

    def observe(
        self,
        pose: Pose2D,
        scan: LaserScan,
        people: np.ndarray | None = None,
        ignore: np.ndarray | None = None,
    ) -> None:
        """Mark and clear unmapped obstacles from a new scan (other robots' returns
        left out: they clear, but do not mark). Returns on tracked ``people`` (rows x, y,
        radius, vx, vy, still) are not marked either, though their beams still clear what
        they pass: someone passing by is the controller's to avoid where they go (a plan
        does not swerve round where they were), and someone who has stood for
        :data:`STILL_TIME` is marked as their body grown by the controller's margin (a
        people layer) until they walk on. A caller that already knows the beams on people
        passes them as ``ignore`` (:func:`beams_on_people`)."""
        scan = self.without_fleet(pose, scan)
        tracked = people is not None and len(people) > 0
        if tracked and ignore is None:
            ignore = beams_on_people(scan, pose, people)
        if ignore is None:
            self.layer.update(pose, scan)
        else:
            self.layer.update(pose, scan, ignore)
        if tracked:
            margin = getattr(getattr(self.local_planner, "config", None), "people_margin", None)
            grow = PERSON_TOLERANCE if margin is None else float(margin)
            self.layer.set_people(standing_people(pose, scan.range_max, people, grow))

    def without_fleet(self, pose: Pose2D, scan: LaserScan) -> LaserScan:
        """``scan`` with the returns off the other robots' bodies (``fleet_bodies``, as
        the fleet layer reports them) made 'no return'."""
        return without_bodies(pose, scan, self.fleet_bodies)

    def last_progress_time(self) -> float:
        """When the robot last came closer to its goal (simulated seconds)."""
        return self._last_progress_time

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
        self._begin(goal, state, xy_tolerance, yaw_tolerance)
        self.external = False
        if self._plan(state):
            leg = self.stats.legs[-1]
            leg.planned = self.path.length if self.path is not None else None
            leg.shortest = self._shortest_length(state.estimate, goal)
            leg.shortest_free = self._shortest_free.length(self.costmap, state.estimate, goal)

    def follow(self, path: PlannedPath, goal: Pose2D, state: RobotState) -> None:
        """Follow a path planned elsewhere (Nav2's FollowPath with ComputePathToPose in the
        tree): the navigator never plans then, keeps driving when the path is blocked or
        the robot strays (the tree replans), and fails when it makes no progress. A new
        path to the same goal while it runs replaces the old one."""
        if self.status is NavStatus.RUNNING and self.external and self.goal == goal:
            self.path = path
            return
        self._begin(goal, state, None, None)
        self.external = True
        self.path = path
        self.stats.legs[-1].planned = path.length

    def _begin(
        self, goal: Pose2D, state: RobotState, xy_tolerance: float | None,
        yaw_tolerance: float | None,
    ) -> None:  # fmt: skip
        self.goal = goal
        self._xy_tol = xy_tolerance or self.config.xy_goal_tolerance
        self._yaw_tol = yaw_tolerance or self.config.yaw_goal_tolerance
        self.status = NavStatus.RUNNING
        self.reason = None
        self.error_code = None
        self._phase = _Phase.FOLLOW
        self._replans_for_goal = 0
        self._advanced = False  # progress made since the last plan
        self._best_distance = state.estimate.distance_to(goal)
        self._last_progress_time = state.time
        self._progress_pose = state.estimate
        self.local_planner.reset()
        self._now = state.time
        self._end_leg("cancelled")
        self.stats.legs.append(Leg(goal, state.time, state.estimate))
        self.path = None

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
        self._updated_at = state.time
        self.horizon = None
        if self.detour is not None:
            return self._drive_detour(state)
        if self.status is not NavStatus.RUNNING or self.goal is None:
            return VelocityCommand(0.0, 0.0)
        pose, goal = state.estimate, self.goal
        distance = pose.distance_to(goal)
        if self._phase is _Phase.FOLLOW and distance <= self._xy_tol:
            self._phase = _Phase.ROTATE
        elif self._phase is _Phase.ROTATE and distance > 3.0 * self._xy_tol:
            self._phase = _Phase.FOLLOW
        if self._phase is _Phase.ROTATE:
            return self._rotate(state)  # in place: a round footprint sweeps nothing new
        order = self.order
        if order is not None and (order.action == "wait" or order.limit is not None):
            self._last_progress_time = state.time  # held by traffic: no recovery
            if order.action == "wait":
                return VelocityCommand(0.0, 0.0)
        return self._limited(self._follow(state, distance))

    def _follow(self, state: RobotState, distance: float) -> VelocityCommand:
        assert self.goal is not None
        if self.external:  # Nav2's progress checker: the robot moved, wherever the path goes
            progressed = (
                state.estimate.distance_to(self._progress_pose) >= self.config.progress_distance
            )
            if progressed:
                self._progress_pose = state.estimate
        else:
            progressed = distance < self._best_distance - self.config.progress_distance
            if progressed:
                self._best_distance = distance
        if progressed:
            self._last_progress_time = state.time
            self._advanced = True
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
        # a robot that advanced since its last plan and sees it blocked by what it has
        # just seen plans again freely (it replans as it sees more, as move_base does)
        if self._path_blocked(here) and not self._replan(state, "path blocked", self._advanced):
            return VelocityCommand(0.0, 0.0)
        moving = self._moving_people(state)
        near = self._near(state, moving)
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

    def _moving_people(self, state: RobotState) -> np.ndarray | None:
        """The tracked people a controller that predicts them gets as people (those who
        could come within its reach this horizon); None for one that does not."""
        people = state.people
        if not len(people) or not getattr(self.local_planner, "predicts_moving", False):
            return None
        est = state.estimate
        gap = np.hypot(people[:, 0] - est.x, people[:, 1] - est.y) - people[:, 2]
        return people[gap <= self.config.obstacle_range + PEOPLE_REACH]

    def _near(self, state: RobotState, moving: np.ndarray | None = None) -> np.ndarray:
        """The obstacle points the local planner avoids: the lidar's within range (but for
        those on the ``moving`` people it predicts instead), and keepout edges (walls to
        the controller too)."""
        near = state.obstacles
        if len(near):
            d = np.hypot(near[:, 0] - state.estimate.x, near[:, 1] - state.estimate.y)
            near = near[d <= self.config.obstacle_range]
        if moving is not None and len(moving) and len(near):
            # only someone within the range can have points on them
            gap = np.hypot(moving[:, 0] - state.estimate.x, moving[:, 1] - state.estimate.y)
            gap -= moving[:, 2] + PERSON_TOLERANCE
            within = moving[gap <= self.config.obstacle_range + 0.01]
            if len(within):
                near = near[~on_people(near, within)]
        if self.zones is not None:
            edge = self.zones.boundary_near(
                state.estimate.x, state.estimate.y, self.config.obstacle_range
            )
            if len(edge):
                near = np.vstack([near.reshape(-1, 2), edge])
        return near

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

    def _replan(self, state: RobotState, why: str, free: bool = False) -> bool:
        """Plan again; ``max_replans`` of them per goal unless ``free``."""
        if self.external:  # the tree plans: keep following, or fail for its recoveries
            if self.path is not None and not why.startswith("no progress"):
                return True
            self._fail(
                f"goal ({self.goal.x:.2f}, {self.goal.y:.2f}) not reached: {why}",
                "FAILED_TO_MAKE_PROGRESS" if self.path is not None else "INVALID_PATH",
            )
            return False
        if not free and self._replans_for_goal >= self.config.max_replans:
            self._fail(
                f"goal ({self.goal.x:.2f}, {self.goal.y:.2f}) not reached: {why} "
                f"after {self._replans_for_goal} replans"
            )
            return False
        self._replans_for_goal += 0 if free else 1
        self._advanced = False
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
        prior = self.path.points if self.path is not None else None
        try:
            self.path = self.plan_path(state.estimate, self.goal, prior)
        except NoPlan as exc:
            self._fail(str(exc), exc.code)
            return False
        return True

    def plan_path(
        self, start: Pose2D, goal: Pose2D, prior: np.ndarray | None = None
    ) -> PlannedPath:
        """A plan from ``start`` to ``goal`` on the costmap as it is (leaving a keepout
        zone or the planners' margin first); :class:`NoPlan` says why there is none."""
        seed = self.seed + self.stats.plans
        self.stats.plans += 1
        if self.zones is not None and self.zones.in_keepout(goal.x, goal.y):
            raise NoPlan(
                f"goal ({goal.x:.2f}, {goal.y:.2f}) lies in a keepout zone", "GOAL_OCCUPIED"
            )
        exit_point = keepout_exit(self.zones, start, self.global_planner.clearance, self.goal)
        escape = exit_point or escape_point(
            self.costmap, start, self.global_planner.clearance + 0.01, self.config.escape_distance
        )
        if not self._regions.joins(
            self.costmap, self.layer.revision, self.global_planner.clearance, escape or start, goal
        ):
            raise NoPlan(
                f"goal ({goal.x:.2f}, {goal.y:.2f}) is unreachable: no free corridor "
                f"leads there from ({start.x:.2f}, {start.y:.2f}) on the map and the obstacles seen"
            )
        extra: dict[str, Any] = {}
        if self._takes_prior and prior is not None:
            extra["prior"] = prior
        try:
            path = self.global_planner.plan(self.costmap, escape or start, goal, seed=seed, **extra)
        except PlanningError as exc:
            raise NoPlan(f"no path to ({goal.x:.2f}, {goal.y:.2f}): {exc}") from None
        if exit_point is not None:  # out of the keepout zone first, on the map without it
            lead = self._lead_out(start, exit_point, seed)
            path = PlannedPath(np.vstack([lead, path.points]), path.planning_time)
        elif escape is not None:  # leave the inflated margin the shortest way first
            path = PlannedPath(np.vstack([[start.x, start.y], path.points]), path.planning_time)
        self.paths.append(path.points.copy())
        self.stats.planning_times.append(path.planning_time)
        return path

    def _lead_out(self, start: Pose2D, exit_point: Pose2D, seed: int) -> np.ndarray:
        """The way from inside a keepout zone to its exit point, planned on the map without
        the zones (around walls); straight when even that finds none."""
        assert self.zones is not None
        try:
            lead = self.global_planner.plan(self.zones.base, start, exit_point, seed=seed)
        except PlanningError:
            return np.array([[start.x, start.y]])
        return lead.points[:-1]

    def _fail(self, reason: str, code: str = "UNKNOWN") -> None:
        self.status = NavStatus.FAILED
        self.reason = reason
        self.error_code = code
        self.path = None
        self._end_leg("failed")
