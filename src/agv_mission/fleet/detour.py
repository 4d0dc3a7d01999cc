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
from scipy import ndimage
from scipy.ndimage import distance_transform_edt
from scipy.sparse.csgraph import dijkstra

from agv_mission.geometry import Pose2D
from agv_mission.maps.costmap import Costmap
from agv_mission.maps.grid import OccupancyGrid
from agv_mission.planners.grid_search import step_graph

PLAN_CLEARANCE = 0.05  # m beyond the radius a cell needs to be on a plan (cost_grid's default)
WALL_CLEARANCE = 0.1  # m beyond the radius a detour pose keeps from walls
NEAR = 5.0  # m searched first
ROOMY = 0.3  # m beyond the radius from walls a detour pose is best kept
PENALTY = 5.0  # m of travel that one m of clearance short of ROOMY is worth


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
    ``search_radius`` metres. The search looks within :data:`NEAR` metres first (most
    ways out are a few metres long), then as far as allowed."""
    for reach in dict.fromkeys((min(NEAR, search_radius), search_radius)):
        found = _search(costmap, pose, radius, keep_clear, bodies, margin, reach)
        if found is not None:
            return found
    return None


def _search(
    costmap: Costmap,
    pose: Pose2D,
    radius: float,
    keep_clear: Sequence[Keepout],
    bodies: Sequence[Keepout],
    margin: float,
    search_radius: float,
) -> Detour | None:
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
    for body_radius, away in _grouped(bodies, grid, rows, cols):
        passable &= away >= body_radius + radius
        target &= away >= body_radius + radius + margin
    for way_radius, away in _grouped(keep_clear, grid, rows, cols):
        target &= away >= way_radius + radius + margin
    start = (r0 - rows.start, c0 - cols.start)
    if not (0 <= start[0] < shape[0] and 0 <= start[1] < shape[1]):
        return None
    # only what the search can reach: the free component round the start
    labels, _ = ndimage.label(passable | _at(shape, start))
    here = labels == labels[start]
    here &= _disc(shape, start, search_radius / res)
    graph = step_graph(here, here, np.ones(shape), connectivity=8)
    node = int(graph.node_of[start[0] * shape[1] + start[1]])
    dist = dijkstra(graph.graph, indices=node, limit=search_radius / res)
    cells = graph.cells
    ok = np.isfinite(dist) & target.ravel()[cells]
    if not ok.any():
        return None
    # nearest, but a pose hugging a wall or a corner costs more: the robot must turn and
    # drive off from there (each cm of clearance short of ROOMY counts as PENALTY cm)
    room = clearance.ravel()[cells[ok]] - radius
    score = dist[ok] * res + PENALTY * np.maximum(ROOMY - room, 0.0)
    best = int(np.flatnonzero(ok)[np.argmin(score)])  # argmin keeps the first of equals
    rr, cc = divmod(int(cells[best]), shape[1])
    x, y = grid.cell_to_world(np.array(rr + rows.start), np.array(cc + cols.start))
    yaw = (
        math.atan2(y - pose.y, x - pose.x) if math.hypot(x - pose.x, y - pose.y) > res else pose.yaw
    )
    return Detour(Pose2D(float(x), float(y), yaw), float(dist[best]) * res)


def _at(shape: tuple[int, int], cell: tuple[int, int]) -> np.ndarray:
    out = np.zeros(shape, dtype=bool)
    out[cell] = True
    return out


def _disc(shape: tuple[int, int], centre: tuple[int, int], cells: float) -> np.ndarray:
    rr, cc = np.ogrid[: shape[0], : shape[1]]
    return (rr - centre[0]) ** 2 + (cc - centre[1]) ** 2 <= cells * cells


def _grouped(
    keepouts: Sequence[Keepout], grid: OccupancyGrid, rows: slice, cols: slice
) -> list[tuple[float, np.ndarray]]:
    """One distance field per radius: robots of a kind share one transform."""
    by_radius: dict[float, list[np.ndarray]] = {}
    for k in keepouts:
        by_radius.setdefault(round(k.radius, 6), []).append(np.asarray(k.points, dtype=float))
    return [(r, _distance_to(lines, grid, rows, cols)) for r, lines in sorted(by_radius.items())]


def _distance_to(
    lines: Sequence[np.ndarray], grid: OccupancyGrid, rows: slice, cols: slice
) -> np.ndarray:
    """Metres from every cell of a window of ``grid`` to the nearest of some polylines: a
    distance transform of the cells they pass through (exact to half a cell). Parts
    outside the window are left out: the window reaches farther than any margin tested
    against it."""
    res = grid.resolution
    pts = np.concatenate([_densified(line.reshape(-1, 2), 0.5 * res) for line in lines])
    r, c = grid.world_to_cell(pts)
    r, c = r - rows.start, c - cols.start
    shape = (rows.stop - rows.start, cols.stop - cols.start)
    inside = (r >= 0) & (r < shape[0]) & (c >= 0) & (c < shape[1])
    if not inside.any():
        return np.full(shape, np.inf)
    free = np.ones(shape, dtype=bool)
    free[r[inside], c[inside]] = False
    return distance_transform_edt(free) * res


def _densified(pts: np.ndarray, step: float) -> np.ndarray:
    """A polyline's points at most ``step`` apart."""
    if len(pts) < 2:
        return pts
    seg = np.diff(pts, axis=0)
    n = np.maximum(np.ceil(np.hypot(seg[:, 0], seg[:, 1]) / step), 1).astype(int)
    t = np.concatenate([np.arange(k) / k for k in n])
    base = np.repeat(pts[:-1], n, axis=0)
    return np.concatenate([base + np.repeat(seg, n, axis=0) * t[:, None], pts[-1:]])
