"""Where a run's robots decide: the :class:`RobotTeam` interface the loop calls, and its
implementation in one process, :class:`InlineTeam`.

The loop (:class:`~agv_mission.missions.run.runner.MissionRun`) asks its team for the
step's clock and fleet orders, lets the team's own robots decide and conclude, has the
team share what they decided, and has it advance the physics; it never asks how many
processes there are. :class:`InlineTeam` is the whole run in this process;
:class:`~agv_mission.missions.run.forked_team.ForkedTeam` spreads the robots over forked
processes behind the same methods (as Gymnasium's ``SyncVectorEnv`` and
``AsyncVectorEnv`` are one ``VectorEnv``). :func:`team_size` says how many processes a run
decides in: ``auto`` forks one per idle core for fleets of :data:`AUTO_FROM` robots or
more, not from a worker process (regress and the service run missions side by side
already).
"""

from __future__ import annotations

import multiprocessing
import os
import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING, Literal, Protocol

if TYPE_CHECKING:
    from agv_mission.missions.run.fleet_orders import FleetCoordinator, FleetOrder
    from agv_mission.missions.run.record import RunRecord
    from agv_mission.missions.run.robot_run import RobotRun
    from agv_mission.missions.run.samples import StepSample
    from agv_mission.world.simulation import SimulatedWorld

#: ``simulation.processes``: a count, or ``auto``.
Processes = int | Literal["auto"]


#: ``auto`` spreads fleets of this many robots or more: below, the two exchanges a step
#: cost about what a second core saves (bench_fleet).
AUTO_FROM = 4


def usable_cores() -> int:
    """The cores this process may run on."""
    if hasattr(os, "sched_getaffinity"):
        return max(1, len(os.sched_getaffinity(0)))
    return max(1, os.cpu_count() or 1)


def idle_cores(samples: int = 3, gap: float = 0.01) -> int:
    """The usable cores nothing else runs on now (this process's own included): the
    fewest over a few readings of the kernel's runnable-task count (Linux; elsewhere all
    usable cores). Robots in lockstep across processes wait for the slowest one: a
    process sharing its core with another program would hold every step up."""
    cores = usable_cores()
    stat = Path("/proc/stat")
    if not stat.is_file():
        return cores
    others = cores
    for i in range(samples):
        if i:
            time.sleep(gap)
        for line in stat.read_text().splitlines():
            if line.startswith("procs_running"):  # this process included
                others = min(others, int(line.split()[1]) - 1)
    return max(1, cores - others)


def team_size(setting: Processes, robots: int, control: object | None) -> int:
    """How many processes a run of ``robots`` robots decides in (1: this one alone)."""
    if robots < 2 or not hasattr(os, "fork"):
        return 1
    if control is not None and not getattr(control, "only_cancels", False):
        return 1  # a control that commands robots (teleop, the service) needs them here
    if threading.active_count() > 1 or threading.current_thread() is not threading.main_thread():
        return 1  # forking a process with other threads may copy a lock one of them held
    if setting == "auto":
        if multiprocessing.parent_process() is not None or robots < AUTO_FROM:
            return 1
        return min(idle_cores(), robots)
    return max(1, min(int(setting), robots))


class RobotTeam(Protocol):
    """Which robots decide in this process, and how the others' decisions reach it."""

    #: this process's robots: they sense, estimate, decide and conclude here
    own: list[RobotRun]
    #: the step's samples wait to be observed until the next step is under way
    observe_later: bool

    @property
    def processes(self) -> int:
        """The processes the robots decide in."""
        ...

    def clock(self, world: SimulatedWorld) -> float:
        """The step's time."""
        ...

    def begin_step(self, now: float, coordinator: FleetCoordinator | None) -> dict[str, FleetOrder]:
        """A new step: the fleet layer's orders for this process's robots (it decides on
        every robot's report, in the first process)."""
        ...

    def share_reports(self) -> None:
        """After the own robots decided: every robot's report where it is needed."""
        ...

    def share_outcomes(self) -> dict[int, StepSample | None]:
        """After the own robots concluded: every robot's status everywhere; the
        observers' sample of each robot (none when nobody observes)."""
        ...

    def advance(self, world: SimulatedWorld, steps: int) -> None:
        """Let the world's physics run ``steps`` steps, with the own robots' scans."""
        ...

    def gather(self, end: tuple[str, str | None], wall_time: float) -> dict[int, RunRecord]:
        """The records of the robots that decided in other processes."""
        ...


class InlineTeam:
    """Every robot decides in this process: the exchanges are no-ops."""

    observe_later = False  # the samples are observed in the step that made them
    processes = 1

    def __init__(self, robots: list[RobotRun], observed: bool) -> None:
        self.own = robots
        self.observed = observed  # the run has observers: every robot makes its sample

    def clock(self, world: SimulatedWorld) -> float:
        return world.time

    def begin_step(self, now: float, coordinator: FleetCoordinator | None) -> dict[str, FleetOrder]:
        if coordinator is None:
            return {}
        return coordinator.decide(now, [r.report() for r in self.own])

    def share_reports(self) -> None:
        return None

    def share_outcomes(self) -> dict[int, StepSample | None]:
        if not self.observed:
            return {}
        return {k: r.sample() for k, r in enumerate(self.own)}

    def advance(self, world: SimulatedWorld, steps: int) -> None:
        advance_world(world, self.own, steps)

    def gather(self, end: tuple[str, str | None], wall_time: float) -> dict[int, RunRecord]:
        return {}


def advance_world(world: SimulatedWorld, robots: list[RobotRun], steps: int) -> None:
    """``steps`` physics steps of ``world``; the lidars of ``robots`` faster than the loop
    scan at their own times within them (to the physics step)."""
    t0 = world.time
    dt = world.dt
    due: dict[int, list[RobotRun]] = {}
    for r in robots:
        for k in r.stack.scan_steps(t0, steps, dt):
            due.setdefault(k, []).append(r)
    done = 0
    for k in sorted(due):
        world.step(k - done)
        done = k
        for r in due[k]:
            r.stack.take_scan(r._scan_filter)
    world.step(steps - done)
