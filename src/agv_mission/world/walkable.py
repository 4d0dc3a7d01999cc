"""Where people can walk on a map: its free cells as polygons, each cell's clearance, and
the walls as RVO2 obstacles (the free space's outline keeps people in, its holes keep them
out), each computed once per map."""

from __future__ import annotations

import numpy as np
import shapely

from agv_mission.maps.distance import obstacle_distance
from agv_mission.maps.grid import FREE, OccupancyGrid
from agv_mission.maps.map_cache import map_table

WALL_SIMPLIFY = 0.02  # m, how far the walls' outline may move when simplified
HULL_SLACK = 0.1  # m an obstacle's convex hull may stand out of it to stand for it (a notch)


def free_space(grid: OccupancyGrid, simplify: float = WALL_SIMPLIFY) -> shapely.Geometry:
    """The grid's free cells as polygons in the map frame (unknown cells are not walkable):
    the filled contour of the free mask half way between free and not-free cell centres
    (contourpy, matplotlib's contouring; 4x faster than a union of the cells' boxes)."""
    import contourpy  # once a mission has people

    free = (grid.data == FREE).astype(np.float64)
    if not free.any():
        return shapely.Polygon()
    height, width = free.shape
    res = grid.resolution
    x = grid.origin.x + (np.arange(width) + 0.5) * res
    y = grid.origin.y + (np.arange(height) + 0.5) * res
    padded = np.zeros((height + 2, width + 2))  # closed outlines at the grid's edge too
    padded[1:-1, 1:-1] = free
    x = np.concatenate([[x[0] - res], x, [x[-1] + res]])
    y = np.concatenate([[y[0] - res], y, [y[-1] + res]])
    gen = contourpy.contour_generator(
        x, y, padded, fill_type=contourpy.FillType.OuterOffset, corner_mask=False
    )
    points, offsets = gen.filled(0.5, 1.5)
    polygons = []
    for p, o in zip(points, offsets, strict=True):
        rings = [p[o[i] : o[i + 1]] for i in range(len(o) - 1)]
        polygons.append(shapely.Polygon(rings[0], rings[1:]))
    shape = shapely.make_valid(shapely.MultiPolygon(polygons))
    return shapely.simplify(shape, simplify) if simplify > 0 else shape


def _polygons(geometry: shapely.Geometry) -> list[shapely.Polygon]:
    if isinstance(geometry, shapely.Polygon):
        return [] if geometry.is_empty else [geometry]
    return [g for g in getattr(geometry, "geoms", []) if isinstance(g, shapely.Polygon)]


def clearance(grid: OccupancyGrid) -> np.ndarray:
    """Each cell's distance to the nearest cell that is not free (walls, unknown), m, from
    the costmap's own distance transform (one per map, shared: tens of ms on a warehouse).
    Read-only."""
    res = grid.resolution

    def build() -> np.ndarray:
        room = obstacle_distance(grid.data != FREE, res) - np.float32(res / 2)
        room.setflags(write=False)
        return room

    return map_table("person_clearance", grid, (), build)


def wall_obstacles(grid: OccupancyGrid) -> list[list[list[float]]]:
    """The map's walls as RVO2 obstacles (vertex lists, one per outline), one per map:
    the free space's outline walked clockwise keeps people in, its holes (as their hulls
    where close enough) keep them out."""

    def build() -> list[list[list[float]]]:
        out = []
        for polygon in _polygons(shapely.orient_polygons(free_space(grid))):
            # RVO2 keeps agents outside counter-clockwise polygons: the free space's outline
            # (counter-clockwise) is walked clockwise to keep them in, its holes the other way.
            out.append([list(p) for p in polygon.exterior.coords[:-1][::-1]])
            out.extend(_obstacle(hole) for hole in polygon.interiors)
        return out

    return map_table("wall_obstacles", grid, (WALL_SIMPLIFY, HULL_SLACK), build)


def _obstacle(hole: shapely.LinearRing) -> list[list[float]]:
    """A hole of the free space (clockwise) as an RVO2 obstacle (counter-clockwise): its
    convex hull where that lies within ``HULL_SLACK`` of it. A rack's uprights stand out of
    its face: 54 corners instead of 4, and ORCA's obstacle tree costs per corner (the
    warehouse's 972 built in 37 ms against 1 ms; a step of 50 people 30 % dearer)."""
    hull = shapely.Polygon(hole).convex_hull
    if isinstance(hull, shapely.Polygon) and (
        shapely.hausdorff_distance(hull.exterior, hole) <= HULL_SLACK + 1e-9
    ):
        return [list(p) for p in shapely.orient_polygons(hull).exterior.coords[:-1]]
    return [list(p) for p in hole.coords[:-1][::-1]]
