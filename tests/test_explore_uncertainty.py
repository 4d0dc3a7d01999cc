"""map_area chooses its frontiers knowing SLAM's uncertainty (issue 32): the nearest
while the estimate is sure, one near mapped structure once it is not."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from agv_mission.behaviors.explore import MapArea, choose_frontier
from agv_mission.geometry import Pose2D
from agv_mission.mapping.frontiers import Frontier
from agv_mission.maps.grid import FREE, OCCUPIED, OccupancyGrid


def open_floor() -> OccupancyGrid:
    """10 x 4 m of known floor with one 0.2 m column at (8.5, 2)."""
    data = np.full((80, 200), FREE, np.int8)
    data[38:42, 168:172] = OCCUPIED
    return OccupancyGrid(data, 0.05, Pose2D(0.0, 0.0, 0.0))


def frontier(goal: tuple[float, float], distance: float) -> Frontier:
    return Frontier(np.array([goal]), goal, goal, distance)


OPEN = frontier((2.0, 2.0), 3.0)  # nearer, 6.5 m from the column: open floor
NEAR_COLUMN = frontier((7.5, 2.0), 4.5)  # 1.5 m farther, 1 m from the column


def test_the_nearest_frontier_while_the_estimate_is_sure() -> None:
    assert choose_frontier([OPEN, NEAR_COLUMN], open_floor(), 0.01, 0.03, 2.0) is OPEN


def test_a_frontier_near_structure_once_the_estimate_is_unsure() -> None:
    """At 6 cm std, each metre of goal beyond 2 m of structure costs two of driving:
    the frontier by the column (1.5 m farther) beats the one in the open (4.5 m blind)."""
    assert choose_frontier([OPEN, NEAR_COLUMN], open_floor(), 0.06, 0.03, 2.0) is NEAR_COLUMN
    # nothing mapped to head for: the nearest still
    empty = OccupancyGrid(np.full((80, 200), FREE, np.int8), 0.05, Pose2D(0.0, 0.0, 0.0))
    assert choose_frontier([OPEN, NEAR_COLUMN], empty, 0.06, 0.03, 2.0) is OPEN


def test_the_explorer_reads_slams_position_std() -> None:
    """The std is the root of the largest eigenvalue of SLAM's xy covariance: the
    direction the scans left open (along a lone wall), not the average."""
    explore = MapArea("map", SimpleNamespace(), SimpleNamespace(), None, "m", None, None, 8, 0.05)
    cov = np.diag([0.0001, 0.0025, 1e-4])  # 1 cm across a wall, 5 cm along it
    explore.mapping = SimpleNamespace(slam=SimpleNamespace(covariance=cov))
    assert abs(explore._position_sigma() - 0.05) < 1e-9
