"""Rooms: labelled polygons of the map frame, with an optional anchor pose to visit."""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
from shapely import Polygon
from shapely.ops import polylabel

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

    def self_intersection(self) -> tuple[int, int] | None:
        """The first pair of edges (indices) that cross, or None for a simple polygon.

        Edge ``i`` runs from vertex ``i`` to vertex ``i + 1``; neighbouring edges share a
        vertex and are not compared.
        """
        pts = [tuple(map(float, p)) for p in self.polygon]
        n = len(pts)
        for i in range(n):
            a, b = pts[i], pts[(i + 1) % n]
            for j in range(i + 1, n):
                if j == i or (j + 1) % n == i or j == (i + 1) % n:
                    continue
                if _segments_intersect(a, b, pts[j], pts[(j + 1) % n]):
                    return i, j
        return None

    def inside_point(self) -> tuple[float, float]:
        """The polygon's pole of inaccessibility (shapely's ``polylabel``): the point
        farthest from its outline, inside even an L- or U-shaped room (where the mean of
        the vertices may lie outside)."""
        return _pole(self.polygon)


@functools.lru_cache(maxsize=256)
def _pole(polygon: tuple[tuple[float, float], ...]) -> tuple[float, float]:
    shape = Polygon(polygon)
    xmin, ymin, xmax, ymax = shape.bounds
    tolerance = max(1e-3, 1e-3 * max(xmax - xmin, ymax - ymin))  # 1 mm, or 0.1 % of its size
    point = polylabel(shape, tolerance=tolerance)
    return float(point.x), float(point.y)


def _segments_intersect(
    p1: tuple[float, ...], p2: tuple[float, ...], q1: tuple[float, ...], q2: tuple[float, ...]
) -> bool:
    """Whether the closed segments p1-p2 and q1-q2 share a point."""

    def orient(a: tuple[float, ...], b: tuple[float, ...], c: tuple[float, ...]) -> float:
        return (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])

    def on_segment(a: tuple[float, ...], b: tuple[float, ...], c: tuple[float, ...]) -> bool:
        return min(a[0], b[0]) <= c[0] <= max(a[0], b[0]) and min(a[1], b[1]) <= c[1] <= max(
            a[1], b[1]
        )

    d1, d2 = orient(q1, q2, p1), orient(q1, q2, p2)
    d3, d4 = orient(p1, p2, q1), orient(p1, p2, q2)
    if ((d1 > 0) != (d2 > 0)) and ((d3 > 0) != (d4 > 0)) and d1 and d2 and d3 and d4:
        return True
    return (
        (d1 == 0 and on_segment(q1, q2, p1))
        or (d2 == 0 and on_segment(q1, q2, p2))
        or (d3 == 0 and on_segment(p1, p2, q1))
        or (d4 == 0 and on_segment(p1, p2, q2))
    )


def room_at(rooms: dict[str, Room], x: float, y: float) -> str | None:
    """The label of the first room whose polygon holds (x, y), if any."""
    return next((label for label, room in rooms.items() if room.contains(x, y)), None)


def reachable_cells(costmap: Costmap, start: Pose2D, margin: float = 0.0) -> np.ndarray:
    """Cells where the robot fits (with ``margin``) and that connect to ``start``."""
    from scipy.ndimage import label  # ~0.5 s: only missions that ask import it

    free = costmap.distance > costmap.robot_radius + margin
    labels, _ = label(free, structure=np.ones((3, 3), dtype=bool))
    rows, cols = costmap.grid.world_to_cell(np.array([start.x, start.y]))
    if not costmap.grid.in_bounds(rows, cols):
        return np.zeros_like(free)
    region = labels[int(rows), int(cols)]
    return labels == region if region else np.zeros_like(free)


def room_point(room: Room, costmap: Costmap, allowed: np.ndarray) -> Pose2D | None:
    """Where a room without an anchor is entered or started from: its pole of
    inaccessibility (:meth:`Room.inside_point`) when the robot may stand there (``allowed``),
    else :func:`visit_point`. Always inside the polygon; ``None`` when nowhere is allowed."""
    x, y = room.inside_point()
    grid = costmap.grid
    rows, cols = grid.world_to_cell(np.array([x, y]))
    if grid.in_bounds(rows, cols) and allowed[int(rows), int(cols)] and room.contains(x, y):
        return Pose2D(x, y, 0.0)
    return visit_point(room, costmap, allowed)


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
    from scipy.ndimage import distance_transform_edt

    to_outline = distance_transform_edt(inside) * grid.resolution
    score = np.where(candidates, np.minimum(costmap.distance, to_outline), -np.inf)
    r, c = np.unravel_index(int(np.argmax(score)), score.shape)
    return Pose2D(float(centres[r, c, 0]), float(centres[r, c, 1]), 0.0)
