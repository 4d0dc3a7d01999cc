"""Rooms: labelled polygons of the map frame, with an optional anchor pose to visit."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import distance_transform_edt, label

from agv_mission.geometry import Pose2D
from agv_mission.maps.costmap import Costmap


@dataclass(frozen=True)
class Room:
    """A labelled room. A robot is in the room when its position lies inside ``polygon``."""

    label: str
    polygon: tuple[tuple[float, float], ...]
    anchor: Pose2D | None = None

    def contains(self, x: float, y: float) -> bool:
        """Even-odd point-in-polygon test."""
        return bool(self.contains_points(np.array([[x, y]], dtype=float))[0])

    def contains_points(self, points: np.ndarray) -> np.ndarray:
        """Even-odd point-in-polygon test of (N, 2) points, edge by edge."""
        x, y = points[:, 0], points[:, 1]
        inside = np.zeros(len(points), dtype=bool)
        poly = np.asarray(self.polygon, dtype=float)
        for (xi, yi), (xj, yj) in zip(poly, np.roll(poly, 1, axis=0), strict=True):
            crosses = (yi > y) != (yj > y)
            with np.errstate(divide="ignore", invalid="ignore"):
                x_at = (xj - xi) * (y - yi) / (yj - yi) + xi
            inside ^= crosses & (x < x_at)
        return inside

    def centroid(self) -> tuple[float, float]:
        poly = np.asarray(self.polygon, dtype=float)
        return float(poly[:, 0].mean()), float(poly[:, 1].mean())


def room_at(rooms: dict[str, Room], x: float, y: float) -> str | None:
    """The label of the first room whose polygon holds (x, y), if any."""
    return next((label for label, room in rooms.items() if room.contains(x, y)), None)


def reachable_cells(costmap: Costmap, start: Pose2D, margin: float = 0.0) -> np.ndarray:
    """Cells where the robot fits (with ``margin``) and that connect to ``start``."""
    free = costmap.distance > costmap.robot_radius + margin
    labels, _ = label(free, structure=np.ones((3, 3), dtype=bool))
    rows, cols = costmap.grid.world_to_cell(np.array([start.x, start.y]))
    if not costmap.grid.in_bounds(rows, cols):
        return np.zeros_like(free)
    region = labels[int(rows), int(cols)]
    return labels == region if region else np.zeros_like(free)


def visit_point(room: Room, costmap: Costmap, allowed: np.ndarray) -> Pose2D | None:
    """The allowed point of ``room`` farthest from both obstacles and the room's outline.

    ``allowed`` (H, W) marks the cells the robot may stand on and reach (see
    :func:`reachable_cells`). ``None`` when no allowed cell lies inside the polygon.
    """
    grid = costmap.grid
    rows, cols = np.mgrid[0 : grid.height, 0 : grid.width]
    centres = grid.cell_to_world(rows, cols)
    inside = room.contains_points(centres.reshape(-1, 2)).reshape(grid.data.shape)
    candidates = inside & allowed
    if not candidates.any():
        return None
    to_outline = distance_transform_edt(inside) * grid.resolution
    score = np.where(candidates, np.minimum(costmap.distance, to_outline), -np.inf)
    r, c = np.unravel_index(int(np.argmax(score)), score.shape)
    return Pose2D(float(centres[r, c, 0]), float(centres[r, c, 1]), 0.0)
