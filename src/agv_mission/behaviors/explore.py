"""Map an area: frontier exploration while SLAM builds the map, then save it."""

from __future__ import annotations

import math

import py_trees
from py_trees.common import Status

from agv_mission.geometry import Pose2D, wrap_angle
from agv_mission.maps.frontiers import find_frontiers
from agv_mission.navigation.handle import RobotHandle
from agv_mission.navigation.navigator import NavStatus

Bounds = tuple[float, float, float, float]


class MapArea(py_trees.behaviour.Behaviour):
    """Drive to the nearest reachable frontier until none is left, then save the map.

    Stops early at a ``coverage`` share of known cells in the bounds or after
    ``time_limit`` simulated seconds. A frontier the navigator fails to reach is
    blacklisted, so exploration never loops on an unreachable one.
    """

    RESELECT_PERIOD = 5.0  # s: re-check that the frontier being approached still exists
    GOAL_TOLERANCE = 0.25  # m: a frontier is seen from near its goal point
    SPIN_RATE = 0.8  # rad/s of the first look around

    def __init__(
        self,
        name: str,
        handle: RobotHandle,
        bounds: Bounds | None,
        save_map: str,
        coverage: float | None,
        time_limit: float | None,
        min_frontier_size: int,
        clearance: float,
    ):
        super().__init__(name)
        self.handle = handle
        self.bounds = bounds
        self.save_map = save_map
        self.coverage = coverage
        self.time_limit = time_limit
        self.min_frontier_size = min_frontier_size
        self.clearance = clearance
        self.goal: Pose2D | None = None
        self.blacklist: list[tuple[float, float]] = []
        self._deadline = math.inf
        self._reselect_at = 0.0
        self.frontiers_visited = 0

    def initialise(self) -> None:
        assert self.handle.begin_mapping is not None, "the runner provides mapping"
        self.handle.begin_mapping(self.bounds)
        self.goal = None
        self.blacklist = []
        self.frontiers_visited = 0
        now = self.handle.state.time
        self._deadline = now + self.time_limit if self.time_limit else math.inf
        self._reselect_at = now
        self._turned = 0.0
        self._last_yaw = self.handle.state.estimate.yaw

    def update(self) -> Status:
        handle, state = self.handle, self.handle.state
        mapping = handle.mapping
        assert mapping is not None
        if self._turned < 2.0 * math.pi:  # look all around before choosing a frontier
            self._turned += abs(wrap_angle(state.estimate.yaw - self._last_yaw))
            self._last_yaw = state.estimate.yaw
            handle.drive(0.0, self.SPIN_RATE)
            return Status.RUNNING
        nav = handle.navigator
        if nav.status is NavStatus.FAILED and self.goal is not None:
            self.blacklist.append((self.goal.x, self.goal.y))
            self.goal = None
        elif nav.status is NavStatus.SUCCEEDED and self.goal is not None:
            # seen from here already: if its frontier is still there, it cannot be mapped
            self.frontiers_visited += 1
            self.blacklist.append((self.goal.x, self.goal.y))
            self.goal = None
        done = self._done(state.time)
        if done is None and (self.goal is None or state.time >= self._reselect_at):
            self._reselect_at = state.time + self.RESELECT_PERIOD
            done = self._next_goal()
        if done is not None:
            nav.cancel()
            handle.stop()
            assert handle.end_mapping is not None
            summary = handle.end_mapping(self.save_map)
            handle.log("map_saved", reason=done, frontiers=self.frontiers_visited, **summary)
            self.feedback_message = done
            return Status.SUCCESS
        cmd = nav.update(state)
        handle.drive(cmd.v, cmd.w)
        return Status.RUNNING

    def _done(self, now: float) -> str | None:
        if now >= self._deadline:
            return "time limit of the task reached"
        if self.coverage is not None and self.handle.mapping.known_fraction() >= self.coverage:
            return f"coverage target {self.coverage:g} reached"
        return None

    def _next_goal(self) -> str | None:
        """Aim at the nearest frontier; ``"no reachable frontier left"`` when done."""
        handle, state = self.handle, self.handle.state
        costmap = handle.navigator.costmap
        est = state.estimate
        frontiers = find_frontiers(
            handle.mapping.grid,
            bounds=self.bounds,
            robot=(est.x, est.y),
            robot_radius=costmap.robot_radius,
            clearance=self.clearance,
            min_size=self.min_frontier_size,
            blacklist=self.blacklist,
        )
        if not frontiers:
            return "no reachable frontier left"
        if self.goal is not None and any(
            math.hypot(f.goal[0] - self.goal.x, f.goal[1] - self.goal.y) < 0.5
            for f in frontiers
            if f.goal is not None
        ):
            return None  # the frontier being approached is still there: keep driving
        best = frontiers[0]
        assert best.goal is not None
        gx, gy = best.goal
        yaw = math.atan2(best.centroid[1] - gy, best.centroid[0] - gx)
        self.goal = Pose2D(gx, gy, yaw)
        handle.navigator.start(
            self.goal, state, xy_tolerance=self.GOAL_TOLERANCE, yaw_tolerance=math.pi
        )
        return None
