"""The map ``grid`` SLAM builds: log-odds occupancy with anchors, the side each cell was
seen from, and the matcher's likelihood field, all kept up to date per integrated scan.

Each integration adds ``log_odds_occupied`` once to every cell holding a beam end point
and ``log_odds_free`` once to every other cell a beam crosses (beams sampled every half
cell; a cell hit by one beam of a scan is not also cleared by that scan), clamped to
``[log_odds_min, log_odds_max]``. Beams without a return (+inf) clear only
``missing_data_ray_length`` (Cartographer's name and 5 m default; gmapping's ``maxUrange``
plays the same part): "nothing within range" is no evidence that all of it is free: an
open door or window would clear a starburst of free space outside the building. With
``free_max_hits`` a cell that held more end points than that is never FREE, however
often beams crossed it afterwards. Each
cell also keeps the mean of the end points that fell in it (the last ``hit_memory`` weigh most), its *anchor*, and the sum of
the directions from its end points back to the scanner, the side it was seen from (see
:mod:`slam`). The likelihood field (cells above ``field_threshold`` log-odds count as
obstacles) and the nearest-obstacle tables are refreshed around each integrated scan.

The map is allocated over ``bounds`` plus ``map_margin`` (or ``initial_size`` around the
start without bounds), on the lattice of multiples of ``resolution`` (so it lines up with
the built-in worlds' maps), and grows in ``grow_step`` chunks when a scan reaches past its
edge.
"""

from __future__ import annotations

import math

import numpy as np

from agv_mission.geometry import Bounds, Pose2D
from agv_mission.mapping.configs import GridSlamConfig
from agv_mission.mapping.likelihood_field import LikelihoodField, field_values
from agv_mission.maps.grid import FREE, MAX_GRID_CELLS, OCCUPIED, UNKNOWN, OccupancyGrid
from agv_mission.sensor_msgs import LaserScan

#: Side (cells) of the tiles the field is refreshed in after a scan.
REFRESH_TILE = 64
#: An anchor that moved less than this (cells) since the field was built around it does
#: not refresh the field.
ANCHOR_REFRESH = 0.1


def _floor_cells(
    direction: np.ndarray, t: np.ndarray, start: float, res: float, size: int
) -> np.ndarray:
    """``clip(floor((start + direction t) / res), 0, size - 1)`` as int64, computed in
    ``direction``'s memory (the same arithmetic, without a temporary per operation)."""
    direction *= t
    direction += start
    direction /= res
    np.floor(direction, out=direction)
    cells = direction.astype(np.int64)
    np.clip(cells, 0, size - 1, out=cells)
    return cells


def _unique(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``np.unique(values, return_inverse=True)`` of a 1-D int array by the same stable
    sort, without the generic function's overhead (several times the work on a scan's
    few hundred end points)."""
    order = np.argsort(values, kind="stable")
    ordered = values[order]
    first = np.empty(len(values), bool)
    first[:1] = True
    np.not_equal(ordered[1:], ordered[:-1], out=first[1:])
    inverse = np.empty(len(values), np.intp)
    inverse[order] = np.cumsum(first) - 1
    return ordered[first], inverse


def _logit(p: float) -> float:
    return math.log(p / (1.0 - p))


class MapTooLarge(ValueError):
    """A scan reaches so far from the map (a pose or a range kilometres off) that holding
    it would take more than :data:`MAX_GRID_CELLS` cells."""


class LogOddsMap:
    """A growable log-odds grid with per-cell anchors and view sides, and the likelihood
    field and nearest-obstacle tables scans are matched against."""

    def __init__(self, config: GridSlamConfig, bounds: Bounds | None, start: Pose2D | None) -> None:
        """An empty map over ``bounds`` (plus ``map_margin``), or ``initial_size`` around
        ``start`` (the origin when None) without bounds."""
        self.config = config
        self.resolution = res = float(config.resolution)
        c = config
        if bounds is not None:
            xmin, xmax, ymin, ymax = bounds
            m = c.map_margin
            xmin, xmax, ymin, ymax = xmin - m, xmax + m, ymin - m, ymax + m
        else:
            cx, cy = (start.x, start.y) if start is not None else (0.0, 0.0)
            h = c.initial_size / 2.0
            xmin, xmax, ymin, ymax = cx - h, cx + h, cy - h, cy + h
        self.ox = math.floor(xmin / res + 1e-9) * res
        self.oy = math.floor(ymin / res + 1e-9) * res
        w = max(int(math.ceil((xmax - self.ox) / res - 1e-9)), 1)
        h = max(int(math.ceil((ymax - self.oy) / res - 1e-9)), 1)
        if h * w > MAX_GRID_CELLS:
            raise MapTooLarge(
                f"a first map of {w * res:.4g} x {h * res:.4g} m is more than "
                f"{MAX_GRID_CELLS:.0e} cells of {res:g} m"
            )
        shape = (h, w)
        self.logodds = np.zeros(shape, np.float32)  # log-odds
        self.field = np.zeros(shape, np.float32)  # likelihood field
        self.near_r = np.full(shape, -1, np.int32)  # nearest obstacle cell (row, col)
        self.near_c = np.full(shape, -1, np.int32)
        self.hx = np.zeros(shape, np.float32)  # sums of end point offsets from the centre
        self.hy = np.zeros(shape, np.float32)
        self.hn = np.zeros(shape, np.float32)  # their (capped) count
        self.vx = np.zeros(shape, np.float32)  # sums of unit vectors end point -> sensor
        self.vy = np.zeros(shape, np.float32)
        self.ax = np.zeros(shape, np.float32)  # anchors: mean offsets
        self.ay = np.zeros(shape, np.float32)
        self.fax = np.zeros(shape, np.float32)  # the anchors the field was last built with
        self.fay = np.zeros(shape, np.float32)
        self._mark = np.zeros(0, bool)  # integrate's scratch: cells hit by the scan
        self._occ_l = _logit(c.occupied_threshold)
        self._free_l = _logit(c.free_threshold)

    def occupancy_grid(self) -> OccupancyGrid:
        """The map in map_saver's trinary convention (a new grid every call)."""
        data = np.full(self.logodds.shape, UNKNOWN, dtype=np.int8)
        free = self.logodds < self._free_l
        if self.config.free_max_hits is not None:
            # hn counts end points up to hit_memory, so small counts are exact.
            free &= self.hn < self.config.free_max_hits + 1
        data[free] = FREE
        occupied = self.logodds > self._occ_l
        if self.config.occupied_min_hits > 1:
            occupied &= self.hn >= self.config.occupied_min_hits - 1e-3
        data[occupied] = OCCUPIED
        if self.config.wall_faces:
            # free_max_hits keeps a cell that held end points from being FREE: UNKNOWN then.
            proud = self._in_front_of_face(occupied, occupied)
            data[proud] = FREE if self.config.free_max_hits is None else UNKNOWN
            if self.config.free_max_hits is None:
                # The same scatter where the log-odds left the cell undecided (its hits and
                # the beams through it to the face about even): in front of the face too.
                undecided = (data == UNKNOWN) & (self.hn > 0)
                data[self._in_front_of_face(undecided, occupied)] = FREE
        return OccupancyGrid(data, self.resolution, Pose2D(self.ox, self.oy, 0.0))

    def _in_front_of_face(self, cells: np.ndarray, occupied: np.ndarray) -> np.ndarray:
        """Those of ``cells`` that stand in front of a wall's face: a face on the boundary
        of two cells scatters the end points into both (the lidar's noise), and both
        become OCCUPIED (or the nearer one undecided), which draws the wall up to a cell in
        front of its face (a localiser matching scans to that map is pushed off every wall
        it sees by as much). Such a cell was seen from one side, the mean of its end points
        (its anchor) lies beyond its centre as seen from the scanner, and the cell behind
        it (along the view) is OCCUPIED: the face is on their boundary, and the map draws
        it there."""
        vx, vy, hn = self.vx, self.vy, self.hn
        norm = np.hypot(vx, vy)
        one_side = norm > 0.5 * hn  # a thin wall seen from both sides cancels out
        # The anchor's offset away from the scanner (v points from the end points to it).
        beyond = (self.ax * vx + self.ay * vy) < 0.0
        candidate = cells & one_side & beyond
        rows, cols = np.nonzero(candidate)
        if not len(rows):
            return candidate
        along_x = np.abs(vx[rows, cols]) >= np.abs(vy[rows, cols])
        br = rows + np.where(along_x, 0, -np.sign(vy[rows, cols])).astype(np.int64)
        bc = cols + np.where(along_x, -np.sign(vx[rows, cols]), 0).astype(np.int64)
        h, w = occupied.shape
        inside = (br >= 0) & (br < h) & (bc >= 0) & (bc < w)
        behind = np.zeros(len(rows), bool)
        behind[inside] = occupied[br[inside], bc[inside]]
        proud = np.zeros_like(occupied)
        proud[rows[behind], cols[behind]] = True
        return proud

    def likelihood_field(self) -> LikelihoodField:
        """The field scans are matched against (shares memory with the map)."""
        return LikelihoodField(
            self.field,
            self.resolution,
            (self.ox, self.oy),
            nearest=(self.near_r, self.near_c),
            anchor=(self.ax, self.ay),
            view=(self.vx, self.vy),
        )

    def ensure_contains(self, xmin: float, xmax: float, ymin: float, ymax: float) -> None:
        """Grow the map (by ``grow_step`` chunks) until it holds the given box."""
        res = self.resolution
        h, w = self.logodds.shape
        step = max(int(math.ceil(self.config.grow_step / res)), 1)
        left = right = down = up = 0
        if xmin < self.ox:
            left = step * int(math.ceil((self.ox - xmin) / res / step))
        if ymin < self.oy:
            down = step * int(math.ceil((self.oy - ymin) / res / step))
        if xmax >= self.ox + w * res:
            right = step * int(math.ceil((xmax - self.ox - w * res) / res / step + 1e-9))
        if ymax >= self.oy + h * res:
            up = step * int(math.ceil((ymax - self.oy - h * res) / res / step + 1e-9))
        if not (left or right or down or up):
            return
        rows, cols = h + down + up, w + left + right
        if rows * cols > MAX_GRID_CELLS:
            raise MapTooLarge(
                f"the map would span {cols * res:.4g} x {rows * res:.4g} m "
                f"({rows * cols:.3g} cells of {res:g} m; at most {MAX_GRID_CELLS:.0e})"
            )
        pad = ((down, up), (left, right))
        for name in ("logodds", "field", "hx", "hy", "hn", "ax", "ay", "fax", "fay", "vx", "vy"):
            setattr(self, name, np.pad(getattr(self, name), pad))
        for name, shift in (("near_r", down), ("near_c", left)):
            arr = getattr(self, name)
            arr[arr >= 0] += shift
            setattr(self, name, np.pad(arr, pad, constant_values=-1))
        self.ox -= left * res
        self.oy -= down * res

    def integrate(self, scan: LaserScan, pose: Pose2D, refresh: bool = True) -> bool:
        """Add ``scan`` seen from ``pose``; False when no beam had anything to add. Without
        ``refresh`` the likelihood field is left stale (a rebuild refreshes it once, with
        :meth:`refresh_all`, after all its scans)."""
        c, res = self.config, self.resolution
        beams = self._beams(scan, pose)
        if beams is None:
            return False
        length, hit, ca, sa, ex, ey = beams
        self.ensure_contains(*_box(ex, ey, pose))
        ox, oy = self.ox, self.oy
        h, w = self.logodds.shape
        cols_e = np.floor((ex - ox) / res).astype(np.int64)
        rows_e = np.floor((ey - oy) / res).astype(np.int64)

        # Free cells: every half cell along each beam, short of its end point; only the
        # samples each beam needs (a few long beams do not inflate the short ones). The
        # arithmetic in place: these arrays hold every sample of the scan.
        step = 0.5 * res
        counts = np.ceil(length / step).astype(np.int64)
        first = np.cumsum(counts) - counts
        t = (np.arange(int(counts.sum())) - np.repeat(first, counts)) * step
        fc = _floor_cells(np.repeat(ca, counts), t, pose.x - ox, res, w)
        free_idx = _floor_cells(np.repeat(sa, counts), t, pose.y - oy, res, h)
        free_idx *= w
        free_idx += fc
        hit_idx = rows_e[hit] * w + cols_e[hit]
        # A cell hit by this scan is not also cleared by it (a scratch mask of the map's
        # size, cleared after use: allocating it per scan cost more than using it). A
        # beam's consecutive samples in one cell are one update (about half of them).
        if self._mark.size != h * w:
            self._mark = np.zeros(h * w, bool)
        mark = self._mark
        mark[hit_idx] = True
        fresh = ~mark[free_idx]
        fresh[1:] &= free_idx[1:] != free_idx[:-1]
        free_idx = free_idx[fresh]
        mark[hit_idx] = False

        # Each touched cell once: the values are read once, updated and written back, and
        # a cell listed twice (a free cell crossed by two beams) gets the same value
        # twice; free and hit cells are disjoint.
        flat = self.logodds.reshape(-1)
        threshold = c.field_threshold
        touched = np.concatenate([free_idx, hit_idx])
        values = flat[touched]
        was = values > threshold
        values[: len(free_idx)] += np.float32(c.log_odds_free)
        values[len(free_idx) :] += np.float32(c.log_odds_occupied)
        np.clip(values, c.log_odds_min, c.log_odds_max, out=values)
        flat[touched] = values
        changed = [touched[was != (values > threshold)]]

        if len(hit_idx):
            changed.append(
                self._update_anchors(
                    hit_idx, cols_e[hit], rows_e[hit], ex[hit], ey[hit], ca[hit], sa[hit], refresh
                )
            )

        if refresh:
            self._refresh_cells(np.concatenate(changed))
        return True

    def _beams(self, scan: LaserScan, pose: Pose2D) -> tuple[np.ndarray, ...] | None:
        """The beams of ``scan`` from ``pose`` that add something: ``length, hit, cos,
        sin, end x, end y`` (None when there are none). A return within range is a hit;
        one past ``max_range`` clears up to it; +inf ("no return") clears
        ``missing_data_ray_length``; nan (an invalid reading) clears nothing."""
        c, res = self.config, self.resolution
        r = scan.ranges.astype(np.float64)
        max_range = min(scan.range_max, c.max_range) if c.max_range else scan.range_max
        finite = np.isfinite(r)
        hit = finite & (r >= scan.range_min) & (r <= max_range)
        clear = min(c.missing_data_ray_length, max(max_range - 2.0 * res, 0.0))
        no_return = np.where(np.isposinf(r), clear, 0.0)
        length = np.where(hit, r, np.where(finite & (r > max_range), max_range, no_return))
        keep = length > 0.0
        if not keep.any():
            return None
        a = scan.angles[keep] + pose.yaw
        length, hit = length[keep], hit[keep]
        ca, sa = np.cos(a), np.sin(a)
        return length, hit, ca, sa, pose.x + length * ca, pose.y + length * sa

    def reserve(self, scans: list[LaserScan], poses: list[Pose2D]) -> None:
        """Grow the map once to hold every beam of ``scans`` seen from ``poses``: a map
        rendered again from many scans would otherwise grow (and copy its tables) chunk
        by chunk as they reach past its edge."""
        boxes = [
            _box(b[4], b[5], pose)
            for scan, pose in zip(scans, poses, strict=True)
            if (b := self._beams(scan, pose)) is not None
        ]
        if boxes:
            lo = np.min(boxes, axis=0)
            hi = np.max(boxes, axis=0)
            self.ensure_contains(float(lo[0]), float(hi[1]), float(lo[2]), float(hi[3]))

    def _update_anchors(
        self,
        hit_idx: np.ndarray,
        cols: np.ndarray,
        rows: np.ndarray,
        ex: np.ndarray,
        ey: np.ndarray,
        ca: np.ndarray,
        sa: np.ndarray,
        refresh: bool,
    ) -> np.ndarray:
        """Anchors: running means of where the end points (``ex``, ``ey``, in the cells
        ``hit_idx`` at ``cols``, ``rows``, along beams of direction (``ca``, ``sa``)) fell in their cells, and
        which side each cell was seen from; the cells whose anchor moved enough to refresh
        their likelihood field."""
        c, res, ox, oy = self.config, self.resolution, self.ox, self.oy
        cells, inverse = _unique(hit_idx)
        offx = ex - (ox + (cols + 0.5) * res)
        offy = ey - (oy + (rows + 0.5) * res)
        k = len(cells)
        hx, hy, hn = (a.reshape(-1) for a in (self.hx, self.hy, self.hn))
        vx, vy = self.vx.reshape(-1), self.vy.reshape(-1)
        ax, ay = self.ax.reshape(-1), self.ay.reshape(-1)
        sx = hx[cells] + np.bincount(inverse, offx, k).astype(np.float32)
        sy = hy[cells] + np.bincount(inverse, offy, k).astype(np.float32)
        sn = hn[cells] + np.bincount(inverse, None, k).astype(np.float32)
        # Which side the cell was seen from (a thin wall has two faces).
        svx = vx[cells] - np.bincount(inverse, ca, k).astype(np.float32)
        svy = vy[cells] - np.bincount(inverse, sa, k).astype(np.float32)
        scale = np.where(sn > c.hit_memory, c.hit_memory / sn, 1.0).astype(np.float32)
        hx[cells], hy[cells], hn[cells] = sx * scale, sy * scale, sn * scale
        vx[cells], vy[cells] = svx * scale, svy * scale
        nax, nay = sx / sn, sy / sn
        fax, fay = self.fax.reshape(-1), self.fay.reshape(-1)
        moved = cells[np.hypot(nax - fax[cells], nay - fay[cells]) > ANCHOR_REFRESH * res]
        ax[cells], ay[cells] = nax, nay
        if refresh:
            fax[moved], fay[moved] = ax[moved], ay[moved]
        return moved

    def refresh_all(self) -> None:
        """Recompute the whole likelihood field and nearest-obstacle tables."""
        h, w = self.logodds.shape
        self.refresh_field(0, h, 0, w)
        self.fax[:], self.fay[:] = self.ax, self.ay

    def _refresh_cells(self, cells: np.ndarray) -> None:
        """Refresh the field around flat cell indices ``cells`` (whose obstacle status or
        anchor changed), tile by tile over each tile's box of changes, so that a scan of
        walls already mapped costs little."""
        if not len(cells):
            return
        w = self.logodds.shape[1]
        rows, cols = np.divmod(cells, w)
        key = (rows // REFRESH_TILE) * (w // REFRESH_TILE + 1) + cols // REFRESH_TILE
        order = np.argsort(key, kind="stable")
        key, rows, cols = key[order], rows[order], cols[order]
        starts = np.flatnonzero(np.r_[True, key[1:] != key[:-1]])
        r0s, r1s = np.minimum.reduceat(rows, starts), np.maximum.reduceat(rows, starts)
        c0s, c1s = np.minimum.reduceat(cols, starts), np.maximum.reduceat(cols, starts)
        for r0, r1, c0, c1 in zip(r0s, r1s, c0s, c1s, strict=True):
            self.refresh_field(int(r0), int(r1) + 1, int(c0), int(c1) + 1)

    def refresh_field(self, r0: int, r1: int, c0: int, c1: int) -> None:
        """Recompute the field and nearest-obstacle tables where cells [r0:r1, c0:c1] may
        change them."""
        c, res = self.config, self.resolution
        m = int(math.ceil(4.0 * c.likelihood_sigma / res)) + 1
        h, w = self.logodds.shape
        # Cells within m of the change are rewritten; they need obstacles within m of them.
        ar0, ar1 = max(r0 - m, 0), min(r1 + m, h)
        ac0, ac1 = max(c0 - m, 0), min(c1 + m, w)
        br0, br1 = max(r0 - 2 * m, 0), min(r1 + 2 * m, h)
        bc0, bc1 = max(c0 - 2 * m, 0), min(c1 + 2 * m, w)
        occupied = self.logodds[br0:br1, bc0:bc1] > c.field_threshold
        anchor = (self.ax[br0:br1, bc0:bc1], self.ay[br0:br1, bc0:bc1])
        values, (nr, nc) = field_values(
            occupied, res, c.likelihood_sigma, anchor, return_nearest=True
        )
        inner = (slice(ar0 - br0, ar1 - br0), slice(ac0 - bc0, ac1 - bc0))
        self.field[ar0:ar1, ac0:ac1] = values[inner]
        # To map indices in place (field_values' fresh arrays): -1 (none) stays.
        nr, nc = nr[inner], nc[inner]
        valid = nr >= 0
        np.add(nr, br0, out=nr, where=valid)
        np.add(nc, bc0, out=nc, where=valid)
        self.near_r[ar0:ar1, ac0:ac1] = nr
        self.near_c[ar0:ar1, ac0:ac1] = nc


def _box(ex: np.ndarray, ey: np.ndarray, pose: Pose2D) -> tuple[float, float, float, float]:
    """``xmin, xmax, ymin, ymax`` of the beam ends ``ex``, ``ey`` and the scanner at ``pose``."""
    return (
        min(ex.min(), pose.x),
        max(ex.max(), pose.x),
        min(ey.min(), pose.y),
        max(ey.max(), pose.y),
    )
