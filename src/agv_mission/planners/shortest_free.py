"""The shortest free path: the yardstick a plan and a drive are measured against.

As the field defines it: the any-angle shortest path in the robot's configuration space,
the map's free space shrunk by the footprint's radius (cells farther than
``robot_radius`` from an obstacle: no clearance margin, no inflation cost, no fillets).
No planner is asked to drive it (it grazes every corner); every planner is compared
with it.

1. **Which way round.** ``cost_grid``'s search with no margin, no inflation cost and
   no fillets (coarse-to-fine Dijkstra, 16-connected, any-angle shortcuts; it searches
   every way round within 5 % of the coarse graph's shortest).
2. **Pulled taut.** The shortest chain of straight free segments between points two
   cells apart along that path (each joined to every later one it sees, checked in
   batches by :func:`path_smoothing.segments_clearance`; a dynamic programme): the
   taut string of that way round, to within a cell at each corner it wraps.
"""

from __future__ import annotations

import numpy as np

from agv_mission.geometry import Pose2D
from agv_mission.maps.costmap import Costmap
from agv_mission.planners.base import PlanningError
from agv_mission.planners.cost_grid import CostGridPlanner
from agv_mission.planners.free_space import FreeSpace
from agv_mission.planners.path_smoothing import path_length, segments_clearance

BATCH = 4096  # segments checked per call: bounds the memory of a long path's batch
STEP_CELLS = 1  # the taut string's corners are chosen among points a cell apart
WINDOW = 0.4  # ... within this of the search's corners, metres


def taut(space: FreeSpace, pts: np.ndarray) -> np.ndarray | None:
    """The shortest polyline from ``pts[0]`` to ``pts[-1]`` whose vertices are points of
    ``pts`` and whose segments cross free cells only; None when there is none."""
    n = len(pts)
    best = np.full(n, np.inf)
    best[0] = 0.0
    parent = np.zeros(n, dtype=np.int64)
    for j in range(1, n):
        lo = 0
        while lo < j:  # every earlier point, in batches
            hi = min(j, lo + BATCH)
            i = np.arange(lo, hi)
            ok = segments_clearance(space, pts[i], np.repeat(pts[j : j + 1], len(i), 0)) > (
                space.required
            )
            cand = np.where(ok, best[i] + np.linalg.norm(pts[i] - pts[j], axis=1), np.inf)
            k = int(np.argmin(cand))
            if cand[k] < best[j]:
                best[j], parent[j] = cand[k], lo + k
            lo = hi
    if not np.isfinite(best[-1]):
        return None
    chain = [n - 1]
    while chain[-1] != 0:
        chain.append(int(parent[chain[-1]]))
    return pts[chain[::-1]]


def near_corners(pts: np.ndarray, step: float, window: float) -> np.ndarray:
    """The polyline's vertices and, within ``window`` of each inner vertex, points
    ``step`` apart along its two segments: where the taut string's corners may be."""
    out = [pts[:1]]
    last = len(pts) - 2
    for i, (a, b) in enumerate(zip(pts[:-1], pts[1:], strict=True)):
        length = float(np.linalg.norm(b - a))
        d = np.arange(step, length, step)
        near_a = (d <= window) & (i > 0)  # (the start is no corner, nor the goal)
        near_b = (d >= length - window) & (i < last)
        d = d[near_a | near_b]
        out.append(a + (d / length)[:, None] * (b - a))
        out.append(b[None, :])
    return np.concatenate(out)


class ShortestFreePath:
    """Finds shortest free paths; keeps the search's coarse graphs between calls (a
    run asks on the same costmap again and again)."""

    def __init__(self) -> None:
        self._search = CostGridPlanner.shortest(0.0)

    def path(self, costmap: Costmap, start: Pose2D, goal: Pose2D) -> np.ndarray:
        """The shortest free path from ``start`` to ``goal`` (map frame, (N, 2)).

        PlanningError when either end is not free for the robot's radius or they are
        not joined by free space."""
        space, s, g = self._search.free_space(costmap, start, goal)
        pts = self._search.local_path(space, s, g)
        if pts is None:
            raise PlanningError(
                f"no free path from ({start.x:.2f}, {start.y:.2f}) to ({goal.x:.2f}, {goal.y:.2f})"
            )
        if len(pts) > 2:
            pulled = taut(space, near_corners(pts, STEP_CELLS * space.res, WINDOW))
            if pulled is not None and path_length(pulled) < path_length(pts):
                pts = pulled
        out = space.to_world(pts)
        out[0], out[-1] = start.xy, goal.xy
        return out

    def length(self, costmap: Costmap, start: Pose2D, goal: Pose2D) -> float | None:
        """The shortest free path's length, None when there is none."""
        try:
            return path_length(self.path(costmap, start, goal))
        except PlanningError:
            return None
