"""Where a run's worker runs: a local process from a fork server, or a Ray task.

A backend starts a worker, hands its connection to the manager (:meth:`RunManager.attach`)
and, when the worker is gone, judges how it ended: a worker that dies (a crash,
``kill -9``) ends its run ``error`` with the reason, without ever stopping the service.
"""

from __future__ import annotations

import asyncio
import contextlib
import secrets
import signal
import threading
from concurrent.futures import ThreadPoolExecutor
from multiprocessing.connection import Connection, Listener
from typing import Any, Protocol

from agv_mission.missions.run.workers import forkserver_context
from agv_mission.service.registry import Registry
from agv_mission.service.worker import ray_entry, worker_main


class ActiveRun(Protocol):
    """What a backend knows of a run it started (the run manager owns the rest)."""

    run_id: str
    process: Any  # multiprocessing.Process, or a Ray ObjectRef
    ended: bool


class RunManager(Protocol):
    """What a backend asks of the run manager that owns the runs it starts."""

    loop: asyncio.AbstractEventLoop | None
    registry: Registry
    stopping: bool

    def attach(self, run_id: str, conn: Connection) -> None: ...

    def detach(self, run: Any) -> None: ...

    def spawn(self, coro: Any) -> None: ...

    async def drained(self, run: Any, timeout: float = 5.0) -> None: ...

    def finish(
        self, run: Any, status: str, reason: str | None, result: dict[str, Any] | None
    ) -> None: ...


class LocalBackend:
    """Each run in a process of this machine, forked from a fork server that has the
    mission stack imported already; the process's exit sentinel says how it ended."""

    judges_exit = True  # a closed connection is not the end: the sentinel is

    def __init__(self, manager: RunManager) -> None:
        self.manager = manager
        self._ctx: Any = None
        self._starter = ThreadPoolExecutor(max_workers=1, thread_name_prefix="start-worker")

    async def start(self) -> None:
        self._ctx = forkserver_context("agv_mission.service.worker")
        from multiprocessing import forkserver

        await asyncio.to_thread(forkserver.ensure_running)

    def launch(self, run: ActiveRun, job: dict[str, Any]) -> None:
        parent, child = self._ctx.Pipe(duplex=True)
        run.process = self._ctx.Process(
            target=worker_main, args=(job, child), name=f"agv-run-{run.run_id}", daemon=False
        )
        self.manager.spawn(self._start_process(run, parent, child))

    async def _start_process(self, run: ActiveRun, parent: Connection, child: Connection) -> None:
        """Start a local worker off the event loop: the fork server answers in a few
        hundred milliseconds on a busy machine, and requests must not wait for that."""
        manager = self.manager
        assert manager.loop is not None
        process = run.process
        try:
            await manager.loop.run_in_executor(self._starter, process.start)
        except Exception as exc:  # the backend refused: this run, not the service
            parent.close()
            manager.finish(run, "error", f"could not start a worker: {exc}", None)
            return
        finally:
            child.close()
        manager.attach(run.run_id, parent)
        manager.loop.add_reader(process.sentinel, self._exited, run)
        manager.registry.update(run.run_id, worker_pid=process.pid)

    def _exited(self, run: ActiveRun) -> None:
        """A local worker process ended: read what it still said, then judge."""
        assert self.manager.loop is not None
        self.manager.loop.remove_reader(run.process.sentinel)
        self.manager.spawn(self._judge_exit(run))

    async def _judge_exit(self, run: ActiveRun) -> None:
        process = run.process
        await self.manager.drained(run)  # everything it said before it ended
        process.join(timeout=5)
        if not run.ended:
            code = process.exitcode
            how = (
                f"killed by {signal.Signals(-code).name}"
                if code is not None and code < 0 and -code in signal.Signals._value2member_map_
                else f"exit code {code}"
            )
            self.manager.finish(run, "error", f"the worker process died ({how})", None)
        self.manager.detach(run)
        with contextlib.suppress(Exception):
            process.close()

    def kill(self, run: ActiveRun) -> None:
        if run.process is not None:
            with contextlib.suppress(Exception):
                run.process.kill()

    def stop(self) -> None:
        """Nothing to release: each process is judged by its own sentinel."""


class RayBackend:
    """Each run a Ray task (on an existing cluster at ``address``, or a new local one) that
    connects back to a listener of the service and says which run it is."""

    judges_exit = False  # the connection closing is what the service sees of a task's end

    def __init__(self, manager: RunManager, workers: int, address: str | None) -> None:
        self.manager = manager
        self.workers = workers
        self.address = address
        self._listener: Listener | None = None
        self._ray: Any = None
        self._task: Any = None  # ray_entry as a Ray task
        self._authkey = b""

    async def start(self) -> None:
        await asyncio.to_thread(self._start_ray)

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
        self._task = ray.remote(num_cpus=1, max_retries=0)(ray_entry)  # exported once
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
                if self.manager.stopping:
                    return
                continue
            if not (isinstance(hello, tuple) and hello[:1] == ("hello",)):
                conn.close()
                continue
            assert self.manager.loop is not None
            self.manager.loop.call_soon_threadsafe(self.manager.attach, str(hello[1]), conn)

    def launch(self, run: ActiveRun, job: dict[str, Any]) -> None:
        assert self._listener is not None
        run.process = self._task.remote(job, self._listener.address, self._authkey)
        future = asyncio.wrap_future(run.process.future())
        future.add_done_callback(lambda f, r=run: self._done(r, f))

    def _done(self, run: ActiveRun, future: asyncio.Future) -> None:
        if run.ended:
            return
        assert self.manager.loop is not None
        self.manager.spawn(self._judge(run, future))

    async def _judge(self, run: ActiveRun, future: asyncio.Future) -> None:
        await asyncio.sleep(0.5)  # the connection back may still be on its way in
        await self.manager.drained(run)
        if not run.ended:
            exc = future.exception()
            reason = (
                f"the Ray task failed: {exc!r}" if exc else "the Ray task ended without a result"
            )
            self.manager.finish(run, "error", reason, None)
        self.manager.detach(run)

    def kill(self, run: ActiveRun) -> None:
        with contextlib.suppress(Exception):
            self._ray.cancel(run.process, force=True)

    def stop(self) -> None:
        if self._listener is not None:
            with contextlib.suppress(OSError):
                self._listener.close()
        if self._ray is not None:
            with contextlib.suppress(Exception):
                self._ray.shutdown()
