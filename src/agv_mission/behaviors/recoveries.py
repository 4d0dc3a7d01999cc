"""Recoveries, as move_base and Nav2 know them, and the node that takes turns with them.

:class:`RecoveryNode` ticks its first child (the goal); each time that fails it runs the
next recovery once, then tries the goal again. When the goal has failed after every
recovery it fails for good with the goal's own reason: bounded, never a loop.
"""

from __future__ import annotations

import math
from collections.abc import Iterator

import numpy as np
import py_trees
from py_trees.common import Status

from agv_mission.behaviors.motion import Dwell
from agv_mission.geometry import wrap_angle
from agv_mission.navigation.handle import RobotHandle


class RecoveryNode(py_trees.composites.Composite):
    """Tick ``goal``; after each failure run the next recovery, then ``goal`` again."""

    def __init__(
        self,
        name: str,
        goal: py_trees.behaviour.Behaviour,
        recoveries: list[py_trees.behaviour.Behaviour],
    ):
        super().__init__(name, children=[goal, *recoveries])
        self.goal = goal
        self.recoveries = recoveries
        self._next = 0

    def tick(self) -> Iterator[py_trees.behaviour.Behaviour]:
        if self.status != Status.RUNNING:
            for child in self.children:
                if child.status != Status.INVALID:
                    child.stop(Status.INVALID)
            self._next = 0
            self.current_child = self.goal
            self.initialise()
        child = self.current_child
        assert child is not None
        yield from child.tick()
        if child.status == Status.RUNNING:
            self.status = Status.RUNNING
        elif child is self.goal and child.status == Status.SUCCESS:
            self.stop(Status.SUCCESS)
        elif child is self.goal:
            if self._next >= len(self.recoveries):
                self.feedback_message = child.feedback_message
                self.stop(Status.FAILURE)
            else:
                self.current_child = self.recoveries[self._next]
                self._next += 1
                self.status = Status.RUNNING
        else:  # a recovery ended, whatever its outcome: try the goal again next tick
            self.current_child = self.goal
            self.status = Status.RUNNING
        yield self

    def stop(self, new_status: Status = Status.INVALID) -> None:
        if new_status == Status.INVALID:
            for child in self.children:
                if child.status != Status.INVALID:
                    child.stop(Status.INVALID)
        super().stop(new_status)


class ClearCostmap(py_trees.behaviour.Behaviour):
    """Forget the obstacles the lidar marked (they may have gone, or been misread)."""

    def __init__(self, name: str, handle: RobotHandle, **_ros: object):
        super().__init__(name)
        self.handle = handle

    def update(self) -> Status:
        self.handle.navigator.clear_costmap()
        self.handle.log("recovery", kind="clear_costmap", node=self.name)
        return Status.SUCCESS


class Spin(py_trees.behaviour.Behaviour):
    """Turn in place by ``angle`` so the lidar sees all around."""

    def __init__(self, name: str, handle: RobotHandle, angle: float, rate: float):
        super().__init__(name)
        self.handle = handle
        self.angle = angle
        self.rate = rate
        self._turned = 0.0
        self._last_yaw = 0.0

    def initialise(self) -> None:
        self._turned = 0.0
        self._last_yaw = self.handle.state.estimate.yaw
        self.handle.log("recovery", kind="spin")

    def update(self) -> Status:
        yaw = self.handle.state.estimate.yaw
        self._turned += abs(wrap_angle(yaw - self._last_yaw))
        self._last_yaw = yaw
        if self._turned >= self.angle:
            self.handle.stop()
            return Status.SUCCESS
        self.handle.drive(0.0, self.rate)
        return Status.RUNNING


class Wait(Dwell):
    """Stand still for ``duration`` simulated seconds (a person may step aside)."""

    def initialise(self) -> None:
        super().initialise()
        self.handle.log("recovery", kind="wait")


class BackUp(py_trees.behaviour.Behaviour):
    """Reverse ``distance`` metres slowly, only if the costmap says the space behind is free."""

    direction = -1.0  # backwards (DriveOnHeading: forwards)
    kind = "back_up"

    def __init__(
        self, name: str, handle: RobotHandle, distance: float, speed: float,
        time_allowance: float | None = None, disable_collision_checks: bool = False,
        **_ros: object,
    ):  # fmt: skip
        super().__init__(name)
        self.handle = handle
        self.distance = distance
        self.speed = speed
        self.time_allowance = time_allowance
        self.check_collisions = not disable_collision_checks
        self._start = (0.0, 0.0)
        self._until = 0.0

    def initialise(self) -> None:
        est = self.handle.state.estimate
        self._start = (est.x, est.y)
        allowance = self.time_allowance or 3.0 * self.distance / self.speed
        self._until = self.handle.state.time + allowance
        self.feedback_message = ""

    def update(self) -> Status:
        est = self.handle.state.estimate
        if math.hypot(est.x - self._start[0], est.y - self._start[1]) >= self.distance:
            self.handle.stop()
            return Status.SUCCESS
        if self.handle.state.time > self._until:
            self.handle.stop()
            self.feedback_message = "backing up made no progress"
            return Status.FAILURE
        costmap = self.handle.navigator.costmap
        back = np.array(
            [
                [est.x + s * math.cos(est.yaw), est.y + s * math.sin(est.yaw)]
                for s in self.direction * np.linspace(0.05, self.distance + 0.05, 5)
            ]
        )
        if self.check_collisions and not costmap.is_free(back).all():
            self.handle.stop()
            self.feedback_message = (
                f"no free space {'behind' if self.direction < 0 else 'ahead of'} the robot"
            )
            self.handle.log("recovery", kind=self.kind, done=False, reason=self.feedback_message)
            return Status.FAILURE
        if self.status != Status.RUNNING:
            self.handle.log("recovery", kind=self.kind, node=self.name)
        self.handle.drive(self.direction * self.speed, 0.0)
        return Status.RUNNING


from agv_mission.behaviors.ports.actions import BackUpPorts, ClearCostmapPorts  # noqa: E402

# The ports of each node type this module's behaviours are (registry slot `behavior`).
BackUp.Config = BackUpPorts
ClearCostmap.Config = ClearCostmapPorts
