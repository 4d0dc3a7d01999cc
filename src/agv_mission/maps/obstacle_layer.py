"""The obstacle layer: what the lidar sees that the static map does not hold.

Every scan clears the marked cells its beams pass through and marks the cells its returns
end in, unless a mapped obstacle is already there (within ``map_tolerance``, so
localisation error does not paint the walls twice). The layered :class:`Costmap` the
planners use is the static one with the marked cells added.

A scan touches only a rolling window around the robot (Nav2's local costmap idea): clearing
looks at the marked cells within ``raytrace_range`` and projects each onto the beam at its
bearing (cleared when that beam reaches past it), so a scan costs O(beams + marked cells
nearby), whatever the size of the map. The layered costmap is patched in place around the
cells that changed (a mark reaches ``robot_radius + inflation_radius + 0.5`` m), not
rebuilt over the whole map.
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import distance_transform_edt

from agv_mission.geometry import Pose2D
from agv_mission.maps.costmap import Costmap, ObstacleLayerConfig, inflation_cost
from agv_mission.sensor_msgs import LaserScan


class ObstacleLayer:
    """Marks and clears unmapped obstacles on the static costmap's grid."""

    def __init__(self, static: Costmap, config: ObstacleLayerConfig) -> None:
        self.static = static
        self.config = config
        self.marks = np.zeros(static.distance.shape, dtype=bool)
        self._layered: Costmap = static
        self._dirty: list[int] | None = None  # row0, row1, col0, col1 of changed cells
        self._any: bool | None = False  # whether any cell is marked (None: not known)
        self.revision = 0  # counts the changes of :attr:`costmap` (patched in place)
        res = static.resolution
        self._reach = static.robot_radius + static.config.inflation_radius + 0.5
        self._pad = int(np.ceil(self._reach / res))
        self._people = np.zeros(0, dtype=np.int64)  # flat cells marked for people standing
        self._held = np.zeros(self.marks.shape, dtype=bool)  # ... which beams do not clear

    @property
    def has_marks(self) -> bool:
        """Whether any obstacle is marked (without scanning the whole grid every call)."""
        if self._any is None:
            self._any = bool(self.marks.any())
        return self._any

    @property
    def costmap(self) -> Costmap:
        """The static costmap with the marked obstacles added (patched when they change)."""
        if self._dirty is not None:
            self._patch()
        return self._layered

    def clear(self) -> None:
        """Forget every marked obstacle (the 'clear costmap' recovery; people still standing
        are marked again with the next scan)."""
        if self.marks.any():
            self.marks[:] = False
            self._layered = self.static
            self._dirty = None
            self.revision += 1
        self._any = False
        self._people = np.zeros(0, dtype=np.int64)
        self._held[:] = False

    def _touch(self, rows: np.ndarray, cols: np.ndarray) -> None:
        box = [int(rows.min()), int(rows.max()), int(cols.min()), int(cols.max())]
        if self._dirty is not None:
            d = self._dirty
            box = [min(d[0], box[0]), max(d[1], box[1]), min(d[2], box[2]), max(d[3], box[3])]
        self._dirty = box

    def _patch(self) -> None:
        """Recompute distance and cost within reach of the changed cells."""
        static, (r0, r1, c0, c1) = self.static, self._dirty
        self._dirty = None
        self.revision += 1
        if self._layered is static:
            self._layered = Costmap(
                static.grid,
                static.robot_radius,
                static.config,
                static.distance.copy(),
                static.cost.copy(),
            )
        h, w, p = self.marks.shape[0], self.marks.shape[1], self._pad
        win = (slice(max(r0 - p, 0), min(r1 + p + 1, h)), slice(max(c0 - p, 0), min(c1 + p + 1, w)))
        ext_r0, ext_c0 = max(r0 - 2 * p, 0), max(c0 - 2 * p, 0)
        ext = (slice(ext_r0, min(r1 + 2 * p + 1, h)), slice(ext_c0, min(c1 + 2 * p + 1, w)))
        marks = self.marks[ext]
        crop = (
            slice(win[0].start - ext_r0, win[0].stop - ext_r0),
            slice(win[1].start - ext_c0, win[1].stop - ext_c0),
        )
        distance = static.distance[win]
        if marks.any():
            near = (distance_transform_edt(~marks)[crop] * static.resolution).astype(np.float32)
            # A mark reaches exactly _reach: every cell it touches is patched when it goes.
            distance = np.where(near <= self._reach, np.minimum(distance, near), distance)
        layered = self._layered
        layered.distance[win] = distance
        layered.cost[win] = inflation_cost(distance, static.robot_radius, static.config)

    def set_people(self, discs: np.ndarray) -> bool:
        """Mark the discs (rows x, y, radius) of the people standing in the robot's way, as
        a people layer of Nav2's social navigation does from a tracker, and unmark those
        marked for people who have walked on; whether anything changed."""
        if not self.config.enabled:
            return False
        grid = self.static.grid
        cells: list[np.ndarray] = []
        res = grid.resolution
        for x, y, r in np.asarray(discs, dtype=float).reshape(-1, 3).tolist():
            n = int(np.ceil(r / res)) + 1
            row, col = grid.world_to_cell(np.array([x, y]))
            rr, cc = np.mgrid[row - n : row + n + 1, col - n : col + n + 1]
            rr, cc = rr.ravel(), cc.ravel()
            inside = grid.in_bounds(rr, cc)
            rr, cc = rr[inside], cc[inside]
            centre = grid.cell_to_world(rr, cc)
            on = np.hypot(centre[:, 0] - x, centre[:, 1] - y) <= r
            cells.append(rr[on] * grid.width + cc[on])
        new = np.unique(np.concatenate(cells)) if cells else np.zeros(0, dtype=np.int64)
        if np.array_equal(new, self._people):
            return False
        flat, held = self.marks.reshape(-1), self._held.reshape(-1)
        for changed, value in ((self._people, False), (new, True)):
            if len(changed):
                flat[changed] = held[changed] = value
                self._touch(*np.divmod(changed, grid.width))
        self._people = new
        self._any = True if len(new) else None
        return True

    def update(self, pose: Pose2D, scan: LaserScan, ignore: np.ndarray | None = None) -> bool:
        """Clear along the beams and mark the returns of ``scan`` seen from ``pose``, but
        for the beams ``ignore`` flags (their returns are not obstacles: tracked people)."""
        if not self.config.enabled:
            return False
        changed = self._clear(pose, scan)
        ranges = scan.ranges
        hit = np.isfinite(ranges) & (ranges <= self.config.max_range)
        if ignore is not None:
            hit &= ~ignore
        if hit.any():
            angles = scan.angle_min + scan.angle_increment * np.flatnonzero(hit) + pose.yaw
            r = ranges[hit].astype(float)
            ends = np.column_stack((pose.x + r * np.cos(angles), pose.y + r * np.sin(angles)))
            unmapped = self.static.clearance(ends) > self.config.map_tolerance
            if unmapped.any():
                rows, cols = self.static.grid.world_to_cell(ends[unmapped])
                inside = self.static.grid.in_bounds(rows, cols)
                rows, cols = rows[inside], cols[inside]
                if len(rows) and not self.marks[rows, cols].all():
                    self.marks[rows, cols] = True
                    self._any = True
                    self._touch(rows, cols)
                    changed = True
        return changed

    def _clear(self, pose: Pose2D, scan: LaserScan) -> bool:
        """Unmark the marked cells within reach that a beam passes through (but people's,
        which :meth:`set_people` keeps)."""
        if self._any is False:  # nothing marked: nothing to clear (no window scan)
            return False
        grid = self.static.grid
        res = grid.resolution
        reach_max = self.config.raytrace_range
        row, col = grid.world_to_cell(np.array([pose.x, pose.y]))
        k = int(np.ceil(reach_max / res)) + 1
        r0, r1 = max(int(row) - k, 0), min(int(row) + k + 1, grid.height)
        c0, c1 = max(int(col) - k, 0), min(int(col) + k + 1, grid.width)
        if r0 >= r1 or c0 >= c1:
            return False
        window = self.marks[r0:r1, c0:c1]
        if len(self._people):  # a person standing stays marked until they walk on
            window = window & ~self._held[r0:r1, c0:c1]
        rr, cc = np.nonzero(window)
        if not len(rr):
            return False
        rr += r0
        cc += c0
        d = grid.cell_to_world(rr, cc) - (pose.x, pose.y)
        dist = np.hypot(d[:, 0], d[:, 1])
        n = len(scan.ranges)
        bearing = np.mod(np.arctan2(d[:, 1], d[:, 0]) - pose.yaw - scan.angle_min, 2.0 * np.pi)
        beam = np.round(bearing / scan.angle_increment).astype(np.int64)
        full_circle = n * scan.angle_increment >= 2.0 * np.pi - 1e-6
        seen = np.ones(len(beam), dtype=bool) if full_circle else beam < n
        beam = beam % n
        ranges = scan.ranges[beam].astype(float)
        reach = np.minimum(np.where(np.isfinite(ranges), ranges, np.inf) - res, reach_max)
        clear = seen & (dist < reach)
        if not clear.any():
            return False
        self.marks[rr[clear], cc[clear]] = False
        self._any = None
        self._touch(rr[clear], cc[clear])
        return True
