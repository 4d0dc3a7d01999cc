"""Primitive actions: raw driving (the seed's cmd_vel scripts), waiting, turning,
the blackboard and the event log. A halted action leaves the robot stopped: the runner
clears the command before every tick, and only a running action sets it."""

from __future__ import annotations

from typing import Any

import py_trees
from py_trees.common import Status

from agv_mission.behaviors.context import TreeContext, blackboard_key
from agv_mission.behaviors.motion import Dwell
from agv_mission.behaviors.recoveries import Spin
from agv_mission.navigation.handle import RobotHandle


class Drive(py_trees.behaviour.Behaviour):
    """Send ``(v, w)`` for ``seconds`` of simulated time, clipped to the robot's limits."""

    def __init__(
        self, name: str, handle: RobotHandle, seconds: float, context: TreeContext,
        v: float = 0.0, w: float = 0.0,
    ):  # fmt: skip
        super().__init__(name)
        self.handle = handle
        robot = context.robot
        self.v = max(-robot.max_linear_velocity, min(robot.max_linear_velocity, v))
        self.w = max(-robot.max_angular_velocity, min(robot.max_angular_velocity, w))
        self.seconds = seconds
        self._until = 0.0

    def initialise(self) -> None:
        self._until = self.handle.state.time + self.seconds

    def update(self) -> Status:
        if self.handle.state.time >= self._until - 1e-9:
            self.handle.stop()
            return Status.SUCCESS
        self.handle.drive(self.v, self.w)
        return Status.RUNNING


class Stop(py_trees.behaviour.Behaviour):
    """Stop the robot; succeeds in the same tick."""

    def __init__(self, name: str, handle: RobotHandle):
        super().__init__(name)
        self.handle = handle

    def update(self) -> Status:
        self.handle.stop()
        return Status.SUCCESS


class WaitFor(Dwell):
    """Stand still for ``seconds`` of simulated time (Nav2's Wait; its ROS ports ignored)."""

    def __init__(self, name: str, handle: RobotHandle, seconds: float, **_ros: Any):
        super().__init__(name, handle, seconds)


class SpinBy(Spin):
    """Turn in place by ``angle`` (counter-clockwise positive) at ``rate`` (Nav2's Spin:
    fails after ``time_allowance``; a recovery event unless ``is_recovery`` is false)."""

    def __init__(
        self, name: str, handle: RobotHandle, angle: float, context: TreeContext,
        rate: float = 1.0, time_allowance: float = 10.0, is_recovery: bool = True,
        **_ros: Any,
    ):  # fmt: skip
        rate = min(rate, context.robot.max_angular_velocity)
        super().__init__(name, handle, abs(angle), rate if angle >= 0 else -rate)
        self.time_allowance = time_allowance
        self.is_recovery = is_recovery
        self._until = 0.0

    def initialise(self) -> None:
        self._turned = 0.0
        self._last_yaw = self.handle.state.estimate.yaw
        self._until = self.handle.state.time + self.time_allowance
        self.feedback_message = ""
        event = "recovery" if self.is_recovery else "behavior"
        self.handle.log(event, kind="spin", node=self.name, angle=round(self.angle, 4))

    def update(self) -> Status:
        if self.handle.state.time > self._until + 1e-9:
            self.handle.stop()
            self.feedback_message = f"spin not done within {self.time_allowance:g} s"
            return Status.FAILURE
        return super().update()


class SetBlackboard(py_trees.behaviour.Behaviour):
    """Write ``value`` to blackboard entry ``key``; succeeds in the same tick."""

    def __init__(self, name: str, handle: RobotHandle, key: str, value: Any, context: TreeContext):
        super().__init__(name)
        self.key = blackboard_key(key) or key
        self.value = value
        self.blackboard = context.blackboard

    def update(self) -> Status:
        self.blackboard[self.key] = self.value
        return Status.SUCCESS


class Log(py_trees.behaviour.Behaviour):
    """Log ``message`` (a ``log`` event of result.json); succeeds in the same tick."""

    def __init__(self, name: str, handle: RobotHandle, message: str):
        super().__init__(name)
        self.handle = handle
        self.message = message

    def update(self) -> Status:
        self.handle.log("log", message=self.message, node=self.name)
        return Status.SUCCESS


from agv_mission.behaviors.ports.actions import (  # noqa: E402
    DrivePorts,
    LogPorts,
    SetBlackboardPorts,
    SpinPorts,
    StopPorts,
    WaitPorts,
)

# The ports of each node type this module's behaviours are (registry slot `behavior`).
Drive.Config = DrivePorts
Log.Config = LogPorts
SetBlackboard.Config = SetBlackboardPorts
SpinBy.Config = SpinPorts
Stop.Config = StopPorts
WaitFor.Config = WaitPorts
