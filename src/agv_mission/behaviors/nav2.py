"""Nav2's action nodes, acting on our navigator: its costmap, the mission's global planner
(ComputePathToPose) and controller (FollowPath), its recoveries, the selectors and the path
handlers; Nav2's conditions are in :mod:`agv_mission.behaviors.nav2_conditions`.

What Nav2's nodes pass on the blackboard: a goal is a :class:`~agv_mission.geometry.Pose2D`
(a room label or a pose mapping is read as one), goals a list of them, a path a
:class:`NavPath` (the plan and the pose it ends at). Error codes are Nav2's numbers
(``nav2_msgs/action/*.action``), written where the tree asks (``error_code_id``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import py_trees
from py_trees.common import Status

from agv_mission.behaviors.context import TreeContext, blackboard_key
from agv_mission.behaviors.ports import nav2 as _p  # noqa: E402
from agv_mission.behaviors.recoveries import BackUp
from agv_mission.geometry import Pose2D
from agv_mission.navigation.handle import RobotHandle
from agv_mission.navigation.navigator import NavStatus, NoPlan
from agv_mission.planners.base import PlannedPath
from agv_mission.planners.path_tracking import closest_point

#: ComputePathToPose's error codes by name (nav2_msgs/action/ComputePathToPose.action);
#: ComputePathThroughPoses's are these + 100.
PLANNER_CODES = {"UNKNOWN": 200, "START_OCCUPIED": 205, "GOAL_OCCUPIED": 206, "NO_VALID_PATH": 208}
#: FollowPath's (nav2_msgs/action/FollowPath.action).
CONTROLLER_CODES = {"UNKNOWN": 100, "INVALID_PATH": 103, "FAILED_TO_MAKE_PROGRESS": 105,
                    "NO_VALID_CONTROL": 106}  # fmt: skip


@dataclass(frozen=True)
class NavPath:
    """A path on the blackboard: the plan and the pose it ends at (the goal's yaw)."""

    plan: PlannedPath
    goal: Pose2D

    @property
    def points(self) -> np.ndarray:
        return self.plan.points


def entry(name: str | None) -> str | None:
    """The blackboard key a port names (``{key}`` or key)."""
    if name is None:
        return None
    return blackboard_key(name) or name


class Nav2Leaf(py_trees.behaviour.Behaviour):
    """A leaf reading and writing blackboard entries named by its ports."""

    def __init__(self, name: str, handle: RobotHandle, context: TreeContext):
        super().__init__(name)
        self.handle = handle
        self.context = context

    def read(self, port: str | None, default: Any = None) -> Any:
        key = entry(port)
        return default if key is None else self.context.blackboard.get(key, default)

    def write(self, port: str | None, value: Any) -> None:
        key = entry(port)
        if key is not None:
            self.context.blackboard[key] = value

    def pose(self, value: Any) -> Pose2D | None:
        if value is None:
            return None
        try:
            return self.context.goal_pose(value)
        except (ValueError, KeyError, TypeError, AttributeError):
            return None


class ComputePathToPose(Nav2Leaf):
    """Plan to the goal in the tick it is ticked (our planners are synchronous)."""

    offset = 0  # added to the planner's error codes (ComputePathThroughPoses: 100)

    def __init__(
        self, name: str, handle: RobotHandle, context: TreeContext, path: str,
        goal: str | None = None, goals: str | None = None, start: str | None = None,
        use_start: bool = False, error_code_id: str | None = None,
        error_msg: str | None = None, last_reached_index: str | None = None, **_ros: Any,
    ):  # fmt: skip
        super().__init__(name, handle, context)
        self.goal_port, self.goals_port, self.path_port = goal, goals, path
        self.start_port = start if use_start else None
        self.code_port, self.msg_port = error_code_id, error_msg
        self.reached_port = last_reached_index

    def targets(self) -> list[Pose2D] | None:
        goal = self.pose(self.read(self.goal_port))
        return None if goal is None else [goal]

    def update(self) -> Status:
        targets = self.targets()
        start = self.pose(self.read(self.start_port)) or self.handle.state.estimate
        if not targets:
            return self._fail("UNKNOWN", "no goal on the blackboard")
        nav = self.handle.navigator
        current = self.read(self.path_port)
        prior = current.points if isinstance(current, NavPath) else None
        pieces: list[np.ndarray] = []
        planning = 0.0
        for target in targets:
            try:
                plan = nav.plan_path(start, target, prior if len(targets) == 1 else None)
            except NoPlan as exc:
                return self._fail(exc.code, str(exc))
            pieces.append(plan.points if not pieces else plan.points[1:])
            planning += plan.planning_time
            start = target
        path = NavPath(PlannedPath(np.vstack(pieces), planning), targets[-1])
        self.write(self.path_port, path)
        self.write(self.code_port, 0)
        self.write(self.msg_port, "")
        self.write(self.reached_port, -1)
        return Status.SUCCESS

    def _fail(self, code: str, message: str) -> Status:
        self.feedback_message = message
        self.write(self.code_port, PLANNER_CODES.get(code, 200) + self.offset)
        self.write(self.msg_port, message)
        return Status.FAILURE


class ComputePathThroughPoses(ComputePathToPose):
    """Plan through every goal in order, one leg after the other."""

    offset = 100

    def targets(self) -> list[Pose2D] | None:
        goals = self.read(self.goals_port) or []
        poses = [self.pose(g) for g in goals]
        return None if any(p is None for p in poses) else poses


class FollowPath(Nav2Leaf):
    """Drive along the path in the entry with the navigator's controller; the end pose
    reached (with its yaw) is success. A failure writes Nav2's controller error code."""

    def __init__(
        self, name: str, handle: RobotHandle, context: TreeContext, path: str,
        error_code_id: str | None = None, error_msg: str | None = None,
        tracking_feedback: str | None = None, **_ros: Any,
    ):  # fmt: skip
        super().__init__(name, handle, context)
        self.path_port, self.code_port, self.msg_port = path, error_code_id, error_msg
        self.feedback_port = tracking_feedback
        self._goal: Pose2D | None = None

    def initialise(self) -> None:
        self.feedback_message = ""
        self._goal = None

    def update(self) -> Status:
        path = self.read(self.path_port)
        if not isinstance(path, NavPath) or len(path.points) == 0:
            return self._fail("INVALID_PATH", "no path to follow")
        nav, state = self.handle.navigator, self.handle.state
        nav.follow(path.plan, path.goal, state)
        self._goal = path.goal
        cmd = nav.update(state)
        self.handle.drive(cmd.v, cmd.w)
        if self.feedback_port is not None:
            self.write(self.feedback_port, round(state.estimate.distance_to(path.goal), 3))
        if nav.status is NavStatus.SUCCEEDED:
            self.handle.stop()
            self.write(self.code_port, 0)
            return Status.SUCCESS
        if nav.status is NavStatus.FAILED:
            self.handle.stop()
            return self._fail(nav.error_code or "UNKNOWN", nav.reason or "the controller failed")
        return Status.RUNNING

    def _fail(self, code: str, message: str) -> Status:
        self.feedback_message = message
        self.write(self.code_port, CONTROLLER_CODES.get(code, 100))
        self.write(self.msg_port, message)
        return Status.FAILURE

    def terminate(self, new_status: Status) -> None:
        nav = self.handle.navigator
        if (
            new_status is Status.INVALID
            and self.status is Status.RUNNING
            and nav.external
            and nav.goal is self._goal
        ):
            nav.cancel()


class SmoothPath(Nav2Leaf):
    """Passes the path on unchanged."""

    def __init__(
        self, name: str, handle: RobotHandle, context: TreeContext, unsmoothed_path: str,
        smoothed_path: str, smoothing_duration: str | None = None,
        was_completed: str | None = None, error_code_id: str | None = None, **_ros: Any,
    ):  # fmt: skip
        super().__init__(name, handle, context)
        self.ports = (unsmoothed_path, smoothed_path, smoothing_duration, was_completed)
        self.code_port = error_code_id

    def update(self) -> Status:
        source, target, duration, completed = self.ports
        path = self.read(source)
        if not isinstance(path, NavPath):
            self.feedback_message = "no path to smooth"
            self.write(self.code_port, 505)
            return Status.FAILURE
        self.write(target, path)
        self.write(duration, 0.0)
        self.write(completed, True)
        self.write(self.code_port, 0)
        return Status.SUCCESS


class DriveOnHeading(BackUp):
    """Drive straight ahead: BackUp's checks, forwards."""

    direction = 1.0
    kind = "drive_on_heading"

    def __init__(
        self, name: str, handle: RobotHandle, dist_to_travel: float = 0.15, speed: float = 0.025,
        time_allowance: float = 10.0, disable_collision_checks: bool = False, **_ros: Any,
    ):  # fmt: skip
        super().__init__(
            name, handle, dist_to_travel, speed, time_allowance, disable_collision_checks
        )


class CancelControl(Nav2Leaf):
    """Stops the path being followed."""

    def __init__(self, name: str, handle: RobotHandle, context: TreeContext, **_ros: Any):
        super().__init__(name, handle, context)

    def update(self) -> Status:
        if self.handle.navigator.status is NavStatus.RUNNING:
            self.handle.navigator.cancel()
        self.handle.stop()
        return Status.SUCCESS


class Selector(Nav2Leaf):
    """Writes its default to its ``selected_*`` entry (no selector topic here)."""

    def __init__(self, name: str, handle: RobotHandle, context: TreeContext, **ports: Any):
        super().__init__(name, handle, context)
        self.default = next((v for k, v in ports.items() if k.startswith("default_")), "")
        self.target = next((v for k, v in ports.items() if k.startswith("selected_")), None)

    def update(self) -> Status:
        self.write(self.target, self.default)
        return Status.SUCCESS


class RemovePassedGoals(Nav2Leaf):
    """Drops the leading goals within ``radius`` of the robot (the last one stays)."""

    def __init__(
        self, name: str, handle: RobotHandle, context: TreeContext, input_goals: str,
        output_goals: str, radius: float = 0.5, input_waypoint_statuses: str | None = None,
        output_waypoint_statuses: str | None = None, **_ros: Any,
    ):  # fmt: skip
        super().__init__(name, handle, context)
        self.ports = (input_goals, output_goals, input_waypoint_statuses, output_waypoint_statuses)
        self.radius = radius

    def update(self) -> Status:
        source, target, statuses_in, statuses_out = self.ports
        goals = list(self.read(source) or [])
        here = self.handle.state.estimate
        while len(goals) > 1:
            pose = self.pose(goals[0])
            if pose is None or here.distance_to(pose) > self.radius:
                break
            self.handle.log("goal_passed", node=self.name, x=round(pose.x, 3), y=round(pose.y, 3))
            goals.pop(0)
        self.write(target, goals)
        self.write(statuses_out, self.read(statuses_in, []))
        return Status.SUCCESS if goals else Status.FAILURE


def arc_lengths(points: np.ndarray) -> np.ndarray:
    """The arc length at each point of a path, from its start."""
    seg = np.linalg.norm(np.diff(points, axis=0), axis=1) if len(points) > 1 else np.zeros(0)
    return np.concatenate([[0.0], np.cumsum(seg)])


def arc_position(points: np.ndarray, pose: Pose2D) -> float:
    """The arc length of the path's closest point to ``pose``."""
    if len(points) < 2:
        return 0.0
    p = closest_point(points, (pose.x, pose.y))
    cum = arc_lengths(points)
    start = points[p.segment]
    return float(cum[p.segment] + np.linalg.norm(np.asarray(p.point) - start))


def _cut(path: NavPath, lo: float, hi: float) -> NavPath:
    points = path.points
    cum = arc_lengths(points)
    keep = (cum >= lo - 1e-9) & (cum <= hi + 1e-9)
    kept = points[keep]
    if len(kept) == 0:
        kept = points[-1:]
    end = path.goal
    if hi < cum[-1] - 1e-9:
        yaw = path.goal.yaw
        if len(kept) > 1:
            d = kept[-1] - kept[-2]
            yaw = math.atan2(d[1], d[0])
        end = Pose2D(float(kept[-1][0]), float(kept[-1][1]), yaw)
    return NavPath(PlannedPath(kept, path.plan.planning_time), end)


class TruncatePath(Nav2Leaf):
    """The path without its last ``distance`` metres."""

    def __init__(
        self, name: str, handle: RobotHandle, context: TreeContext, input_path: str,
        output_path: str, distance: float = 1.0,
    ):  # fmt: skip
        super().__init__(name, handle, context)
        self.ports, self.distance = (input_path, output_path), distance

    def update(self) -> Status:
        path = self.read(self.ports[0])
        if not isinstance(path, NavPath):
            self.feedback_message = "no path"
            return Status.FAILURE
        total = float(arc_lengths(path.points)[-1])
        self.write(self.ports[1], _cut(path, 0.0, max(total - self.distance, 0.0)))
        return Status.SUCCESS


class TruncatePathLocal(Nav2Leaf):
    """The path around the robot: ``distance_backward`` behind it to ``distance_forward``
    ahead (negative: to the end)."""

    def __init__(
        self, name: str, handle: RobotHandle, context: TreeContext, input_path: str,
        output_path: str, distance_forward: float = 8.0, distance_backward: float = 4.0,
        **_ros: Any,
    ):  # fmt: skip
        super().__init__(name, handle, context)
        self.ports = (input_path, output_path)
        self.forward, self.backward = distance_forward, distance_backward

    def update(self) -> Status:
        path = self.read(self.ports[0])
        if not isinstance(path, NavPath):
            self.feedback_message = "no path"
            return Status.FAILURE
        s = arc_position(path.points, self.handle.state.estimate)
        hi = math.inf if self.forward < 0 else s + self.forward
        self.write(self.ports[1], _cut(path, max(s - max(self.backward, 0.0), 0.0), hi))
        return Status.SUCCESS


def _selector(xml: str) -> type[Selector]:
    return type(xml, (Selector,), {"__doc__": f"Nav2's {xml}: writes its default."})


PlannerSelector = _selector("PlannerSelector")
ControllerSelector = _selector("ControllerSelector")
SmootherSelector = _selector("SmootherSelector")
GoalCheckerSelector = _selector("GoalCheckerSelector")
ProgressCheckerSelector = _selector("ProgressCheckerSelector")
PathHandlerSelector = _selector("PathHandlerSelector")


# The ports of each node type this module's behaviours are (registry slot `behavior`).
ComputePathToPose.Config = _p.ComputePathToPosePorts
ComputePathThroughPoses.Config = _p.ComputePathThroughPosesPorts
FollowPath.Config = _p.FollowPathPorts
SmoothPath.Config = _p.SmoothPathPorts
DriveOnHeading.Config = _p.DriveOnHeadingPorts
CancelControl.Config = _p.CancelControlPorts
RemovePassedGoals.Config = _p.RemovePassedGoalsPorts
TruncatePath.Config = _p.TruncatePathPorts
TruncatePathLocal.Config = _p.TruncatePathLocalPorts
PlannerSelector.Config = _p.PlannerSelectorPorts
ControllerSelector.Config = _p.ControllerSelectorPorts
SmootherSelector.Config = _p.SmootherSelectorPorts
GoalCheckerSelector.Config = _p.GoalCheckerSelectorPorts
ProgressCheckerSelector.Config = _p.ProgressCheckerSelectorPorts
PathHandlerSelector.Config = _p.PathHandlerSelectorPorts
