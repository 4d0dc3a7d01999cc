"""Travel-time estimates for dispatch: shortest distances over a robot's free space.

A dispatcher asks for many (robot, from, to) times when tasks are released; planning
each would cost tens of milliseconds. Instead the costmap's free cells are pooled into
blocks of about ``block`` metres (a block is passable when any of its cells is free for
the robot, as cost_grid's coarse search does) and one Dijkstra from each origin gives
the distance to every block; times are that distance over the robot's nominal speed.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.sparse.csgraph import dijkstra

from agv_mission.geometry import Pose2D
from agv_mission.maps.costmap import Costmap
from agv_mission.planners.grid_search import StepGraph, pool, step_graph

CLEARANCE = 0.05  # m beyond the radius a cell needs to be on a plan (cost_grid's default)


class GridTravelTime:
    """Seconds from pose to pose for one robot: coarse shortest distance / ``speed``."""

    def __init__(self, costmap: Costmap, speed: float, block: float = 0.2) -> None:
        self.costmap = costmap
        self.speed = speed
        self.k = max(1, int(round(block / costmap.resolution)))
        free = costmap.distance > costmap.robot_radius + CLEARANCE
        self.passable = pool(free, self.k, False, "any")
        shape = self.passable.shape
        self.graph: StepGraph = step_graph(self.passable, self.passable, np.ones(shape), 8)
        self._from: dict[int, np.ndarray] = {}

    def _node(self, pose: Pose2D) -> int:
        rows, cols = self.costmap.grid.world_to_cell(np.array([pose.x, pose.y]))
        r, c = int(rows) // self.k, int(cols) // self.k
        h, w = self.passable.shape
        if not (0 <= r < h and 0 <= c < w):
            return -1
        return int(self.graph.node_of[r * w + c])

    def distance(self, a: Pose2D, b: Pose2D) -> float:
        """Metres over free space from ``a`` to ``b`` (inf where none joins them)."""
        s, g = self._node(a), self._node(b)
        if s < 0 or g < 0:
            return math.inf
        if s not in self._from:
            self._from[s] = dijkstra(self.graph.graph, indices=s)
        blocks = float(self._from[s][g])
        return blocks * self.k * self.costmap.resolution

    def __call__(self, a: Pose2D, b: Pose2D) -> float:
        return self.distance(a, b) / self.speed
