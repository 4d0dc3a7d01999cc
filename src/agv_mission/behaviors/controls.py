"""Control nodes with BT.CPP / Nav2 semantics: children run left to right."""

from __future__ import annotations

from collections.abc import Iterator

import py_trees
from py_trees.common import Status

from agv_mission.navigation.handle import RobotHandle

Behaviour = py_trees.behaviour.Behaviour


def halt(children: list[Behaviour]) -> None:
    """Stop every child still running (a halted action stops the robot and lets go)."""
    for child in children:
        if child.status is Status.RUNNING:
            child.stop(Status.INVALID)


class Sequence(py_trees.composites.Sequence):
    """Ticks children in order; fails on the first failure, resumes at the running child."""

    def __init__(self, name: str, children: list[Behaviour]):
        super().__init__(name=name, memory=True, children=children)


class ReactiveSequence(py_trees.composites.Sequence):
    """Re-ticks every earlier child each tick: conditions guard the running action."""

    def __init__(self, name: str, children: list[Behaviour]):
        super().__init__(name=name, memory=False, children=children)


class Fallback(py_trees.composites.Selector):
    """Succeeds on the first child that succeeds; resumes at the running child."""

    def __init__(self, name: str, children: list[Behaviour]):
        super().__init__(name=name, memory=True, children=children)


class ReactiveFallback(py_trees.composites.Selector):
    """Re-ticks earlier children every tick; one that runs or succeeds halts the later."""

    def __init__(self, name: str, children: list[Behaviour]):
        super().__init__(name=name, memory=False, children=children)


class _Control(py_trees.composites.Composite):
    """A composite whose ``step`` decides the status after ticking what it ticks."""

    def __init__(self, name: str, children: list[Behaviour]):
        super().__init__(name=name, children=children)

    def tick(self) -> Iterator[Behaviour]:
        if self.status is not Status.RUNNING:
            for child in self.children:
                if child.status is not Status.INVALID:
                    child.stop(Status.INVALID)
            self.initialise()
        status = yield from self.step()
        if status is Status.RUNNING:
            self.status = Status.RUNNING
        else:
            self.stop(status)
        yield self

    def step(self) -> Iterator[Behaviour]:  # pragma: no cover - abstract
        raise NotImplementedError
        yield self

    def stop(self, new_status: Status = Status.INVALID) -> None:
        halt(self.children)
        super().stop(new_status)


class Parallel(_Control):
    """Ticks every unfinished child each tick; succeeds at ``success_count`` successes,
    fails at ``failure_count`` failures (-1: all children), halting the rest."""

    def __init__(
        self, name: str, children: list[Behaviour], success_count: int = -1, failure_count: int = 1
    ):
        super().__init__(name, children)
        self.success_count = success_count
        self.failure_count = failure_count
        self._done: dict[int, Status] = {}

    def initialise(self) -> None:
        self._done = {}

    def step(self) -> Iterator[Behaviour]:
        n = len(self.children)
        need_success = n if self.success_count < 0 else min(self.success_count, n)
        need_failure = n if self.failure_count < 0 else min(self.failure_count, n)
        for i, child in enumerate(self.children):
            if i in self._done:
                continue
            yield from child.tick()
            if child.status in (Status.SUCCESS, Status.FAILURE):
                self._done[i] = child.status
        successes = sum(s is Status.SUCCESS for s in self._done.values())
        failures = sum(s is Status.FAILURE for s in self._done.values())
        if successes >= need_success:
            return Status.SUCCESS
        if failures >= need_failure or n - failures < need_success:
            failed = next((c for c in self.children if c.status is Status.FAILURE), None)
            self.feedback_message = failed.feedback_message if failed else "failed"
            return Status.FAILURE
        return Status.RUNNING


class PipelineSequence(_Control):
    """Nav2's PipelineSequence: each tick re-ticks every child up to the furthest one
    started; earlier children that run keep running; fails when any fails."""

    def __init__(self, name: str, children: list[Behaviour]):
        super().__init__(name, children)
        self._furthest = 0

    def initialise(self) -> None:
        self._furthest = 0

    def step(self) -> Iterator[Behaviour]:
        for i, child in enumerate(self.children):
            yield from child.tick()
            if child.status is Status.FAILURE:
                self.feedback_message = child.feedback_message
                return Status.FAILURE
            if child.status is Status.RUNNING and i >= self._furthest:
                self._furthest = i
                return Status.RUNNING
        return Status.SUCCESS


class RoundRobin(_Control):
    """Nav2's RoundRobin: ticks one child at a time in turn; succeeds on the first success
    (the next tick starts at the next child); fails when every child failed in a row."""

    def __init__(self, name: str, children: list[Behaviour], wrap_around: bool = False):
        super().__init__(name, children)
        self._index = 0

    def step(self) -> Iterator[Behaviour]:
        failures = 0
        while failures < len(self.children):
            child = self.children[self._index]
            yield from child.tick()
            if child.status is Status.RUNNING:
                return Status.RUNNING
            self._index = (self._index + 1) % len(self.children)
            if child.status is Status.SUCCESS:
                return Status.SUCCESS
            failures += 1
            self.feedback_message = child.feedback_message
        return Status.FAILURE


class Recovery(_Control):
    """Nav2's RecoveryNode: the first child is the action, the second its recovery. When
    the action fails the recovery runs, then the action again, ``number_of_retries``
    times; fails when the recovery fails or the retries are spent."""

    def __init__(
        self, name: str, children: list[Behaviour], number_of_retries: int = 1,
        handle: RobotHandle | None = None,
    ):  # fmt: skip
        if len(children) != 2:
            raise ValueError("a recovery node has exactly two children")
        super().__init__(name, children)
        self.number_of_retries = number_of_retries
        self.handle = handle
        self._retries = 0
        self._current = 0

    def initialise(self) -> None:
        self._retries = 0
        self._current = 0

    def step(self) -> Iterator[Behaviour]:
        action, recovery = self.children
        while True:
            child = self.children[self._current]
            yield from child.tick()
            if child.status is Status.RUNNING:
                return Status.RUNNING
            if child is action:
                if child.status is Status.SUCCESS:
                    return Status.SUCCESS
                if self._retries >= self.number_of_retries:
                    self.feedback_message = child.feedback_message
                    return Status.FAILURE
                self._current = 1
                if self.handle is not None:  # what the tree's recoveries do, in the events
                    self.handle.log(
                        "tree_recovery", node=self.name, retry=self._retries + 1,
                        of=self.number_of_retries, reason=child.feedback_message or "failed",
                    )  # fmt: skip
            else:
                if child.status is Status.FAILURE:
                    self.feedback_message = child.feedback_message or "the recovery failed"
                    return Status.FAILURE
                self._retries += 1
                self._current = 0
                # the action runs again next tick: a node that ended restarts on its tick
                return Status.RUNNING


from agv_mission.behaviors.ports.controls import (  # noqa: E402
    FallbackPorts,
    ParallelPorts,
    PipelineSequencePorts,
    ReactiveFallbackPorts,
    ReactiveSequencePorts,
    RecoveryPorts,
    RoundRobinPorts,
    SequencePorts,
)

# The ports of each node type this module's behaviours are (registry slot `behavior`).
Fallback.Config = FallbackPorts
Parallel.Config = ParallelPorts
PipelineSequence.Config = PipelineSequencePorts
ReactiveFallback.Config = ReactiveFallbackPorts
ReactiveSequence.Config = ReactiveSequencePorts
Recovery.Config = RecoveryPorts
RoundRobin.Config = RoundRobinPorts
Sequence.Config = SequencePorts
