"""The ways people take to their goals: the shortest path on a coarse grid of the space a
person fits in (:class:`RouteGrid`, one per map and size)."""

from __future__ import annotations

from array import array
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np
import shapely

from agv_mission.maps.grid import OccupancyGrid
from agv_mission.maps.map_cache import map_table
from agv_mission.world.walkable import clearance

if TYPE_CHECKING:  # scipy.sparse (~0.1 s) only once a mission has people to route
    from scipy.sparse import csr_matrix

ROUTE_CELL = 0.25  # m, the routing grid (a person is 0.5 m wide: doors still pass)


def route_grid(grid: OccupancyGrid, radius: float) -> RouteGrid:
    """The :class:`RouteGrid` of ``grid`` for people of ``radius``, one per map and size,
    shared by the mission's checks and its runs (its ways to goals are kept)."""
    return map_table("route_grid", grid, float(radius), lambda: RouteGrid(grid, radius))


class RouteGrid:
    """Ways on a coarse grid of the space a person of ``radius`` fits in; one tree per goal
    cell, computed when first asked for and kept (:func:`route_grid`: one per map).

    A coarse cell is walkable when the person fits anywhere in it, and stands for the map
    cell in it with the most room (its ``point``); two neighbouring cells are joined when
    the person fits all along the straight line between their points. Cell centres alone
    lost every gap narrower than about 0.85 m that the 0.25 m grid happened to straddle:
    real 0.8 m doors, and routes through them refused as walled off."""

    def __init__(self, grid: OccupancyGrid, radius: float):
        k = max(1, round(ROUTE_CELL / grid.resolution))  # map cells a side
        self.cell = k * grid.resolution
        x0, _, y0, _ = grid.extent
        self.origin = np.array([x0, y0])
        self.shape = (max(1, grid.height // k), max(1, grid.width // k))
        height, width = self.shape
        clear = clearance(grid)
        room = np.full((height * k, width * k), -np.inf, dtype=np.float32)
        rows, cols = min(grid.height, height * k), min(grid.width, width * k)
        room[:rows, :cols] = clear[:rows, :cols]
        blocks = room.reshape(height, k, width, k).transpose(0, 2, 1, 3).reshape(height, width, -1)
        best = blocks.argmax(axis=2)
        most = np.take_along_axis(blocks, best[..., None], axis=2)[..., 0]
        self.walkable = most >= radius + grid.resolution
        self._room = most.ravel()  # each cell's point's distance to a wall
        r = np.arange(height)[:, None] * k + best // k
        c = np.arange(width)[None, :] * k + best % k
        self.points = grid.cell_to_world(r.ravel(), c.ravel())  # each cell's roomiest point
        self.graph = self._graph(grid, clear, radius)
        self._trees: dict[int, array[int]] = {}  # goal: predecessors
        self._labels: np.ndarray | None = None

    @property
    def cell_area(self) -> float:
        return self.cell * self.cell

    def component(self, node: int) -> int:
        """The connected piece of walkable space ``node`` lies in (-1: none)."""
        if self._labels is None:
            from scipy.sparse.csgraph import connected_components

            _, labels = connected_components(self.graph, directed=False)
            self._labels = np.where(self.walkable.ravel(), labels, -1)
        return int(self._labels[node])

    def cells_within(self, area: Sequence[tuple[float, float]]) -> np.ndarray:
        """The walkable cells whose points lie inside the polygon ``area`` (flat)."""
        cells = np.flatnonzero(self.walkable.ravel())
        points = self.points[cells]
        return cells[shapely.contains_xy(shapely.Polygon(area), points[:, 0], points[:, 1])]

    def node(self, xy: Sequence[float]) -> int | None:
        """The walkable routing cell nearest ``xy`` (None when there is none)."""
        col = int(np.floor((xy[0] - self.origin[0]) / self.cell))
        row = int(np.floor((xy[1] - self.origin[1]) / self.cell))
        height, width = self.shape
        if 0 <= row < height and 0 <= col < width and self.walkable[row, col]:
            return row * width + col
        near = np.flatnonzero(self.walkable.ravel())
        if near.size == 0:
            return None
        gap = self.points[near] - np.asarray(xy, dtype=float)
        return int(near[np.argmin(np.hypot(gap[:, 0], gap[:, 1]))])

    def _graph(self, grid: OccupancyGrid, clear: np.ndarray, radius: float) -> csr_matrix:
        """Neighbours (8-connected) joined where the person fits all along the line
        between their points (sampled every half map cell)."""
        height, width = self.shape
        index = np.arange(height * width).reshape(height, width)
        ok = self.walkable
        a_all, b_all = [], []
        for dr, dc in ((0, 1), (1, 0), (1, 1), (1, -1)):
            a = (slice(0, height - dr), slice(max(0, -dc), width - max(0, dc)))
            b = (slice(dr, height), slice(max(0, dc), width - max(0, -dc) or None))
            both = ok[a] & ok[b]
            a_all.append(index[a][both])
            b_all.append(index[b][both])
        a, b = np.concatenate(a_all), np.concatenate(b_all)
        length = np.hypot(*(self.points[b] - self.points[a]).T)
        # the room shrinks at most as fast as one walks: a line no longer than twice the
        # room its ends have, less the person, is clear; the others are looked along
        doubt = np.flatnonzero(np.minimum(self._room[a], self._room[b]) - length / 2 < radius)
        pa, pb = self.points[a[doubt]], self.points[b[doubt]]
        samples = max(2, int(np.ceil(3 * self.cell * 2 / grid.resolution)))
        t = np.linspace(0.0, 1.0, samples)[None, :, None]
        along = pa[:, None, :] + (pb - pa)[:, None, :] * t  # (edges, samples, 2)
        rows, cols = grid.world_to_cell(along.reshape(-1, 2))
        inside = grid.in_bounds(rows, cols)
        room = np.full(len(rows), -np.inf)
        room[inside] = clear[rows[inside], cols[inside]]
        keep = np.ones(len(a), dtype=bool)
        keep[doubt] = (room.reshape(len(doubt), samples) >= radius).all(axis=1)
        a, b, length = a[keep], b[keep], length[keep]
        n = height * width
        from scipy.sparse import csr_matrix

        # every edge both ways: a directed search needs no transposed copy per goal
        return csr_matrix(
            (np.concatenate([length, length]), (np.concatenate([a, b]), np.concatenate([b, a]))),
            shape=(n, n),
        )

    def path(self, start: int, goal: int) -> np.ndarray | None:
        """The cells' points from ``start`` to ``goal`` (None when not connected)."""
        tree = self._trees.get(goal)
        if tree is None:
            # fewest cells (8-connected, a breadth-first tree on the two-way graph: 0.17
            # against 11 ms for Dijkstra's a goal on the warehouse); pulling the way taut
            # straightens it
            from scipy.sparse.csgraph import breadth_first_order

            _, order = breadth_first_order(
                self.graph, goal, directed=True, return_predecessors=True
            )
            # walked a node at a time: an array of Python ints (a list's items cost every
            # garbage collection a visit)
            tree = self._trees[goal] = array("i", order.astype(np.int32).tobytes())
        if start != goal and tree[start] < 0:
            return None
        nodes = [start]
        node = start
        while node != goal:
            node = tree[node]
            nodes.append(node)
        return self.points[nodes]
