"""Keepout and speed filters (Nav2's costmap filters) on the costmap's grid.

Zones come as polygons (map frame) or as Nav2 filter masks; both end up as two rasters on
the costmap's grid: ``keepout`` (bool) and ``speed`` (the speed limit of each cell, m/s,
``inf`` where none). Keepout cells are obstacles of the planning costmap (lethal and
inflated like walls, so every planner keeps the footprint out); a robot whose footprint
already overlaps one leaves by :meth:`ZoneFilters.exit_point`. A speed limit applies while
the footprint overlaps a limited cell; :meth:`ZoneFilters.speed_cap` also brakes ahead of a
zone, so the robot is down to the limit by the time its footprint reaches it.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import shapely

from agv_mission.geometry import Pose2D
from agv_mission.maps.costmap import Costmap
from agv_mission.maps.grid import OCCUPIED, OccupancyGrid
from agv_mission.maps.rooms import reachable_cells

Polygon = Sequence[tuple[float, float]]

#: A keepout mask cell is kept out of when its filter value reaches map_server's default
#: occupied threshold (0.65, in percent).
KEEPOUT_THRESHOLD = 65.0


@dataclass(frozen=True)
class FilterMask:
    """A Nav2 filter mask (a map_server image) with its ``CostmapFilterInfo`` terms:
    filter value = ``base + multiplier * mask value``."""

    grid: OccupancyGrid
    base: float = 0.0
    multiplier: float = 1.0


def polygon_cells(grid: OccupancyGrid, polygon: Polygon) -> np.ndarray:
    """(H, W) bool: the cells of ``grid`` whose centres lie inside ``polygon``."""
    rows, cols = np.mgrid[0 : grid.height, 0 : grid.width]
    centres = grid.cell_to_world(rows, cols)
    return shapely.contains_xy(shapely.Polygon(polygon), centres[..., 0], centres[..., 1])


def _mask_values(grid: OccupancyGrid, mask: FilterMask) -> tuple[np.ndarray, np.ndarray]:
    """The mask's raw values at ``grid``'s cell centres and where they are known and
    non-zero (Nav2: 0 and unknown mean no filter there)."""
    rows, cols = np.mgrid[0 : grid.height, 0 : grid.width]
    mr, mc = mask.grid.world_to_cell(grid.cell_to_world(rows, cols))
    inside = mask.grid.in_bounds(mr, mc)
    raw = np.zeros(grid.data.shape, dtype=np.float64)
    raw[inside] = mask.grid.data[mr[inside], mc[inside]]
    return raw, inside & (raw > 0)


class ZoneFilters:
    """The keepout and speed rasters of a mission's zones, over its base costmap."""

    def __init__(
        self, base: Costmap, max_speed: float, keepout: np.ndarray, speed: np.ndarray
    ) -> None:
        self.base = base
        self.grid = base.grid
        self.robot_radius = base.robot_radius
        self.max_speed = max_speed
        self.keepout = keepout
        self.speed = speed
        self.costmap = base.with_obstacles(keepout) if keepout.any() else base
        from scipy.ndimage import distance_transform_edt  # ~0.5 s: missions with zones only

        res = self.grid.resolution
        # metres from each cell centre to the nearest keepout cell centre (0 inside)
        self.keepout_distance = (
            (distance_transform_edt(~keepout) * res).astype(np.float32)
            if keepout.any()
            else np.full(keepout.shape, np.inf, dtype=np.float32)
        )
        self.levels = sorted({float(v) for v in np.unique(speed[np.isfinite(speed)])})
        self._level_distance = [
            (distance_transform_edt(~(speed <= level)) * res).astype(np.float32)
            for level in self.levels
        ]

    @classmethod
    def build(
        cls,
        base: Costmap,
        max_speed: float,
        keepout_polygons: Sequence[Polygon] = (),
        speed_polygons: Sequence[tuple[Polygon, float]] = (),
        keepout_masks: Sequence[FilterMask] = (),
        speed_masks: Sequence[tuple[FilterMask, bool]] = (),
    ) -> ZoneFilters:
        """Rasterise zones on ``base``'s grid. ``speed_polygons``: (polygon, m/s);
        ``speed_masks``: (mask, in percent of ``max_speed`` or else m/s)."""
        grid = base.grid
        keepout = np.zeros(grid.data.shape, dtype=bool)
        speed = np.full(grid.data.shape, np.inf, dtype=np.float32)
        for polygon in keepout_polygons:
            keepout |= polygon_cells(grid, polygon)
        for polygon, limit in speed_polygons:
            cells = polygon_cells(grid, polygon)
            speed[cells] = np.minimum(speed[cells], limit)
        for mask in keepout_masks:
            raw, known = _mask_values(grid, mask)
            keepout |= known & (mask.base + mask.multiplier * raw >= KEEPOUT_THRESHOLD)
        for mask, percent in speed_masks:
            raw, known = _mask_values(grid, mask)
            value = mask.base + mask.multiplier * raw
            limit = value / 100.0 * max_speed if percent else value
            limited = known & (limit > 0.0)  # Nav2 ignores limits out of range
            limit = np.minimum(limit, max_speed).astype(np.float32)
            speed[limited] = np.minimum(speed[limited], limit[limited])
        speed[speed >= max_speed] = np.inf  # no cap at or above the robot's own limit
        return cls(base, max_speed, keepout, speed)

    @property
    def empty(self) -> bool:
        return not self.keepout.any() and not self.levels

    def _at(self, field: np.ndarray, x: float, y: float, outside: float) -> float:
        rows, cols = self.grid.world_to_cell(np.array([x, y]))
        if not bool(self.grid.in_bounds(rows, cols)):
            return outside
        return float(field[int(rows), int(cols)])

    def keepout_clearance(self, x: float, y: float) -> float:
        """Metres from the point to the nearest keepout cell (0 inside one)."""
        return self._at(self.keepout_distance, x, y, math.inf)

    def in_keepout(self, x: float, y: float) -> bool:
        """Whether a footprint centred at (x, y) overlaps a keepout zone."""
        return self.keepout_clearance(x, y) < self.robot_radius

    def exit_point(
        self,
        x: float,
        y: float,
        margin: float,
        toward: tuple[float, float] | None = None,
    ) -> tuple[float, float] | None:
        """The nearest point whose footprint (plus ``margin``) is clear of every keepout
        zone and obstacle of the base map, in the free space the robot stands in, when the
        robot at (x, y) is within that margin of a keepout zone; ``None`` when it is not
        (or there is no way out). Of ways out as short (to a map cell), the one nearest
        ``toward`` (the goal): from the middle of a square zone any side is as near, and
        leaving away from the goal cost a patrol 20 s."""
        need = self.robot_radius + margin
        if self.keepout_clearance(x, y) > need:
            return None
        ok = (self.keepout_distance > need) & (self.base.distance > need)
        joined = ok & reachable_cells(self.base, Pose2D(x, y, 0.0))  # not through a wall
        rows, cols = np.nonzero(joined if joined.any() else ok)
        if rows.size == 0:
            return None
        centres = self.grid.cell_to_world(rows, cols)
        d = np.hypot(centres[:, 0] - x, centres[:, 1] - y)
        best = centres[int(np.argmin(d))]
        if toward is not None:
            short = centres[d <= d.min() + self.grid.resolution]
            best = short[np.argmin(np.hypot(short[:, 0] - toward[0], short[:, 1] - toward[1]))]
        return float(best[0]), float(best[1])

    @functools.cached_property
    def boundary_points(self) -> np.ndarray:
        """(N, 2) map-frame centres of keepout cells on a zone's edge: what the local
        controller treats as obstacles."""
        from scipy.ndimage import binary_erosion

        edge = self.keepout & ~binary_erosion(self.keepout, border_value=1)
        rows, cols = np.nonzero(edge)
        return self.grid.cell_to_world(rows, cols).reshape(-1, 2)

    def boundary_near(self, x: float, y: float, reach: float) -> np.ndarray:
        """Keepout edge points within ``reach`` of (x, y); none while the footprint is in
        (or at) a keepout zone, which it must be free to leave."""
        pts = self.boundary_points
        if not len(pts) or self.keepout_clearance(x, y) <= self.robot_radius + 0.1:
            return pts[:0]
        return pts[np.hypot(pts[:, 0] - x, pts[:, 1] - y) <= reach]

    def limit_at(self, x: float, y: float) -> float:
        """The speed limit on a footprint centred at (x, y) (inf outside every zone)."""
        for level, distance in zip(self.levels, self._level_distance, strict=True):
            if self._at(distance, x, y, math.inf) < self.robot_radius:
                return level
        return math.inf

    def speed_cap(self, x: float, y: float, decel: float, lead: float) -> float:
        """The highest linear speed allowed at (x, y): a zone's limit while the footprint
        overlaps it, and ahead of one the speed from which braking at ``decel`` (m/s^2)
        reaches the limit at its edge, ``lead`` metres (the distance covered before a
        command takes effect) early."""
        cap = math.inf
        for level, distance in zip(self.levels, self._level_distance, strict=True):
            gap = self._at(distance, x, y, math.inf) - self.robot_radius - lead
            cap = min(cap, math.sqrt(level * level + 2.0 * decel * max(gap, 0.0)))
        return cap

    def keepout_grid(self) -> OccupancyGrid:
        """The keepout filter mask as an occupancy grid (100 kept out, 0 free)."""
        data = np.where(self.keepout, OCCUPIED, 0).astype(np.int8)
        return OccupancyGrid(data, self.grid.resolution, self.grid.origin)

    def speed_grid(self) -> OccupancyGrid:
        """The speed filter mask: each cell's limit in percent of the robot's maximum
        speed (``CostmapFilterInfo`` type 1, base 0, multiplier 1), 0 where none."""
        percent = np.where(np.isfinite(self.speed), self.speed / self.max_speed * 100.0, 0.0)
        data = np.clip(np.ceil(percent), 0, 100).astype(np.int8)
        return OccupancyGrid(data, self.grid.resolution, self.grid.origin)


#: Speed above the limit by more than this fraction counts as a violation (the contract's
#: "within 5 % of the limit").
SPEED_TOLERANCE = 0.05


def zone_metrics(zones: ZoneFilters, t: np.ndarray, xy: np.ndarray) -> dict[str, object]:
    """``metrics.zones`` of a true trajectory (times ``t``, positions ``xy`` (N, 2)).

    Speed is the true one between consecutive samples, held against the limit on the
    footprint at the interval's midpoint.
    """
    n = len(t)
    dt = np.diff(t) if n > 1 else np.zeros(0)
    inside = np.array([zones.in_keepout(x, y) for x, y in xy], dtype=bool)
    keepout_time = float(np.sum(dt[inside[:-1]])) if n > 1 else 0.0
    started_inside = bool(inside[0]) if n else False
    left_at = int(np.argmin(inside)) if started_inside and not inside.all() else 0
    after_exit = float(np.sum(dt[left_at:][inside[left_at:-1]])) if started_inside else 0.0
    limited_time = violation_time = 0.0
    worst = 0.0
    if zones.levels and n > 1:
        mid = 0.5 * (xy[1:] + xy[:-1])
        speed = np.hypot(*np.diff(xy, axis=0).T) / np.maximum(dt, 1e-9)
        for k, (x, y) in enumerate(mid):
            limit = zones.limit_at(float(x), float(y))
            if math.isfinite(limit):
                limited_time += float(dt[k])
                worst = max(worst, float(speed[k]) / limit)
                if speed[k] > limit * (1.0 + SPEED_TOLERANCE):
                    violation_time += float(dt[k])
    return {
        "keepout_time": round(keepout_time, 3),
        "started_in_keepout": started_inside,
        "keepout_time_after_exit": round(after_exit, 3),
        "speed_limited_time": round(limited_time, 3),
        "speed_violation_time": round(violation_time, 3),
        "max_speed_ratio": round(worst, 3),
    }
