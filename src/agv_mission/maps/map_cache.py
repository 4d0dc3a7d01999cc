"""Per-map tables (distance transforms, likelihood fields, distance fields) built once and
shared between runs.

Building them costs tens of milliseconds on turtlebot3_world and over a second on a
30 x 50 m warehouse (the signed distance field), and every run on the same map, in one
process (a sweep, the service running many missions), would otherwise build them again.
Keys are the map's content (a digest of its cells, resolution and origin), so a map loaded
twice, or copied, hits; an edited map misses. The tables are read-only.
"""

from __future__ import annotations

import hashlib
import threading
from collections import OrderedDict
from collections.abc import Callable, Hashable
from typing import TypeVar

import numpy as np

from agv_mission.maps.grid import OccupancyGrid

T = TypeVar("T")

#: Tables kept (least recently used dropped first): a warehouse's take ~25 MB.
MAX_ENTRIES = 12

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
