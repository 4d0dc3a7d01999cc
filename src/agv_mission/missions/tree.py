"""Mission -> py_trees behaviour tree: one sequence of task subtrees."""

from __future__ import annotations

from dataclasses import dataclass

import py_trees

from agv_mission.behaviors.motion import Dwell, Wander
from agv_mission.behaviors.navigate import NavigateToPose
from agv_mission.behaviors.rooms import InRoom, RecordRoom
from agv_mission.geometry import Pose2D
from agv_mission.missions.schema import (
    GoToTask,
    Mission,
    PatrolTask,
    RecordRoomTask,
    VisitRoomsTask,
    WanderTask,
)
from agv_mission.navigation.handle import RobotHandle
from agv_mission.robots.description import RobotDescription


@dataclass
class MissionTree:
    """The root and, in mission order, the subtree of each task."""

    root: py_trees.behaviour.Behaviour
    tasks: list[py_trees.behaviour.Behaviour]

    def render(self) -> str:
        return py_trees.display.unicode_tree(self.root, show_status=True)


def build_tree(
    mission: Mission,
    handle: RobotHandle,
    robot: RobotDescription,
    room_goals: dict[str, Pose2D],
) -> MissionTree:
    tasks = [
        _task_subtree(i, task, handle, robot, room_goals) for i, task in enumerate(mission.tasks)
    ]
    root = py_trees.composites.Sequence(name="mission", memory=True, children=tasks)
    return MissionTree(root, tasks)


def _task_subtree(
    index: int,
    task: object,
    handle: RobotHandle,
    robot: RobotDescription,
    room_goals: dict[str, Pose2D],
) -> py_trees.behaviour.Behaviour:
    label = f"task {index + 1}: {task.type}"  # type: ignore[attr-defined]
    if isinstance(task, GoToTask):
        p = task.pose
        return NavigateToPose(
            f"{label} ({p.x:g}, {p.y:g}, {p.yaw:.2f})", handle, p.to_pose2d(), task=index
        )
    if isinstance(task, PatrolTask):
        legs: list[py_trees.behaviour.Behaviour] = []
        for loop in range(task.loops):
            for j, wp in enumerate(task.waypoints):
                legs.append(
                    NavigateToPose(
                        f"loop {loop + 1} waypoint {j + 1} ({wp.x:g}, {wp.y:g})",
                        handle,
                        wp.to_pose2d(),
                        task=index,
                        loop=loop + 1,
                        waypoint=j + 1,
                    )
                )
                if task.dwell > 0:
                    legs.append(Dwell(f"dwell {task.dwell:g} s", handle, task.dwell))
        return py_trees.composites.Sequence(name=label, memory=True, children=legs)
    if isinstance(task, WanderTask):
        speed = task.speed if task.speed is not None else robot.max_linear_velocity
        return Wander(
            label,
            handle,
            task.duration,
            task.min_range,
            min(speed, robot.max_linear_velocity),
            min(task.turn_rate, robot.max_angular_velocity),
            task.sector,
        )
    if isinstance(task, VisitRoomsTask):
        visits: list[py_trees.behaviour.Behaviour] = []
        for room in task.rooms:
            steps: list[py_trees.behaviour.Behaviour] = [
                NavigateToPose(f"enter {room}", handle, room_goals[room], task=index, room=room),
                InRoom(f"in {room}?", handle, handle.rooms[room]),
            ]
            if task.record:
                steps.append(RecordRoom(f"record {room}", handle, room, task=index))
            visits.append(
                py_trees.composites.Sequence(name=f"visit {room}", memory=True, children=steps)
            )
        return py_trees.composites.Sequence(name=label, memory=True, children=visits)
    if isinstance(task, RecordRoomTask):
        return RecordRoom(f"{label} {task.room}", handle, task.room, task=index)
    raise TypeError(f"no behaviour for task type {type(task).__name__}")
