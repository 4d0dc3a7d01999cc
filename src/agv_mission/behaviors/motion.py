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
    """Drive forward while the way ahead is clear; otherwise turn in place.

    Clear: the range within ``sector`` of straight ahead exceeds ``min_range`` (the
    course's ``wander.py``), and no scan point lies in the corridor the robot's footprint
    (``robot_radius`` + ``SIDE_MARGIN``) would sweep over ``min_range``, so a robot as wide
    as the waffle does not scrape a wall it drives along. Succeeds after ``duration``
    simulated seconds.
    """

    SIDE_MARGIN = 0.05  # m of room kept on each side of the footprint

    def __init__(
        self,
        name: str,
        handle: RobotHandle,
        duration: float,
        min_range: float,
        speed: float,
        turn_rate: float,
        sector: float,
        robot_radius: float = 0.0,
    ):
        super().__init__(name)
        self.robot_radius = robot_radius
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
        state = self.handle.state
        clear = state.range_ahead(self.half_width) > self.min_range and not (
            state.path_ahead_blocked(self.min_range, self.robot_radius, self.SIDE_MARGIN)
        )
        if clear:
            self.handle.drive(self.speed, 0.0)
            self.feedback_message = "drive"
        else:
            self.handle.drive(0.0, self.turn_rate)
            self.feedback_message = "turn"
        return Status.RUNNING
