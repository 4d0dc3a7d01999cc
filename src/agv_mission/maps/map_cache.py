"""Per-map tables (distance transforms, likelihood fields, distance fields) built once and
shared between runs.

Building them costs tens of milliseconds on turtlebot3_world and over a second on a
30 x 50 m warehouse (the signed distance field), and every run on the same map, in one
process (a sweep, the service running many missions), would otherwise build them again.
Keys are the map's content (a digest of its cells, resolution and origin), so a map loaded
twice, or copied, hits; an edited map misses. The tables are read-only.

The tables every mission's check needs (a world's free space, the costmap's distance
field) are also stored on disk for later processes (:func:`stored_array_table`): they are
cheap to build, but building them needs ``scipy.ndimage``, whose import (~0.5 s) costs
more than all the rest of ``agv-mission validate``.
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import os
import threading
from collections import OrderedDict
from collections.abc import Callable, Hashable
from pathlib import Path
from typing import TypeVar

import numpy as np

from agv_mission.atomic import atomic_write_bytes
from agv_mission.maps.grid import OccupancyGrid

T = TypeVar("T")

#: Tables kept (least recently used dropped first): a warehouse's take ~25 MB.
MAX_ENTRIES = 12

#: Tables kept on disk (the least recently used deleted first): a warehouse's ~2.4 MB.
MAX_STORED = 64
#: Where the stored tables live; without it ``$XDG_CACHE_HOME/agv-mission/maps``.
STORE_ENV = "AGV_MISSION_MAP_CACHE"

_lock = threading.Lock()
_tables: OrderedDict[tuple[Hashable, ...], object] = OrderedDict()


def array_key(data: np.ndarray) -> tuple[Hashable, ...]:
    """An array's identity by content: cells, shape and type."""
    data = np.ascontiguousarray(data)
    digest = hashlib.blake2b(data.tobytes(), digest_size=16).hexdigest()
    return (digest, data.shape, str(data.dtype))


def grid_key(grid: OccupancyGrid) -> tuple[Hashable, ...]:
    """The map's identity by content: cells, shape, resolution and origin."""
    o = grid.origin
    return (*array_key(grid.data), float(grid.resolution), o.x, o.y, o.yaw)


def map_table(kind: str, grid: OccupancyGrid, params: Hashable, build: Callable[[], T]) -> T:
    """The table ``kind`` of ``grid`` with ``params``: built by ``build()`` on a miss."""
    return cached_table((kind, grid_key(grid), params), build)


def array_table(kind: str, data: np.ndarray, params: Hashable, build: Callable[[], T]) -> T:
    """The table ``kind`` of the array ``data`` (e.g. a mask) with ``params``."""
    return cached_table((kind, array_key(data), params), build)


def stored_array_table(
    kind: str, data: np.ndarray, params: Hashable, build: Callable[[], np.ndarray]
) -> np.ndarray:
    """:func:`array_table` of an array the shape of ``data``, also kept on disk for later
    processes: read from there on a miss in memory, else built by ``build()`` and stored.
    A store that cannot be read or written costs only the build."""
    key = (kind, array_key(data), params)

    def load_or_build() -> np.ndarray:
        path = _stored_path(key)
        table = _read_stored(path, data.shape)
        if table is None:
            table = np.ascontiguousarray(build())
            _store(path, table)
        table.setflags(write=False)
        return table

    return cached_table(key, load_or_build)


def cached_table(key: tuple[Hashable, ...], build: Callable[[], T]) -> T:
    """The table under ``key``, built by ``build()`` on a miss; old tables are dropped."""
    with _lock:
        hit = _tables.get(key)
        if hit is not None:
            _tables.move_to_end(key)
            return hit  # type: ignore[return-value]
    value = build()
    with _lock:
        _tables[key] = value
        while len(_tables) > MAX_ENTRIES:
            _tables.popitem(last=False)
    return value


def clear() -> None:
    """Forget every table (tests; memory)."""
    with _lock:
        _tables.clear()


def store_dir() -> Path:
    """The folder of the stored tables."""
    given = os.environ.get(STORE_ENV)
    if given:
        return Path(given)
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "agv-mission" / "maps"


def _stored_path(key: tuple[Hashable, ...]) -> Path:
    digest = hashlib.blake2b(repr(key).encode(), digest_size=16).hexdigest()
    return store_dir() / f"{key[0]}-{digest}.npy"


def _read_stored(path: Path, shape: tuple[int, ...]) -> np.ndarray | None:
    """The table stored at ``path`` (marked used), or None when there is none whole."""
    try:
        table = np.load(path, allow_pickle=False)
        os.utime(path)
    except (OSError, ValueError, EOFError):
        return None
    return table if isinstance(table, np.ndarray) and table.shape == shape else None


def _store(path: Path, table: np.ndarray) -> None:
    """Write ``table`` to ``path`` atomically and drop the least recently used beyond
    :data:`MAX_STORED`."""
    buffer = io.BytesIO()
    np.save(buffer, table, allow_pickle=False)
    with contextlib.suppress(OSError):
        atomic_write_bytes(path, buffer.getvalue())
        stored = sorted(path.parent.glob("*.npy"), key=_used_at)
        for old in stored[: max(len(stored) - MAX_STORED, 0)]:
            old.unlink(missing_ok=True)


def _used_at(path: Path) -> float:
    try:
        return path.stat().st_mtime
    except OSError:
        return 0.0
