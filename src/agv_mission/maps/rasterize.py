"""Rasterise world geometry (boxes, cylinders) into an occupancy grid.

A cell is OCCUPIED when the geometry overlaps its square with positive area (touching
an edge only does not count, so a box whose sides lie on cell boundaries occupies
exactly the cells inside it). Cells reachable from the spawn through non-occupied
cells (4-connected flood fill) are FREE and everything else is UNKNOWN, which is
what a ``map_saver`` map of the world would show: the outside of the arena and the
inside of closed obstacles are unknown.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence

import numpy as np

from agv_mission.geometry import Bounds, Pose2D
from agv_mission.maps.grid import FREE, MAX_GRID_CELLS, OCCUPIED, UNKNOWN, OccupancyGrid
from agv_mission.maps.map_cache import stored_array_table
from agv_mission.maps.worlds import Box, Cylinder

_EPS = 1e-7  # metres: overlaps thinner than this do not count as touching


class WorldTooLarge(ValueError):
    """Bounds whose grid would hold more than :data:`MAX_GRID_CELLS` cells."""


def grid_shape(bounds: Bounds, resolution: float) -> tuple[int, int]:
    """(height, width) in cells of a grid covering ``bounds`` (rounded up)."""
    xmin, xmax, ymin, ymax = bounds
    if not (xmax > xmin and ymax > ymin):
        raise ValueError(f"empty bounds {bounds}: need xmax > xmin and ymax > ymin")
    if resolution <= 0:
        raise ValueError(f"resolution must be > 0, got {resolution}")
    cols, rows = (xmax - xmin) / resolution, (ymax - ymin) / resolution  # inf: 1e308 m
    if not cols * rows <= MAX_GRID_CELLS:
        raise WorldTooLarge(
            f"a grid of {xmax - xmin:.4g} x {ymax - ymin:.4g} m is {cols * rows:.3g} cells "
            f"of {resolution:g} m (at most {MAX_GRID_CELLS:.0e})"
        )
    width = math.ceil(cols - 1e-9)
    height = math.ceil(rows - 1e-9)
    return height, width


def occupancy_mask(
    boxes: Iterable[Box],
    cylinders: Iterable[Cylinder],
    shape: tuple[int, int],
    resolution: float,
    origin: Pose2D,
) -> np.ndarray:
    """Boolean (H, W) mask of the cells touched by the geometry (grid origin yaw must be 0)."""
    if origin.yaw != 0.0:
        raise ValueError("rasterising into a rotated grid is not supported")
    mask = np.zeros(shape, dtype=bool)
    for box in boxes:
        _mark_box(mask, box, resolution, origin)
    for cyl in cylinders:
        _mark_cylinder(mask, cyl, resolution, origin)
    return mask


def rasterize(
    boxes: Iterable[Box],
    cylinders: Iterable[Cylinder],
    bounds: Bounds,
    resolution: float,
    spawn: Pose2D | Sequence[float],
) -> OccupancyGrid:
    """Occupancy grid of the geometry over ``bounds``; free space is what the spawn reaches.

    Raises ``ValueError`` when the spawn lies outside the bounds or inside geometry.
    """
    xmin, _, ymin, _ = bounds
    shape = grid_shape(bounds, resolution)
    origin = Pose2D(float(xmin), float(ymin), 0.0)
    occupied = occupancy_mask(boxes, cylinders, shape, resolution, origin)

    sx, sy = (spawn.x, spawn.y) if isinstance(spawn, Pose2D) else (spawn[0], spawn[1])
    col = math.floor((sx - origin.x) / resolution)
    row = math.floor((sy - origin.y) / resolution)
    if not (0 <= row < shape[0] and 0 <= col < shape[1]):
        raise ValueError(f"spawn ({sx:.3f}, {sy:.3f}) lies outside the bounds {bounds}")
    if occupied[row, col]:
        raise ValueError(f"spawn ({sx:.3f}, {sy:.3f}) lies inside an obstacle")

    data = np.full(shape, UNKNOWN, dtype=np.int8)
    data[spawn_region(occupied, row, col)] = FREE
    data[occupied] = OCCUPIED
    return OccupancyGrid(data=data, resolution=float(resolution), origin=origin)


def spawn_region(occupied: np.ndarray, row: int, col: int) -> np.ndarray:
    """The cells (H, W bool, read-only) that cell (row, col) reaches through cells not
    ``occupied``, 4-connected; stored for later processes, as the world is the same."""

    def build() -> np.ndarray:
        from scipy import ndimage  # ~0.5 s: only when not stored

        labels, _ = ndimage.label(~occupied)  # default structure: 4-connectivity
        return labels == labels[row, col]

    return stored_array_table("spawn_region", occupied, (row, col), build)


# --------------------------------------------------------------------------- helpers


def _window(
    mask: np.ndarray, cx: float, cy: float, ex: float, ey: float, res: float, origin: Pose2D
) -> tuple[slice, slice] | None:
    """Row/col slices of the cells that may overlap the AABB centred at (cx, cy)."""
    c0 = max(math.floor((cx - ex - origin.x) / res) - 1, 0)
    c1 = min(math.ceil((cx + ex - origin.x) / res) + 1, mask.shape[1])
    r0 = max(math.floor((cy - ey - origin.y) / res) - 1, 0)
    r1 = min(math.ceil((cy + ey - origin.y) / res) + 1, mask.shape[0])
    if c0 >= c1 or r0 >= r1:
        return None
    return slice(r0, r1), slice(c0, c1)


def _cell_centres(rows: slice, cols: slice, res: float, origin: Pose2D):
    xs = origin.x + (np.arange(cols.start, cols.stop) + 0.5) * res
    ys = origin.y + (np.arange(rows.start, rows.stop) + 0.5) * res
    return xs[None, :], ys[:, None]


def _mark_box(mask: np.ndarray, box: Box, res: float, origin: Pose2D) -> None:
    c, s = math.cos(box.yaw), math.sin(box.yaw)
    ex = abs(c) * box.half_x + abs(s) * box.half_y
    ey = abs(s) * box.half_x + abs(c) * box.half_y
    win = _window(mask, box.x, box.y, ex, ey, res, origin)
    if win is None:
        return
    xs, ys = _cell_centres(*win, res, origin)
    dx, dy = xs - box.x, ys - box.y
    h = res / 2.0
    # Separating-axis test between each cell square and the (rotated) box.
    hit = (np.abs(dx) < ex + h - _EPS) & (np.abs(dy) < ey + h - _EPS)
    if box.yaw % (math.pi / 2.0) != 0.0:
        spread = h * (abs(c) + abs(s))
        hit &= np.abs(dx * c + dy * s) < box.half_x + spread - _EPS
        hit &= np.abs(-dx * s + dy * c) < box.half_y + spread - _EPS
    mask[win] |= hit


def _mark_cylinder(mask: np.ndarray, cyl: Cylinder, res: float, origin: Pose2D) -> None:
    win = _window(mask, cyl.x, cyl.y, cyl.radius, cyl.radius, res, origin)
    if win is None:
        return
    xs, ys = _cell_centres(*win, res, origin)
    h = res / 2.0
    gx = np.maximum(np.abs(xs - cyl.x) - h, 0.0)
    gy = np.maximum(np.abs(ys - cyl.y) - h, 0.0)
    mask[win] |= gx**2 + gy**2 < (cyl.radius - _EPS) ** 2
