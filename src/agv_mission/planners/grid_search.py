"""Cost-aware grid searches for :mod:`cost_grid`: step graphs in CSR form, pooled coarse
graphs and the fine search within a band of blocks round a coarse path (or a prior one).

A step costs its length times ``1 + cost_weight * cost / 252`` (:func:`cost_factor`);
Dijkstra from ``scipy.sparse.csgraph`` does the search in C.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import binary_dilation
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import dijkstra

from agv_mission.planners.free_space import MAX_COST, MOVES_8, MOVES_16, FreeSpace, cost_factor

NEAR_CELLS = 6  # see StepGraph.near_cheapest


@dataclass
class StepGraph:
    """A directed step graph over some cells of a grid (both directions of every move)."""

    graph: csr_matrix
    cells: np.ndarray  # flat grid index of each node
    node_of: np.ndarray  # node of each flat grid index, -1 where none

    def cheapest(self, start: int, goal: int) -> np.ndarray | None:
        """Flat indices of the cheapest cell path from ``start`` to ``goal`` (None if none)."""
        s, g = int(self.node_of[start]), int(self.node_of[goal])
        if s < 0 or g < 0:
            return None
        dist, pred = dijkstra(self.graph, indices=s, return_predecessors=True)
        if not np.isfinite(dist[g]):
            return None
        nodes = [g]
        while nodes[-1] != s:
            nodes.append(int(pred[nodes[-1]]))
        return self.cells[np.array(nodes[::-1], dtype=np.int64)]

    def near_cheapest(self, start: int, goal: int, slack: float) -> np.ndarray | None:
        """Flat indices of every cell on some path from ``start`` to ``goal`` that costs at
        most ``1 + slack`` times the cheapest (None if not joined): each way round an
        obstacle whose cost is that close, not only the cheapest one.

        Where many ways tie (parallel aisles, open floor) the slack shrinks until the
        cells number at most ``NEAR_CELLS`` times the cheapest path's, down to that path.
        """
        s, g = int(self.node_of[start]), int(self.node_of[goal])
        if s < 0 or g < 0:
            return None
        dist, pred = dijkstra(self.graph, indices=[s, g], return_predecessors=True)
        best = dist[0, g]
        if not np.isfinite(best):
            return None
        nodes = [g]
        while nodes[-1] != s:
            nodes.append(int(pred[0, nodes[-1]]))
        total = dist[0] + dist[1]
        for share in (slack, slack / 2.0, slack / 4.0):
            near = np.flatnonzero(total <= (1.0 + share) * best + 1e-9)
            if near.size <= NEAR_CELLS * len(nodes):
                return self.cells[near]
        return self.cells[np.array(nodes[::-1], dtype=np.int64)]


def _directed_moves(connectivity: int, stride: int) -> list[tuple[int, float, tuple[int, ...]]]:
    """(flat offset, length in cells, flat offsets of the cells squeezed between) of both
    directions of every move on a grid ``stride`` cells wide, by increasing offset (so a
    node's neighbours come out in increasing order: sorted CSR indices)."""
    out = []
    for dr, dc, step, between in MOVES_16 if connectivity == 16 else MOVES_8:
        out.append((dr * stride + dc, step, tuple(ir * stride + ic for ir, ic in between)))
        back = tuple((ir - dr) * stride + (ic - dc) for ir, ic in between)
        out.append((-dr * stride - dc, step, back))
    return sorted(out)


def step_graph(
    allowed: np.ndarray, passable: np.ndarray, factor: np.ndarray, connectivity: int = 16
) -> StepGraph:
    """The 8- or 16-connected step graph over the ``allowed`` cells of a grid.

    A move needs both ends allowed and the cells it squeezes between ``passable`` (no
    corner cutting); it costs its length in cells times the mean ``factor`` of its ends.
    Built straight into CSR form (one row of up to 16 neighbours per node), with no
    sorting or duplicate summing.
    """
    h, w = allowed.shape
    pad = 2  # the longest move reaches two cells: a padded grid needs no bounds checks
    stride = w + 2 * pad
    moves = _directed_moves(connectivity, stride)
    cells = np.flatnonzero(allowed)
    n = cells.size
    rows, cols = np.divmod(cells, w)
    at = (rows + pad) * stride + (cols + pad)
    node_pad = np.full((h + 2 * pad) * stride, -1, dtype=np.int32)
    node_pad[at] = np.arange(n, dtype=np.int32)
    pass_pad = np.zeros((h + 2 * pad, stride), dtype=bool)
    pass_pad[pad : pad + h, pad : pad + w] = passable
    pass_flat = pass_pad.ravel()
    nb = node_pad[at[:, None] + np.array([m[0] for m in moves])[None, :]]
    ok = nb >= 0
    for j, (_, _, between) in enumerate(moves):
        for offset in between:
            ok[:, j] &= pass_flat[at + offset]
    fac = factor.ravel()[cells]
    half_steps = 0.5 * np.array([m[1] for m in moves])
    wts = half_steps[None, :] * (fac[:, None] + fac[np.where(ok, nb, 0)])
    indptr = np.zeros(n + 1, dtype=np.int32)
    np.cumsum(ok.sum(axis=1), out=indptr[1:])
    graph = csr_matrix((wts[ok], nb[ok], indptr), shape=(n, n))
    node_of = np.full(h * w, -1, dtype=np.int64)
    node_of[cells] = np.arange(n)
    return StepGraph(graph, cells, node_of)


def pool(a: np.ndarray, k: int, fill: float | bool, how: str) -> np.ndarray:
    """Blocks of k x k cells reduced by ``how`` ('any' or 'min'); edges padded with fill."""
    h, w = a.shape
    hc, wc = -(-h // k), -(-w // k)
    padded = np.full((hc * k, wc * k), fill, dtype=a.dtype)
    padded[:h, :w] = a
    op = np.logical_or if how == "any" else np.minimum
    cols = padded[:, 0::k].copy()  # strided slices: far faster than reducing a reshape
    for j in range(1, k):
        op(cols, padded[:, j::k], out=cols)
    out = cols[0::k].copy()
    for i in range(1, k):
        op(out, cols[i::k], out=out)
    return out


def coarse_graph(space: FreeSpace, cost_weight: float, k: int) -> StepGraph:
    """Blocks of k x k cells: passable when any cell is free, costing the cheapest one."""
    free = space.free
    cost = pool(np.where(free, space.costmap.cost, np.uint8(255)), k, 255, "min")
    passable = pool(free, k, False, "any")
    return step_graph(passable, passable, cost_factor(np.minimum(cost, MAX_COST), cost_weight))


def corridor_path(
    space: FreeSpace,
    blocks: np.ndarray,
    k: int,
    band: int,
    factor: np.ndarray,
    start_cell: int,
    goal_cell: int,
) -> np.ndarray | None:
    """The cheapest fine cell path within ``band`` of the k x k ``blocks`` (flat block
    indices); None when that band holds no path."""
    h, w = space.free.shape
    corridor = np.zeros((-(-h // k), -(-w // k)), dtype=bool)
    corridor.ravel()[blocks] = True
    grown = binary_dilation(corridor, np.ones((3, 3), dtype=bool), iterations=band)
    allowed = np.repeat(np.repeat(grown, k, axis=0), k, axis=1)[:h, :w] & space.free
    return step_graph(allowed, space.free, factor).cheapest(start_cell, goal_cell)


def blocks_along(space: FreeSpace, pts: np.ndarray, k: int) -> np.ndarray:
    """Flat indices of the k x k blocks a local-frame polyline passes through (sampled
    every half block), clipped to the grid."""
    h, w = space.free.shape
    wc = -(-w // k)
    local_pts = np.asarray(pts, dtype=float)[:, :2]
    d = np.diff(local_pts, axis=0)
    n = np.maximum(np.ceil(np.linalg.norm(d, axis=1) / (0.5 * k * space.res)), 1).astype(int)
    samples = np.concatenate(
        [
            a + np.outer(np.arange(m) / m, b - a)
            for a, b, m in zip(local_pts, local_pts[1:], n, strict=False)
        ]
        + [local_pts[-1:]]
    )
    cols = np.clip((samples[:, 0] / space.res).astype(int) // k, 0, wc - 1)
    rows = np.clip((samples[:, 1] / space.res).astype(int) // k, 0, -(-h // k) - 1)
    return rows * wc + cols


def block_of(cell: int, w: int, k: int) -> int:
    """Flat index of the k x k block holding flat ``cell`` of a grid ``w`` cells wide."""
    return (cell // w // k) * -(-w // k) + (cell % w) // k
