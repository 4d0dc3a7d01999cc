"""BehaviorTree.CPP v4's built-ins that have no older node type of ours, with BT.CPP's
semantics (``src/controls/*.cpp`` there); times are simulated time."""

from __future__ import annotations

from collections.abc import Iterator

import py_trees
from py_trees.common import Status

from agv_mission.behaviors.controls import _Control, halt
from agv_mission.behaviors.motion import Dwell
from agv_mission.navigation.handle import RobotHandle

Behaviour = py_trees.behaviour.Behaviour


class SequenceWithMemory(_Control):
    """Ticks children in order; a failure fails it and the next start resumes at the
    failed child; only when every child has succeeded does it start over."""

    def __init__(self, name: str, children: list[Behaviour]):
        super().__init__(name, children)
        self._index = 0

    def step(self) -> Iterator[Behaviour]:
        while self._index < len(self.children):
            child = self.children[self._index]
            yield from child.tick()
            if child.status is Status.RUNNING:
                return Status.RUNNING
            if child.status is Status.FAILURE:
                self.feedback_message = child.feedback_message
                return Status.FAILURE
            self._index += 1
        self._index = 0
        return Status.SUCCESS


class ParallelAll(_Control):
    """Ticks every unfinished child each tick until all have ended; fails when at least
    ``max_failures`` (-1: all) failed, succeeds otherwise."""

    def __init__(self, name: str, children: list[Behaviour], max_failures: int = 1):
        super().__init__(name, children)
        self.max_failures = max_failures
        self._done: dict[int, Status] = {}

    def initialise(self) -> None:
        self._done = {}

    def step(self) -> Iterator[Behaviour]:
        for i, child in enumerate(self.children):
            if i in self._done:
                continue
            yield from child.tick()
            if child.status in (Status.SUCCESS, Status.FAILURE):
                self._done[i] = child.status
        if len(self._done) < len(self.children):
            return Status.RUNNING
        failures = sum(s is Status.FAILURE for s in self._done.values())
        limit = len(self.children) if self.max_failures < 0 else self.max_failures
        return Status.FAILURE if failures >= max(limit, 1) else Status.SUCCESS


class IfThenElse(_Control):
    """The first child is asked once per run; then the chosen branch runs to its end."""

    def __init__(self, name: str, children: list[Behaviour]):
        super().__init__(name, children)
        self._branch = 0

    def initialise(self) -> None:
        self._branch = 0

    def step(self) -> Iterator[Behaviour]:
        if self._branch == 0:
            test = self.children[0]
            yield from test.tick()
            if test.status is Status.RUNNING:
                return Status.RUNNING
            self._branch = 1 if test.status is Status.SUCCESS else 2
            if self._branch >= len(self.children):
                self.feedback_message = "the condition failed and there is no else branch"
                return Status.FAILURE
        child = self.children[self._branch]
        yield from child.tick()
        self.feedback_message = child.feedback_message
        return child.status


class WhileDoElse(_Control):
    """The first child is asked every tick; its answer picks the branch that runs, and
    the other branch is halted."""

    def step(self) -> Iterator[Behaviour]:
        test = self.children[0]
        yield from test.tick()
        if test.status is Status.RUNNING:
            return Status.RUNNING
        branch = 1 if test.status is Status.SUCCESS else 2
        halt([c for i, c in enumerate(self.children) if i not in (0, branch)])
        if branch >= len(self.children):
            self.feedback_message = "the condition failed and there is no else branch"
            return Status.FAILURE
        child = self.children[branch]
        yield from child.tick()
        self.feedback_message = child.feedback_message
        return child.status


class AlwaysSuccess(py_trees.behaviour.Behaviour):
    """Succeeds in the tick it starts."""

    def __init__(self, name: str, handle: RobotHandle):
        super().__init__(name)

    def update(self) -> Status:
        return Status.SUCCESS


class AlwaysFailure(py_trees.behaviour.Behaviour):
    """Fails in the tick it starts."""

    def __init__(self, name: str, handle: RobotHandle):
        super().__init__(name)

    def update(self) -> Status:
        self.feedback_message = "AlwaysFailure"
        return Status.FAILURE


class Sleep(Dwell):
    """Runs for ``seconds`` of simulated time, the robot standing."""

    def __init__(self, name: str, handle: RobotHandle, seconds: float):
        super().__init__(name, handle, seconds)


from agv_mission.behaviors.ports.btcpp import (  # noqa: E402
    AlwaysFailurePorts,
    AlwaysSuccessPorts,
    IfThenElsePorts,
    ParallelAllPorts,
    SequenceWithMemoryPorts,
    SleepPorts,
    WhileDoElsePorts,
)

# The ports of each node type this module's behaviours are (registry slot `behavior`).
AlwaysFailure.Config = AlwaysFailurePorts
AlwaysSuccess.Config = AlwaysSuccessPorts
IfThenElse.Config = IfThenElsePorts
ParallelAll.Config = ParallelAllPorts
SequenceWithMemory.Config = SequenceWithMemoryPorts
Sleep.Config = SleepPorts
WhileDoElse.Config = WhileDoElsePorts
