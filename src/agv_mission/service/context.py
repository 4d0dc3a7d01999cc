"""What the service's routes share: how ``serve`` was started and the service's parts."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from agv_mission.service.registry import Registry
from agv_mission.service.runs import RunManager
from agv_mission.service.sandbox import DataDirGuard


class ApiError(Exception):
    """An answer other than success: its status and its body (or the body's ``detail``)."""

    def __init__(self, status: int, detail: Any) -> None:
        self.status, self.detail = status, detail


@dataclass
class Settings:
    """What ``serve`` was started with."""

    data_dir: Path
    workers: int
    queue_size: int = 1000
    backend: str = "local"
    address: str | None = None
    token: str | None = None
    # the run observers a front end adds to every run (``serve`` adds the bag writer, as
    # ``run`` does): a module-level function of the loaded mission, so a worker process or
    # Ray task receives it by reference
    observers: Callable[[Any], list[Any]] | None = None

    def __post_init__(self) -> None:
        self.token = self.token or None  # an empty token is no token


@dataclass(frozen=True)
class Service:
    """One service: its settings, run registry, run manager and data-directory guard."""

    settings: Settings
    registry: Registry
    manager: RunManager
    guard: DataDirGuard

    async def get_run(self, run_id: str) -> dict[str, Any]:
        """From the registry's cache (SQLite only on a miss, off the event loop); 404."""
        run = await self.registry.aget(run_id)
        if run is None:
            raise ApiError(404, f"no run {run_id!r}")
        return run
