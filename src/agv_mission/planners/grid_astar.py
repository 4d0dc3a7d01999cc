"""Global planning on the costmap grid: shortest grid path + line-of-sight smoothing.

The search graph is the set of cells whose clearance exceeds ``robot_radius +
clearance``; neighbours are the 8 surrounding cells (plus the 8 knight moves with
``connectivity: 16``, the default), and a diagonal or knight move needs the cells it
squeezes between to be free as well (no corner cutting). A step costs its
length times ``1 + cost_weight * cost / 252`` (mean inflation cost of the two cells),
so with ``cost_weight > 0`` paths keep to the middle of corridors and doors.

The search itself runs in C: Dijkstra from ``scipy.sparse.csgraph`` over the free
cells (the same optimum an A* with an admissible heuristic finds; a heuristic would
save expansions but not in Python). Smoothing replaces runs of cells by straight
segments ("string pulling") when every cell the segment crosses is free *and* no
nearer to an obstacle than the path it replaces, so it keeps the clearance the
search chose. This planner is the reference for path quality.
"""

from __future__ import annotations

import math
import time

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra

from agv_mission.geometry import Pose2D
from agv_mission.maps.costmap import Costmap
from agv_mission.planners.base import PlannedPath, PlanningError
from agv_mission.planners.configs import GridAstarConfig

SQRT2, SQRT5 = math.sqrt(2.0), math.sqrt(5.0)
EDGE_EPS = 1e-6  # cells: points this close to a cell edge count for both cells
# Undirected moves (drow, dcol, length in cells, cells the move squeezes between),
# 8-connected first, then the knight moves that 16-connectivity adds.
_MOVES_8 = (
    (0, 1, 1.0, ()),
    (1, 0, 1.0, ()),
    (1, 1, SQRT2, ((1, 0), (0, 1))),
    (1, -1, SQRT2, ((1, 0), (0, -1))),
)
_MOVES_16 = _MOVES_8 + (
    (1, 2, SQRT5, ((0, 1), (1, 1))),
    (2, 1, SQRT5, ((1, 0), (1, 1))),
    (1, -2, SQRT5, ((0, -1), (1, -1))),
    (2, -1, SQRT5, ((1, 0), (1, -1))),
)


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
            clr = float(self.costmap.clearance(np.array([pose.x, pose.y])))
            raise PlanningError(
                f"{what} ({pose.x:.2f}, {pose.y:.2f}) is not free: clearance {clr:.3f} m, "
                f"needs more than {self.required:.3f} m (robot radius + clearance margin)"
            )
        return px, py


def shortest_cell_path(
    space: FreeSpace,
    start_cell: int,
    goal_cell: int,
    cost_weight: float = 0.0,
    connectivity: int = 16,
) -> np.ndarray | None:
    """Flat cell indices of the cheapest 8- or 16-connected path (None if unreachable)."""
    h, w = space.height, space.width
    free = space.free
    node_of = np.full(h * w, -1, dtype=np.int64)
    cells = np.flatnonzero(space.free_flat)
    node_of[cells] = np.arange(cells.size)
    if cost_weight > 0.0:
        factor = 1.0 + cost_weight * space.costmap.cost.astype(np.float64) / 252.0
    else:
        factor = None
    src, dst, wts = [], [], []
    for dr, dc, step, between in _MOVES_16 if connectivity == 16 else _MOVES_8:
        r1 = h - dr
        c0, c1 = max(0, -dc), w - max(0, dc)
        ok = free[:r1, c0:c1] & free[dr : r1 + dr, c0 + dc : c1 + dc]
        for ir, ic in between:  # no corner cutting: the cells the move passes through
            ok &= free[ir : r1 + ir, c0 + ic : c1 + ic]
        rr, cc = np.nonzero(ok)
        cc += c0
        ia = rr * w + cc
        ib = (rr + dr) * w + (cc + dc)
        if factor is None:
            wt = np.full(ia.size, step)
        else:
            fa, fb = factor.ravel()[ia], factor.ravel()[ib]
            wt = step * 0.5 * (fa + fb)
        src.append(node_of[ia])
        dst.append(node_of[ib])
        wts.append(wt)
    n = cells.size
    graph = coo_matrix(
        (np.concatenate(wts), (np.concatenate(src), np.concatenate(dst))), shape=(n, n)
    ).tocsr()
    s_node, g_node = int(node_of[start_cell]), int(node_of[goal_cell])
    dist, pred = dijkstra(graph, directed=False, indices=s_node, return_predecessors=True)
    if not np.isfinite(dist[g_node]):
        return None
    nodes = [g_node]
    while nodes[-1] != s_node:
        nodes.append(int(pred[nodes[-1]]))
    return cells[np.array(nodes[::-1], dtype=np.int64)]


def string_pull(space: FreeSpace, pts: np.ndarray, keep_clearance: bool = True) -> np.ndarray:
    """Greedy line-of-sight shortcut of a polyline through free cells.

    A vertex is skipped when the straight segment that replaces it crosses only free
    cells and (``keep_clearance``) none nearer to an obstacle than the part of the path
    it replaces came, or than the edge of the inflation zone (beyond it every cell
    costs nothing, so there is no clearance to keep).
    """
    n = len(pts)
    if n <= 2:
        return pts
    w = space.width
    cell = np.floor(pts[:, 1] / space.res).astype(np.int64) * w + np.floor(
        pts[:, 0] / space.res
    ).astype(np.int64)
    comfort = space.costmap.robot_radius + space.costmap.config.inflation_radius
    path_dist = np.minimum(space.distance_flat[cell], comfort)
    out = [0]
    i = 0
    while i < n - 1:
        j = i + 1
        floor_d = min(path_dist[i], path_dist[j])
        while j + 1 < n:
            floor_next = min(floor_d, path_dist[j + 1])
            seg = space.segment_cells(pts[i, 0], pts[i, 1], pts[j + 1, 0], pts[j + 1, 1])
            if seg is None or not space.free_flat[seg].all():
                break
            if keep_clearance and space.distance_flat[seg].min() < floor_next:
                break
            j += 1
            floor_d = floor_next
        out.append(j)
        i = j
    return pts[out]


def _drop_collinear(pts: np.ndarray) -> np.ndarray:
    if len(pts) <= 2:
        return pts
    d = np.diff(pts, axis=0)
    cross = d[:-1, 0] * d[1:, 1] - d[:-1, 1] * d[1:, 0]
    keep = np.concatenate([[True], np.abs(cross) > 1e-12, [True]])
    return pts[keep]


def grid_path(
    space: FreeSpace,
    start: tuple[float, float],
    goal: tuple[float, float],
    cost_weight: float = 0.0,
    smooth: bool = True,
    connectivity: int = 16,
) -> np.ndarray | None:
    """Local-frame polyline from ``start`` to ``goal`` (both free), or None if unreachable."""
    w = space.width
    s_cell = int(start[1] / space.res) * w + int(start[0] / space.res)
    g_cell = int(goal[1] / space.res) * w + int(goal[0] / space.res)
    if s_cell == g_cell or space.segment_free(*start, *goal):
        return np.array([start, goal], dtype=float)
    cells = shortest_cell_path(space, s_cell, g_cell, cost_weight, connectivity)
    if cells is None:
        return None
    centres = space.cell_centres(cells // w, cells % w)
    # Start and goal lie anywhere in their cells: go through the cell centre when the
    # straight line to the next centre would clip a cell the move did not check.
    head = [start] if space.segment_free(*start, *centres[1]) else [start, centres[0]]
    tail = [goal] if space.segment_free(*centres[-2], *goal) else [centres[-1], goal]
    pts = np.array([*head, *centres[1:-1], *tail], dtype=float)
    return string_pull(space, pts, cost_weight > 0.0) if smooth else _drop_collinear(pts)


class GridAstarPlanner:
    """Shortest grid path over the costmap, smoothed by line of sight."""

    Config = GridAstarConfig

    def __init__(self, config: GridAstarConfig) -> None:
        self.config = config

    @property
    def clearance(self) -> float:
        return self.config.clearance

    def diagnostics(self) -> dict[str, float]:
        return {}

    def plan(self, costmap: Costmap, start: Pose2D, goal: Pose2D, seed: int = 0) -> PlannedPath:
        """Plan from ``start`` to ``goal`` (``seed`` is unused: the search is deterministic)."""
        t0 = time.perf_counter()
        cfg = self.config
        space = FreeSpace(costmap, cfg.clearance)
        s = space.check_endpoint(start, "start")
        g = space.check_endpoint(goal, "goal")
        pts = grid_path(space, s, g, cfg.cost_weight, cfg.smooth, cfg.connectivity)
        return space.planned_path(pts, start, goal, t0)
