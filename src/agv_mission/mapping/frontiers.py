"""Frontier detection for exploration.

A *frontier cell* is a ``FREE`` cell with an ``UNKNOWN`` 4-neighbour (cells past the grid's
edge count as unknown). :func:`find_frontiers` groups frontier cells inside ``bounds`` into
8-connected clusters (:func:`scipy.ndimage.label`), drops clusters smaller than
``min_size`` cells (and frontier cells that only border a small enclosed unknown pocket,
such as the inside of a pillar) and gives each one a *goal*: the point of known free space, reachable
from the robot, where the robot's footprint fits with ``clearance`` to spare (the same
test as :meth:`agv_mission.maps.costmap.Costmap.is_free` on a costmap built from the same
grid with unknown cells as obstacles), closest to the frontier and at most ``goal_reach``
from it. The robot's 360 degree scanner sees the frontier from there. Reachability is
8-connectivity through such cells from the robot's cell; ``distance`` is the robot's
shortest 8-connected path to the goal through them (Dijkstra), so the nearest frontier is
nearest by driving, not through a wall (Yamauchi's greedy exploration).

"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy import ndimage
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra

from agv_mission.geometry import Bounds
from agv_mission.maps.grid import FREE, UNKNOWN, OccupancyGrid

_EIGHT = np.ones((3, 3), dtype=bool)


@dataclass
class Frontier:
    """One cluster of frontier cells."""

    cells: np.ndarray  # (K, 2) map-frame centres of its cells
    centroid: tuple[float, float]
    goal: tuple[float, float] | None  # reachable free point to look at it from
    distance: float  # robot -> goal along free space (m); inf without a robot or goal

    @property
    def size(self) -> int:
        """Number of cells."""
        return int(len(self.cells))


def frontier_mask(grid: OccupancyGrid, min_unknown: int = 0, open_share: float = 0.8) -> np.ndarray:
    """Boolean (H, W): ``FREE`` cells with an ``UNKNOWN`` 4-neighbour (or on the edge).

    Unknown pockets of fewer than ``min_unknown`` cells (4-connected, not touching the
    grid's edge) do not count: the inside of a pillar or a piece of furniture ringed by
    scan hits stays unknown however long the robot looks at it. Unless at least
    ``open_share`` of the cells around the pocket (8-neighbours) are ``FREE``: that is no
    object's inside but a shadow that a look from elsewhere fills (a strip behind a
    pillar), and left unknown it would block a costmap that treats unknown as an
    obstacle.
    """
    unknown = grid.data == UNKNOWN
    if min_unknown > 0:
        labels, count = ndimage.label(unknown)
        sizes = np.bincount(labels.ravel(), minlength=count + 1)
        border = np.unique(np.concatenate([labels[0], labels[-1], labels[:, 0], labels[:, -1]]))
        big = sizes >= min_unknown
        small = np.flatnonzero(~big)
        small = small[small > 0]
        if len(small) and open_share <= 1.0:
            # FREE share of each small pocket's ring (cells next to it, not in it)
            grown = ndimage.grey_dilation(np.where(np.isin(labels, small), labels, 0), size=3)
            ring = (grown > 0) & (labels == 0)
            total = np.bincount(grown[ring], minlength=count + 1)
            free = np.bincount(grown[ring & (grid.data == FREE)], minlength=count + 1)
            big |= free >= open_share * np.maximum(total, 1)
        big[border] = True
        big[0] = False
        unknown = big[labels]
    unknown = np.pad(unknown, 1, constant_values=True)
    near_unknown = unknown[:-2, 1:-1] | unknown[2:, 1:-1] | unknown[1:-1, :-2] | unknown[1:-1, 2:]
    return (grid.data == FREE) & near_unknown


def bounds_mask(grid: OccupancyGrid, bounds: Bounds | Sequence[float] | None) -> np.ndarray:
    """Boolean (H, W): cells whose centre lies inside ``bounds`` (all without bounds)."""
    if bounds is None:
        return np.ones(grid.data.shape, dtype=bool)
    xmin, xmax, ymin, ymax = (float(b) for b in bounds)
    rows, cols = np.indices(grid.data.shape)
    xy = grid.cell_to_world(rows, cols)
    return (xy[..., 0] >= xmin) & (xy[..., 0] <= xmax) & (xy[..., 1] >= ymin) & (xy[..., 1] <= ymax)


def find_frontiers(
    grid: OccupancyGrid,
    bounds: Bounds | Sequence[float] | None = None,
    robot: tuple[float, float] | Sequence[float] | None = None,
    robot_radius: float = 0.105,
    clearance: float = 0.05,
    min_size: int = 5,
    min_unknown: int = 100,
    open_share: float = 0.8,
    goal_reach: float = 1.0,
    goal_margin: float = 0.0,
    reachable_only: bool = True,
    blacklist: Sequence[tuple[float, float]] = (),
    blacklist_radius: float = 0.3,
) -> list[Frontier]:
    """Frontier clusters of ``grid`` inside ``bounds``, nearest (by driving) first.

    ``min_size``: fewest cells of a cluster; ``min_unknown``, ``open_share``: see
    :func:`frontier_mask`;
    ``robot_radius`` + ``clearance``: the clearance a goal needs; ``goal_reach`` (m): how
    far from its frontier a goal may be; ``goal_margin`` (m): more clearance a goal gets
    when its frontier has such a point within ``goal_reach`` (a goal on the very edge of
    the traversable space turns untraversable as soon as the map gains a cell of wall
    next to it, and the navigator then gives up on it).

    ``robot`` (map-frame x, y) enables reachability and distances; without it every
    frontier with a traversable cell within ``goal_reach`` gets that cell as its goal and
    ``distance`` is ``inf``. With ``reachable_only`` (default) frontiers without a goal are
    left out. Frontiers whose goal lies within ``blacklist_radius`` of a ``blacklist``
    point (goals that failed before) are left out too.
    """
    res = grid.resolution
    mask = frontier_mask(grid, min_unknown, open_share) & bounds_mask(grid, bounds)
    labels, count = ndimage.label(mask, structure=_EIGHT)
    if count == 0:
        return []
    sizes = np.bincount(labels.ravel(), minlength=count + 1)
    keep = sizes >= max(int(min_size), 1)
    keep[0] = False
    labels = np.where(keep[labels], labels, 0)
    if not labels.any():
        return []

    # Cells where the footprint fits (unknown counts as an obstacle, as in the costmap).
    distance = ndimage.distance_transform_edt(grid.data == FREE) * res
    traversable = distance > robot_radius + clearance
    reach = traversable
    robot_cell = None
    if robot is not None:
        robot_cell, reach = _reach(grid, traversable, robot, robot_radius + clearance)

    # For every reachable cell: the nearest frontier cell (any cluster) and how far it is.
    d_front, (fr, fc) = ndimage.distance_transform_edt(labels == 0, return_indices=True)
    d_front = d_front * res
    cand = reach & (d_front <= goal_reach)
    cr, cc = np.nonzero(cand)
    goal_of: dict[int, tuple[int, int]] = {}
    if len(cr):
        lab = labels[fr[cr, cc], fc[cr, cc]]
        tight = distance[cr, cc] <= robot_radius + clearance + goal_margin
        order = np.lexsort((d_front[cr, cc], tight, lab))  # by label, margin, distance
        lab_sorted = lab[order]
        first = np.ones(len(order), dtype=bool)
        first[1:] = lab_sorted[1:] != lab_sorted[:-1]
        for i in order[first]:
            goal_of[int(lab[i])] = (int(cr[i]), int(cc[i]))

    path_len = None
    if robot_cell is not None and goal_of:
        path_len = _geodesic(reach, robot_cell, res)

    black = np.asarray(blacklist, dtype=float).reshape(-1, 2)
    out: list[Frontier] = []
    index = ndimage.value_indices(labels, ignore_value=0)
    for lab, (rows, cols) in index.items():
        cells = grid.cell_to_world(rows, cols)
        centroid = cells.mean(axis=0)
        goal, dist = None, math.inf
        if lab in goal_of:
            gr, gc = goal_of[lab]
            gxy = grid.cell_to_world(np.array(gr), np.array(gc))
            goal = (float(gxy[0]), float(gxy[1]))
            if path_len is not None:
                dist = float(path_len[gr, gc])
            if len(black) and np.min(np.hypot(*(black - gxy).T)) <= blacklist_radius:
                continue
        if goal is None and reachable_only:
            continue
        out.append(Frontier(cells, (float(centroid[0]), float(centroid[1])), goal, dist))
    out.sort(key=lambda f: (f.distance, -f.size))
    return out


def path_lengths(
    grid: OccupancyGrid,
    robot: tuple[float, float] | Sequence[float],
    robot_radius: float = 0.105,
    clearance: float = 0.05,
) -> np.ndarray:
    """(H, W): the robot's shortest 8-connected path (m) to each cell of ``grid`` where its
    footprint fits with ``clearance`` (the traversable cells of :func:`find_frontiers`),
    ``inf`` where it cannot go."""
    res = grid.resolution
    traversable = ndimage.distance_transform_edt(grid.data == FREE) * res > robot_radius + clearance
    start, reach = _reach(grid, traversable, robot, robot_radius + clearance)
    if start is None:
        return np.full(grid.data.shape, np.inf)
    return _geodesic(reach, start, res)


def _reach(
    grid: OccupancyGrid, traversable: np.ndarray, robot: Sequence[float], needed: float
) -> tuple[tuple[int, int] | None, np.ndarray]:
    """The robot's cell (:func:`_snap`, within ``needed`` clearance and two cells) and the
    traversable cells connected to it (none when it has no cell)."""
    cell = _snap(grid, traversable, robot, max_snap=needed + 2 * grid.resolution)
    if cell is None:
        return None, np.zeros_like(traversable)
    comp, _ = ndimage.label(traversable, structure=_EIGHT)
    return cell, comp == comp[cell]


def _snap(
    grid: OccupancyGrid, traversable: np.ndarray, xy: Sequence[float], max_snap: float
) -> tuple[int, int] | None:
    """The robot's cell, or the nearest traversable cell within ``max_snap`` metres (the
    robot may stand closer to a wall than the clearance asks)."""
    rows, cols = grid.world_to_cell(np.asarray(xy, dtype=float)[:2])
    r, c = int(rows), int(cols)
    if not grid.in_bounds(np.array(r), np.array(c)):
        return None
    if traversable[r, c]:
        return r, c
    k = int(math.ceil(max_snap / grid.resolution))
    r0, r1 = max(r - k, 0), min(r + k + 1, grid.height)
    c0, c1 = max(c - k, 0), min(c + k + 1, grid.width)
    win = traversable[r0:r1, c0:c1]
    if not win.any():
        return None
    wr, wc = np.nonzero(win)
    d = np.hypot(wr + r0 - r, wc + c0 - c)
    i = int(np.argmin(d))
    if d[i] * grid.resolution > max_snap:
        return None
    return int(wr[i] + r0), int(wc[i] + c0)


def _geodesic(region: np.ndarray, start: tuple[int, int], res: float) -> np.ndarray:
    """Shortest 8-connected path lengths (m) from ``start`` through ``region`` cells."""
    h, w = region.shape
    ids = np.full(region.shape, -1, dtype=np.int64)
    rr, cc = np.nonzero(region)
    ids[rr, cc] = np.arange(len(rr))
    src, dst, wts = [], [], []
    for dr, dc in ((0, 1), (1, 0), (1, 1), (1, -1)):
        c0, c1 = max(0, -dc), w - max(0, dc)
        a = ids[0 : h - dr, c0:c1]
        b = ids[dr:h, c0 + dc : c1 + dc]
        ok = (a >= 0) & (b >= 0)
        src.append(a[ok])
        dst.append(b[ok])
        wts.append(np.full(int(ok.sum()), res * math.hypot(dr, dc)))
    n = len(rr)
    graph = coo_matrix(
        (np.concatenate(wts), (np.concatenate(src), np.concatenate(dst))), shape=(n, n)
    ).tocsr()
    dist = dijkstra(graph, directed=False, indices=int(ids[start]))
    out = np.full(region.shape, np.inf)
    out[rr, cc] = dist
    return out
