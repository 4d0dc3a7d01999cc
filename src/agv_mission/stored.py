"""Values kept on disk for later processes: what a fresh process would otherwise import a
heavy library to compute (a world's free space and distance field need scipy.ndimage, the
list of OMPL's planners needs OMPL's libraries), keyed by everything they depend on.

``agv-mission validate`` of a mission whose values are stored imports neither. A store that
cannot be read or written costs only the computation; a damaged file is computed again.
The folder is ``$AGV_MISSION_STORE``, else ``$XDG_CACHE_HOME/agv-mission/stored``; it
keeps the :data:`MAX_STORED` files used last.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
from collections.abc import Hashable
from pathlib import Path

from agv_mission.atomic import atomic_write_bytes

#: Files kept (the least recently used deleted first): a warehouse's distance field ~2.4 MB.
MAX_STORED = 64
STORE_ENV = "AGV_MISSION_STORE"


def store_dir() -> Path | None:
    """The folder of the stored values (None: no home to keep them in)."""
    given = os.environ.get(STORE_ENV)
    if given:
        return Path(given)
    try:
        base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    except RuntimeError:  # no home directory: nothing is stored
        return None
    return Path(base) / "agv-mission" / "stored"


def stored_path(kind: str, key: Hashable, suffix: str) -> Path | None:
    """Where the value ``kind`` of ``key`` (its ``repr`` names it exactly) is kept."""
    folder = store_dir()
    if folder is None:
        return None
    digest = hashlib.blake2b(repr(key).encode(), digest_size=16).hexdigest()
    return folder / f"{kind}-{digest}{suffix}"


def read_stored(path: Path | None) -> bytes | None:
    """The bytes stored at ``path`` (marked used), or None."""
    if path is None:
        return None
    try:
        data = path.read_bytes()
    except OSError:
        return None
    with contextlib.suppress(OSError):  # a store another user owns is still read
        os.utime(path)
    return data


def store(path: Path | None, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically; drop the least recently used files beyond
    :data:`MAX_STORED`."""
    if path is None:
        return
    with contextlib.suppress(OSError):
        atomic_write_bytes(path, data)
        kept = sorted(
            (p for p in path.parent.iterdir() if not p.name.startswith(".")), key=_used_at
        )
        for old in kept[: max(len(kept) - MAX_STORED, 0)]:
            old.unlink(missing_ok=True)


def _used_at(path: Path) -> float:
    try:
        return path.stat().st_mtime
    except OSError:
        return 0.0
