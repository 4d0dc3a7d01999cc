"""The live hubs of a service's runs, kept in memory while they matter, and the results of
finished runs a late client or a run object needs (read once, off the event loop)."""

from __future__ import annotations

import asyncio
import contextlib
import json
from collections import OrderedDict
from collections.abc import Container
from pathlib import Path
from typing import Any

from agv_mission.service import stream_messages as msg
from agv_mission.service.hub import SNAPSHOT_ORDER, Hub
from agv_mission.service.registry import FINAL, Registry
from agv_mission.service.stream import STREAM_FILE

FINISHED_HUBS = 64  # finished runs whose stream stays in memory for late clients
RESULT_CACHE = 256  # result.json contents kept in memory


def end_text(status: str, reason: str | None, result: dict[str, Any] | None) -> str:
    """The stream's last message."""
    return msg.dumps({"type": "end", "status": status, "reason": reason, "result": result})


def read_result(run_dir: Path) -> dict[str, Any] | None:
    path = run_dir / "result.json"
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None


def _snapshot_of(path: Path) -> dict[str, dict[str | None, str]]:
    """The latest message of each snapshot kind (per robot) in a finished run's
    ``stream.jsonl``."""
    latest: dict[str, dict[str | None, str]] = {}
    if path.is_file():
        with open(path, encoding="utf-8") as f:
            for line in f:
                with contextlib.suppress(ValueError, AttributeError):
                    message = json.loads(line)
                    kind = message.get("type")
                    if kind in SNAPSHOT_ORDER:
                        latest.setdefault(kind, {})[message.get("robot")] = line.rstrip("\n")
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


class LiveHubs:
    """One :class:`Hub` per run that is queued, running, watched or recently finished
    (LRU beyond :data:`FINISHED_HUBS` finished ones); ``active`` is the manager's table of
    running runs, whose hubs are never retired."""

    def __init__(self, registry: Registry, results: ResultCache, active: Container[str]) -> None:
        self.registry = registry
        self.results = results
        self.active = active
        self.hubs: OrderedDict[str, Hub] = OrderedDict()

    def open(self, run_id: str) -> None:
        """A new run's hub, before its first client or message."""
        self.hubs[run_id] = Hub()

    def __getitem__(self, run_id: str) -> Hub:
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
            hub.end = end_text(run["status"], run["reason"], result)
        self.hubs[run_id] = hub
        self.retire()
        return hub

    def retire(self) -> None:
        """Forget the oldest finished, unwatched hubs beyond :data:`FINISHED_HUBS`."""
        finished = [
            rid
            for rid, hub in self.hubs.items()
            if hub.end is not None and not hub.clients and rid not in self.active
        ]
        for rid in finished[: max(0, len(finished) - FINISHED_HUBS)]:
            self.hubs.pop(rid, None)
