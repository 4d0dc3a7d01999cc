"""Per-map tables (distance transforms, likelihood fields, distance fields) built once and
shared between runs.

Building them costs tens of milliseconds on turtlebot3_world and over a second on a
30 x 50 m warehouse (the signed distance field), and every run on the same map, in one
process (a sweep, the service running many missions), would otherwise build them again.
Keys are the map's content (a digest of its cells, resolution and origin), so a map loaded
twice, or copied, hits; an edited map misses. The tables are read-only.

The tables every mission's check needs (a world's free space, the costmap's distance
field) are also stored on disk for later processes (:func:`stored_array_table`, see
:mod:`agv_mission.stored`): they are cheap to build, but building them needs
``scipy.ndimage``, whose import (~0.5 s) costs more than all the rest of
``agv-mission validate``.
"""

from __future__ import annotations

import hashlib
import io
import threading
from collections import OrderedDict
from collections.abc import Callable, Hashable
from pathlib import Path
from typing import TypeVar

import numpy as np

from agv_mission.maps.grid import OccupancyGrid
from agv_mission.stored import read_stored, store, stored_path

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


def stored_array_table(
    kind: str, data: np.ndarray, params: Hashable, build: Callable[[], np.ndarray]
) -> np.ndarray:
    """:func:`array_table` of an array the shape of ``data``, also kept on disk for later
    processes: read from there on a miss in memory, else built by ``build()`` and stored.
    A store that cannot be read or written costs only the build."""
    key = (kind, array_key(data), params)

    def load_or_build() -> np.ndarray:
        path = stored_path(kind, key, ".npy")
        table = _read_table(path, data.shape)
        if table is None:
            table = np.ascontiguousarray(build())
            buffer = io.BytesIO()
            np.save(buffer, table, allow_pickle=False)
            store(path, buffer.getvalue())
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


def _read_table(path: Path | None, shape: tuple[int, ...]) -> np.ndarray | None:
    """The array stored at ``path`` when it is whole and of ``shape``, else None."""
    data = read_stored(path)
    if data is None:
        return None
    try:
        table = np.load(io.BytesIO(data), allow_pickle=False)
    except (OSError, ValueError, EOFError):
        return None
    return table if isinstance(table, np.ndarray) and table.shape == shape else None
