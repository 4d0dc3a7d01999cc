"""The default global planner: a cost-aware grid search, any-angle smoothing and fillets.

What Nav2's NavFn / Smac 2D do, made fast in numpy + scipy:

1. **Coarse search.** The costmap is pooled into blocks of about ``coarse_resolution``
   (a block is passable when any of its cells is free for the robot; its cost is the
   lowest of those cells') and searched with Dijkstra (``scipy.sparse.csgraph``, in C).
   A step costs its length times ``1 + cost_weight * cost / 252``, so the search prefers
   the middle of corridors and doors over their edges.
2. **Fine search in a band.** The same cost-aware search on the full-resolution cells
   within ``band`` blocks of the coarse path (16-connected, no corner cutting). Should
   the band hold no path (a block that looked passable was not), the whole grid is
   searched.
3. **Any-angle smoothing.** The cell path becomes a polyline whose vertices are the
   cells where it turns; a vertex is dropped when the straight segment that replaces it
   is free and comes no nearer to an obstacle than the path it replaces did (nor nearer
   than the edge of the inflation zone, beyond which every cell costs nothing).
4. **Fillets.** Each remaining corner is rounded by a circular arc of radius up to
   ``max_turn_radius`` that keeps the same clearance, so the curvature the robot must
   follow is bounded and it need not stop at corners.

A search over 30 x 50 m at 0.05 m (600 000 cells) touches 40 000 coarse blocks and the
band's few tens of thousands of cells: tens of milliseconds. Everything is
deterministic: the same costmap, start and goal give the same path.

``plan(..., prior=path)`` searches first within ``band`` blocks of a previous path and
keeps that way round obstacles unless it is blocked or another way is clearly shorter:
replans then keep their homotopy class.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np
from scipy.ndimage import binary_dilation
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import dijkstra

from agv_mission.geometry import Pose2D
from agv_mission.maps.costmap import Costmap
from agv_mission.planners.base import PlannedPath
from agv_mission.planners.configs import CostGridConfig
from agv_mission.planners.grid_astar import _MOVES_8, _MOVES_16, EDGE_EPS, FreeSpace

MAX_COST = 252.0
# How much the coarse graph may misjudge a path's length (blocks of 0.2 m on a leg of a
# few metres): the shortest-path check searches every way round obstacles within it.
COARSE_SLACK = 0.05
# Shortcuts may end at any turn of the cell path and at every few cells between: the
# tangent to an obstacle often touches the middle of a straight run.
SHORTCUT_EVERY = 4
NEAR_CELLS = 6  # see StepGraph.near_cheapest
COARSE_CACHE = 4  # coarse graphs kept (a few MB each)


# --------------------------------------------------------------------------- searches


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
    for dr, dc, step, between in _MOVES_16 if connectivity == 16 else _MOVES_8:
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
    factor = 1.0 + cost_weight * np.minimum(cost, MAX_COST).astype(np.float64) / MAX_COST
    return step_graph(passable, passable, factor)


def corridor_path(
    space: FreeSpace,
    corridor: np.ndarray,
    k: int,
    band: int,
    factor: np.ndarray,
    start_cell: int,
    goal_cell: int,
) -> np.ndarray | None:
    """The cheapest fine cell path within ``band`` blocks of the ``corridor`` blocks."""
    h, w = space.free.shape
    grown = binary_dilation(corridor, np.ones((3, 3), dtype=bool), iterations=band)
    allowed = np.repeat(np.repeat(grown, k, axis=0), k, axis=1)[:h, :w] & space.free
    return step_graph(allowed, space.free, factor).cheapest(start_cell, goal_cell)


# --------------------------------------------------------------------------- smoothing


def _turns(cells: np.ndarray, w: int, every: int = 0) -> np.ndarray:
    """Indices into ``cells`` of the path's ends, of every cell where it turns and (with
    ``every``) of every ``every``-th cell: the vertices shortcuts may end at."""
    rows, cols = np.divmod(cells, w)
    if len(cells) <= 2:
        return np.arange(len(cells))
    d = np.stack([np.diff(rows), np.diff(cols)], axis=1)
    turn = np.any(d[1:] != d[:-1], axis=1)
    idx = [[0], np.flatnonzero(turn) + 1, [len(cells) - 1]]
    if every > 0:
        idx.append(np.arange(0, len(cells), every))
    return np.unique(np.concatenate(idx))


def segments_cells(space: FreeSpace, a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, ...]:
    """The cells of many segments ``a[i] -> b[i]`` at once, the same cells
    :meth:`FreeSpace.segment_cells` finds for one (the cells at the ends and either side
    of every grid-line crossing, both cells within ``EDGE_EPS`` of an edge; it may leave
    out a cell whose corner the segment passes within ``EDGE_EPS``).

    Returns ``(cells, mask, inside)``: flat indices (m, p), which of them are real, and
    which segments stay on the grid.
    """
    res = space.res
    u0, v0 = a[:, 0] / res, a[:, 1] / res
    du, dv = b[:, 0] / res - u0, b[:, 1] / res - v0
    m = len(a)
    parts = [np.zeros((m, 1)), np.ones((m, 1))]
    for c0, d in ((u0, du), (v0, dv)):
        lo = np.ceil(np.minimum(c0, c0 + d))
        count = np.where(d != 0.0, np.floor(np.maximum(c0, c0 + d)) - lo + 1.0, 0.0)
        most = int(count.max(initial=0.0))
        if most > 0:
            k = np.arange(most)
            with np.errstate(divide="ignore", invalid="ignore"):
                t = (lo[:, None] + k[None, :] - c0[:, None]) / d[:, None]
            t[k[None, :] >= count[:, None]] = np.nan
            parts.append(t)
    # The cells either side of every crossing cover every piece between crossings too:
    # no need for the pieces' midpoints (nor to sort the crossings).
    t = np.concatenate(parts, axis=1)
    valid = ~np.isnan(t)
    t = np.where(valid, t, 0.0)
    u, v = u0[:, None] + t * du[:, None], v0[:, None] + t * dv[:, None]
    cols = np.floor(np.concatenate([u - EDGE_EPS, u + EDGE_EPS, u - EDGE_EPS, u + EDGE_EPS], 1))
    rows = np.floor(np.concatenate([v - EDGE_EPS, v - EDGE_EPS, v + EDGE_EPS, v + EDGE_EPS], 1))
    mask = np.tile(valid, 4)
    on_grid = (cols >= 0) & (rows >= 0) & (cols < space.width) & (rows < space.height)
    inside = np.all(on_grid | ~mask, axis=1)
    mask &= on_grid
    cells = np.where(mask, rows * space.width + cols, 0).astype(np.int64)
    return cells, mask, inside


def segments_clearance(space: FreeSpace, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Least obstacle distance along each segment ``a[i] -> b[i]``; -inf where it crosses a
    cell that is not free or leaves the grid."""
    cells, mask, inside = segments_cells(space, a, b)
    free = np.all(space.free_flat[cells] | ~mask, axis=1) & inside
    least = np.min(np.where(mask, space.distance_flat[cells], np.inf), axis=1)
    return np.where(free, least, -np.inf)


def any_angle(
    space: FreeSpace, pts: np.ndarray, seg_floor: np.ndarray, comfort: float
) -> np.ndarray:
    """Greedy line-of-sight shortcuts of the polyline ``pts`` (local frame).

    ``seg_floor[i]`` is the least clearance of the path between vertices i and i + 1.
    A run of vertices is replaced by one segment when that segment crosses only free
    cells, none nearer to an obstacle than the run came (capped at ``comfort``), give or
    take a cell. From each vertex, the segments to vertices 1, 2, 4, 8, ... ahead are
    checked in one batch (:func:`segments_clearance`), then 16 at a time between the
    farthest one reached and the nearest one missed.
    """
    n = len(pts)
    if n <= 2:
        return pts
    floor = np.minimum(seg_floor, comfort)
    slack = space.res  # a cell of clearance is not worth a zigzag
    out = [0]
    i = 0
    while i < n - 1:
        lowest = np.minimum.accumulate(floor[i:])  # lowest[e - 1 - i]: the run i..e

        def reaches(ends: np.ndarray, i: int = i, lowest: np.ndarray = lowest) -> np.ndarray:
            starts = np.repeat(pts[i : i + 1], len(ends), axis=0)
            return segments_clearance(space, starts, pts[ends]) >= lowest[ends - 1 - i] - slack

        # gallop (i + 2, i + 3, i + 5, i + 9, ..., the end), then narrow down between the
        # last end reached and the first one missed, 16 ends at a time
        ends = np.unique(np.minimum(i + 1 + 2 ** np.arange(int(math.log2(n - i)) + 2), n - 1))
        lo, hi = i + 1, n
        while True:
            ends = ends[(ends > lo) & (ends < hi)]
            if ends.size == 0:
                break
            ok = reaches(ends)
            if ok.all():
                lo = int(ends[-1])
            else:
                fail = int(np.argmin(ok))
                lo, hi = (int(ends[fail - 1]) if fail > 0 else lo), int(ends[fail])
            ends = np.unique(np.linspace(lo + 1, hi - 1, 16).round().astype(np.int64))
        out.append(lo)
        i = lo
    return pts[out]


def _segment_clearance(space: FreeSpace, a: np.ndarray, b: np.ndarray) -> float:
    seg = space.segment_cells(a[0], a[1], b[0], b[1])
    return 0.0 if seg is None else float(space.distance_flat[seg].min())


def _arc_clear(space: FreeSpace, arc: np.ndarray, floor: float) -> bool:
    return bool(np.all(segments_clearance(space, arc[:-1], arc[1:]) >= floor - 1e-6))


def fillet(
    space: FreeSpace,
    pts: np.ndarray,
    comfort: float,
    max_radius: float,
    min_radius: float,
    spacing: float,
) -> np.ndarray:
    """Round each corner of ``pts`` with the largest circular arc (<= ``max_radius``) that
    stays free and no nearer to obstacles than the two segments it joins (capped at
    ``comfort``). Arcs are sampled every ``spacing`` metres; corners that take no arc of
    at least ``min_radius`` stay sharp."""
    n = len(pts)
    if n <= 2 or max_radius <= 0.0:
        return pts
    clear = [_segment_clearance(space, pts[i], pts[i + 1]) for i in range(n - 1)]
    lengths = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    out: list[np.ndarray] = [pts[:1]]
    for i in range(1, n - 1):
        a, v, b = pts[i - 1], pts[i], pts[i + 1]
        u1, u2 = (v - a) / lengths[i - 1], (b - v) / lengths[i]
        cross = u1[0] * u2[1] - u1[1] * u2[0]
        turn = math.atan2(cross, float(np.dot(u1, u2)))  # signed deflection
        if abs(turn) < 1e-3 or abs(turn) > math.pi - 1e-3:
            out.append(v[None])
            continue
        half_tan = math.tan(abs(turn) / 2.0)
        t_max = min(
            lengths[i - 1] * (1.0 if i == 1 else 0.5), lengths[i] * (1.0 if i == n - 2 else 0.5)
        )
        radius = min(max_radius, t_max / half_tan)
        normal = np.array([-u1[1], u1[0]]) * math.copysign(1.0, turn)
        start_angle = math.atan2(-normal[1], -normal[0])
        arc = None
        # Keep the clearance the path had; failing that, any radius the robot can take
        # at speed is worth coming closer (never inside the required clearance).
        for floor, smallest in (
            (min(clear[i - 1], clear[i], comfort), min_radius),
            (0.0, min_radius),
        ):
            r = radius
            while arc is None and r >= smallest:
                t = r * half_tan
                centre = v - u1 * t + normal * r
                steps = max(2, math.ceil(r * abs(turn) / spacing) + 1)
                angles = start_angle + np.linspace(0.0, turn, steps)
                candidate = centre + r * np.stack([np.cos(angles), np.sin(angles)], axis=1)
                if _arc_clear(space, candidate, floor):
                    arc = candidate
                r *= 0.7
        out.append(v[None] if arc is None else arc)
    out.append(pts[-1:])
    return np.concatenate(out, axis=0)


def max_curvature(points: np.ndarray, window: float = 0.2) -> float:
    """Largest heading change per metre over any ``window`` of arclength of a polyline:
    about 1/r on an arc of radius r > window, and (turn angle) / window at a corner."""
    pts = np.asarray(points, dtype=float)
    seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    pts = pts[np.concatenate([[True], seg > 1e-9])]
    if len(pts) < 3:
        return 0.0
    cum = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(pts, axis=0), axis=1))])
    step = window / 10.0
    s = np.arange(0.0, cum[-1], step)
    xy = np.stack([np.interp(s, cum, pts[:, 0]), np.interp(s, cum, pts[:, 1])], axis=1)
    d = np.diff(xy, axis=0)
    heading = np.unwrap(np.arctan2(d[:, 1], d[:, 0]))
    if len(heading) <= 10:
        return float(abs(heading[-1] - heading[0]) / max(cum[-1], window))
    return float(np.max(np.abs(heading[10:] - heading[:-10])) / window)


# --------------------------------------------------------------------------- the plugin


class CostGridPlanner:
    """Cost-aware coarse-to-fine grid search, any-angle shortcuts and corner fillets."""

    Config = CostGridConfig

    def __init__(self, config: CostGridConfig) -> None:
        self.config = config
        # The coarse graphs last used, by (clearance, block, cost weight, content hashes).
        self._coarse: dict[tuple, StepGraph] = {}

    @property
    def clearance(self) -> float:
        return self.config.clearance

    def diagnostics(self) -> dict[str, float]:
        return {}

    def plan(
        self,
        costmap: Costmap,
        start: Pose2D,
        goal: Pose2D,
        seed: int = 0,
        prior: np.ndarray | None = None,
    ) -> PlannedPath:
        """Plan from ``start`` to ``goal``. With ``prior`` (the previous path, map frame)
        the new path keeps its way round obstacles unless that way is blocked or another is
        clearly shorter. ``seed`` is unused: the search is deterministic."""
        t0 = time.perf_counter()
        cfg = self.config
        space = FreeSpace(costmap, cfg.clearance)
        s = space.check_endpoint(start, "start")
        g = space.check_endpoint(goal, "goal")
        return space.planned_path(self.local_path(space, s, g, prior), start, goal, t0)

    def local_path(
        self,
        space: FreeSpace,
        start: tuple[float, float],
        goal: tuple[float, float],
        prior: np.ndarray | None = None,
    ) -> np.ndarray | None:
        """The smoothed path in the grid's frame, or None when start and goal are not joined.

        A fresh plan longer than ``max_detour`` times the shortest path at the same
        clearance (the inflation cost took it round, say, a row of pillars rather than
        between them) is searched again with a quarter of the cost weight, down to none.
        """
        cfg = self.config
        comfort = space.costmap.robot_radius + space.costmap.config.inflation_radius
        if self._straight_is_best(space, start, goal, comfort):
            return np.array([start, goal], dtype=float)
        weight = cfg.cost_weight
        pts = self._search(space, start, goal, weight, prior)
        if pts is None or prior is not None or weight == 0.0 or cfg.max_detour is None:
            return pts
        if _length(pts) <= cfg.max_detour * math.dist(start, goal):
            return pts
        shortest = self._search(space, start, goal, 0.0, None, fillets=False, slack=COARSE_SLACK)
        bound = cfg.max_detour * _length(shortest) if shortest is not None else math.inf
        while _length(pts) > bound and weight > 0.0:
            weight = weight / 4.0 if weight > cfg.cost_weight / 60.0 else 0.0
            pts = self._search(space, start, goal, weight, None, slack=COARSE_SLACK)
            if pts is None:
                return shortest
        return pts

    def _search(
        self,
        space: FreeSpace,
        start: tuple[float, float],
        goal: tuple[float, float],
        weight: float,
        prior: np.ndarray | None,
        fillets: bool = True,
        slack: float | None = None,
    ) -> np.ndarray | None:
        """Coarse-to-fine search with inflation cost ``weight``, then smoothing. With
        ``slack`` the fine search may use every coarse way within ``1 + slack`` of the
        cheapest (see :meth:`StepGraph.near_cheapest`), not only the cheapest."""
        cfg = self.config
        costmap = space.costmap
        comfort = costmap.robot_radius + costmap.config.inflation_radius
        w = space.width
        s_cell = int(start[1] / space.res) * w + int(start[0] / space.res)
        g_cell = int(goal[1] / space.res) * w + int(goal[0] / space.res)
        factor = 1.0 + weight * costmap.cost.astype(np.float64) / MAX_COST
        k = max(1, round(cfg.coarse_resolution / space.res))
        cells = None
        if k > 1:
            coarse = self._coarse_graph(space, k, weight)
            wc = -(-w // k)
            s_block = (s_cell // w // k) * wc + (s_cell % w) // k
            g_block = (g_cell // w // k) * wc + (g_cell % w) // k
            if slack is None:
                blocks = coarse.cheapest(s_block, g_block)
            else:
                blocks = coarse.near_cheapest(s_block, g_block, slack)
            if blocks is None:
                return None  # no block path: not joined at the fine level either
            cells = self._in_corridor(space, blocks, k, factor, s_cell, g_cell)
        if cells is None:  # the corridor held no path: search every cell
            cells = step_graph(space.free, space.free, factor).cheapest(s_cell, g_cell)
        if cells is None:
            return None
        pts = self.smooth(space, start, goal, cells, comfort, weight, fillets)
        if prior is None or len(prior) < 2 or k == 1:
            return pts
        kept = self._along_prior(space, prior, k, factor, s_cell, g_cell)
        if kept is None:
            return pts
        kept_pts = self.smooth(space, start, goal, kept, comfort, weight, fillets)
        return pts if _length(pts) < cfg.keep_prior * _length(kept_pts) else kept_pts

    def _straight_is_best(
        self,
        space: FreeSpace,
        start: tuple[float, float],
        goal: tuple[float, float],
        comfort: float,
    ) -> bool:
        """The straight line is free and (with a cost weight) outside the inflation zone."""
        line = space.segment_cells(*start, *goal)
        if line is None or not space.free_flat[line].all():
            return False
        return self.config.cost_weight == 0.0 or space.distance_flat[line].min() >= comfort - 1e-6

    def _coarse_graph(self, space: FreeSpace, k: int, weight: float) -> StepGraph:
        """The coarse graph of ``space``'s costmap, reused while the free cells (and, with a
        cost weight, the costs) are the same. Keyed by content, not identity: the obstacle
        layer patches its costmap in place."""
        cost_key = hash(space.costmap.cost.tobytes()) if weight > 0.0 else 0
        key = (space.required, k, weight, hash(space.free_bytes), cost_key)
        graph = self._coarse.pop(key, None)
        if graph is None:
            graph = coarse_graph(space, weight, k)
        self._coarse[key] = graph  # most recently used last
        while len(self._coarse) > COARSE_CACHE:
            self._coarse.pop(next(iter(self._coarse)))
        return graph

    def _in_corridor(
        self,
        space: FreeSpace,
        blocks: np.ndarray,
        k: int,
        factor: np.ndarray,
        s_cell: int,
        g_cell: int,
    ) -> np.ndarray | None:
        h, w = space.free.shape
        corridor = np.zeros((-(-h // k), -(-w // k)), dtype=bool)
        corridor.ravel()[blocks] = True
        return corridor_path(space, corridor, k, self.config.band, factor, s_cell, g_cell)

    def refine(
        self,
        space: FreeSpace,
        start: tuple[float, float],
        goal: tuple[float, float],
        path: np.ndarray,
    ) -> np.ndarray | None:
        """``path`` (local frame, e.g. a sampling planner's) made cost-aware and smooth:
        the cheapest path within ``band`` blocks of it, then shortcuts and fillets. None
        when the band holds no path."""
        costmap = space.costmap
        comfort = costmap.robot_radius + costmap.config.inflation_radius
        if len(path) == 2 and self._straight_is_best(space, start, goal, comfort):
            return np.array([start, goal], dtype=float)
        w = space.width
        s_cell = int(start[1] / space.res) * w + int(start[0] / space.res)
        g_cell = int(goal[1] / space.res) * w + int(goal[0] / space.res)
        factor = 1.0 + self.config.cost_weight * costmap.cost.astype(np.float64) / MAX_COST
        k = max(1, round(self.config.coarse_resolution / space.res))
        cells = self._along_prior(space, path, k, factor, s_cell, g_cell, local=True)
        if cells is None:
            return None
        return self.smooth(space, start, goal, cells, comfort, self.config.cost_weight)

    def _along_prior(
        self,
        space: FreeSpace,
        prior: np.ndarray,
        k: int,
        factor: np.ndarray,
        s_cell: int,
        g_cell: int,
        local: bool = False,
    ) -> np.ndarray | None:
        """The cheapest path within ``band`` blocks of ``prior`` (map frame unless
        ``local``); None when the band holds none (the way is blocked)."""
        h, w = space.free.shape
        wc = -(-w // k)
        if not local:
            prior = np.array([space.to_local(float(x), float(y)) for x, y in prior[:, :2]])
        local_pts = np.asarray(prior, dtype=float)[:, :2]
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
        return self._in_corridor(space, rows * wc + cols, k, factor, s_cell, g_cell)

    def smooth(
        self,
        space: FreeSpace,
        start: tuple[float, float],
        goal: tuple[float, float],
        cells: np.ndarray,
        comfort: float,
        weight: float,
        fillets: bool = True,
    ) -> np.ndarray:
        """Cell path -> any-angle polyline -> filleted polyline (local frame)."""
        cfg = self.config
        w = space.width
        dist = space.distance_flat[cells]
        turns = _turns(cells, w, SHORTCUT_EVERY)
        centres = space.cell_centres(cells[turns] // w, cells[turns] % w)
        # least clearance of the cell path between consecutive turn vertices
        seg_floor = np.minimum.reduceat(dist, turns[:-1]) if len(turns) > 1 else dist[:1]
        seg_floor = np.minimum(seg_floor, dist[turns[1:]])
        pts = centres.copy()
        pts[0], pts[-1] = start, goal
        if not space.segment_free(*pts[0], *pts[1]):
            pts = np.vstack([[start], centres])
            seg_floor = np.concatenate([[dist[0]], seg_floor])
        if not space.segment_free(*pts[-2], *pts[-1]):
            pts = np.vstack([pts[:-1], centres[-1:], [goal]])
            seg_floor = np.concatenate([seg_floor, [dist[-1]]])
        floor_cap = comfort if weight > 0.0 else space.required
        pts = any_angle(space, pts, seg_floor, floor_cap)
        if fillets:
            radius = cfg.max_turn_radius
            pts = fillet(space, pts, floor_cap, radius, cfg.min_turn_radius, space.res)
        keep = np.ones(len(pts), dtype=bool)
        keep[1:] = np.linalg.norm(np.diff(pts, axis=0), axis=1) > 1e-9
        return pts[keep]


def _length(pts: np.ndarray) -> float:
    return float(np.sum(np.linalg.norm(np.diff(pts, axis=0), axis=1)))
