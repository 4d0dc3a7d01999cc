"""The run manager: a bounded queue, at most N worker processes, and their connections.

It lives in the service's event loop. Each worker's connection (and, for local processes,
its exit sentinel) is watched with ``loop.add_reader``: messages are handled the moment
they arrive and a worker that dies (a crash, ``kill -9``) ends its run ``error`` with
the reason, without ever stopping the service.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import multiprocessing
import os
import pickle
import secrets
import signal
import socket
import struct
import threading
import uuid
from collections import OrderedDict, deque
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from multiprocessing.connection import Connection, Listener
from pathlib import Path
from typing import Any

from agv_mission.service import messages as msg
from agv_mission.service.hub import SNAPSHOT_ORDER, Hub
from agv_mission.service.registry import FINAL, Registry, Submission
from agv_mission.service.worker import STREAM_FILE, worker_main

WORKER_PRELOAD = [
    "agv_mission.service.worker",
    "agv_mission.missions.loader",
    "agv_mission.missions.runner",
    "agv_mission.missions.outputs",
    "matplotlib.pyplot",
]
PROGRESS_SAVE_PERIOD = 2.0  # seconds between progress writes to the registry per run
STOP_GRACE = 20.0  # seconds running missions get to write their results on shutdown
FINISHED_HUBS = 64  # finished runs whose stream stays in memory for late clients
RESULT_CACHE = 256  # result.json contents kept in memory
READ_BATCH = 50  # worker messages handled before HTTP requests get their turn
LINK_BUFFER = 1 << 20  # bytes a worker link buffers (a map message is a few hundred kB)
LIVE_NICE = 5  # the service's own CPU priority below its missions' (nice increment)


class QueueFull(Exception):
    """The bounded queue holds as many runs as it may."""


class NotActive(Exception):
    """The run is not in a state where this command means anything (409)."""


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


class WorkerLink:
    """The service's end of a worker's connection, on the event loop: multiprocessing's
    frames (a 4-byte length, or -1 and an 8-byte one, then a pickle) read from an asyncio
    stream, so a frame half written never blocks the loop, and commands written without
    waiting. The worker keeps a plain :class:`Connection`."""

    def __init__(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        self.reader = reader
        self.writer = writer

    @classmethod
    async def of(cls, conn: Connection) -> WorkerLink:
        fd = os.dup(conn.fileno())
        conn.close()
        reader, writer = await asyncio.open_connection(
            sock=socket.socket(fileno=fd), limit=LINK_BUFFER
        )
        return cls(reader, writer)

    async def recv(self) -> tuple[Any, ...]:
        (size,) = struct.unpack("!i", await self.reader.readexactly(4))
        if size == -1:
            (size,) = struct.unpack("!Q", await self.reader.readexactly(8))
        return pickle.loads(await self.reader.readexactly(size))

    def send(self, item: tuple[Any, ...]) -> None:
        if self.writer.is_closing():
            return
        data = pickle.dumps(item)
        self.writer.write(struct.pack("!i", len(data)) + data)

    def close(self) -> None:
        with contextlib.suppress(Exception):
            self.writer.close()


def _pool_context() -> Any:
    ctx = multiprocessing.get_context("forkserver")
    ctx.set_forkserver_preload(WORKER_PRELOAD)
    return ctx


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
    ) -> None:
        self.registry = registry
        self.live_nice = live_nice
        self.workers = workers
        self.queue_size = queue_size
        self.backend = backend
        self.address = address
        self.queue: deque[str] = deque()
        self.active: dict[str, ActiveRun] = {}
        self.hubs: OrderedDict[str, Hub] = OrderedDict()
        self.loop: asyncio.AbstractEventLoop | None = None
        self.stopping = False
        self._ctx: Any = None
        self._listener: Listener | None = None
        self._ray: Any = None
        self._idle = asyncio.Event()
        self.results = ResultCache(registry)
        self._tasks: set[asyncio.Task] = set()
        self._starter = ThreadPoolExecutor(max_workers=1, thread_name_prefix="start-worker")

    # ------------------------------------------------------------------ lifecycle

    async def start(self) -> tuple[list[str], list[str]]:
        """Recover the registry after any stop and start the backend."""
        self.loop = asyncio.get_running_loop()
        interrupted, queued = self.registry.recover()
        if self.backend == "ray":
            await asyncio.to_thread(self._start_ray)
        else:
            self._ctx = _pool_context()
            from multiprocessing import forkserver

            await asyncio.to_thread(forkserver.ensure_running)
        if self.live_nice:
            # Missions come first: the fan-out of live streams (this thread: the event
            # loop) yields the CPU to the workers, which keep the fork server's priority.
            with contextlib.suppress(OSError):
                os.nice(self.live_nice)
        for run_id in queued:
            self.queue.append(run_id)
            self.hubs[run_id] = Hub()
        self._schedule()
        return interrupted, queued

    def _start_ray(self) -> None:
        import ray

        if not ray.is_initialized():
            options: dict[str, Any] = {"include_dashboard": False, "logging_level": "WARNING"}
            if self.address:
                options["address"] = self.address
            else:  # a new local instance, whatever a stale /tmp/ray file says
                options["address"] = "local"
                options["num_cpus"] = self.workers
            ray.init(**options)
        self._ray = ray
        local = self.address is None or self.address.split(":")[0] in ("127.0.0.1", "localhost")
        host = "127.0.0.1" if local else "0.0.0.0"  # tasks on other nodes call back
        self._authkey = secrets.token_bytes(32)
        self._listener = Listener((host, 0), authkey=self._authkey)
        threading.Thread(target=self._accept, daemon=True, name="ray-accept").start()

    def _accept(self) -> None:
        """Ray tasks connect back here and say which run they are."""
        assert self._listener is not None
        while True:
            try:
                conn = self._listener.accept()
                hello = conn.recv()
            except (OSError, EOFError):
                if self.stopping:
                    return
                continue
            if not (isinstance(hello, tuple) and hello[:1] == ("hello",)):
                conn.close()
                continue
            assert self.loop is not None
            self.loop.call_soon_threadsafe(self._attach, str(hello[1]), conn)

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
            self._kill(run)
            self._finish(run, "aborted", "the service stopped before the run could end", None)
            self._detach(run)
        if self._listener is not None:
            with contextlib.suppress(OSError):
                self._listener.close()
        if self._ray is not None:
            with contextlib.suppress(Exception):
                self._ray.shutdown()

    # ------------------------------------------------------------------ submission

    def check_room(self) -> None:
        if len(self.queue) >= self.queue_size:
            raise QueueFull(f"the queue holds {self.queue_size} runs; try again later")

    async def submit(self, submission: Submission) -> dict[str, Any]:
        """Queue a run; answer once its row is on disk (a 201 is never lost by a crash)."""
        self.check_room()
        run, stored = self.registry.add(submission)
        self.queue.append(run["id"])
        self.hubs[run["id"]] = Hub()
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
                self._hub(run_id).finish(self._end_text("error", str(exc), None))

    def _launch(self, run_id: str) -> None:
        sub = self.registry.submission(run_id)
        job = {
            "run_id": run_id,
            "data_dir": str(self.registry.data_dir),
            "run_dir": str(self.registry.run_dir(run_id)),
            "mission": sub.mission,
            "sets": sub.sets,
            "seed": sub.seed,
        }
        run = ActiveRun(run_id)
        self.active[run_id] = run
        self.registry.set_status(run_id, "running")
        if self.backend == "ray":
            assert self._listener is not None
            task = self._ray.remote(num_cpus=1, max_retries=0)(ray_entry)
            run.process = task.remote(job, self._listener.address, self._authkey)
            future = asyncio.wrap_future(run.process.future())
            future.add_done_callback(lambda f, r=run: self._ray_done(r, f))
            return
        parent, child = self._ctx.Pipe(duplex=True)
        run.process = self._ctx.Process(
            target=worker_main, args=(job, child), name=f"agv-run-{run_id}", daemon=False
        )
        self._spawn(self._start_process(run, parent, child))

    async def _start_process(self, run: ActiveRun, parent: Connection, child: Connection) -> None:
        """Start a local worker off the event loop: the fork server answers in a few
        hundred milliseconds on a busy machine, and requests must not wait for that."""
        assert self.loop is not None
        process = run.process
        try:
            await self.loop.run_in_executor(self._starter, process.start)
        except Exception as exc:  # the backend refused: this run, not the service
            parent.close()
            self._finish(run, "error", f"could not start a worker: {exc}", None)
            return
        finally:
            child.close()
        self._attach(run.run_id, parent)
        self.loop.add_reader(process.sentinel, self._exited, run)
        self.registry.update(run.run_id, worker_pid=process.pid)

    def _attach(self, run_id: str, conn: Connection) -> None:
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
        if self.backend == "local" and run.process is not None:
            return  # the process's sentinel says how it ended
        if not run.ended:
            self._finish(run, "error", "the worker's connection closed unexpectedly", None)

    async def _drained(self, run: ActiveRun, timeout: float = 5.0) -> None:
        """Wait until everything the worker said is handled (its connection closed)."""
        if run.pump is not None:
            with contextlib.suppress(asyncio.TimeoutError, Exception):
                await asyncio.wait_for(asyncio.shield(run.pump), timeout)

    def _handle(self, run: ActiveRun, item: tuple[Any, ...]) -> None:
        kind = item[0]
        hub = self._hub(run.run_id)
        if kind == "msg":
            hub.publish(item[1], item[2], item[3])
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
        elif kind == "end":
            self._finish(run, item[1], item[2], item[3])

    def _spawn(self, coro: Any) -> None:
        """A background task, referenced until it ends (the loop keeps weak references)."""
        assert self.loop is not None
        task = self.loop.create_task(coro)
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    def _exited(self, run: ActiveRun) -> None:
        """A local worker process ended: read what it still said, then judge."""
        assert self.loop is not None
        self.loop.remove_reader(run.process.sentinel)
        self._spawn(self._judge_exit(run))

    async def _judge_exit(self, run: ActiveRun) -> None:
        process = run.process
        await self._drained(run)  # everything it said before it ended
        process.join(timeout=5)
        if not run.ended:
            code = process.exitcode
            how = (
                f"killed by {signal.Signals(-code).name}"
                if code is not None and code < 0 and -code in signal.Signals._value2member_map_
                else f"exit code {code}"
            )
            self._finish(run, "error", f"the worker process died ({how})", None)
        self._detach(run)
        with contextlib.suppress(Exception):
            process.close()

    def _ray_done(self, run: ActiveRun, future: asyncio.Future) -> None:
        if run.ended:
            return
        assert self.loop is not None
        self._spawn(self._ray_judge(run, future))

    async def _ray_judge(self, run: ActiveRun, future: asyncio.Future) -> None:
        await asyncio.sleep(0.5)  # the connection back may still be on its way in
        await self._drained(run)
        if not run.ended:
            exc = future.exception()
            reason = (
                f"the Ray task failed: {exc!r}" if exc else "the Ray task ended without a result"
            )
            self._finish(run, "error", reason, None)
        self._detach(run)

    def _detach(self, run: ActiveRun) -> None:
        if run.link is not None:
            run.link.close()
            run.link = None
        if run.pump is not None and not run.pump.done():
            run.pump.cancel()

    def _finish(
        self, run: ActiveRun, status: str, reason: str | None, result: dict[str, Any] | None
    ) -> None:
        if run.ended:
            return
        run.ended = True
        if result is not None:
            self.results.put(run.run_id, result)
        fields: dict[str, Any] = {}
        if run.progress:
            fields["progress"] = run.progress
        self.registry.set_status(run.run_id, status, reason, **fields)
        self._hub(run.run_id).finish(self._end_text(status, reason, result))
        for future in run.replies.values():
            if not future.done():
                future.set_result((409, {"detail": f"the run ended ({status})"}))
        self.active.pop(run.run_id, None)
        self._retire_hubs()
        self._idle.set()
        self._schedule()

    def _end_text(self, status: str, reason: str | None, result: dict[str, Any] | None) -> str:
        return msg.dumps({"type": "end", "status": status, "reason": reason, "result": result})

    def _kill(self, run: ActiveRun) -> None:
        if self.backend == "ray":
            with contextlib.suppress(Exception):
                self._ray.cancel(run.process, force=True)
        elif run.process is not None:
            with contextlib.suppress(Exception):
                run.process.kill()

    # ------------------------------------------------------------------ service -> worker

    def _send(self, run: ActiveRun, command: tuple[Any, ...]) -> None:
        if run.link is None:
            run.pending.append(command)
            return
        run.link.send(command)  # never waits; a dead worker is judged by its sentinel

    def cancel(self, run_id: str) -> None:
        if run_id in self.queue:
            self.queue.remove(run_id)
            self.registry.forget_submission(run_id)
            reason = "cancelled before it started"
            self.registry.set_status(run_id, "aborted", reason)
            self._hub(run_id).finish(self._end_text("aborted", reason, None))
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

    def cmd_vel(self, run_id: str, v: float, w: float) -> bool:
        run = self.active.get(run_id)
        if run is None:
            return False
        self._send(run, ("cmd_vel", v, w))
        return True

    def goal(self, run_id: str, x: float, y: float, yaw: float) -> None:
        run = self.active.get(run_id)
        if run is None or run.status != "running" or run.progress.get("task_type") != "teleop":
            raise NotActive("the run's current task is not teleop")
        self._send(run, ("goal", x, y, yaw))

    async def record_room(self, run_id: str, label: str) -> tuple[int, dict[str, Any]]:
        run = self.active.get(run_id)
        if run is None or run.status != "running":
            raise NotActive("the run is not running")
        request_id = uuid.uuid4().hex
        future: asyncio.Future = asyncio.get_running_loop().create_future()
        run.replies[request_id] = future
        self._send(run, ("record", request_id, label))
        try:
            return await asyncio.wait_for(future, 10.0)
        finally:
            run.replies.pop(request_id, None)

    # ------------------------------------------------------------------ live streams

    def _hub(self, run_id: str) -> Hub:
        hub = self.hubs.get(run_id)
        if hub is None:
            hub = self.hubs[run_id] = Hub()
        return hub

    async def hub_for(self, run_id: str, run: dict[str, Any]) -> Hub:
        """The live hub of a run; for a finished run no longer in memory, one rebuilt from
        its ``stream.jsonl`` (read off the event loop) so that a late client still gets the
        snapshot and the end."""
        hub = self.hubs.get(run_id)
        if hub is not None:
            self.hubs.move_to_end(run_id)
            return hub
        run_dir = self.registry.run_dir(run_id)
        latest = await asyncio.to_thread(_snapshot_of, run_dir / STREAM_FILE)
        hub = self.hubs.get(run_id)  # another client may have rebuilt it meanwhile
        if hub is not None:
            return hub
        hub = Hub()
        hub.latest.update(latest)
        if run["status"] in FINAL:
            result = await self.results.get(run_id)
            hub.end = self._end_text(run["status"], run["reason"], result)
        self.hubs[run_id] = hub
        self._retire_hubs()
        return hub

    def _retire_hubs(self) -> None:
        finished = [
            rid
            for rid, hub in self.hubs.items()
            if hub.end is not None and not hub.clients and rid not in self.active
        ]
        for rid in finished[: max(0, len(finished) - FINISHED_HUBS)]:
            self.hubs.pop(rid, None)

    def live_progress(self, run_id: str) -> dict[str, Any] | None:
        run = self.active.get(run_id)
        return run.progress if run is not None and run.progress else None


def read_result(run_dir: Path) -> dict[str, Any] | None:
    path = run_dir / "result.json"
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None


def _snapshot_of(path: Path) -> dict[str, str]:
    """The latest message of each snapshot kind in a finished run's ``stream.jsonl``."""
    latest: dict[str, str] = {}
    if path.is_file():
        with open(path, encoding="utf-8") as f:
            for line in f:
                with contextlib.suppress(ValueError):
                    kind = json.loads(line).get("type")
                    if kind in SNAPSHOT_ORDER:
                        latest[kind] = line.rstrip("\n")
    return latest


class ResultCache:
    """``result.json`` of finished runs, read once off the event loop and kept (LRU)."""

    def __init__(self, registry: Registry, size: int = RESULT_CACHE) -> None:
        self.registry = registry
        self.size = size
        self._results: OrderedDict[str, dict[str, Any] | None] = OrderedDict()

    async def get(self, run_id: str) -> dict[str, Any] | None:
        if run_id in self._results:
            self._results.move_to_end(run_id)
            return self._results[run_id]
        result = await asyncio.to_thread(read_result, self.registry.run_dir(run_id))
        self.put(run_id, result)
        return result

    def put(self, run_id: str, result: dict[str, Any] | None) -> None:
        self._results[run_id] = result
        self._results.move_to_end(run_id)
        while len(self._results) > self.size:
            self._results.popitem(last=False)


def ray_entry(job: dict[str, Any], address: Any, authkey: bytes) -> None:
    """A Ray task: connect back to the service, then run like a local worker."""
    from multiprocessing.connection import Client

    conn = Client(address, authkey=authkey)
    conn.send(("hello", job["run_id"]))
    worker_main(job, conn)


def default_workers() -> int:
    return os.cpu_count() or 1
