"""Where a robot can step aside: the nearest free pose out of other robots' way.

A yielding robot searches the free cells of its own costmap (Dijkstra over the 8-connected
cell graph, the same graph the grid planners use) for the nearest one from which its
footprint keeps clear of the paths it must leave free and of every other robot's body.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.ndimage import distance_transform_edt
from scipy.sparse.csgraph import dijkstra

from agv_mission.geometry import Pose2D
from agv_mission.maps.costmap import Costmap
from agv_mission.maps.grid import OccupancyGrid
from agv_mission.planners.grid_search import step_graph

PLAN_CLEARANCE = 0.05  # m beyond the radius a cell needs to be on a plan (cost_grid's default)
WALL_CLEARANCE = 0.1  # m beyond the radius a detour pose keeps from walls


@dataclass(frozen=True)
class Keepout:
    """Space a detour pose must keep clear of: a polyline (or one point) swept by a body of
    ``radius`` metres."""

    points: np.ndarray  # (k, 2), map frame
    radius: float


@dataclass(frozen=True)
class Detour:
    pose: Pose2D
    distance: float  # metres along the cell graph from the robot to the pose


def find_detour(
    costmap: Costmap,
    pose: Pose2D,
    radius: float,
    keep_clear: Sequence[Keepout],
    bodies: Sequence[Keepout],
    margin: float,
    search_radius: float,
) -> Detour | None:
    """The nearest pose (by travel over free cells) from which a robot of ``radius`` at
    ``pose`` keeps ``margin`` from every ``keep_clear`` path and every other robot's body
    in ``bodies`` (bodies also block the way there). None when none lies within
    ``search_radius`` metres."""
    grid = costmap.grid
    res = grid.resolution
    reach = max((k.radius for k in (*keep_clear, *bodies)), default=0.0) + radius + margin
    pad = int(math.ceil((search_radius + reach) / res))
    r0, c0 = (int(v) for v in grid.world_to_cell(np.array([pose.x, pose.y])))
    rows = slice(max(r0 - pad, 0), min(r0 + pad + 1, grid.height))
    cols = slice(max(c0 - pad, 0), min(c0 + pad + 1, grid.width))
    if rows.start >= rows.stop or cols.start >= cols.stop:
        return None
    clearance = costmap.distance[rows, cols]
    shape = clearance.shape
    passable = clearance > radius + PLAN_CLEARANCE
    target = clearance > radius + WALL_CLEARANCE
    for body in bodies:
        away = _distance_to(body.points, grid, rows, cols)
        passable &= away >= body.radius + radius
        target &= away >= body.radius + radius + margin
    for way in keep_clear:
        target &= _distance_to(way.points, grid, rows, cols) >= way.radius + radius + margin
    start = (r0 - rows.start, c0 - cols.start)
    if not (0 <= start[0] < shape[0] and 0 <= start[1] < shape[1]):
        return None
    passable[start] = True
    graph = step_graph(passable, passable, np.ones(shape), connectivity=8)
    node = int(graph.node_of[start[0] * shape[1] + start[1]])
    dist = dijkstra(graph.graph, indices=node, limit=search_radius / res)
    cells = graph.cells
    ok = np.isfinite(dist) & target.ravel()[cells]
    if not ok.any():
        return None
    best = int(np.flatnonzero(ok)[np.argmin(dist[ok])])  # argmin keeps the first of equals
    rr, cc = divmod(int(cells[best]), shape[1])
    x, y = grid.cell_to_world(np.array(rr + rows.start), np.array(cc + cols.start))
    yaw = (
        math.atan2(y - pose.y, x - pose.x) if math.hypot(x - pose.x, y - pose.y) > res else pose.yaw
    )
    return Detour(Pose2D(float(x), float(y), yaw), float(dist[best]) * res)


def _distance_to(points: np.ndarray, grid: OccupancyGrid, rows: slice, cols: slice) -> np.ndarray:
    """Metres from every cell of a window of ``grid`` to a polyline: a distance transform
    of the cells the polyline passes through (exact to half a cell). Parts outside the
    window are left out: the window reaches farther than any margin tested against it."""
    pts = np.asarray(points, dtype=float).reshape(-1, 2)
    res = grid.resolution
    if len(pts) > 1:
        seg = np.diff(pts, axis=0)
        n = np.maximum(np.ceil(np.hypot(seg[:, 0], seg[:, 1]) / (0.5 * res)), 1).astype(int)
        t = [np.arange(k) / k for k in n]
        pts = np.concatenate(
            [p + s * f[:, None] for p, s, f in zip(pts[:-1], seg, t, strict=True)] + [pts[-1:]]
        )
    r, c = grid.world_to_cell(pts)
    r, c = r - rows.start, c - cols.start
    shape = (rows.stop - rows.start, cols.stop - cols.start)
    inside = (r >= 0) & (r < shape[0]) & (c >= 0) & (c < shape[1])
    if not inside.any():
        return np.full(shape, np.inf)
    free = np.ones(shape, dtype=bool)
    free[r[inside], c[inside]] = False
    return distance_transform_edt(free) * res
