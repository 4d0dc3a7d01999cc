"""Conditions: succeed or fail in the tick they are asked, never run."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import py_trees
from py_trees.common import Status

from agv_mission.behaviors.context import TreeContext, blackboard_key
from agv_mission.maps.rooms import reachable_cells
from agv_mission.navigation.handle import RobotHandle


class Condition(py_trees.behaviour.Behaviour):
    """A check of the robot's state: ``check`` says yes or no (and why not)."""

    def __init__(self, name: str, handle: RobotHandle):
        super().__init__(name)
        self.handle = handle

    def update(self) -> Status:
        why_not = self.check()
        if why_not is None:
            self.feedback_message = ""
            return Status.SUCCESS
        self.feedback_message = why_not
        return Status.FAILURE

    def check(self) -> str | None:
        """None when the condition holds, else why it does not."""
        raise NotImplementedError


class InRoomCondition(Condition):
    """The estimated position lies inside the room's polygon."""

    def __init__(self, name: str, handle: RobotHandle, room: str):
        super().__init__(name, handle)
        self.room = room

    def check(self) -> str | None:
        est = self.handle.state.estimate
        room = self.handle.rooms.get(self.room)
        if room is None:
            return f"unknown room {self.room!r}"
        if room.contains(est.x, est.y):
            return None
        return f"robot at ({est.x:.2f}, {est.y:.2f}) is not inside room {self.room!r}"


class AtPose(Condition):
    """The estimated position is within ``tolerance`` of ``pose``."""

    def __init__(
        self, name: str, handle: RobotHandle, pose: Any, tolerance: float, context: TreeContext
    ):
        super().__init__(name, handle)
        self.pose = context.goal_pose(pose)
        self.tolerance = tolerance

    def check(self) -> str | None:
        est = self.handle.state.estimate
        d = math.hypot(est.x - self.pose.x, est.y - self.pose.y)
        return None if d <= self.tolerance else f"{d:.2f} m from ({self.pose.x}, {self.pose.y})"


class RangeAheadBelow(Condition):
    """The nearest lidar return within ``fov`` of straight ahead is closer than
    ``distance`` (the seed's ``range_ahead < 0.8``)."""

    def __init__(self, name: str, handle: RobotHandle, distance: float, fov: float = 0.35):
        super().__init__(name, handle)
        self.distance = distance
        self.fov = fov

    def check(self) -> str | None:
        ahead = self.handle.state.range_ahead(self.fov)
        return None if ahead < self.distance else f"range ahead {ahead:.2f} m"


class PersonNear(Condition):
    """A person's edge is within ``distance`` of the robot's footprint (the distance of
    ``metrics.people``), from the people the run hands the robot's state each step."""

    def __init__(self, name: str, handle: RobotHandle, distance: float):
        super().__init__(name, handle)
        self.distance = distance

    def check(self) -> str | None:
        people = np.asarray(self.handle.state.people, dtype=float)
        if people.size == 0:
            return f"nobody within {self.distance:g} m"
        people = people.reshape(len(people), -1)[:, :3]  # x, y, radius (then velocities)
        est = self.handle.state.estimate
        footprint = float(self.handle.navigator.costmap.robot_radius)
        gaps = np.hypot(people[:, 0] - est.x, people[:, 1] - est.y) - footprint - people[:, 2]
        nearest = float(gaps.min())
        if nearest < self.distance:
            return None
        return f"nobody within {self.distance:g} m (nearest {nearest:.2f} m)"


class TimeElapsed(Condition):
    """At least ``seconds`` of simulated time since the mission started."""

    def __init__(self, name: str, handle: RobotHandle, seconds: float):
        super().__init__(name, handle)
        self.seconds = seconds

    def check(self) -> str | None:
        t = self.handle.state.time
        return None if t >= self.seconds - 1e-9 else f"t = {t:.2f} s < {self.seconds:g} s"


class CheckBlackboard(Condition):
    """Blackboard entry ``key`` equals, is below or is above a value."""

    def __init__(
        self,
        name: str,
        handle: RobotHandle,
        key: str,
        context: TreeContext,
        equals: Any = None,
        less: float | None = None,
        greater: float | None = None,
    ):
        super().__init__(name, handle)
        self.key = blackboard_key(key) or key
        self.blackboard = context.blackboard
        self.equals, self.less, self.greater = equals, less, greater

    def check(self) -> str | None:
        if self.key not in self.blackboard:
            return f"no blackboard entry {self.key!r}"
        value = self.blackboard[self.key]
        try:
            if self.equals is not None:
                ok = value == self.equals
            elif self.less is not None:
                ok = value < self.less
            else:
                ok = value > self.greater  # type: ignore[operator]
        except TypeError:
            return f"{self.key} = {value!r} cannot be compared"
        return None if ok else f"{self.key} = {value!r}"


class IsPathClear(Condition):
    """Free space (with the planner's clearance, lidar obstacles included) joins the
    robot's estimate to ``goal``: a plan exists and nothing seen blocks it."""

    def __init__(self, name: str, handle: RobotHandle, goal: Any, context: TreeContext):
        super().__init__(name, handle)
        self.goal = context.goal_pose(goal)

    def check(self) -> str | None:
        nav = self.handle.navigator
        costmap = nav.costmap
        margin = float(nav.global_planner.clearance)
        cells = reachable_cells(costmap, self.handle.state.estimate, margin)
        r, c = costmap.grid.world_to_cell(np.array([self.goal.x, self.goal.y]))
        if costmap.grid.in_bounds(r, c) and cells.any() and bool(cells[int(r), int(c)]):
            return None
        return f"no free way to ({self.goal.x:.2f}, {self.goal.y:.2f})"


from agv_mission.behaviors.ports.conditions import (  # noqa: E402
    AtPosePorts,
    CheckBlackboardPorts,
    InRoomPorts,
    IsPathClearPorts,
    PersonNearPorts,
    RangeAheadBelowPorts,
    TimeElapsedPorts,
)

# The ports of each node type this module's behaviours are (registry slot `behavior`).
AtPose.Config = AtPosePorts
CheckBlackboard.Config = CheckBlackboardPorts
InRoomCondition.Config = InRoomPorts
IsPathClear.Config = IsPathClearPorts
PersonNear.Config = PersonNearPorts
RangeAheadBelow.Config = RangeAheadBelowPorts
TimeElapsed.Config = TimeElapsedPorts
