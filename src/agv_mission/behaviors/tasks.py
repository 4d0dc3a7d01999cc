"""The task types of ``mission-format.md`` as action nodes: each builds the subtree it
has always been (legs of ``NavigateToPose`` with recoveries, retries and the failure
policy) under one :class:`TaskNode`, wherever it stands in a tree.

A task node is numbered in tree order (``context.next_task()``); its events carry that
number as ``task``, and ``result.json`` reports it per task with what its ports model
(:mod:`agv_mission.behaviors.ports`) adds from those events.
"""

from __future__ import annotations

from typing import Any

import py_trees
from py_trees.common import Status

from agv_mission.behaviors.context import TreeContext
from agv_mission.behaviors.explore import MapArea
from agv_mission.behaviors.motion import Dwell, Wander
from agv_mission.behaviors.navigate import NavigateToPose
from agv_mission.behaviors.outcome import LegOutcome
from agv_mission.behaviors.patrol import PatrolLoops
from agv_mission.behaviors.recoveries import BackUp, ClearCostmap, RecoveryNode, Spin, Wait
from agv_mission.behaviors.revisit import revisit_sigma
from agv_mission.behaviors.rooms import InRoom, RecordRoom, SettleLocalization
from agv_mission.behaviors.teleop import RemoteControl
from agv_mission.geometry import Pose2D
from agv_mission.navigation.handle import RobotHandle

Behaviour = py_trees.behaviour.Behaviour


def recovery(kind: str, context: TreeContext) -> Behaviour:
    """One of the navigator's recoveries, configured by ``stack.navigation``."""
    nav, handle = context.nav, context.handle
    if kind == "clear_costmap":
        return ClearCostmap("clear costmap", handle)
    if kind == "spin":
        rate = min(nav.spin_rate, context.robot.max_angular_velocity)
        return Spin("spin", handle, nav.spin_angle, rate)
    if kind == "wait":
        return Wait(f"wait {nav.wait_time:g} s", handle, nav.wait_time)
    return BackUp("back up", handle, nav.backup_distance, nav.backup_speed)


def goal_leg(
    name: str, pose: Pose2D, context: TreeContext, recoveries: list[str] | None = None,
    **details: object,
) -> Behaviour:  # fmt: skip
    """Navigate to ``pose``, with the recoveries between attempts."""
    navigate = NavigateToPose(name, context.handle, pose, **details)
    kinds = context.nav.recoveries if recoveries is None else recoveries
    if not kinds:
        return navigate
    return RecoveryNode(
        f"{name} (with recoveries)", navigate, [recovery(k, context) for k in kinds]
    )


def settle(duration: float, handle: RobotHandle) -> Behaviour:
    """Stand still while the localiser updates (0 s: succeeds in the same tick)."""
    return SettleLocalization(f"settle {duration:g} s", handle, duration)


class TaskNode(py_trees.decorators.Decorator):
    """A task of the mission: its subtree's status, and its number and ports for reports."""

    def __init__(self, name: str, child: Behaviour, index: int, ports: dict[str, Any]):
        super().__init__(name=name, child=child)
        self.task_index = index
        self.ports = ports

    def update(self) -> Status:
        if self.decorated.status is Status.FAILURE:
            self.feedback_message = self.decorated.feedback_message
        return self.decorated.status


def _leg(
    name: str, child: Behaviour, handle: RobotHandle, on_failure: str, retries: int,
    **details: object,
) -> Behaviour:  # fmt: skip
    """Apply the task's failure policy to one leg and log how it ends."""
    if on_failure == "retry":
        child = py_trees.decorators.Retry(f"retry x{retries}", child, retries + 1)
    return LegOutcome(name, child, handle, skip=on_failure == "skip", **details)


class GoTo(TaskNode):
    """Navigate to one pose (the ``go_to`` task)."""

    def __init__(
        self, name: str, handle: RobotHandle, context: TreeContext, pose: Any,
        on_failure: str = "abort", retries: int = 1,
    ):  # fmt: skip
        i = context.next_task()
        p = context.goal_pose(pose)
        leg = _leg(
            f"{name} ({p.x:g}, {p.y:g}, {p.yaw:.2f})",
            goal_leg("go", p, context, task=i + 1),
            handle, on_failure, retries, task=i + 1,
        )  # fmt: skip
        super().__init__(name, leg, i, {"pose": pose})


class Patrol(TaskNode):
    """Visit the waypoints in order, ``loops`` times, dwelling at each."""

    def __init__(
        self, name: str, handle: RobotHandle, context: TreeContext, waypoints: list[Any],
        loops: int = 1, dwell: float = 0.0, on_failure: str = "abort", retries: int = 1,
    ):  # fmt: skip
        i = context.next_task()
        legs: list[Behaviour] = []
        for j, wp in enumerate(waypoints):
            p = context.goal_pose(wp)
            details = {"task": i + 1, "loop": 1, "waypoint": j + 1}
            goal = goal_leg("go", p, context, **details)
            name_j = f"waypoint {j + 1} ({p.x:g}, {p.y:g})"
            legs.append(_leg(name_j, goal, handle, on_failure, retries, **details))
            if dwell > 0:
                legs.append(Dwell(f"dwell {dwell:g} s", handle, dwell))
        one_round = py_trees.composites.Sequence(name="round", memory=True, children=legs)
        super().__init__(name, PatrolLoops("rounds", one_round, loops), i, {"loops": loops})


class VisitRooms(TaskNode):
    """Enter each room in order (optionally recording the pose in it)."""

    def __init__(
        self, name: str, handle: RobotHandle, context: TreeContext, rooms: list[str],
        record: bool = False, settle: float = 1.0, on_failure: str = "abort", retries: int = 1,
    ):  # fmt: skip
        i = context.next_task()
        visits: list[Behaviour] = []
        for room in rooms:
            steps: list[Behaviour] = [
                NavigateToPose(
                    f"enter {room}", handle, context.goal_pose(room), task=i + 1, room=room
                )
            ]
            kinds = context.nav.recoveries
            if kinds:
                steps[0] = RecoveryNode(
                    f"enter {room} (with recoveries)", steps[0],
                    [recovery(k, context) for k in kinds],
                )  # fmt: skip
            if record:
                steps.append(_settle(settle, handle))
            steps.append(InRoom(f"in {room}?", handle, handle.rooms[room]))
            if record:
                steps.append(RecordRoom(f"record {room}", handle, room, task=i + 1))
            visit = py_trees.composites.Sequence(name=f"visit {room}", memory=True, children=steps)
            visits.append(_leg(room, visit, handle, on_failure, retries, task=i + 1, room=room))
        seq = py_trees.composites.Sequence(name="rooms", memory=True, children=visits)
        super().__init__(name, seq, i, {"rooms": rooms})


def _settle(duration: float, handle: RobotHandle) -> Behaviour:
    return settle(duration, handle)


class RecordRoomTaskNode(TaskNode):
    """Record the estimated pose under ``room`` after settling."""

    def __init__(
        self, name: str, handle: RobotHandle, context: TreeContext, room: str, settle: float = 1.0
    ):
        i = context.next_task()
        record = RecordRoom(f"record {room}", handle, room, task=i + 1)
        seq = py_trees.composites.Sequence(
            name="settle, record", memory=True, children=[_settle(settle, handle), record]
        )
        super().__init__(name, seq, i, {"room": room})


class WanderTaskNode(TaskNode):
    """Drive ahead while the way is clear, turn otherwise, for ``duration`` seconds."""

    def __init__(
        self, name: str, handle: RobotHandle, context: TreeContext, duration: float,
        min_range: float = 0.8, speed: float | None = None, turn_rate: float = 0.4,
        sector: float = 20.0,
    ):  # fmt: skip
        i = context.next_task()
        robot = context.robot
        v = min(speed or robot.max_linear_velocity, robot.max_linear_velocity)
        turn = min(turn_rate, robot.max_angular_velocity)
        wander = Wander(
            "wander", handle, duration, min_range, v, turn, sector,
            robot_radius=robot.footprint_radius,
        )  # fmt: skip
        super().__init__(name, wander, i, {"duration": duration})


class MapAreaTaskNode(TaskNode):
    """Explore by frontiers while SLAM builds the map, then save it."""

    def __init__(
        self, name: str, handle: RobotHandle, context: TreeContext, bounds: Any = None,
        save_map: str = "map", coverage: float | None = None, time_limit: float | None = None,
        min_frontier_size: int = 8,
    ):  # fmt: skip
        if context.mapper is None:
            raise ValueError("a map_area task needs a mapper")
        i = context.next_task()
        explore = MapArea(
            "explore", handle, context.mapper,
            bounds.as_tuple() if bounds is not None else None,
            save_map, coverage, time_limit, min_frontier_size,
            clearance=handle.navigator.global_planner.clearance,
            revisit_sigma=revisit_sigma(context.robot.lidar, MapArea.FEATURE_RANGE),
        )  # fmt: skip
        super().__init__(name, explore, i, {"save_map": save_map})


class Teleop(TaskNode):
    """The robot under remote command for ``duration`` seconds (or until cancelled)."""

    def __init__(
        self, name: str, handle: RobotHandle, context: TreeContext, duration: float | None = None
    ):
        i = context.next_task()
        super().__init__(name, RemoteControl("remote control", handle, duration, task=i + 1), i, {})


class NavigateToGoal(py_trees.decorators.Decorator):
    """Plan and drive to ``goal`` (a pose or a room label), with recoveries between
    attempts: the leg every goal-directed task is made of, as a node of its own."""

    def __init__(
        self, name: str, handle: RobotHandle, goal: Any, context: TreeContext,
        recoveries: list[str] | None = None, behavior_tree: str | None = None, **_ros: Any,
    ):  # fmt: skip
        p = context.goal_pose(goal)
        super().__init__(
            name=name, child=goal_leg(f"to ({p.x:g}, {p.y:g})", p, context, recoveries)
        )

    def update(self) -> Status:
        if self.decorated.status is Status.FAILURE:
            self.feedback_message = self.decorated.feedback_message
        return self.decorated.status


from agv_mission.behaviors.ports.actions import NavigateToPosePorts  # noqa: E402
from agv_mission.behaviors.ports.tasks import (  # noqa: E402
    GoToTask,
    MapAreaTask,
    PatrolTask,
    RecordRoomTask,
    TeleopTask,
    VisitRoomsTask,
    WanderTask,
)

# The ports of each node type this module's behaviours are (registry slot `behavior`).
GoTo.Config = GoToTask
MapAreaTaskNode.Config = MapAreaTask
NavigateToGoal.Config = NavigateToPosePorts
Patrol.Config = PatrolTask
RecordRoomTaskNode.Config = RecordRoomTask
Teleop.Config = TeleopTask
VisitRooms.Config = VisitRoomsTask
WanderTaskNode.Config = WanderTask
