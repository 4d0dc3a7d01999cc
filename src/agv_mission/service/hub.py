"""Fan-out of one run's live stream to its WebSocket clients, in the service process.

The worker encodes each message once; the hub keeps the latest of each kind a late client
needs first (map, rooms, recorded, tree, plan, goal, state) and appends every message to
each client's own bounded queue. A client that reads too slowly loses the oldest of the
thinnable messages (state, scan, particles, horizon); one that falls behind even on the
others is dropped. Nothing here ever waits for a client, so no client slows a mission.
"""

from __future__ import annotations

import asyncio
import json
from collections import deque
from typing import Any

THINNABLE = frozenset({"state", "scan", "particles", "horizon"})
SNAPSHOT_ORDER = ("map", "rooms", "recorded", "tree", "plan", "goal", "state")
CLIENT_QUEUE = 200  # messages a client may lag behind before thinning starts
CLIENT_HARD_LIMIT = 2000  # non-thinnable backlog at which a client is dropped


class Client:
    """One subscriber: a bounded queue its sender task drains."""

    def __init__(self) -> None:
        self.queue: deque[tuple[str, str]] = deque()
        self.ready = asyncio.Event()
        self.dropped = False
        self.thinned = 0

    def put(self, kind: str, text: str) -> None:
        if self.dropped:
            return
        q = self.queue
        q.append((kind, text))
        if len(q) > CLIENT_QUEUE:
            for i, (k, _) in enumerate(q):
                if k in THINNABLE:
                    del q[i]
                    self.thinned += 1
                    break
            else:
                if len(q) > CLIENT_HARD_LIMIT:
                    self.dropped = True
                    q.clear()
        self.ready.set()


class Hub:
    """The live stream of one run."""

    def __init__(self) -> None:
        self.clients: set[Client] = set()
        self.latest: dict[str, str] = {}
        self.state: dict[str, Any] | None = None
        self.end: str | None = None

    def publish(self, kind: str, text: str) -> None:
        if kind in SNAPSHOT_ORDER:
            self.latest[kind] = text
            if kind == "state":
                self.state = None  # parsed lazily
        for client in self.clients:
            client.put(kind, text)

    def set_status(self, status: str) -> None:
        """A paused (or resumed) run sends no steps: republish its last state with the
        new status, so that every client sees the change."""
        state = self.latest_state()
        if state is None:
            return
        state["status"] = status
        self.publish("state", json.dumps(state, separators=(",", ":")))

    def latest_state(self) -> dict[str, Any] | None:
        text = self.latest.get("state")
        return json.loads(text) if text else None

    def finish(self, text: str) -> None:
        self.end = text
        for client in self.clients:
            client.put("end", text)

    def subscribe(self) -> Client:
        """A new client: the snapshot first (in the agreed order), then live messages."""
        client = Client()
        for kind in SNAPSHOT_ORDER:
            if kind in self.latest:
                client.queue.append((kind, self.latest[kind]))
        if self.end is not None:
            client.queue.append(("end", self.end))
        client.ready.set()
        self.clients.add(client)
        return client

    def unsubscribe(self, client: Client) -> None:
        self.clients.discard(client)
