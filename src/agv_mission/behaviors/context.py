"""What a tree's nodes share beyond the robot's handle: the blackboard, the room goals,
the navigation settings, the mapper, and the numbering of task nodes.

A node type whose constructor takes a ``context`` keyword gets the tree's
:class:`TreeContext`; one that takes ``handle`` (decorators, controls) gets the handle.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from agv_mission.behaviors.ports.values import BLACKBOARD_REF, blackboard_key
from agv_mission.geometry import Pose2D
from agv_mission.navigation.config import NavigationConfig
from agv_mission.navigation.handle import RobotHandle
from agv_mission.robots.description import RobotDescription

__all__ = ["BLACKBOARD_REF", "TreeContext", "blackboard_key"]


@dataclass
class TreeContext:
    """Shared by every node of one robot's tree."""

    handle: RobotHandle
    robot: RobotDescription
    nav: NavigationConfig
    room_goals: dict[str, Pose2D] = field(default_factory=dict)
    mapper: Any = None  # a behaviors.explore.Mapper, for map_area tasks
    blackboard: dict[str, Any] = field(default_factory=dict)
    tasks: int = 0  # task nodes numbered so far

    def next_task(self) -> int:
        """The 0-based index of the next task node (its events carry its number, the index
        plus 1, as ``task``: tasks count from 1 in every report, as in result.json)."""
        self.tasks += 1
        return self.tasks - 1

    def goal_pose(self, goal: Any) -> Pose2D:
        """A pose port's value as a pose: a Pose model, a {x, y, yaw} mapping, a room label."""
        if isinstance(goal, str):
            if goal in self.room_goals:
                return self.room_goals[goal]
            room = self.handle.rooms.get(goal)
            if room is None:
                raise ValueError(f"unknown room {goal!r}")
            if room.anchor is not None:
                return room.anchor
            x, y = room.centroid()
            return Pose2D(x, y, 0.0)
        if isinstance(goal, dict):
            return Pose2D(float(goal["x"]), float(goal["y"]), float(goal.get("yaw", 0.0)))
        if isinstance(goal, Pose2D):
            return goal
        return goal.to_pose2d()
