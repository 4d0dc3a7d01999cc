"""Where a plan can start and whether it can end: the free space's connected regions (a
cheap check before a planner spends its budget on a hopeless query) and the nearest
comfortably free point for a robot standing inside the planners' margin.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.ndimage import label

from agv_mission.geometry import Pose2D
from agv_mission.maps.costmap import Costmap
from agv_mission.maps.zones import ZoneFilters
from agv_mission.planners.free_space import FreeSpace


class FreeRegions:
    """The connected regions of a costmap's free space, labelled once per costmap revision."""

    def __init__(self) -> None:
        self._regions: tuple[Any, ...] | None = None  # costmap, revision, margin, labels

    def joins(
        self, costmap: Costmap, revision: int, margin: float, start: Pose2D, goal: Pose2D
    ) -> bool:
        """Whether free space (with the planners' margin) joins start and goal: a cheap
        check that spares a sampling planner its whole time budget on a hopeless query.
        The free space's connected regions are labelled once per costmap (a patrol asks
        at every waypoint; a 30 x 50 m map takes ~10 ms to label)."""
        key = (costmap, revision, margin)  # patched in place as obstacles come and go
        cached = self._regions
        if cached is None or cached[0] is not costmap or cached[1:3] != key[1:]:
            free = costmap.distance > costmap.robot_radius + margin
            cached = (*key, label(free, structure=np.ones((3, 3), dtype=bool))[0])
            self._regions = cached
        regions = cached[3]
        grid = costmap.grid
        rows, cols = grid.world_to_cell(np.array([[start.x, start.y], [goal.x, goal.y]]))
        inside = grid.in_bounds(rows, cols)
        region = regions[int(rows[0]), int(cols[0])] if inside[0] else 0
        if not inside[1] or not region:
            return True  # let the planner report what is wrong with start or goal
        return bool(regions[int(rows[1]), int(cols[1])] == region) or not bool(
            costmap.is_free(np.array([goal.x, goal.y]), margin)
        )


def escape_point(
    costmap: Costmap, pose: Pose2D, margin: float, escape_distance: float
) -> Pose2D | None:
    """The nearest comfortably free point when the robot stands inside the margin the
    planners require (``margin``: it drifted close to a wall); ``None`` when it is free
    already or none is within ``escape_distance``."""
    here = np.array([pose.x, pose.y])
    grid = costmap.grid
    # the planners' own test of a start (on a cell's edge, a round-number pose on a
    # 5 cm grid, both cells must be free)
    space = FreeSpace(costmap, margin)
    if space.point_free(*space.to_local(pose.x, pose.y)):
        return None
    rows, cols = grid.world_to_cell(here)
    reach = int(np.ceil(escape_distance / grid.resolution))
    r0, r1 = max(int(rows) - reach, 0), min(int(rows) + reach + 1, grid.height)
    c0, c1 = max(int(cols) - reach, 0), min(int(cols) + reach + 1, grid.width)
    rr, cc = np.mgrid[r0:r1, c0:c1]
    centres = grid.cell_to_world(rr.ravel(), cc.ravel())
    ok = costmap.is_free(centres, margin)
    if not ok.any():
        return None
    candidates = centres[ok]
    nearest = candidates[np.argmin(np.linalg.norm(candidates - here, axis=1))]
    if np.linalg.norm(nearest - here) > escape_distance:
        return None
    return Pose2D(float(nearest[0]), float(nearest[1]), pose.yaw)


def keepout_exit(
    zones: ZoneFilters | None, pose: Pose2D, clearance: float, goal: Pose2D | None
) -> Pose2D | None:
    """Where a robot inside (or at the margin of) a keepout zone leaves it: the nearest
    point clear of it (by ``clearance``), reached straight, so it drives out instead of
    freezing."""
    if zones is None:
        return None
    towards = None if goal is None else (goal.x, goal.y)
    out = zones.exit_point(pose.x, pose.y, clearance + 0.02, towards)
    return None if out is None else Pose2D(out[0], out[1], pose.yaw)
