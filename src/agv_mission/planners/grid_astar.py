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

import time

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra

from agv_mission.geometry import Pose2D
from agv_mission.maps.costmap import Costmap
from agv_mission.planners.base import PlannedPath
from agv_mission.planners.configs import GridAstarConfig
from agv_mission.planners.free_space import (
    MOVES_8,
    MOVES_16,
    FreeSpace,
    FreeSpacePlanner,
    cost_factor,
)


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
    factor = cost_factor(space.costmap.cost, cost_weight) if cost_weight > 0.0 else None
    src, dst, wts = [], [], []
    for dr, dc, step, between in MOVES_16 if connectivity == 16 else MOVES_8:
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
    path_dist = np.minimum(space.distance_flat[cell], space.comfort)
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
    s_cell, g_cell = space.cell_index(start), space.cell_index(goal)
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


class GridAstarPlanner(FreeSpacePlanner[GridAstarConfig]):
    """Shortest grid path over the costmap, smoothed by line of sight."""

    Config = GridAstarConfig

    def plan(self, costmap: Costmap, start: Pose2D, goal: Pose2D, seed: int = 0) -> PlannedPath:
        """Plan from ``start`` to ``goal`` (``seed`` is unused: the search is deterministic)."""
        t0 = time.perf_counter()
        cfg = self.config
        space, s, g = self.free_space(costmap, start, goal)
        pts = grid_path(space, s, g, cfg.cost_weight, cfg.smooth, cfg.connectivity)
        return space.planned_path(pts, start, goal, t0)
