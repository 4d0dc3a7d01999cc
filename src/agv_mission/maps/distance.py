"""Distance transforms of map masks, computed once per mask and shared.

A 30 x 50 m map at 5 cm is 600k cells; its Euclidean distance transform takes tens of
milliseconds, and every run on that map needs it (the costmap's clearance, the particle
filter's likelihood field). Runs in one process (a regression suite, the service) share
the result: the cache is keyed by the mask's content, and the arrays handed out are
read-only so that no caller can change another's map. Later processes read it from disk
(:func:`~agv_mission.maps.map_cache.stored_array_table`): ``agv-mission validate`` then
never imports ``scipy.ndimage``.
"""

from __future__ import annotations

import numpy as np

from agv_mission.maps.map_cache import stored_array_table


def obstacle_distance(blocked: np.ndarray, resolution: float) -> np.ndarray:
    """Metres (float32) from each cell centre to the nearest ``True`` cell of ``blocked``.

    Read-only: copy before changing it.
    """
    blocked = np.ascontiguousarray(blocked, dtype=bool)

    def build() -> np.ndarray:
        from scipy.ndimage import distance_transform_edt  # ~0.5 s: only when not stored

        return (distance_transform_edt(~blocked) * resolution).astype(np.float32)

    return stored_array_table("obstacle_distance", blocked, float(resolution), build)
