"""The run manager: a bounded queue, at most N workers, and their connections.

It lives in the service's event loop. Each worker's connection is read by a task of its
own (:class:`~agv_mission.service.links.WorkerLink`): messages are handled the moment they
arrive; the backend (:mod:`agv_mission.service.backends`) says when a worker is gone and
how, without ever stopping the service.
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import uuid
from collections import deque
from dataclasses import dataclass, field
from multiprocessing.connection import Connection
from typing import Any

from agv_mission.service.backends import LocalBackend, RayBackend
from agv_mission.service.links import WorkerLink
from agv_mission.service.live import LiveHubs, ResultCache, end_text
from agv_mission.service.registry import Registry, Submission

PROGRESS_SAVE_PERIOD = 2.0  # seconds between progress writes to the registry per run
STOP_GRACE = 20.0  # seconds running missions get to write their results on shutdown
READ_BATCH = 50  # worker messages handled before HTTP requests get their turn
LIVE_NICE = 5  # the service's own CPU priority below its missions' (nice increment)


class QueueFull(Exception):
    """The bounded queue holds as many runs as it may."""


class NotActive(Exception):
    """The run is not in a state where this command means anything (409)."""


class UnknownRobot(Exception):
    """A command names no robot of the run, or names none in a fleet run (422)."""


@dataclass
class ActiveRun:
    run_id: str
    link: WorkerLink | None = None
    pump: asyncio.Task | None = None
    process: Any = None  # multiprocessing.Process, or a Ray ObjectRef
    status: str = "running"
    progress: dict[str, Any] = field(default_factory=dict)
    replies: dict[str, asyncio.Future] = field(default_factory=dict)
    ended: bool = False
    saved_at: float = 0.0
    pending: list[tuple[Any, ...]] = field(default_factory=list)  # commands before connect
    robots: dict[str, tuple[float, float]] = field(default_factory=dict)  # name -> limits

    def robot(self, name: str | None) -> str:
        """The robot a command means: ``name``, or the run's only robot when omitted."""
        names = ", ".join(self.robots)
        if name is None:
            if len(self.robots) == 1:
                return next(iter(self.robots))
            raise UnknownRobot(f"the run has {len(self.robots)} robots ({names}): name one (robot)")
        if name not in self.robots:
            raise UnknownRobot(f"the run has no robot {name!r}; its robots: {names}")
        return name

    def task_type(self, name: str) -> str | None:
        """The robot's current task type, as its latest progress said."""
        robots = self.progress.get("robots") or {}
        return (robots.get(name) or {}).get("task_type")


class RunManager:
    """Queue, workers and live hubs of every run of one service."""

    def __init__(
        self,
        registry: Registry,
        workers: int,
        queue_size: int,
        backend: str = "local",
        address: str | None = None,
        live_nice: int = LIVE_NICE,
        observers: Any = None,
    ) -> None:
        self.registry = registry
        self.observers = observers
        self.live_nice = live_nice
        self.workers = workers
        self.queue_size = queue_size
        self.queue: deque[str] = deque()
        self.paces: dict[str, float | None] = {}  # paces set while queued, by run id
        self.active: dict[str, ActiveRun] = {}
        self.loop: asyncio.AbstractEventLoop | None = None
        self.stopping = False
        self._idle = asyncio.Event()
        self.results = ResultCache(registry)
        self.live = LiveHubs(registry, self.results, self.active)
        self._tasks: set[asyncio.Task] = set()
        self.backend: LocalBackend | RayBackend = (
            RayBackend(self, workers, address) if backend == "ray" else LocalBackend(self)
        )

    # ------------------------------------------------------------------ lifecycle

    async def start(self) -> tuple[list[str], list[str]]:
        """Recover the registry after any stop and start the backend."""
        self.loop = asyncio.get_running_loop()
        interrupted, queued = self.registry.recover()
        await self.backend.start()
        if self.live_nice:
            # Missions come first: the fan-out of live streams (this thread: the event
            # loop) yields the CPU to the workers, which keep the fork server's priority.
            with contextlib.suppress(OSError):
                os.nice(self.live_nice)
        for run_id in queued:
            self.queue.append(run_id)
            self.live.open(run_id)
        self._schedule()
        return interrupted, queued

    async def shutdown(self) -> None:
        """SIGINT/SIGTERM: running missions end ``aborted`` with their results; queued
        ones stay queued for the next start."""
        self.stopping = True
        for run in list(self.active.values()):
            self._send(run, ("cancel", "the service is stopping"))
        deadline = asyncio.get_running_loop().time() + STOP_GRACE
        while self.active and asyncio.get_running_loop().time() < deadline:
            self._idle.clear()
            with contextlib.suppress(asyncio.TimeoutError):
                await asyncio.wait_for(self._idle.wait(), 0.5)
        for run in list(self.active.values()):
            self.backend.kill(run)
            self.finish(run, "aborted", "the service stopped before the run could end", None)
            self.detach(run)
        self.backend.stop()

    # ------------------------------------------------------------------ submission

    def check_room(self) -> None:
        if len(self.queue) >= self.queue_size:
            raise QueueFull(f"the queue holds {self.queue_size} runs; try again later")

    async def submit(self, submission: Submission, run_id: str | None = None) -> dict[str, Any]:
        """Queue a run; answer once its row is on disk (a 201 is never lost by a crash)."""
        self.check_room()
        run, stored = self.registry.add(submission, run_id)
        self.queue.append(run["id"])
        self.live.open(run["id"])
        self._schedule()
        await asyncio.wrap_future(stored)
        return run  # as accepted: queued (it may have started since)

    def _schedule(self) -> None:
        while not self.stopping and self.queue and len(self.active) < self.workers:
            run_id = self.queue.popleft()
            try:
                self._launch(run_id)
            except Exception as exc:  # the backend refused: this run, not the service
                self.active.pop(run_id, None)
                self.registry.set_status(run_id, "error", f"could not start a worker: {exc}")
                self.live[run_id].finish(end_text("error", str(exc), None))

    def _launch(self, run_id: str) -> None:
        sub = self.registry.submission(run_id)
        job = {
            "run_id": run_id,
            "data_dir": str(self.registry.data_dir),
            "run_dir": str(self.registry.run_dir(run_id)),
            "mission": sub.mission,
            "sets": sub.sets,
            "seed": sub.seed,
            "mission_path": sub.mission_path,
            "pace": self.paces.pop(run_id, sub.pace),
            "observers": self.observers,
        }
        run = ActiveRun(run_id)
        self.active[run_id] = run
        self.registry.set_status(run_id, "running")
        self.backend.launch(run, job)

    def attach(self, run_id: str, conn: Connection) -> None:
        """A worker's connection is up: read it from now on (a run already over closes it)."""
        run = self.active.get(run_id)
        if run is None or run.ended:
            conn.close()
            return
        assert self.loop is not None
        run.pump = self.loop.create_task(self._pump(run, conn), name=f"pump-{run_id}")

    # ------------------------------------------------------------------ worker -> service

    async def _pump(self, run: ActiveRun, conn: Connection) -> None:
        """Read the worker's messages as they come, never blocking the event loop on a
        message only half arrived; yield to HTTP requests every :data:`READ_BATCH`."""
        link = await WorkerLink.of(conn)
        run.link = link
        for command in run.pending:
            link.send(command)
        run.pending.clear()
        try:
            while True:
                for _ in range(READ_BATCH):
                    self._handle(run, await link.recv())
                await asyncio.sleep(0)
        except (asyncio.IncompleteReadError, ConnectionError, OSError, EOFError):
            pass
        if self.backend.judges_exit and run.process is not None:
            return  # the process's sentinel says how it ended
        if not run.ended:
            self.finish(run, "error", "the worker's connection closed unexpectedly", None)

    async def drained(self, run: ActiveRun, timeout: float = 5.0) -> None:
        """Wait until everything the worker said is handled (its connection closed)."""
        if run.pump is not None:
            with contextlib.suppress(asyncio.TimeoutError, Exception):
                await asyncio.wait_for(asyncio.shield(run.pump), timeout)

    def _handle(self, run: ActiveRun, item: tuple[Any, ...]) -> None:
        kind = item[0]
        hub = self.live[run.run_id]
        if kind == "msg":
            hub.publish(item[1], item[2], item[3], robot=item[4])
        elif kind == "progress":
            run.progress = item[1]
            now = asyncio.get_running_loop().time()
            if now - run.saved_at >= PROGRESS_SAVE_PERIOD:
                run.saved_at = now
                self.registry.update(run.run_id, progress=run.progress)
        elif kind == "status":
            run.status = item[1]
            self.registry.set_status(run.run_id, item[1])
            hub.set_status(item[1])
        elif kind == "reply":
            future = run.replies.pop(item[1], None)
            if future is not None and not future.done():
                future.set_result((item[2], item[3]))
        elif kind == "robots":
            run.robots = {str(k): (float(v), float(w)) for k, (v, w) in item[1].items()}
        elif kind == "end":
            self.finish(run, item[1], item[2], item[3])

    def spawn(self, coro: Any) -> None:
        """A background task, referenced until it ends (the loop keeps weak references)."""
        assert self.loop is not None
        task = self.loop.create_task(coro)
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    def detach(self, run: ActiveRun) -> None:
        """The worker is gone: close its link and stop reading it."""
        if run.link is not None:
            run.link.close()
            run.link = None
        if run.pump is not None and not run.pump.done():
            run.pump.cancel()

    def finish(
        self, run: ActiveRun, status: str, reason: str | None, result: dict[str, Any] | None
    ) -> None:
        """The run's end (the first one said counts): registry, stream, waiting replies."""
        if run.ended:
            return
        run.ended = True
        if result is not None:
            self.results.put(run.run_id, result)
        fields: dict[str, Any] = {}
        if run.progress:
            fields["progress"] = run.progress
        self.registry.set_status(run.run_id, status, reason, **fields)
        self.live[run.run_id].finish(end_text(status, reason, result))
        for future in run.replies.values():
            if not future.done():
                future.set_result((409, {"detail": f"the run ended ({status})"}))
        self.active.pop(run.run_id, None)
        self.live.retire()
        self._idle.set()
        self._schedule()

    # ------------------------------------------------------------------ service -> worker

    def _send(self, run: ActiveRun, command: tuple[Any, ...]) -> None:
        if run.link is None:
            run.pending.append(command)
            return
        run.link.send(command)  # never waits; a dead worker is judged by its sentinel

    def cancel(self, run_id: str) -> None:
        if run_id in self.queue:
            self.queue.remove(run_id)
            self.paces.pop(run_id, None)
            self.registry.forget_submission(run_id)
            reason = "cancelled before it started"
            self.registry.set_status(run_id, "aborted", reason)
            self.live[run_id].finish(end_text("aborted", reason, None))
            return
        run = self.active.get(run_id)
        if run is None or run.ended:
            raise NotActive("the run is already final")
        self._send(run, ("cancel", "cancelled through the API"))

    def pause(self, run_id: str) -> None:
        run = self.active.get(run_id)
        if run is None or run.status != "running":
            raise NotActive("the run is not running")
        run.status = "paused"  # a second pause answers 409 at once
        self._send(run, ("pause",))

    def resume(self, run_id: str) -> None:
        run = self.active.get(run_id)
        if run is None or run.status != "paused":
            raise NotActive("the run is not paused")
        run.status = "running"
        self._send(run, ("resume",))

    def set_pace(self, run_id: str, pace: float | None) -> None:
        """A new pace (simulated seconds per wall second; None: flat out) for a run queued
        or under way."""
        if run_id in self.queue:
            self.paces[run_id] = pace
        else:
            run = self.active.get(run_id)
            if run is None or run.ended:
                raise NotActive("the run is already final")
            self._send(run, ("pace", pace))
        self.registry.update(run_id, pace=pace)

    def cmd_vel(
        self, run_id: str, robot: str | None, v: float, w: float
    ) -> tuple[str, float, float] | None:
        """Send a robot a remote command, clamped to its limits; the robot and the command
        sent (None when the run is not active or not loaded yet). An unknown or missing
        robot raises :class:`UnknownRobot`."""
        run = self.active.get(run_id)
        if run is None or not run.robots:
            return None
        name = run.robot(robot)
        v_max, w_max = run.robots[name]
        v, w = min(max(v, -v_max), v_max), min(max(w, -w_max), w_max)
        self._send(run, ("cmd_vel", name, v, w))
        return name, v, w

    def limits(self, run_id: str, robot: str) -> tuple[float, float] | None:
        run = self.active.get(run_id)
        return None if run is None else run.robots.get(robot)

    def _running(self, run_id: str, robot: str | None) -> tuple[ActiveRun, str]:
        run = self.active.get(run_id)
        if run is None or run.status != "running" or not run.robots:
            raise NotActive("the run is not running")
        return run, run.robot(robot)

    async def goal(
        self, run_id: str, robot: str | None, x: float, y: float, yaw: float
    ) -> tuple[str, int, dict[str, Any]]:
        """Send a robot whose task is teleop a goal; the worker answers 202, or 422 when no
        path reaches it."""
        run, name = self._running(run_id, robot)
        if run.task_type(name) != "teleop":
            raise NotActive(f"{name}'s current task is not teleop")
        return (name, *await self._ask(run, "goal", name, x, y, yaw))

    async def record_room(
        self, run_id: str, robot: str | None, label: str
    ) -> tuple[int, dict[str, Any]]:
        run, name = self._running(run_id, robot)
        return await self._ask(run, "record", name, label)

    async def _ask(self, run: ActiveRun, kind: str, *args: Any) -> tuple[int, dict[str, Any]]:
        """A command the worker answers: (HTTP status, body)."""
        request_id = uuid.uuid4().hex
        future: asyncio.Future = asyncio.get_running_loop().create_future()
        run.replies[request_id] = future
        self._send(run, (kind, request_id, *args))
        try:
            return await asyncio.wait_for(future, 10.0)
        finally:
            run.replies.pop(request_id, None)

    def live_progress(self, run_id: str) -> dict[str, Any] | None:
        run = self.active.get(run_id)
        return run.progress if run is not None and run.progress else None
