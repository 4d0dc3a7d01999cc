"""Fan-out of one run's live stream to its WebSocket clients, in the service process.

The worker encodes each message once; the hub keeps the latest of each kind a late client
needs first (map, rooms, recorded, tree, plan, goal, state) and appends every message to
each client's own queue; in a fleet run the snapshot holds the latest of each kind per robot
(a message's ``robot``). Nothing here ever waits for a client, so no client slows a
mission. A client's sender takes everything queued at once and thins it: of the frequent
kinds (state, scan, particles, horizon) a message is skipped when a newer one of its kind
(of the same robot) is waiting and it is closer in simulated time than :data:`SPACING` to
the last one sent (so every client still gets at least 5 states per simulated second of
every robot, and the newest of each kind always). A client that lags by more than :data:`CLIENT_QUEUE` messages loses
the oldest frequent ones; one that falls behind even on the others is dropped.

Many clients share a budget: each frequent kind goes out at most :data:`KIND_BUDGET`
times per wall second over all the run's clients (a token bucket per client and kind: 50
clients get 12 states a second each; one client sees 5 states per simulated second of a
run at up to 120x real time, 12 clients at 10x); a client may ask for less (``?rate=N``: the dashboard takes 25). A message
over budget is held (the newest replaces it) and sent when its client has a token again,
so the fan-out's CPU stays bounded however many watch, and the last state always
arrives. Each client's sender wakes at most 20 times a second (``live_api.SEND_PERIOD``),
except for a status change, a pong or the end.
"""

from __future__ import annotations

import asyncio
import json
import math
from collections import deque
from typing import Any

SPACING = {"state": 0.2, "scan": 0.2, "horizon": 0.2, "particles": 0.5, "people": 0.1}  # sim s
THINNABLE = frozenset(SPACING)
URGENT = frozenset({"end", "pong", "recorded"})  # sent without waiting for the next period
SNAPSHOT_ORDER = ("map", "rooms", "recorded", "robots", "tree", "plan", "goal", "state")
EVENT_BACKLOG = 1000  # a run's latest events a late client is sent after the snapshot
CLIENT_QUEUE = 500  # messages a client may lag behind before the oldest frequent ones go
CLIENT_HARD_LIMIT = 5000  # backlog of other messages at which a client is dropped
KIND_BUDGET = 600.0  # messages of one frequent kind per wall second, over all clients
BURST = 0.5  # wall seconds of budget a client may spend at once

Item = tuple[str, str, "float | None", str]  # kind, text, sim time, thinning key


def thin_key(kind: str, robot: str | None) -> str:
    """Frequent kinds are thinned per robot: one robot's states never crowd out another's."""
    return kind if robot is None else f"{kind}/{robot}"


class Client:
    """One subscriber: a queue its sender task drains."""

    def __init__(self, max_rate: float = KIND_BUDGET) -> None:
        self.max_rate = max_rate  # what the client asked for (``?rate=``), per frequent kind
        self.queue: deque[Item] = deque()
        self.ready = asyncio.Event()  # something is queued
        self.urgent = asyncio.Event()  # something is queued that should not wait a period
        self.dropped = False
        self.thinned = 0
        self.last_t: dict[str, float] = {}
        self.held: dict[str, tuple[str, str, float | None]] = {}  # key -> kind, text, t
        self.rate = max_rate  # messages of a frequent kind per wall second (token bucket)
        self.tokens: dict[str, tuple[float, float]] = {}  # kind -> (tokens, at wall time)

    def put(
        self,
        kind: str,
        text: str,
        t: float | None = None,
        urgent: bool = False,
        robot: str | None = None,
    ) -> None:
        if self.dropped:
            return
        if urgent or kind in URGENT:
            self.urgent.set()
        q = self.queue
        q.append((kind, text, t, thin_key(kind, robot)))
        if len(q) > CLIENT_QUEUE:
            for i, item in enumerate(q):
                if item[0] in THINNABLE:
                    del q[i]
                    self.thinned += 1
                    break
            else:
                if len(q) > CLIENT_HARD_LIMIT:
                    self.dropped = True
                    q.clear()
        self.ready.set()

    def take(self, now: float) -> tuple[list[tuple[str, str]], float | None]:
        """What to send at wall time ``now`` (thinned, see the module's docstring) and when
        a held message falls due (None: nothing held)."""
        batch = list(self.queue)
        self.queue.clear()
        newest = {key: i for i, (kind, _, _, key) in enumerate(batch) if kind in SPACING}
        out = []
        for i, (kind, text, t, key) in enumerate(batch):
            if kind not in SPACING:
                out.append((kind, text))
                continue
            too_close = t is not None and t - self.last_t.get(key, -math.inf) < SPACING[kind] - 1e-6
            if too_close and i != newest[key]:
                self.thinned += 1
                continue
            if not self._token(key, now):
                if key in self.held:
                    self.thinned += 1
                self.held[key] = (kind, text, t)
                continue
            self._sent(key, t)
            self.held.pop(key, None)
            out.append((kind, text))
        due = None
        for key in list(self.held):
            if self._token(key, now):
                kind, text, t = self.held.pop(key)
                self._sent(key, t)
                out.append((kind, text))
            else:
                tokens, _ = self.tokens[key]
                ready_at = now + (1.0 - tokens) / self.rate
                due = ready_at if due is None else min(due, ready_at)
        return out, due

    def _token(self, key: str, now: float) -> bool:
        """Take one of ``key``'s tokens (a kind, per robot; refilled at ``rate``, up to half
        a second's worth)."""
        capacity = max(1.0, self.rate * BURST)
        tokens, at = self.tokens.get(key, (capacity, now))
        tokens = min(capacity, tokens + (now - at) * self.rate)
        ok = tokens >= 1.0
        self.tokens[key] = (tokens - 1.0 if ok else tokens, now)
        return ok

    def _sent(self, key: str, t: float | None) -> None:
        if t is not None:
            self.last_t[key] = t


class Hub:
    """The live stream of one run."""

    def __init__(self) -> None:
        self.clients: set[Client] = set()
        # kind -> robot (None: the run's, not one robot's) -> the latest message's text
        self.latest: dict[str, dict[str | None, str]] = {}
        # the events so far (robot, text): a page opened late still shows what happened
        self.events: deque[tuple[str | None, str]] = deque(maxlen=EVENT_BACKLOG)
        self.end: str | None = None

    def publish(
        self,
        kind: str,
        text: str,
        t: float | None = None,
        urgent: bool = False,
        robot: str | None = None,
    ) -> None:
        if kind in SNAPSHOT_ORDER:
            self.latest.setdefault(kind, {})[robot] = text
        elif kind == "event":
            self.events.append((robot, text))
        for client in self.clients:
            client.put(kind, text, t, urgent, robot)

    def set_status(self, status: str) -> None:
        """A paused (or resumed) run sends no steps: republish every robot's last state
        with the new status, so that every client sees the change."""
        for robot, state in self.latest_states().items():
            state["status"] = status
            text = json.dumps(state, separators=(",", ":"))
            self.publish("state", text, state.get("t"), True, robot)

    def latest_states(self) -> dict[str | None, dict[str, Any]]:
        return {robot: json.loads(text) for robot, text in self.latest.get("state", {}).items()}

    def finish(self, text: str) -> None:
        self.end = text
        for client in self.clients:
            client.put("end", text)

    def subscribe(self, max_rate: float = KIND_BUDGET) -> Client:
        """A new client: the snapshot first (in the agreed order), the events so far, then
        live messages; at most ``max_rate`` messages of each frequent kind per wall second (a page that draws
        20 frames a second needs no more)."""
        client = Client(max_rate)
        for kind in SNAPSHOT_ORDER:
            for robot, text in self.latest.get(kind, {}).items():
                client.queue.append((kind, text, None, thin_key(kind, robot)))
        for robot, text in self.events:
            client.queue.append(("event", text, None, thin_key("event", robot)))
        if self.end is not None:
            client.queue.append(("end", self.end, None, "end"))
        client.ready.set()
        self.clients.add(client)
        self._share()
        return client

    def unsubscribe(self, client: Client) -> None:
        self.clients.discard(client)
        self._share()

    def _share(self) -> None:
        rate = KIND_BUDGET / max(1, len(self.clients))
        for client in self.clients:
            client.rate = min(rate, client.max_rate)
