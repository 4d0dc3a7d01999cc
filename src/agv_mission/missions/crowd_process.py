"""The crowd walking in a process of its own, as pedestrian simulators run beside a robot's
software in the field (pedsim_ros and HuNavSim are ROS nodes of their own).

People decide every ``DECISION_PERIOD`` (0.2 s, two control steps) from where the robots
truly are at the start of the step they decide in; the robots decide from where the
people are. Both read the same instant, so the crowd's decision is asked for as soon as
the step's robot poses are known (after faults moved them) and made in the crowd process
while the robots decide; the walk it decided (every control step's positions up to the
next decision) is read back when the people move, at the end of the step. The crowd
process runs the very calls the run would make in its own process, in the same order,
from the same state (forked from it): the walks are the same, bit for bit (a test).

Why: the crowd is the largest part of what people cost a run (ORCA's step through one
binding call per person, the ways to new goals), and run between the robots' work in one
process it ran with cold caches, at twice the cost it has on its own (bench_people); in
its own process it costs about its own, on another core, off the control loop's path.
Its CPU time is the run's too: ``cpu_seconds`` reports it (``bench_people`` adds it).
"""

from __future__ import annotations

import contextlib
import multiprocessing
import os
import signal
import sys
import threading
import time
import traceback
import weakref
from multiprocessing import Pipe
from multiprocessing.connection import Connection
from pathlib import Path

import numpy as np

from agv_mission.missions.team import Processes, idle_cores
from agv_mission.world.crowd import Crowd

#: People from which a crowd gets a process of its own: with fewer, the two exchanges a
#: decision costs more than it saves (bench_people).
OWN_PROCESS_FROM = 10

_ERROR = b"ERR:"  # a failure's message follows (a walk's buffer never starts so: its
# first number is a count of decisions, a small float)


def own_process(setting: Processes, people: int) -> bool:
    """Whether a run's crowd of ``people`` walks in a process of its own: ``auto`` when a
    second core is idle, in a run started from the command line (not a worker process:
    regress and the service run missions side by side already); ``1`` never; more
    processes always. Never from a process running other threads (a fork may copy a lock
    one of them held)."""
    if people < OWN_PROCESS_FROM or not hasattr(os, "fork") or setting == 1:
        return False
    if threading.active_count() > 1 or threading.current_thread() is not threading.main_thread():
        return False
    if setting == "auto":
        return multiprocessing.parent_process() is None and idle_cores() >= 2
    return True


class CrowdProcess:
    """The crowd of a run in a forked process, read as the run reads a :class:`Crowd`:
    ``positions``, ``velocities``, ``active``, ``everyone``, ``deciding``, ``decisions``,
    ``ids``, ``radii``, ``step``; :meth:`ask` sends a decision's robots ahead."""

    def __init__(self, crowd: Crowd) -> None:
        self.ids, self.radii = crowd.ids, crowd.radii
        self.positions = crowd.positions.copy()
        self.velocities = crowd.velocities.copy()
        self.active = crowd.active.copy()
        self.decisions = crowd.decisions
        self.time = crowd.time
        self.cpu_seconds = 0.0  # the crowd process's CPU time, once closed
        self._walk: list[tuple[np.ndarray, np.ndarray]] = []  # (positions, active) a step
        self._asked = False
        self._n = len(crowd.ids)
        mine, theirs = Pipe(duplex=True)
        sys.stdout.flush()
        sys.stderr.flush()
        pid = os.fork()
        if pid == 0:  # the crowd process
            code = 0
            try:
                mine.close()
                signal.signal(signal.SIGINT, signal.SIG_IGN)  # the run's process decides
                signal.signal(signal.SIGTERM, signal.SIG_IGN)
                _serve(crowd, theirs)
            except BaseException:  # noqa: BLE001 - the crowd process never returns
                code = 1
            finally:
                os._exit(code)
        theirs.close()
        self._link: Connection | None = mine
        self._pid = pid
        self._finalizer = weakref.finalize(self, _release, mine, pid)

    @property
    def everyone(self) -> bool:
        return bool(self.active.all())

    @property
    def deciding(self) -> bool:
        """Whether the next step decides (the decided walk is walked)."""
        return not self._walk

    def ask(self, dt: float, robots: np.ndarray) -> None:
        """Start the next decision in the crowd process from ``robots`` (rows x, y, vx, vy,
        radius: the robots' true poses and velocities now); ``step`` reads it back."""
        if self._walk or self._asked or self._link is None:
            return
        self._link.send_bytes(np.concatenate([[dt], np.asarray(robots, float).ravel()]))
        self._asked = True

    def step(self, dt: float, robots: np.ndarray | None = None) -> None:
        """Advance everyone ``dt`` seconds (as :meth:`Crowd.step`)."""
        if not self._walk:
            self.ask(dt, np.zeros((0, 5)) if robots is None else robots)
            self._read()
        positions, active = self._walk.pop(0)
        self.positions[:] = positions
        self.active[:] = active
        self.time += dt

    def _read(self) -> None:
        assert self._link is not None, "the crowd process is closed"
        data = self._link.recv_bytes()
        self._asked = False
        if data.startswith(_ERROR):
            raise RuntimeError(f"the crowd process failed: {data[len(_ERROR) :].decode()}")
        buf = np.frombuffer(data, dtype=float)
        n = self._n
        self.decisions = int(buf[0])
        self.velocities[:] = buf[1 : 1 + 2 * n].reshape(n, 2)
        steps = buf[1 + 2 * n :].reshape(-1, 3 * n)
        self._walk = [(row[: 2 * n].reshape(n, 2), row[2 * n :] > 0.5) for row in steps]

    def close(self) -> None:
        """End the crowd process and take its CPU time."""
        link, self._link = self._link, None
        if link is None:
            return
        try:
            if self._asked:
                link.recv_bytes()  # a decision the run ended before walking
            link.send_bytes(b"")
            self.cpu_seconds = float(np.frombuffer(link.recv_bytes(), dtype=float)[0])
        except (EOFError, OSError):
            pass
        self._finalizer()


def _serve(crowd: Crowd, link: Connection) -> None:
    """The crowd process: decide when asked, then walk the decided period and send each
    step's positions and presence; an empty message ends it (its CPU time the answer)."""
    while True:
        try:
            data = link.recv_bytes()
        except EOFError:
            return
        if not data:
            link.send_bytes(np.array([time.process_time()]).tobytes())
            return
        try:
            asked = np.frombuffer(data, dtype=float)
            dt, robots = float(asked[0]), asked[1:].reshape(-1, 5)
            walk = []
            crowd.step(dt, robots)
            walk.append(_state(crowd))
            while not crowd.deciding:
                crowd.step(dt)
                walk.append(_state(crowd))
            head = np.concatenate([[crowd.decisions], crowd.velocities.ravel()])
            link.send_bytes(np.concatenate([head, *walk]).tobytes())
        except Exception as exc:  # noqa: BLE001 - reported to the run
            where = traceback.extract_tb(exc.__traceback__)[-1:]
            at = f" (at {Path(where[0].filename).name}:{where[0].lineno})" if where else ""
            link.send_bytes(_ERROR + f"{type(exc).__name__}: {exc}{at}".encode())


def _state(crowd: Crowd) -> np.ndarray:
    return np.concatenate([crowd.positions.ravel(), crowd.active.astype(float)])


def _release(link: Connection, pid: int) -> None:
    """Close the link (the crowd process then exits) and reap it."""
    link.close()
    with contextlib.suppress(ChildProcessError):
        os.waitpid(pid, 0)
