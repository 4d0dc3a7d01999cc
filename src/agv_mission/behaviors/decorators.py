"""Decorators with BT.CPP semantics; every time is simulated time (the handle's clock),
never the wall clock (py_trees' own Timeout reads the wall clock)."""

from __future__ import annotations

import math
from collections.abc import Iterator

import py_trees
from py_trees.common import Status

from agv_mission.navigation.handle import RobotHandle

Behaviour = py_trees.behaviour.Behaviour


class Inverter(py_trees.decorators.Inverter):
    """Success becomes failure and failure success."""

    def __init__(self, name: str, child: Behaviour):
        super().__init__(name=name, child=child)


class ForceSuccess(py_trees.decorators.Decorator):
    """Succeeds whenever its child ends."""

    def update(self) -> Status:
        return Status.RUNNING if self.decorated.status is Status.RUNNING else Status.SUCCESS


class ForceFailure(py_trees.decorators.Decorator):
    """Fails whenever its child ends."""

    def update(self) -> Status:
        if self.decorated.status is Status.RUNNING:
            return Status.RUNNING
        self.feedback_message = "forced failure"
        return Status.FAILURE


class Retry(py_trees.decorators.Retry):
    """Runs its child again after a failure, ``num_attempts`` tries in all (-1: forever)."""

    def __init__(self, name: str, child: Behaviour, num_attempts: int):
        # py_trees' Retry fails at its first failure given -1 (BT.CPP's "retry forever")
        tries = math.inf if num_attempts < 0 else num_attempts
        super().__init__(name=name, child=child, num_failures=tries)  # type: ignore[arg-type]

    def update(self) -> Status:
        status = super().update()
        if status is Status.FAILURE:
            self.feedback_message = self.decorated.feedback_message or "failed"
        return status


class Repeat(py_trees.decorators.Repeat):
    """Runs its child again after each success, ``num_cycles`` times (-1: until the
    mission's time limit); fails when the child fails."""

    def __init__(self, name: str, child: Behaviour, num_cycles: int):
        super().__init__(name=name, child=child, num_success=num_cycles)

    def update(self) -> Status:
        status = super().update()
        if status is Status.FAILURE:
            self.feedback_message = self.decorated.feedback_message or "failed"
        return status


class KeepRunningUntilFailure(py_trees.decorators.Decorator):
    """Runs its child again after every success; fails when it fails."""

    def update(self) -> Status:
        if self.decorated.status is Status.FAILURE:
            self.feedback_message = self.decorated.feedback_message or "failed"
            return Status.FAILURE
        return Status.RUNNING


class _Gate(py_trees.decorators.Decorator):
    """A decorator that decides, each tick, whether its child is ticked at all."""

    def tick(self) -> Iterator[Behaviour]:
        if self.status is not Status.RUNNING:
            self.initialise()
        status = self.gate()
        if status is None:
            yield from self.decorated.tick()
            status = self.update()
        if status is not Status.RUNNING:
            self.stop(status)
        self.status = status
        yield self

    def gate(self) -> Status | None:
        """A status to return without ticking the child, or None to tick it."""
        return None

    def update(self) -> Status:
        return self.decorated.status


class Timeout(_Gate):
    """Halts its child and fails once ``seconds`` of simulated time have passed."""

    def __init__(self, name: str, child: Behaviour, seconds: float, handle: RobotHandle):
        super().__init__(name=name, child=child)
        self.seconds = seconds
        self.handle = handle
        self._until = math.inf

    def initialise(self) -> None:
        self._until = self.handle.state.time + self.seconds

    def gate(self) -> Status | None:
        if self.handle.state.time >= self._until - 1e-9:
            self.feedback_message = f"timed out after {self.seconds:g} s"
            return Status.FAILURE
        return None


class Delay(_Gate):
    """Stands still ``seconds`` of simulated time, then runs its child."""

    def __init__(self, name: str, child: Behaviour, seconds: float, handle: RobotHandle):
        super().__init__(name=name, child=child)
        self.seconds = seconds
        self.handle = handle
        self._until = 0.0

    def initialise(self) -> None:
        self._until = self.handle.state.time + self.seconds

    def gate(self) -> Status | None:
        if self.handle.state.time < self._until - 1e-9:
            self.handle.stop()
            return Status.RUNNING
        return None


class _Throttle(_Gate):
    """Ticks its child when :meth:`due` says so or while it runs; between, returns what
    it returned last. Its state lasts until it is halted (Nav2's decorators keep theirs
    across successes)."""

    def __init__(self, name: str, child: Behaviour, handle: RobotHandle):
        super().__init__(name=name, child=child)
        self.handle = handle
        self._last: Status | None = None

    def initialise(self) -> None:
        pass

    def terminate(self, new_status: Status) -> None:
        if new_status is Status.INVALID:
            self.reset()
            self._last = None

    def reset(self) -> None:
        """Forget the state: the next tick ticks the child."""

    def due(self) -> bool:
        return True

    def ticked(self, status: Status) -> None:
        """The child ended with ``status`` (success or failure)."""

    def gate(self) -> Status | None:
        if self._last is None or self.decorated.status is Status.RUNNING or self.due():
            return None
        return self._last

    def update(self) -> Status:
        status = self.decorated.status
        if status is not Status.RUNNING:
            self.ticked(status)
        self._last = status
        if status is Status.FAILURE:
            self.feedback_message = self.decorated.feedback_message
        return status


class RateController(_Throttle):
    """Ticks its child at most ``hz`` times per simulated second (Nav2's RateController):
    once it has ended, not again until the period has passed (in between it returns what
    the child last returned); a running child is ticked every tick."""

    def __init__(self, name: str, child: Behaviour, hz: float, handle: RobotHandle):
        super().__init__(name, child, handle)
        self.period = 1.0 / hz
        self._next = -math.inf

    def reset(self) -> None:
        self._next = -math.inf

    def due(self) -> bool:
        return self.handle.state.time >= self._next - 1e-9

    def ticked(self, status: Status) -> None:
        if status is Status.SUCCESS:
            self._next = self.handle.state.time + self.period


class RunOnce(_Gate):
    """Runs its child once; afterwards succeeds at once (``then_skip``) or repeats the
    child's result without ticking it."""

    def __init__(self, name: str, child: Behaviour, then_skip: bool = True):
        super().__init__(name=name, child=child)
        self.then_skip = then_skip
        self._result: Status | None = None

    def gate(self) -> Status | None:
        if self._result is None:
            return None
        return Status.SUCCESS if self.then_skip else self._result

    def update(self) -> Status:
        status = self.decorated.status
        if status is not Status.RUNNING:
            self._result = status
        return status


class SubTree(py_trees.decorators.Decorator):
    """A named subtree (BT.CPP ``<SubTree ID>``), expanded in place: its status is its
    root's."""

    def __init__(self, name: str, child: Behaviour, tree_id: str):
        super().__init__(name=name, child=child)
        self.tree_id = tree_id

    def update(self) -> Status:
        if self.decorated.status is Status.FAILURE:
            self.feedback_message = self.decorated.feedback_message
        return self.decorated.status


from agv_mission.behaviors.ports.decorators import (  # noqa: E402
    DelayPorts,
    ForceFailurePorts,
    ForceSuccessPorts,
    InverterPorts,
    KeepRunningUntilFailurePorts,
    RateControllerPorts,
    RepeatPorts,
    RetryPorts,
    RunOncePorts,
    TimeoutPorts,
)

# The ports of each node type this module's behaviours are (registry slot `behavior`).
Delay.Config = DelayPorts
ForceFailure.Config = ForceFailurePorts
ForceSuccess.Config = ForceSuccessPorts
Inverter.Config = InverterPorts
KeepRunningUntilFailure.Config = KeepRunningUntilFailurePorts
RateController.Config = RateControllerPorts
Repeat.Config = RepeatPorts
Retry.Config = RetryPorts
RunOnce.Config = RunOncePorts
Timeout.Config = TimeoutPorts
