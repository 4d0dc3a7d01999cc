"""Mission -> py_trees behaviour tree: one sequence of task subtrees.

Every goal is a leg: ``NavigateToPose`` inside a :class:`RecoveryNode` (the configured
recoveries, one per failed attempt), optionally retried, and wrapped in a
:class:`LegOutcome` that logs how it ended and applies the task's ``on_failure``.
"""

from __future__ import annotations

from dataclasses import dataclass

import py_trees

from agv_mission.behaviors.battery import Charge, Dock, Undock
from agv_mission.behaviors.explore import MapArea, Mapper
from agv_mission.behaviors.motion import Dwell, Wander
from agv_mission.behaviors.navigate import NavigateToPose
from agv_mission.behaviors.outcome import LegOutcome
from agv_mission.behaviors.patrol import PatrolLoops
from agv_mission.behaviors.recoveries import BackUp, ClearCostmap, RecoveryNode, Spin, Wait
from agv_mission.behaviors.rooms import InRoom, RecordRoom, SettleLocalization
from agv_mission.behaviors.teleop import RemoteControl
from agv_mission.geometry import Pose2D
from agv_mission.missions.schema import (
    ChargeTask,
    DockTask,
    FailurePolicy,
    GoToTask,
    MapAreaTask,
    Mission,
    PatrolTask,
    RecordRoomTask,
    TeleopTask,
    UndockTask,
    VisitRoomsTask,
    WanderTask,
)
from agv_mission.navigation.config import NavigationConfig
from agv_mission.navigation.handle import RobotHandle
from agv_mission.robots.description import RobotDescription

Behaviour = py_trees.behaviour.Behaviour


@dataclass
class MissionTree:
    """The root and, in mission order, the subtree of each task."""

    root: Behaviour
    tasks: list[Behaviour]

    def render(self) -> str:
        return py_trees.display.unicode_tree(self.root, show_status=True)


def build_tree(
    mission: Mission,
    handle: RobotHandle,
    robot: RobotDescription,
    room_goals: dict[str, Pose2D],
    mapper: Mapper | None = None,
) -> MissionTree:
    """The tree of ``mission``; ``mapper`` serves its map_area tasks."""
    builder = _Builder(handle, robot, room_goals, mission.stack.navigation, mapper)
    tasks = [builder.task(i, task) for i, task in enumerate(mission.tasks)]
    root = py_trees.composites.Sequence(name="mission", memory=True, children=tasks)
    return MissionTree(root, tasks)


@dataclass
class _Builder:
    handle: RobotHandle
    robot: RobotDescription
    room_goals: dict[str, Pose2D]
    nav: NavigationConfig
    mapper: Mapper | None

    def task(self, index: int, task: object) -> Behaviour:
        label = f"task {index + 1}: {task.type}"  # type: ignore[attr-defined]
        if isinstance(task, GoToTask):
            p = task.pose
            return self.leg(
                f"{label} ({p.x:g}, {p.y:g}, {p.yaw:.2f})",
                self.goal("go", p.to_pose2d(), task=index),
                task,
                task=index,
            )
        if isinstance(task, PatrolTask):
            legs: list[Behaviour] = []
            for j, wp in enumerate(task.waypoints):
                details = {"task": index, "loop": 1, "waypoint": j + 1}
                name = f"waypoint {j + 1} ({wp.x:g}, {wp.y:g})"
                legs.append(
                    self.leg(name, self.goal("go", wp.to_pose2d(), **details), task, **details)
                )
                if task.dwell > 0:
                    legs.append(Dwell(f"dwell {task.dwell:g} s", self.handle, task.dwell))
            one_round = py_trees.composites.Sequence(name="round", memory=True, children=legs)
            return PatrolLoops(label, one_round, task.loops)
        if isinstance(task, VisitRoomsTask):
            visits: list[Behaviour] = []
            for room in task.rooms:
                steps: list[Behaviour] = [
                    self.goal(f"enter {room}", self.room_goals[room], task=index, room=room)
                ]
                if task.record:
                    steps.append(self.settle(task.settle))
                steps.append(InRoom(f"in {room}?", self.handle, self.handle.rooms[room]))
                if task.record:
                    steps.append(RecordRoom(f"record {room}", self.handle, room, task=index))
                visit = py_trees.composites.Sequence(
                    name=f"visit {room}", memory=True, children=steps
                )
                visits.append(self.leg(f"{room}", visit, task, task=index, room=room))
            return py_trees.composites.Sequence(name=label, memory=True, children=visits)
        if isinstance(task, WanderTask):
            speed = min(
                task.speed or self.robot.max_linear_velocity, self.robot.max_linear_velocity
            )
            turn = min(task.turn_rate, self.robot.max_angular_velocity)
            return Wander(
                label,
                self.handle,
                task.duration,
                task.min_range,
                speed,
                turn,
                task.sector,
                robot_radius=self.robot.footprint_radius,
            )
        if isinstance(task, MapAreaTask):
            if self.mapper is None:
                raise ValueError("a map_area task needs a mapper")
            return MapArea(
                label,
                self.handle,
                self.mapper,
                task.bounds.as_tuple() if task.bounds else None,
                task.save_map,
                task.coverage,
                task.time_limit,
                task.min_frontier_size,
                clearance=self.handle.navigator.global_planner.clearance,
            )
        if isinstance(task, RecordRoomTask):
            record = RecordRoom(f"record {task.room}", self.handle, task.room, task=index)
            return py_trees.composites.Sequence(
                name=label, memory=True, children=[self.settle(task.settle), record]
            )
        if isinstance(task, TeleopTask):
            return RemoteControl(label, self.handle, task.duration, task=index)
        if isinstance(task, DockTask):
            return Dock(f"{label} ({task.dock})", self.handle, dock=task.dock)
        if isinstance(task, UndockTask):
            return Undock(label, self.handle)
        if isinstance(task, ChargeTask):
            return Charge(f"{label} (to {task.until:g})", self.handle, until=task.until)
        raise TypeError(f"no behaviour for task type {type(task).__name__}")

    def settle(self, duration: float) -> Behaviour:
        """Stand still while the localiser updates (0 s: succeeds in the same tick)."""
        return SettleLocalization(f"settle {duration:g} s", self.handle, duration)

    def goal(self, name: str, pose: Pose2D, **details: object) -> Behaviour:
        """Navigate to ``pose``, with the configured recoveries between attempts."""
        navigate = NavigateToPose(name, self.handle, pose, **details)
        recoveries = [self.recovery(kind) for kind in self.nav.recoveries]
        if not recoveries:
            return navigate
        return RecoveryNode(f"{name} (with recoveries)", navigate, recoveries)

    def recovery(self, kind: str) -> Behaviour:
        nav, handle = self.nav, self.handle
        if kind == "clear_costmap":
            return ClearCostmap("clear costmap", handle)
        if kind == "spin":
            return Spin(
                "spin", handle, nav.spin_angle, min(nav.spin_rate, self.robot.max_angular_velocity)
            )
        if kind == "wait":
            return Wait(f"wait {nav.wait_time:g} s", handle, nav.wait_time)
        return BackUp("back up", handle, nav.backup_distance, nav.backup_speed)

    def leg(
        self, name: str, child: Behaviour, policy: FailurePolicy, **details: object
    ) -> Behaviour:
        """Apply the task's failure policy to one leg and log how it ends."""
        if policy.on_failure == "retry":
            child = py_trees.decorators.Retry(f"retry x{policy.retries}", child, policy.retries + 1)
        return LegOutcome(name, child, self.handle, skip=policy.on_failure == "skip", **details)
