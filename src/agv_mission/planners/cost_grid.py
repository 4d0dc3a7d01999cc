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
   searched. (Both searches: :mod:`grid_search`.)
3. **Any-angle smoothing and fillets** (:mod:`path_smoothing`): shortcuts that keep the
   clearance the path had, then circular arcs of radius up to ``max_turn_radius`` at
   the corners, so the robot need not stop at them.

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

import numpy as np

from agv_mission.geometry import Pose2D
from agv_mission.maps.costmap import Costmap
from agv_mission.planners.base import PlannedPath
from agv_mission.planners.configs import CostGridConfig
from agv_mission.planners.free_space import FreeSpace, FreeSpacePlanner, cost_factor
from agv_mission.planners.grid_search import (
    StepGraph,
    block_of,
    blocks_along,
    coarse_graph,
    corridor_path,
    step_graph,
)
from agv_mission.planners.path_smoothing import path_length, smooth

# How much the coarse graph may misjudge a path's length (blocks of 0.2 m on a leg of a
# few metres): the shortest-path check searches every way round obstacles within it.
COARSE_SLACK = 0.05
COARSE_CACHE = 4  # coarse graphs kept (a few MB each)


class CostGridPlanner(FreeSpacePlanner[CostGridConfig]):
    """Cost-aware coarse-to-fine grid search, any-angle shortcuts and corner fillets."""

    Config = CostGridConfig

    def __init__(self, config: CostGridConfig) -> None:
        super().__init__(config)
        # The coarse graphs last used, by (clearance, block, cost weight, content hashes).
        self._coarse: dict[tuple, StepGraph] = {}

    @classmethod
    def shortest(cls, clearance: float) -> CostGridPlanner:
        """The planner of the shortest path at ``clearance``: no inflation cost, no
        fillets (the reference a plan's length is measured against)."""
        return cls(CostGridConfig(clearance=clearance, cost_weight=0.0, max_turn_radius=0.0))

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
        space, s, g = self.free_space(costmap, start, goal)
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
        if self._straight_is_best(space, start, goal):
            return np.array([start, goal], dtype=float)
        weight = cfg.cost_weight
        pts = self._search(space, start, goal, weight, prior)
        if pts is None or prior is not None or weight == 0.0 or cfg.max_detour is None:
            return pts
        if path_length(pts) <= cfg.max_detour * math.dist(start, goal):
            return pts
        shortest = self._search(space, start, goal, 0.0, None, fillets=False, slack=COARSE_SLACK)
        bound = cfg.max_detour * path_length(shortest) if shortest is not None else math.inf
        while path_length(pts) > bound and weight > 0.0:
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
        w = space.width
        s_cell, g_cell = space.cell_index(start), space.cell_index(goal)
        factor = cost_factor(space.costmap.cost, weight)
        k = self._block(space)
        cells = None
        if k > 1:
            coarse = self._coarse_graph(space, k, weight)
            s_block, g_block = block_of(s_cell, w, k), block_of(g_cell, w, k)
            if slack is None:
                blocks = coarse.cheapest(s_block, g_block)
            else:
                blocks = coarse.near_cheapest(s_block, g_block, slack)
            if blocks is None:
                return None  # no block path: not joined at the fine level either
            cells = corridor_path(space, blocks, k, cfg.band, factor, s_cell, g_cell)
        if cells is None:  # the corridor held no path: search every cell
            cells = step_graph(space.free, space.free, factor).cheapest(s_cell, g_cell)
        if cells is None:
            return None
        pts = self._smooth(space, start, goal, cells, weight, fillets)
        if prior is None or len(prior) < 2 or k == 1:
            return pts
        kept = self._along_prior(space, prior, k, factor, s_cell, g_cell)
        if kept is None:
            return pts
        kept_pts = self._smooth(space, start, goal, kept, weight, fillets)
        return pts if path_length(pts) < cfg.keep_prior * path_length(kept_pts) else kept_pts

    def _straight_is_best(
        self,
        space: FreeSpace,
        start: tuple[float, float],
        goal: tuple[float, float],
    ) -> bool:
        """The straight line is free and (with a cost weight) outside the inflation zone."""
        line = space.segment_cells(*start, *goal)
        if line is None or not space.free_flat[line].all():
            return False
        if self.config.cost_weight == 0.0:
            return True
        return space.distance_flat[line].min() >= space.comfort - 1e-6

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

    def _block(self, space: FreeSpace) -> int:
        """Cells per side of a coarse block."""
        return max(1, round(self.config.coarse_resolution / space.res))

    def _along_prior(
        self,
        space: FreeSpace,
        prior: np.ndarray,
        k: int,
        factor: np.ndarray,
        s_cell: int,
        g_cell: int,
    ) -> np.ndarray | None:
        """The cheapest path within ``band`` blocks of ``prior`` (map frame); None when
        the band holds none (the way is blocked)."""
        prior = np.array([space.to_local(float(x), float(y)) for x, y in prior[:, :2]])
        blocks = blocks_along(space, prior, k)
        return corridor_path(space, blocks, k, self.config.band, factor, s_cell, g_cell)

    def _smooth(
        self,
        space: FreeSpace,
        start: tuple[float, float],
        goal: tuple[float, float],
        cells: np.ndarray,
        weight: float,
        fillets: bool = True,
    ) -> np.ndarray:
        """Shortcuts and fillets (:func:`path_smoothing.smooth`): with a cost weight they
        keep the clearance the path had up to the edge of the inflation zone, without one
        only the required clearance."""
        cfg = self.config
        floor_cap = space.comfort if weight > 0.0 else space.required
        radius = cfg.max_turn_radius if fillets else 0.0
        return smooth(space, start, goal, cells, floor_cap, radius, cfg.min_turn_radius)
