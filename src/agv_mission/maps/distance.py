"""Distance transforms of map masks, computed once per mask and shared.

A 30 x 50 m map at 5 cm is 600k cells; its Euclidean distance transform takes tens of
milliseconds, and every run on that map needs it (the costmap's clearance, the particle
filter's likelihood field). Runs in one process (a regression suite, the service) share
the result: the cache is keyed by the mask's content, and the arrays handed out are
read-only so that no caller can change another's map.
"""

from __future__ import annotations

import hashlib
import threading
from collections import OrderedDict

import numpy as np
from scipy.ndimage import distance_transform_edt

_CACHE_SIZE = 16
_cache: OrderedDict[tuple[str, tuple[int, ...], float], np.ndarray] = OrderedDict()
_lock = threading.Lock()


def obstacle_distance(blocked: np.ndarray, resolution: float) -> np.ndarray:
    """Metres (float32) from each cell centre to the nearest ``True`` cell of ``blocked``.

    Read-only: copy before changing it.
    """
    blocked = np.ascontiguousarray(blocked, dtype=bool)
    key = (hashlib.sha1(blocked.tobytes()).hexdigest(), blocked.shape, float(resolution))
    with _lock:
        hit = _cache.get(key)
        if hit is not None:
            _cache.move_to_end(key)
            return hit
    distance = (distance_transform_edt(~blocked) * resolution).astype(np.float32)
    distance.setflags(write=False)
    with _lock:
        _cache[key] = distance
        while len(_cache) > _CACHE_SIZE:
            _cache.popitem(last=False)
    return distance
