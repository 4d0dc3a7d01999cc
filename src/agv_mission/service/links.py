"""The link between the service and one worker: both of its ends.

The service talks to a worker over one duplex :class:`multiprocessing.connection.Connection`
(a pipe for local processes, a socket for Ray tasks). Worker -> service: ``("msg", type,
text, t, robot)`` live-stream messages (JSON text, encoded once in the worker; ``robot``
None for what is the run's, not one robot's), ``("robots", {name: (v_max, w_max)})``,
``("status", status)``, ``("progress", dict)``, ``("reply", request_id, code, body)`` and
finally ``("end", status, reason, result)``. Service -> worker: ``("cancel", reason)``,
``("pause",)``, ``("resume",)``, ``("pace", pace)``, ``("cmd_vel", robot, v, w)``, ``("goal", request_id,
robot, x, y, yaw)``, ``("record", request_id, robot, label)``.

Neither end waits for the other: the worker sends from a thread of its own
(:class:`Outbox`), and the service reads the frames from an asyncio stream
(:class:`WorkerLink`), so a frame half written never blocks its event loop.
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import pickle
import socket
import struct
import threading
from collections import deque
from multiprocessing.connection import Connection
from typing import Any

LINK_BUFFER = 1 << 20  # bytes a worker link buffers (a map message is a few hundred kB)
COALESCED = frozenset({"state", "scan", "particles", "horizon", "people"})  # latest wins, queued


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


class Outbox:
    """Sends to the service from a thread of its own, so the mission never waits for it.

    When the service reads slowly (a busy event loop, a full socket buffer), a frequent
    message (state, scan, particles, horizon) still queued is replaced in place by the
    newer one of its kind and robot; other messages keep their order and are all delivered.
    """

    def __init__(self, conn: Connection) -> None:
        self.conn = conn
        self.closed = False
        self._queue: deque[list[Any]] = deque()
        self._slots: dict[tuple[str, Any], list[Any]] = {}  # (kind, robot) -> unsent slot
        self._cond = threading.Condition()
        self._stop = False
        self.coalesced = 0
        self._thread = threading.Thread(target=self._pump, name="outbox", daemon=True)
        self._thread.start()

    def put(self, item: tuple[Any, ...]) -> None:
        with self._cond:
            if self.closed or self._stop:
                return
            kind = _slot_key(item)
            slot = self._slots.get(kind) if kind is not None else None
            if slot is not None:
                slot[0] = item
                self.coalesced += 1
                return
            slot = [item]
            self._queue.append(slot)
            if kind is not None:
                self._slots[kind] = slot
            self._cond.notify()

    def _pump(self) -> None:
        while True:
            with self._cond:
                while not self._queue and not self._stop:
                    self._cond.wait()
                if not self._queue:
                    return
                slot = self._queue.popleft()
                item = slot[0]
                key = _slot_key(item)
                if key is not None and self._slots.get(key) is slot:
                    del self._slots[key]
            try:
                self.conn.send(item)
            except (OSError, EOFError, BrokenPipeError, ValueError):
                with self._cond:
                    self.closed = True
                    self._queue.clear()
                    self._slots.clear()
                return

    def close(self, timeout: float = 30.0) -> None:
        """Deliver everything queued, then stop the thread."""
        with self._cond:
            self._stop = True
            self._cond.notify()
        self._thread.join(timeout)


def _slot_key(item: tuple[Any, ...]) -> tuple[str, Any] | None:
    """A frequent message's coalescing key: its kind and robot (None: never coalesced)."""
    if item[0] == "msg" and item[1] in COALESCED:
        return item[1], item[4] if len(item) > 4 else None
    return None
