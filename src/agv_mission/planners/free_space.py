"""The free space every grid-based global planner searches, and what those planners share.

:class:`FreeSpace` holds the cells a robot of the costmap's radius (plus the planner's
clearance) may occupy, in the grid's own metric frame, with exact segment traversal;
:class:`FreeSpacePlanner` is the part of a planner plugin that is the same for
``grid_astar``, ``cost_grid`` and ``ompl`` (config, clearance, end points).
"""

from __future__ import annotations

import math
import time
from typing import Generic, Protocol, TypeVar

import numpy as np

from agv_mission.geometry import Pose2D
from agv_mission.maps.costmap import Costmap
from agv_mission.planners.base import PlannedPath, PlanningError

SQRT2, SQRT5 = math.sqrt(2.0), math.sqrt(5.0)
EDGE_EPS = 1e-6  # cells: points this close to a cell edge count for both cells
MAX_COST = 252.0  # the costmap's highest cost outside lethal cells
# Undirected moves (drow, dcol, length in cells, cells the move squeezes between),
# 8-connected first, then the knight moves that 16-connectivity adds.
MOVES_8 = (
    (0, 1, 1.0, ()),
    (1, 0, 1.0, ()),
    (1, 1, SQRT2, ((1, 0), (0, 1))),
    (1, -1, SQRT2, ((1, 0), (0, -1))),
)
MOVES_16 = MOVES_8 + (
    (1, 2, SQRT5, ((0, 1), (1, 1))),
    (2, 1, SQRT5, ((1, 0), (1, 1))),
    (1, -2, SQRT5, ((0, -1), (1, -1))),
    (2, -1, SQRT5, ((1, 0), (1, -1))),
)


def cost_factor(cost: np.ndarray, weight: float) -> np.ndarray:
    """What a step over cells of inflation ``cost`` costs per unit length: ``1 + weight *
    cost / 252``, so that with ``weight > 0`` paths keep to the middle of corridors."""
    return 1.0 + weight * cost.astype(np.float64) / MAX_COST


class FreeSpace:
    """Cells a robot of the costmap's radius (plus ``margin``) may occupy.

    Works in the grid's own metric frame (origin at the outer corner of cell (0, 0),
    axes along the grid) so that a rotated map origin needs no special case. Holds
    numpy data only: safe to capture in OMPL callbacks.
    """

    def __init__(self, costmap: Costmap, margin: float) -> None:
        grid = costmap.grid
        self.costmap = costmap
        self.res = float(grid.resolution)
        self.height, self.width = grid.height, grid.width
        self.required = costmap.robot_radius + margin
        self.free = np.ascontiguousarray(costmap.distance > self.required)
        self.free_flat = self.free.ravel()
        self.free_bytes = self.free_flat.tobytes()
        self.distance_flat = np.ascontiguousarray(costmap.distance).ravel()
        o = grid.origin
        self.ox, self.oy = o.x, o.y
        self.cos, self.sin = math.cos(o.yaw), math.sin(o.yaw)

    @property
    def size(self) -> tuple[float, float]:
        """(width, height) of the grid in metres."""
        return self.width * self.res, self.height * self.res

    @property
    def comfort(self) -> float:
        """Obstacle distance beyond which every cell costs nothing (the edge of the
        inflation zone): more clearance than this is not worth a longer path."""
        return self.costmap.robot_radius + self.costmap.config.inflation_radius

    def cell_index(self, p: tuple[float, float]) -> int:
        """Flat index of the cell holding the local point ``p`` (on the grid)."""
        return int(p[1] / self.res) * self.width + int(p[0] / self.res)

    def to_local(self, x: float, y: float) -> tuple[float, float]:
        dx, dy = x - self.ox, y - self.oy
        return self.cos * dx + self.sin * dy, -self.sin * dx + self.cos * dy

    def planned_path(
        self, pts: np.ndarray | None, start: Pose2D, goal: Pose2D, t0: float
    ) -> PlannedPath:
        """A grid search's cells as the path from ``start`` to ``goal`` (exact end points,
        timed from ``t0``); ``pts`` None means the search found no way."""
        if pts is None:
            raise PlanningError(
                f"no path from ({start.x:.2f}, {start.y:.2f}) to ({goal.x:.2f}, {goal.y:.2f}): "
                "they are not connected by free space"
            )
        points = self.to_world(pts)
        points[0], points[-1] = start.xy, goal.xy
        return PlannedPath(points=points, planning_time=time.perf_counter() - t0)

    def to_world(self, pts: np.ndarray) -> np.ndarray:
        px, py = pts[:, 0], pts[:, 1]
        x = self.ox + self.cos * px - self.sin * py
        y = self.oy + self.sin * px + self.cos * py
        return np.stack([x, y], axis=1)

    def cell_centres(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """Local-frame centres of cells, shape (N, 2)."""
        return np.stack([(cols + 0.5) * self.res, (rows + 0.5) * self.res], axis=1)

    def point_free(self, px: float, py: float) -> bool:
        """Is the local point in a free cell? Within ``EDGE_EPS`` of a cell edge, both
        cells must be free (so that rounding in frame changes cannot matter)."""
        u, v = px / self.res, py / self.res  # as Costmap.world_to_cell divides
        if u < 0.0 or v < 0.0:
            return False
        col, row = int(u), int(v)
        if col >= self.width or row >= self.height:
            return False
        if not self.free_bytes[row * self.width + col]:
            return False
        fu, fv = u - col, v - row
        if EDGE_EPS < fu < 1.0 - EDGE_EPS and EDGE_EPS < fv < 1.0 - EDGE_EPS:
            return True
        cols = {math.floor(u - EDGE_EPS), math.floor(u + EDGE_EPS)}
        rows = {math.floor(v - EDGE_EPS), math.floor(v + EDGE_EPS)}
        return all(
            0 <= c < self.width and 0 <= r < self.height and self.free_bytes[r * self.width + c]
            for c in cols
            for r in rows
        )

    def segment_cells(self, ax: float, ay: float, bx: float, by: float) -> np.ndarray | None:
        """Flat indices of every cell the segment passes through; None if it leaves the grid.

        Exact traversal: the segment is cut at every grid line it crosses and each piece
        and each crossing point is assigned to its cell; a point within ``EDGE_EPS`` of a
        cell edge counts for the cells on both sides (a segment along a grid line needs
        both rows free).
        """
        u0, v0 = ax / self.res, ay / self.res
        du, dv = bx / self.res - u0, by / self.res - v0
        ts = [np.array([0.0, 1.0])]
        if du != 0.0:
            ks = np.arange(math.ceil(min(u0, u0 + du)), math.floor(max(u0, u0 + du)) + 1)
            ts.append((ks - u0) / du)
        if dv != 0.0:
            ks = np.arange(math.ceil(min(v0, v0 + dv)), math.floor(max(v0, v0 + dv)) + 1)
            ts.append((ks - v0) / dv)
        t = np.unique(np.concatenate(ts))
        t = np.concatenate([t, 0.5 * (t[:-1] + t[1:])])  # crossings and piece midpoints
        u, v = u0 + t * du, v0 + t * dv
        cols = np.concatenate([np.floor(u - EDGE_EPS), np.floor(u + EDGE_EPS)]).astype(np.int64)
        rows = np.concatenate([np.floor(v - EDGE_EPS), np.floor(v + EDGE_EPS)]).astype(np.int64)
        cols, rows = np.concatenate([cols, cols]), np.repeat(rows.reshape(2, -1), 2, axis=0).ravel()
        if (
            cols.min() < 0
            or rows.min() < 0
            or cols.max() >= self.width
            or rows.max() >= self.height
        ):
            return None
        return rows * self.width + cols

    def segment_free(self, ax: float, ay: float, bx: float, by: float) -> bool:
        """True when every cell the segment passes through is free."""
        cells = self.segment_cells(ax, ay, bx, by)
        return cells is not None and bool(self.free_flat[cells].all())

    def check_endpoint(self, pose: Pose2D, what: str) -> tuple[float, float]:
        """Local coordinates of ``pose``; PlanningError if it is outside or not free."""
        px, py = self.to_local(pose.x, pose.y)
        w, h = self.size
        if not (0.0 <= px < w and 0.0 <= py < h):
            raise PlanningError(f"{what} ({pose.x:.2f}, {pose.y:.2f}) is outside the map")
        if not self.point_free(px, py):
            # the least of the cells it stands on (two or four on a cell's edge)
            eps = EDGE_EPS * self.res
            corners = np.array(
                [[pose.x + dx, pose.y + dy] for dx in (-eps, eps) for dy in (-eps, eps)]
            )
            clr = float(self.costmap.clearance(corners).min())
            raise PlanningError(
                f"{what} ({pose.x:.2f}, {pose.y:.2f}) is not free: clearance {clr:.3f} m, "
                f"needs more than {self.required:.3f} m (robot radius + clearance margin)"
            )
        return px, py


class ClearanceConfig(Protocol):
    """A planner config with the margin its paths keep beyond the robot's radius."""

    clearance: float


ConfigT = TypeVar("ConfigT", bound=ClearanceConfig)


class FreeSpacePlanner(Generic[ConfigT]):
    """What the grid-based global planners share: built from their config, they keep its
    ``clearance`` and plan between two free end points of a :class:`FreeSpace`."""

    def __init__(self, config: ConfigT) -> None:
        self.config = config

    @property
    def clearance(self) -> float:
        return self.config.clearance

    def diagnostics(self) -> dict[str, float]:
        return {}

    def free_space(
        self, costmap: Costmap, start: Pose2D, goal: Pose2D
    ) -> tuple[FreeSpace, tuple[float, float], tuple[float, float]]:
        """The free space of ``costmap`` at this planner's clearance and the local
        coordinates of ``start`` and ``goal``; PlanningError when either is not free."""
        space = FreeSpace(costmap, self.config.clearance)
        return space, space.check_endpoint(start, "start"), space.check_endpoint(goal, "goal")
