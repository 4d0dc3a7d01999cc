"""Saved maps hold what was seen, not the canvas SLAM allocated.

SLAM grows its grid in chunks and starts from a canvas around the start or the bounds
(the 19 x 11 m house got a 22 x 20 m map), so a saved map would carry metres of unknown
border. :func:`crop_to_known` cuts the grid to the box of its known (FREE or OCCUPIED)
cells plus a small margin of unknown, which keeps every frontier a frontier.
"""

from __future__ import annotations

import math

import numpy as np

from agv_mission.geometry import Pose2D
from agv_mission.maps.grid import UNKNOWN, OccupancyGrid

#: Metres of unknown kept around what was seen.
CROP_MARGIN = 0.5


def crop_to_known(grid: OccupancyGrid, margin: float = CROP_MARGIN) -> OccupancyGrid:
    """``grid`` cut to its known cells plus ``margin`` metres (never beyond the grid); the
    grid itself when nothing is known. Cells keep their place in the map frame."""
    known = grid.data != UNKNOWN
    rows, cols = np.flatnonzero(known.any(axis=1)), np.flatnonzero(known.any(axis=0))
    if not len(rows):
        return grid
    m = int(math.ceil(margin / grid.resolution - 1e-9))
    r0, r1 = max(int(rows[0]) - m, 0), min(int(rows[-1]) + m + 1, grid.height)
    c0, c1 = max(int(cols[0]) - m, 0), min(int(cols[-1]) + m + 1, grid.width)
    if (r0, r1, c0, c1) == (0, grid.height, 0, grid.width):
        return grid
    o = grid.origin
    dx, dy = c0 * grid.resolution, r0 * grid.resolution
    c, s = math.cos(o.yaw), math.sin(o.yaw)
    origin = Pose2D(o.x + c * dx - s * dy, o.y + s * dx + c * dy, o.yaw)
    return OccupancyGrid(grid.data[r0:r1, c0:c1].copy(), grid.resolution, origin)
