"""Motion leaves that need no planner: waiting and wandering (seed exercise 7.3)."""

from __future__ import annotations

import math

import py_trees
from py_trees.common import Status

from agv_mission.navigation.handle import RobotHandle


class Dwell(py_trees.behaviour.Behaviour):
    """Stand still for ``duration`` simulated seconds (py_trees' Timeout uses the wall clock)."""

    def __init__(self, name: str, handle: RobotHandle, duration: float):
        super().__init__(name)
        self.handle = handle
        self.duration = duration
        self._until = 0.0

    def initialise(self) -> None:
        self._until = self.handle.state.time + self.duration

    def update(self) -> Status:
        self.handle.stop()
        return Status.SUCCESS if self.handle.state.time >= self._until - 1e-9 else Status.RUNNING


class Wander(py_trees.behaviour.Behaviour):
    """Drive forward while the range ahead exceeds ``min_range``; otherwise turn in place.

    Succeeds after ``duration`` simulated seconds, like ``wander.py`` of the course.
    """

    def __init__(
        self,
        name: str,
        handle: RobotHandle,
        duration: float,
        min_range: float,
        speed: float,
        turn_rate: float,
        sector: float,
    ):
        super().__init__(name)
        self.handle = handle
        self.duration = duration
        self.min_range = min_range
        self.speed = speed
        self.turn_rate = turn_rate
        self.half_width = math.radians(sector)
        self._until = 0.0

    def initialise(self) -> None:
        self._until = self.handle.state.time + self.duration

    def update(self) -> Status:
        if self.handle.state.time >= self._until - 1e-9:
            self.handle.stop()
            return Status.SUCCESS
        if self.handle.state.range_ahead(self.half_width) > self.min_range:
            self.handle.drive(self.speed, 0.0)
            self.feedback_message = "drive"
        else:
            self.handle.drive(0.0, self.turn_rate)
            self.feedback_message = "turn"
        return Status.RUNNING
