"""Nav2's condition nodes on our navigator: is the path still valid, has the goal been
updated or reached, is the robot stuck or near its goal, which error codes are present, has
a timer expired or a distance been travelled (what Nav2's trees branch on)."""

from __future__ import annotations

from typing import Any

import numpy as np
from py_trees.common import Status

from agv_mission.behaviors.context import TreeContext
from agv_mission.behaviors.nav2 import Nav2Leaf, NavPath, arc_lengths, arc_position
from agv_mission.behaviors.ports import nav2_conditions as _p
from agv_mission.geometry import Pose2D
from agv_mission.navigation.handle import RobotHandle
from agv_mission.navigation.navigator import NavStatus

#: The codes each Would...RecoveryHelp condition answers yes to (Nav2's own sets).
RECOVERABLE = {
    "would_a_controller_recovery_help": {100, 104, 105, 106},
    "would_a_planner_recovery_help": {200, 207, 208, 300, 307, 308},
    "would_a_smoother_recovery_help": {500, 502, 503, 504},
}


class PathValid(Nav2Leaf):
    """The path ahead of the robot keeps the robot's radius clear of what the costmap
    holds (the map and the obstacles the lidar marked)."""

    def __init__(
        self, name: str, handle: RobotHandle, context: TreeContext, path: str,
        collision_poses: str | None = None, **_ros: Any,
    ):  # fmt: skip
        super().__init__(name, handle, context)
        self.path_port, self.poses_port = path, collision_poses

    def update(self) -> Status:
        path = self.read(self.path_port)
        if not isinstance(path, NavPath) or len(path.points) == 0:
            self.feedback_message = "no path"
            return Status.FAILURE
        costmap = self.handle.navigator.costmap
        points = path.points
        s = arc_position(points, self.handle.state.estimate)
        cum = arc_lengths(points)
        step = costmap.resolution
        samples = np.arange(s, cum[-1] + 1e-9, step) if cum[-1] > s else np.array([cum[-1]])
        xy = np.stack(
            [np.interp(samples, cum, points[:, 0]), np.interp(samples, cum, points[:, 1])], axis=1
        )
        blocked = costmap.clearance(xy) <= costmap.robot_radius
        self.write(self.poses_port, xy[blocked].tolist())
        if blocked.any():
            self.feedback_message = "the path is blocked"
            return Status.FAILURE
        return Status.SUCCESS


class GoalUpdated(Nav2Leaf):
    """Succeeds when the goal (or goals) differs from what it saw: when first ticked
    (GoalUpdated) or when last ticked (GlobalUpdatedGoal)."""

    def __init__(
        self, name: str, handle: RobotHandle, context: TreeContext, goal: str = "goal",
        goals: str = "goals",
    ):  # fmt: skip
        super().__init__(name, handle, context)
        self.ports = (goal, goals)
        self._seen: tuple[Any, Any] | None = None

    def initialise(self) -> None:
        if self._seen is None:
            self._seen = self._now()

    def _now(self) -> tuple[Any, Any]:
        goals = self.read(self.ports[1])
        return (self.read(self.ports[0]), tuple(goals) if goals is not None else None)

    def update(self) -> Status:
        now = self._now()
        if now != self._seen:
            self._seen = now
            return Status.SUCCESS
        return Status.FAILURE


class GoalReached(Nav2Leaf):
    """The estimate is within the navigation's xy tolerance of the goal."""

    def __init__(
        self, name: str, handle: RobotHandle, context: TreeContext, goal: str = "goal",
        **_ros: Any,
    ):  # fmt: skip
        super().__init__(name, handle, context)
        self.goal_port = goal

    def update(self) -> Status:
        goal = self.pose(self.read(self.goal_port))
        if goal is None:
            return Status.FAILURE
        near = self.handle.state.estimate.distance_to(goal) <= self.context.nav.xy_goal_tolerance
        return Status.SUCCESS if near else Status.FAILURE


class IsStuck(Nav2Leaf):
    """The navigator drives a goal but has made no progress for half its timeout."""

    def update(self) -> Status:
        nav = self.handle.navigator
        if nav.status is not NavStatus.RUNNING:
            return Status.FAILURE
        idle = self.handle.state.time - nav.last_progress_time()
        return Status.SUCCESS if idle > 0.5 * self.context.nav.progress_timeout else Status.FAILURE


class IsGoalNearby(Nav2Leaf):
    """What is left of the path is shorter than ``proximity_threshold``."""

    def __init__(
        self, name: str, handle: RobotHandle, context: TreeContext, path: str,
        proximity_threshold: float = 1.0, **_ros: Any,
    ):  # fmt: skip
        super().__init__(name, handle, context)
        self.path_port, self.threshold = path, proximity_threshold

    def update(self) -> Status:
        path = self.read(self.path_port)
        if not isinstance(path, NavPath):
            return Status.FAILURE
        left = float(arc_lengths(path.points)[-1]) - arc_position(
            path.points, self.handle.state.estimate
        )
        return Status.SUCCESS if left <= self.threshold else Status.FAILURE


class ErrorCodesPresent(Nav2Leaf):
    """The error code in the entry is one of the codes this condition checks."""

    def __init__(
        self, name: str, handle: RobotHandle, context: TreeContext, error_code: str,
        error_codes_to_check: Any = None, node_type: str = "are_error_codes_present",
    ):  # fmt: skip
        super().__init__(name, handle, context)
        self.code_port = error_code
        codes = error_codes_to_check
        if isinstance(codes, str):
            codes = [c for c in codes.replace(";", ",").split(",") if c.strip()]
        self.codes = {int(c) for c in codes} if codes else set()

    def update(self) -> Status:
        code = self.read(self.code_port, 0) or 0
        return Status.SUCCESS if int(code) in self.codes else Status.FAILURE


class AreErrorCodesPresent(ErrorCodesPresent):
    """The error code is one of ``error_codes_to_check``."""


def _checker(node_type: str) -> type[ErrorCodesPresent]:
    class Checker(ErrorCodesPresent):
        def __init__(self, name: str, handle: RobotHandle, context: TreeContext, **ports: Any):
            super().__init__(name, handle, context, **ports)
            self.codes = self.codes or set(RECOVERABLE[node_type])

    Checker.__name__ = "".join(p.capitalize() for p in node_type.split("_"))
    return Checker


WouldAControllerRecoveryHelp = _checker("would_a_controller_recovery_help")
WouldAPlannerRecoveryHelp = _checker("would_a_planner_recovery_help")
WouldASmootherRecoveryHelp = _checker("would_a_smoother_recovery_help")


class TimeExpired(Nav2Leaf):
    """Succeeds once every ``seconds`` (the first period starts at its first tick)."""

    def __init__(
        self, name: str, handle: RobotHandle, context: TreeContext, seconds: float = 1.0,
        path: str | None = None,
    ):  # fmt: skip
        super().__init__(name, handle, context)
        self.seconds, self.path_port = seconds, path
        self._since: float | None = None
        self._path: Any = None

    def update(self) -> Status:
        now = self.handle.state.time
        path = self.read(self.path_port) if self.path_port else None
        if self._since is None or path is not self._path:
            self._since, self._path = now, path
            return Status.FAILURE
        if now - self._since >= self.seconds - 1e-9:
            self._since = now
            return Status.SUCCESS
        return Status.FAILURE


class DistanceTraveled(Nav2Leaf):
    """Succeeds once every ``distance`` metres the robot drove."""

    def __init__(
        self, name: str, handle: RobotHandle, context: TreeContext, distance: float = 1.0,
        **_ros: Any,
    ):  # fmt: skip
        super().__init__(name, handle, context)
        self.distance = distance
        self._from: Pose2D | None = None

    def update(self) -> Status:
        here = self.handle.state.estimate
        if self._from is None:
            self._from = here
            return Status.FAILURE
        if here.distance_to(self._from) >= self.distance:
            self._from = here
            return Status.SUCCESS
        return Status.FAILURE


class TransformAvailable(Nav2Leaf):
    """Succeeds: the simulated robot's frames are always there."""

    def __init__(self, name: str, handle: RobotHandle, context: TreeContext, **_ros: Any):
        super().__init__(name, handle, context)

    def update(self) -> Status:
        return Status.SUCCESS


class GoalUpdatedCondition(GoalUpdated):
    """Nav2's GoalUpdated."""


class GlobalUpdatedGoal(GoalUpdated):
    """Nav2's GlobalUpdatedGoal."""


class ValidatePath(PathValid):
    """Nav2's ValidatePath."""


class IsPathValid(PathValid):
    """Nav2's IsPathValid."""


class PathExpiringTimer(TimeExpired):
    """Succeeds when ``seconds`` passed since the path last changed."""


# The ports of each node type this module's behaviours are (registry slot `behavior`).
GoalReached.Config = _p.GoalReachedPorts
IsStuck.Config = _p.IsStuckPorts
IsGoalNearby.Config = _p.IsGoalNearbyPorts
TimeExpired.Config = _p.TimeExpiredPorts
DistanceTraveled.Config = _p.DistanceTraveledPorts
TransformAvailable.Config = _p.TransformAvailablePorts
AreErrorCodesPresent.Config = _p.AreErrorCodesPresentPorts
WouldAControllerRecoveryHelp.Config = _p.WouldAControllerRecoveryHelpPorts
WouldAPlannerRecoveryHelp.Config = _p.WouldAPlannerRecoveryHelpPorts
WouldASmootherRecoveryHelp.Config = _p.WouldASmootherRecoveryHelpPorts
GoalUpdatedCondition.Config = _p.GoalUpdatedPorts
GlobalUpdatedGoal.Config = _p.GlobalUpdatedGoalPorts
ValidatePath.Config = _p.ValidatePathPorts
IsPathValid.Config = _p.IsPathValidPorts
PathExpiringTimer.Config = _p.PathExpiringTimerPorts
