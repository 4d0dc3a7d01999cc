"""Robots deciding in parallel processes, on one world replicated in each: the forked
:class:`~agv_mission.missions.run.team.RobotTeam`.

A fleet's cost is its robots' decisions: sensing, localisation, the tree and the MPC of
every robot, one after the other on one core. A :class:`ForkedTeam` spreads them over
processes forked from the set-up run: every process holds the whole run (the world, every
robot, the fleet layer, the people) and steps it the same way, but each robot senses,
estimates and decides in one process only, its owner; the other processes stand for it
with its :class:`~agv_mission.missions.run.samples.RobotReport`. Physics, people and the
fleet layer's decisions are deterministic given the same inputs, so the replicas stay
identical and the outcome is the one of a single process, bit for bit (a test runs both).

A step has two exchanges, through the first process (the one the run was set up in,
which also owns robots and alone talks to observers): the robots' reports after they
decided, their outcomes (and the observers' samples) after they concluded. At the end
the first process gathers the other processes' robots' records.

Processes are forked (POSIX), only from a process that runs no other thread
(:func:`~agv_mission.missions.run.team.team_size` says how many).
"""

from __future__ import annotations

import contextlib
import dataclasses
import multiprocessing
import os
import signal
import sys
import traceback
import weakref
from collections.abc import Callable
from multiprocessing.connection import Connection
from pathlib import Path
from typing import TYPE_CHECKING, Any

from agv_mission.missions.run.team import advance_world

if TYPE_CHECKING:
    from agv_mission.missions.run.fleet_orders import FleetCoordinator, FleetOrder
    from agv_mission.missions.run.record import RunRecord
    from agv_mission.missions.run.robot_run import RobotRun
    from agv_mission.missions.run.samples import RobotReport, StepSample
    from agv_mission.world.simulation import SimulatedWorld

_UNSENT = object()

#: The observers' work (the bag's messages of every robot), which the first process does
#: while the others decide, in robots' decisions per robot: bench_fleet's 10-robot
#: mission with a BagWriter spent 0.21 s of CPU in on_step over 30 simulated seconds
#: (0.7 ms per robot per simulated second) against ~11 ms per robot deciding.
OBSERVED_EXTRA = 0.065


def shares(robots: int, size: int, first_extra: float = 0.0) -> list[range]:
    """Contiguous blocks of robot indices for ``size`` processes, even in work when the
    first process also carries ``first_extra`` of a robot's decisions per robot while
    the others decide (the fleet layer and the physics run between the steps' decisions,
    while the others wait: not counted)."""
    total = robots * (1.0 + first_extra)
    first = min(robots, max(0, round(total / size - robots * first_extra - 1e-9)))
    rest, others = robots - first, max(size - 1, 1)
    bounds = [0, first] + [first + (rest * p) // others for p in range(1, others + 1)]
    return [range(bounds[p], bounds[p + 1]) for p in range(size)]


class TeamError(RuntimeError):
    """A robot process failed (the message names the exception and where) or ended
    unexpectedly."""


class _Finish(Exception):
    """The first process asks for the records: unwind a robot process's step."""

    def __init__(self, message: tuple[Any, ...]) -> None:
        super().__init__("finish")
        self.message = message


class ForkedTeam:
    """Robots deciding in forked processes: which decide in this one, and the exchanges
    with the others (made by :meth:`fork`)."""

    observe_later = True  # the samples are observed while the robot processes decide

    def __init__(self, robots: list[RobotRun], own: list[int]) -> None:
        self.robots = robots
        self.own_indices = own
        self.own = [robots[k] for k in own]
        self.links: list[Connection] = []  # the first process: one per robot process
        self.pids: list[int] = []
        self.parent: Connection | None = None  # a robot process: its link to the first
        self.observed = False  # the first process has observers (samples go to it)
        self.orders: dict[str, FleetOrder] = {}  # a robot process: this step's fleet orders
        self.world: SimulatedWorld | None = None  # the world, when mirrored
        self.physics = True  # this process steps the physics
        self._stepped = 0  # the first process: physics steps taken elsewhere since its mirror
        self._names: list[list[str]] = []  # the first process: each link's robots' names
        self._sent: dict[int, Any] = {}  # each own robot's traffic path as last sent
        self._finalizer: weakref.finalize | None = None

    @property
    def processes(self) -> int:
        """The processes the robots decide in."""
        return len(self.links) + 1

    # ------------------------------------------------------------------ forking
    @classmethod
    def fork(
        cls,
        robots: list[RobotRun],
        size: int,
        observed: bool,
        serve: Callable[[ForkedTeam], None],
        mirror: SimulatedWorld | None = None,
    ) -> ForkedTeam:
        """Fork ``size - 1`` robot processes and share the robots out (:func:`shares`). In
        each robot process ``serve(team)`` runs the run's steps as the first process orders
        them; it never returns there (the process exits). With ``mirror`` (the run's world,
        when no lidar scans between control steps) only the last process steps the
        physics, while the first runs the fleet layer: each step's state reaches the first
        process, then the others with the step's orders, and their worlds mirror it."""
        self = cls(robots, list(range(len(robots))))
        self.world = mirror
        self.physics = mirror is None
        blocks = shares(len(self.robots), size, OBSERVED_EXTRA if observed else 0.0)

        def owned(p: int) -> list[int]:
            return list(blocks[p])

        self.observed = observed
        sys.stdout.flush()
        sys.stderr.flush()
        for p in range(1, size):
            mine, theirs = multiprocessing.Pipe(duplex=True)
            pid = os.fork()
            if pid == 0:  # a robot process
                code = 0
                try:
                    mine.close()
                    for link in self.links:
                        link.close()
                    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the first process decides
                    signal.signal(signal.SIGTERM, signal.SIG_IGN)
                    self.links, self.pids, self.parent = [], [], theirs
                    self.physics = mirror is None or p == size - 1
                    self.own_indices = owned(p)
                    self.own = [self.robots[k] for k in self.own_indices]
                    serve(self)
                except BaseException:  # noqa: BLE001 - a robot process never returns
                    code = 1
                finally:
                    os._exit(code)
            theirs.close()
            self.links.append(mine)
            self.pids.append(pid)
            self._names.append([self.robots[k].name for k in owned(p)])
        self.own_indices = owned(0)
        self.own = [self.robots[k] for k in self.own_indices]
        self._finalizer = weakref.finalize(self, _release, list(self.links), list(self.pids))
        return self

    # ------------------------------------------------------------------ a step
    def clock(self, world: SimulatedWorld) -> float:
        """The step's time: the world's, or in the first process while the physics
        process still steps, the time it will reach (the same additions MuJoCo makes)."""
        t = world.time
        for _ in range(self._stepped):
            t += world.dt
        return t

    def advance(self, world: SimulatedWorld, steps: int) -> None:
        """``steps`` physics steps of the world, in the processes that step it; the
        physics process then sends its state to the first process, which will wait for it."""
        if self.physics:
            advance_world(world, self.own, steps)
        if self.world is None:
            return
        if self.physics and self.parent is not None:
            self.parent.send(("world", self.world.snapshot()))
        elif self.parent is None:
            self._stepped = steps

    def begin_step(self, now: float, coordinator: FleetCoordinator | None) -> dict[str, FleetOrder]:
        """One more step: the first process takes the world's state from the physics
        process (when mirrored), the fleet layer decides there, and it sends every robot
        process its robots' fleet orders (and the state, when it mirrors it); the orders
        for this process's robots."""
        if self.parent is not None:
            return self.orders
        orders: dict[str, FleetOrder] = {}
        if coordinator is not None:  # on every robot's report, the others' as they shared them
            orders = coordinator.decide(now, [r.report() for r in self.robots])
        snapshot = None
        if self.world is not None and self._stepped:
            expected = self.clock(self.world)
            snapshot = self._receive(self.links[-1], "world")[1]
            self.world.mirror(snapshot)
            self._stepped = 0
            if self.world.time != expected:
                raise TeamError(f"robot processes out of step: {self.world.time} != {expected}")
        own = {self.robots[k].name for k in self.own_indices}
        last = len(self.links) - 1
        for i, (link, names) in enumerate(zip(self.links, self._names, strict=True)):
            mine = {name: orders[name] for name in names if name in orders}
            link.send(("step", mine, snapshot if i != last else None))
        return {name: order for name, order in orders.items() if name in own}

    def share_reports(self) -> None:
        """After the own robots decided: every robot's report reaches the first process
        (the fleet layer's there) and its command, outcome and wall contact every process.
        A traffic path travels only when it changed."""
        robots = self.robots
        if self.parent is not None:
            mine: dict[int, RobotReport] = {}
            same: list[int] = []
            for k in self.own_indices:
                report = robots[k].report()
                if report.traffic_path is self._sent.get(k, _UNSENT):
                    same.append(k)
                    report = dataclasses.replace(report, traffic_path=None)
                else:
                    self._sent[k] = report.traffic_path
                mine[k] = report
            self.parent.send(("reports", (mine, same)))
            for k, report in self._receive(self.parent, "reports")[1].items():
                if k not in mine:
                    robots[k].take_report(report)
            return
        merged = {k: robots[k].report() for k in self.own_indices}
        for link in self.links:
            theirs, same = self._receive(link, "reports")[1]
            for k, report in theirs.items():
                if k in same:
                    report = dataclasses.replace(report, traffic_path=robots[k].traffic_path)
                robots[k].take_report(report)
                merged[k] = report
        light = {k: dataclasses.replace(r, traffic_path=None) for k, r in merged.items()}
        for link in self.links:
            link.send(("reports", light))

    def share_outcomes(self) -> dict[int, StepSample | None]:
        """After the own robots concluded: every robot's status everywhere; with
        observers, every robot's sample in the first process (the robot processes make
        their robots' own)."""
        mine: dict[int, tuple[str | None, str | None, StepSample | None]] = {}
        for k in self.own_indices:
            r = self.robots[k]
            mine[k] = (r.status, r.reason, r.sample() if self.observed else None)
        merged = self._exchange("outcomes", mine)
        samples: dict[int, StepSample | None] = {}
        for k, (status, reason, sample) in merged.items():
            if k not in mine:
                r = self.robots[k]
                r.status, r.reason = status, reason
            samples[k] = sample
        return samples

    def _exchange(self, tag: str, mine: dict[int, Any]) -> dict[int, Any]:
        """Star exchange through the first process: everyone's entries to everyone."""
        if self.parent is not None:
            self.parent.send((tag, mine))
            return self._receive(self.parent, tag)[1]
        merged = dict(mine)
        for link in self.links:
            merged.update(self._receive(link, tag)[1])
        # the robot processes need neither the samples nor their own entries back
        for link in self.links:
            link.send((tag, _without_samples(tag, merged)))
        return merged

    def _receive(self, link: Connection, tag: str) -> tuple[Any, ...]:
        try:
            message = link.recv()
        except EOFError:
            if self.parent is not None:
                raise SystemExit(0) from None  # the first process is gone
            raise TeamError("a robot process ended unexpectedly") from None
        if message[0] == tag:
            return message
        if message[0] == "finish" and self.parent is not None:
            raise _Finish(message)
        if message[0] == "error":
            raise TeamError(f"a robot process failed: {message[1]}")
        raise TeamError(f"robot processes out of step: {message[0]!r} instead of {tag!r}")

    # ------------------------------------------------------------------ the end
    def gather(self, end: tuple[str, str | None], wall_time: float) -> dict[int, RunRecord]:
        """The first process: the other processes' robots' records (each process ends its
        robots with the run's ``end`` first, when the run ended outside a step there)."""
        records: dict[int, RunRecord] = {}
        for link in self.links:
            try:
                link.send(("finish", end, wall_time))
                while True:
                    message = link.recv()
                    if message[0] == "records":
                        records.update(message[1])
                        break
                    if message[0] == "error":
                        raise TeamError(f"a robot process failed: {message[1]}")
            except (EOFError, OSError):
                raise TeamError("a robot process ended before sending its records") from None
        self.close()
        return records

    def close(self) -> None:
        if self._finalizer is not None:
            self._finalizer()

    def serve(
        self,
        step: Callable[[], object],
        end: Callable[[str, str | None], object],
        record: Callable[[int, float], RunRecord],
    ) -> None:
        """A robot process: step when told, then send its robots' records."""
        link = self.parent
        assert link is not None, "only a robot process serves"
        while True:
            try:
                message = link.recv()
            except EOFError:
                return
            if message[0] == "step":
                self.orders, snapshot = message[1], message[2]
                if snapshot is not None and self.world is not None:
                    self.world.mirror(snapshot)  # before the step reads the clock
                try:
                    step()
                    continue
                except _Finish as finish:
                    message = finish.message
                except SystemExit:
                    return
                except BaseException as exc:  # noqa: BLE001 - reported to the first process
                    link.send(("error", _failure(exc)))
                    continue
            if message[0] == "finish":
                _, (status, reason), wall_time = message
                try:
                    end(status, reason)
                    link.send(("records", {k: record(k, wall_time) for k in self.own_indices}))
                except BaseException as exc:  # noqa: BLE001 - reported to the first process
                    link.send(("error", _failure(exc)))
                return


def _failure(exc: BaseException) -> str:
    """A robot process's failure in one line for the run's reason, with where it
    happened."""
    where = traceback.extract_tb(exc.__traceback__)[-1:]
    at = f" (at {Path(where[0].filename).name}:{where[0].lineno})" if where else ""
    return f"{type(exc).__name__}: {exc}{at}"


def _without_samples(tag: str, merged: dict[int, Any]) -> dict[int, Any]:
    if tag != "outcomes":
        return merged
    return {k: (status, reason, None) for k, (status, reason, _) in merged.items()}


def _release(links: list[Connection], pids: list[int]) -> None:
    """Close the links (a waiting robot process then exits) and reap the processes."""
    for link in links:
        link.close()
    for pid in pids:
        with contextlib.suppress(ChildProcessError):
            os.waitpid(pid, 0)
