"""Occupancy grids in the ROS convention: row 0 is the bottom of the map (lowest y)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from agv_mission.geometry import Pose2D

FREE = 0
OCCUPIED = 100
UNKNOWN = -1
#: Most cells a grid may hold, whatever draws it (a world rasterised, a map image read,
#: SLAM's map grown): 10^8, a 500 m square at 5 cm (SLAM's thirteen tables take ~52 bytes a
#: cell: 5 GiB; Freiburg's 1.7 km campus log needs about a third). A body 10^9 m long, a PGM
#: header claiming billions of pixels or a pose kilometres off would ask for terabytes.
MAX_GRID_CELLS = 100_000_000
_UNKNOWN_RANK = 50.5  # worse than any free-ish value (<= 50), better than occupied (> 50)


@dataclass
class OccupancyGrid:
    """A 2D occupancy grid like ``nav_msgs/OccupancyGrid``.

    ``data[row, col]`` is ``FREE`` (0), ``OCCUPIED`` (100) or ``UNKNOWN`` (-1); row 0 is
    the lowest y. ``origin`` is the map-frame pose of the lower-left corner of cell (0, 0).
    """

    data: np.ndarray  # int8, shape (height, width)
    resolution: float
    origin: Pose2D

    @property
    def height(self) -> int:
        return int(self.data.shape[0])

    @property
    def width(self) -> int:
        return int(self.data.shape[1])

    @property
    def extent(self) -> tuple[float, float, float, float]:
        """(xmin, xmax, ymin, ymax) of the grid in the map frame (origin yaw ignored)."""
        x0, y0 = self.origin.x, self.origin.y
        return (x0, x0 + self.width * self.resolution, y0, y0 + self.height * self.resolution)

    def world_to_cell(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(rows, cols) of map-frame points ``xy`` of shape (..., 2); may be out of bounds."""
        xy = np.asarray(xy, dtype=float)
        px, py = xy[..., 0] - self.origin.x, xy[..., 1] - self.origin.y
        if self.origin.yaw != 0.0:
            c, s = np.cos(self.origin.yaw), np.sin(self.origin.yaw)
            px, py = c * px + s * py, -s * px + c * py
        cols = np.floor(px / self.resolution).astype(np.int64)
        rows = np.floor(py / self.resolution).astype(np.int64)
        return rows, cols

    def cell_to_world(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """Map-frame centres of cells, shape (..., 2)."""
        px = (np.asarray(cols, dtype=float) + 0.5) * self.resolution
        py = (np.asarray(rows, dtype=float) + 0.5) * self.resolution
        if self.origin.yaw != 0.0:
            c, s = np.cos(self.origin.yaw), np.sin(self.origin.yaw)
            px, py = c * px - s * py, s * px + c * py
        return np.stack([px + self.origin.x, py + self.origin.y], axis=-1)

    def in_bounds(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        return (rows >= 0) & (rows < self.height) & (cols >= 0) & (cols < self.width)

    def value_at(self, xy: np.ndarray) -> np.ndarray:
        """Cell values at map-frame points; ``UNKNOWN`` outside the grid."""
        rows, cols = self.world_to_cell(xy)
        inside = self.in_bounds(rows, cols)
        out = np.full(rows.shape, UNKNOWN, dtype=np.int8)
        out[inside] = self.data[rows[inside], cols[inside]]
        return out

    def resampled(self, resolution: float) -> OccupancyGrid:
        """The grid at another cell size over (at least) the same extent, conservatively.

        A new cell takes the worst of the old cells it overlaps: occupied (> 50) over
        unknown over free, so that a coarser costmap never opens a gap in a wall.
        """
        if resolution == self.resolution:
            return self
        ratio = self.resolution / resolution
        height = max(1, int(np.ceil(self.height * ratio - 1e-9)))
        width = max(1, int(np.ceil(self.width * ratio - 1e-9)))
        rank = self.data.astype(np.float32)
        rank[self.data < 0] = _UNKNOWN_RANK
        row_starts = np.minimum(
            (np.arange(height) / ratio + 1e-9).astype(np.int64), self.height - 1
        )
        col_starts = np.minimum((np.arange(width) / ratio + 1e-9).astype(np.int64), self.width - 1)
        worst = np.maximum.reduceat(
            np.maximum.reduceat(rank, row_starts, axis=0), col_starts, axis=1
        )
        data = np.where(worst == _UNKNOWN_RANK, UNKNOWN, worst).astype(np.int8)
        return OccupancyGrid(data=data, resolution=float(resolution), origin=self.origin)

    def counts(self) -> dict[str, int]:
        """Number of free, occupied and unknown cells."""
        return {
            "free": int(np.count_nonzero(self.data == FREE)),
            "occupied": int(np.count_nonzero(self.data == OCCUPIED)),
            "unknown": int(np.count_nonzero(self.data == UNKNOWN)),
        }
