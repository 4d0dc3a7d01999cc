"""``grid`` SLAM: log-odds occupancy-grid mapping with scan-to-map matching.

Like hector mapping / Cartographer's local SLAM (without loop closure): every scan after
the robot has moved is matched against the map built so far, starting from the last
corrected pose composed with the odometry motion since
(:class:`~agv_mission.mapping.scan_matching.CorrelativeMatcher`: correlative
branch and bound over +-0.2 m / +-10 deg, then a point-to-line refinement fused with the
odometry prior); the scan is then integrated into the map at the corrected pose once the
robot has moved ``update_min_d`` / ``update_min_a`` since the last integration. The true
pose is never used.

Map: log-odds per cell (``resolution`` 0.05 m). Each integration adds
``log_odds_occupied`` once to every cell holding a beam end point and ``log_odds_free``
once to every other cell a beam crosses (beams sampled every half cell; a cell hit by
one beam of a scan is not also cleared by that scan), clamped to
``[log_odds_min, log_odds_max]``. Beams without a return clear up to the max range minus
two cells when ``clear_no_return`` is set. Each cell also keeps the mean of the end
points that fell in it (the last ``hit_memory`` weigh most), its *anchor*: the matcher
measures distances to anchors, not to cell centres, which keeps sub-cell detail (a wall
face on a cell boundary is at the face, not somewhere on a two-cell plateau), and the sum
of the directions from its end points back to the scanner, the side it was seen from: the
matcher never pairs a point with a surface seen from the other side (a 10 cm wall is two
cells; seen from its second side for the first time, only the first face is mapped).

:meth:`GridSlam.occupancy_grid` gives the map in map_saver's trinary convention:
``OCCUPIED`` above ``occupied_threshold`` (probability), ``FREE`` below
``free_threshold``, ``UNKNOWN`` between. With the defaults one hit makes a cell
OCCUPIED and three pass-throughs make it FREE, so right after :meth:`GridSlam.reset`
the map has no FREE cell yet (an explorer should turn or drive before it concludes that
no frontier is left). The matcher's likelihood field (cells above
``field_threshold`` log-odds count as obstacles) and nearest-obstacle tables are kept up
to date incrementally around each integrated scan.

The map is allocated over ``bounds`` plus ``map_margin`` (or ``initial_size`` around the
start without bounds), on the lattice of multiples of ``resolution`` (so it lines up with
the built-in worlds' maps), and grows in ``grow_step`` chunks when a scan reaches past its
edge.

The pose estimate keeps a covariance (relative to the map): odometry motion adds
``odom_*_noise``, each refined match replaces it by the match's. Between scans the
estimate is the last corrected pose composed with the odometry motion since, so it moves
smoothly at the control rate (SLAM's ``map -> odom``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from time import perf_counter

import numpy as np

from agv_mission.geometry import Bounds, Pose2D
from agv_mission.mapping.configs import GridSlamConfig
from agv_mission.mapping.likelihood_field import LikelihoodField, field_values
from agv_mission.mapping.scan_matching import CorrelativeMatcher, MatchResult
from agv_mission.maps.grid import FREE, OCCUPIED, UNKNOWN, OccupancyGrid
from agv_mission.messages import LaserScan

_TINY_COV = np.diag([1e-6, 1e-6, 1e-6])


def _logit(p: float) -> float:
    return math.log(p / (1.0 - p))


class GridSlam:
    """Occupancy-grid SLAM with correlative + point-to-line scan-to-map matching."""

    Config = GridSlamConfig

    def __init__(
        self,
        config: GridSlamConfig,
        bounds: Bounds | Sequence[float] | None = None,
        rng: np.random.Generator | None = None,
    ) -> None:
        c = config
        if c.free_threshold >= c.occupied_threshold:
            raise ValueError("slam: free_threshold must be below occupied_threshold")
        if c.coarse_block & (c.coarse_block - 1):
            raise ValueError("slam: coarse_block must be a power of two")
        if bounds is not None and (
            len(bounds) != 4 or not (bounds[1] > bounds[0] and bounds[3] > bounds[2])
        ):
            raise ValueError(f"slam: bounds must be (xmin, xmax, ymin, ymax), got {bounds}")
        self.config = config
        self.bounds: Bounds | None = (
            (float(bounds[0]), float(bounds[1]), float(bounds[2]), float(bounds[3]))
            if bounds is not None
            else None
        )
        self.rng = rng  # unused: the plugin is deterministic
        self.resolution = float(c.resolution)
        self.matcher = CorrelativeMatcher(
            linear_window=c.linear_search_window,
            angular_window=c.angular_search_window,
            angular_step=c.angular_search_step,
            coarse_block=c.coarse_block,
            translation_weight=c.translation_delta_cost_weight,
            rotation_weight=c.rotation_delta_cost_weight,
            refinement=c.refinement,
            iterations=c.refine_iterations,
            point_sigma=c.point_sigma,
            scan_sigma=c.scan_sigma,
        )
        self._occ_l = _logit(c.occupied_threshold)
        self._free_l = _logit(c.free_threshold)
        #: (time, x, y, yaw) of every processed scan, in the map frame.
        self.trajectory: list[tuple[float, float, float, float]] = []
        #: Wall seconds per scan integration / per scan match (for benchmarks).
        self.integrate_times: list[float] = []
        self.match_times: list[float] = []
        #: The last match (None before the first).
        self.last_match: MatchResult | None = None
        self.integrations = 0
        self.matches = 0
        self.rejected_matches = 0
        self._pose = Pose2D(0.0, 0.0, 0.0)
        self._odom = Pose2D(0.0, 0.0, 0.0)
        self._cov = _TINY_COV.copy()
        self._last_integrated: Pose2D | None = None
        self._grid_cache: tuple[int, OccupancyGrid] | None = None
        self._allocate(None)

    # ------------------------------------------------------------------ runner API

    @property
    def pose(self) -> Pose2D:
        """The corrected pose at the last processed scan."""
        return self._pose

    @property
    def covariance(self) -> np.ndarray:
        """(3, 3) covariance of :attr:`pose` (x, y, yaw) relative to the map."""
        return self._cov.copy()

    @property
    def map_to_odom(self) -> Pose2D:
        """SLAM's ``map -> odom`` transform."""
        return self._pose.compose(Pose2D(0.0, 0.0, 0.0).relative_to(self._odom))

    @property
    def log_odds(self) -> np.ndarray:
        """The log-odds map (float32, row 0 at the lowest y); do not modify."""
        return self._logodds

    @property
    def origin(self) -> tuple[float, float]:
        """Map-frame (x, y) of the lower-left corner of cell (0, 0)."""
        return self._ox, self._oy

    def reset(self, pose: Pose2D, odom: Pose2D) -> None:
        """Start a new map with the robot at ``pose`` (map frame) and odometry ``odom``."""
        self._pose, self._odom = pose, odom
        self._cov = _TINY_COV.copy()
        self._last_integrated = None
        self.trajectory.clear()
        self.integrate_times.clear()
        self.match_times.clear()
        self.last_match = None
        self.integrations = self.matches = self.rejected_matches = 0
        self._allocate(pose)

    def update(self, odom: Pose2D, scan: LaserScan | None, truth: Pose2D, time: float) -> Pose2D:
        """Corrected pose; matches and integrates ``scan`` when due. ``truth`` is unused."""
        c = self.config
        delta = odom.relative_to(self._odom)
        predicted = self._pose.compose(delta)
        if scan is None:
            return predicted
        pose = predicted
        if self._last_integrated is not None:
            moved = math.hypot(delta.x, delta.y) >= c.match_min_d or abs(delta.yaw) >= c.match_min_a
            if not moved:
                return predicted
            pose = self._match(scan, predicted, delta)
        self._pose, self._odom = pose, odom
        last = self._last_integrated
        if last is None:
            self._integrate(scan, pose)
        else:
            since = pose.relative_to(last)
            if math.hypot(since.x, since.y) >= c.update_min_d or abs(since.yaw) >= c.update_min_a:
                self._integrate(scan, pose)
        self.trajectory.append((float(time), pose.x, pose.y, pose.yaw))
        return pose

    def diagnostics(self) -> dict[str, float]:
        return {
            "integrations": self.integrations,
            "matches": self.matches,
            "rejected_matches": self.rejected_matches,
        }

    def occupancy_grid(self) -> OccupancyGrid:
        """The current map, trinary (``FREE`` / ``OCCUPIED`` / ``UNKNOWN``). The same
        object is returned until the next integration: do not modify it."""
        if self._grid_cache is not None and self._grid_cache[0] == self.integrations:
            return self._grid_cache[1]
        data = np.full(self._logodds.shape, UNKNOWN, dtype=np.int8)
        data[self._logodds < self._free_l] = FREE
        data[self._logodds > self._occ_l] = OCCUPIED
        grid = OccupancyGrid(data, self.resolution, Pose2D(self._ox, self._oy, 0.0))
        self._grid_cache = (self.integrations, grid)
        return grid

    def likelihood_field(self) -> LikelihoodField:
        """The field scans are matched against (shares memory with the plugin)."""
        return LikelihoodField(
            self._field,
            self.resolution,
            (self._ox, self._oy),
            nearest=(self._near_r, self._near_c),
            anchor=(self._ax, self._ay),
            view=(self._vx, self._vy),
        )

    # ------------------------------------------------------------------ matching

    def _scan_points(self, scan: LaserScan) -> np.ndarray:
        """Robot-frame end points (N, 2) of the valid returns, in beam order."""
        r = scan.ranges.astype(np.float64)
        ok = np.isfinite(r) & (r >= scan.range_min) & (r <= scan.range_max)
        limit = self.config.match_max_range
        if limit is not None:
            ok &= r <= limit
        a = scan.angles[ok]
        r = r[ok]
        return np.stack([r * np.cos(a), r * np.sin(a)], axis=1)

    def _predict_cov(self, delta: Pose2D) -> np.ndarray:
        """Covariance of the prediction: the last pose's moved by the odometry ``delta``."""
        c = self.config
        d = math.hypot(delta.x, delta.y)
        st = c.odom_translation_noise * d + 1e-3
        sa = c.odom_rotation_noise * abs(delta.yaw) + c.odom_rotation_per_metre * d + 1e-3
        cy, sy = math.cos(self._pose.yaw), math.sin(self._pose.yaw)
        jx = np.array(
            [
                [1.0, 0.0, -sy * delta.x - cy * delta.y],
                [0.0, 1.0, cy * delta.x - sy * delta.y],
                [0.0, 0.0, 1.0],
            ]
        )
        ju = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
        cov = jx @ self._cov @ jx.T + ju @ np.diag([st * st, st * st, sa * sa]) @ ju.T
        # Keep it within the search window: the matcher cannot correct more anyway.
        lin, ang = c.linear_search_window, c.angular_search_window
        limit = np.array([lin, lin, ang]) ** 2 + 1e-12
        scale = np.sqrt(np.minimum(1.0, limit / np.maximum(np.diag(cov), 1e-18)))
        return cov * np.outer(scale, scale)

    def _match(self, scan: LaserScan, predicted: Pose2D, delta: Pose2D) -> Pose2D:
        c = self.config
        cov = self._predict_cov(delta)
        points = self._scan_points(scan)
        if len(points) < c.min_points:
            self.rejected_matches += 1
            self._cov = cov
            return predicted
        t0 = perf_counter()
        prior = cov if c.odom_prior else None
        result = self.matcher.match(self.likelihood_field(), points, predicted.as_array(), prior)
        self.match_times.append(perf_counter() - t0)
        self.last_match = result
        self.matches += 1
        if result.score < c.min_score:
            self.rejected_matches += 1
            self._cov = cov
            return predicted
        if result.refined and result.covariance is not None and c.odom_prior:
            self._cov = 0.5 * (result.covariance + result.covariance.T)
        else:
            self._cov = _TINY_COV.copy() if result.refined else cov
        x, y, yaw = (float(v) for v in result.pose)
        return Pose2D(x, y, yaw)

    # ------------------------------------------------------------------ mapping

    def _allocate(self, start: Pose2D | None) -> None:
        c, res = self.config, self.resolution
        if self.bounds is not None:
            xmin, xmax, ymin, ymax = self.bounds
            m = c.map_margin
            xmin, xmax, ymin, ymax = xmin - m, xmax + m, ymin - m, ymax + m
        else:
            cx, cy = (start.x, start.y) if start is not None else (0.0, 0.0)
            h = c.initial_size / 2.0
            xmin, xmax, ymin, ymax = cx - h, cx + h, cy - h, cy + h
        self._ox = math.floor(xmin / res + 1e-9) * res
        self._oy = math.floor(ymin / res + 1e-9) * res
        w = max(int(math.ceil((xmax - self._ox) / res - 1e-9)), 1)
        h = max(int(math.ceil((ymax - self._oy) / res - 1e-9)), 1)
        shape = (h, w)
        self._logodds = np.zeros(shape, np.float32)  # log-odds
        self._field = np.zeros(shape, np.float32)  # likelihood field
        self._near_r = np.full(shape, -1, np.int32)  # nearest obstacle cell (row, col)
        self._near_c = np.full(shape, -1, np.int32)
        self._hx = np.zeros(shape, np.float32)  # sums of end point offsets from the centre
        self._hy = np.zeros(shape, np.float32)
        self._hn = np.zeros(shape, np.float32)  # their (capped) count
        self._vx = np.zeros(shape, np.float32)  # sums of unit vectors end point -> sensor
        self._vy = np.zeros(shape, np.float32)
        self._ax = np.zeros(shape, np.float32)  # anchors: mean offsets
        self._ay = np.zeros(shape, np.float32)
        self._grid_cache = None

    def _ensure_contains(self, xmin: float, xmax: float, ymin: float, ymax: float) -> None:
        """Grow the map (by ``grow_step`` chunks) until it holds the given box."""
        res = self.resolution
        h, w = self._logodds.shape
        step = max(int(math.ceil(self.config.grow_step / res)), 1)
        left = right = down = up = 0
        if xmin < self._ox:
            left = step * int(math.ceil((self._ox - xmin) / res / step))
        if ymin < self._oy:
            down = step * int(math.ceil((self._oy - ymin) / res / step))
        if xmax >= self._ox + w * res:
            right = step * int(math.ceil((xmax - self._ox - w * res) / res / step + 1e-9))
        if ymax >= self._oy + h * res:
            up = step * int(math.ceil((ymax - self._oy - h * res) / res / step + 1e-9))
        if not (left or right or down or up):
            return
        pad = ((down, up), (left, right))
        for name in ("_logodds", "_field", "_hx", "_hy", "_hn", "_ax", "_ay", "_vx", "_vy"):
            setattr(self, name, np.pad(getattr(self, name), pad))
        for name, shift in (("_near_r", down), ("_near_c", left)):
            arr = getattr(self, name)
            arr[arr >= 0] += shift
            setattr(self, name, np.pad(arr, pad, constant_values=-1))
        self._ox -= left * res
        self._oy -= down * res
        self._grid_cache = None

    def _integrate(self, scan: LaserScan, pose: Pose2D) -> None:
        t0 = perf_counter()
        c, res = self.config, self.resolution
        r = scan.ranges.astype(np.float64)
        max_range = min(scan.range_max, c.max_range) if c.max_range else scan.range_max
        finite = np.isfinite(r)
        hit = finite & (r >= scan.range_min) & (r <= max_range)
        clear = max(max_range - 2.0 * res, 0.0) if c.clear_no_return else 0.0
        length = np.where(hit, r, np.where(finite & (r > max_range), max_range, clear))
        keep = length > 0.0
        if not keep.any():
            self._last_integrated = pose
            return
        a = scan.angles[keep] + pose.yaw
        length, hit = length[keep], hit[keep]
        ca, sa = np.cos(a), np.sin(a)
        ex, ey = pose.x + length * ca, pose.y + length * sa
        self._ensure_contains(
            min(ex.min(), pose.x),
            max(ex.max(), pose.x),
            min(ey.min(), pose.y),
            max(ey.max(), pose.y),
        )
        ox, oy = self._ox, self._oy

        # The window of the map this scan touches.
        cols_e = np.floor((ex - ox) / res).astype(np.int64)
        rows_e = np.floor((ey - oy) / res).astype(np.int64)
        pr, pc = int(math.floor((pose.y - oy) / res)), int(math.floor((pose.x - ox) / res))
        r0, r1 = min(int(rows_e.min()), pr), max(int(rows_e.max()), pr) + 1
        c0, c1 = min(int(cols_e.min()), pc), max(int(cols_e.max()), pc) + 1
        wh, ww = r1 - r0, c1 - c0
        n = wh * ww

        # Free cells: every half cell along each beam, short of its end point.
        step = 0.5 * res
        t = np.arange(int(math.ceil(length.max() / step)) + 1) * step
        along = t[None, :] < length[:, None]
        fc = np.floor(((pose.x - ox) + ca[:, None] * t[None, :])[along] / res).astype(np.int64)
        fr = np.floor(((pose.y - oy) + sa[:, None] * t[None, :])[along] / res).astype(np.int64)
        np.clip(fc - c0, 0, ww - 1, out=fc)
        np.clip(fr - r0, 0, wh - 1, out=fr)
        free = np.zeros(n, bool)
        free[fr * ww + fc] = True
        occ = np.zeros(n, bool)
        hit_idx = (rows_e[hit] - r0) * ww + (cols_e[hit] - c0)
        occ[hit_idx] = True
        free &= ~occ

        window = self._logodds[r0:r1, c0:c1]
        update = np.where(occ, np.float32(c.log_odds_occupied), np.float32(0.0))
        update[free] = c.log_odds_free
        window += update.reshape(wh, ww)
        np.clip(window, c.log_odds_min, c.log_odds_max, out=window)

        if len(hit_idx):
            # Anchors: running means of where the end points fell in their cells.
            offx = ex[hit] - (ox + (cols_e[hit] + 0.5) * res)
            offy = ey[hit] - (oy + (rows_e[hit] + 0.5) * res)
            hx, hy = self._hx[r0:r1, c0:c1], self._hy[r0:r1, c0:c1]
            hn = self._hn[r0:r1, c0:c1]
            hx += np.bincount(hit_idx, offx, n).reshape(wh, ww).astype(np.float32)
            hy += np.bincount(hit_idx, offy, n).reshape(wh, ww).astype(np.float32)
            hn += np.bincount(hit_idx, None, n).reshape(wh, ww).astype(np.float32)
            # Which side the cell was seen from (a thin wall has two faces).
            vx, vy = self._vx[r0:r1, c0:c1], self._vy[r0:r1, c0:c1]
            vx -= np.bincount(hit_idx, ca[hit], n).reshape(wh, ww).astype(np.float32)
            vy -= np.bincount(hit_idx, sa[hit], n).reshape(wh, ww).astype(np.float32)
            over = hn > c.hit_memory
            if over.any():
                scale = c.hit_memory / hn[over]
                hx[over] *= scale
                hy[over] *= scale
                vx[over] *= scale
                vy[over] *= scale
                hn[over] = c.hit_memory
            seen = hn > 0
            self._ax[r0:r1, c0:c1][seen] = hx[seen] / hn[seen]
            self._ay[r0:r1, c0:c1][seen] = hy[seen] / hn[seen]

        self._refresh_field(r0, r1, c0, c1)
        self._last_integrated = pose
        self.integrations += 1
        self.integrate_times.append(perf_counter() - t0)

    def _refresh_field(self, r0: int, r1: int, c0: int, c1: int) -> None:
        """Recompute the field and nearest-obstacle tables where cells [r0:r1, c0:c1] may
        change them."""
        c, res = self.config, self.resolution
        m = int(math.ceil(4.0 * c.likelihood_sigma / res)) + 1
        h, w = self._logodds.shape
        # Cells within m of the change are rewritten; they need obstacles within m of them.
        ar0, ar1 = max(r0 - m, 0), min(r1 + m, h)
        ac0, ac1 = max(c0 - m, 0), min(c1 + m, w)
        br0, br1 = max(r0 - 2 * m, 0), min(r1 + 2 * m, h)
        bc0, bc1 = max(c0 - 2 * m, 0), min(c1 + 2 * m, w)
        occupied = self._logodds[br0:br1, bc0:bc1] > c.field_threshold
        anchor = (self._ax[br0:br1, bc0:bc1], self._ay[br0:br1, bc0:bc1])
        values, (nr, nc) = field_values(
            occupied, res, c.likelihood_sigma, anchor, return_nearest=True
        )
        inner = (slice(ar0 - br0, ar1 - br0), slice(ac0 - bc0, ac1 - bc0))
        self._field[ar0:ar1, ac0:ac1] = values[inner]
        nr, nc = nr[inner], nc[inner]
        valid = nr >= 0
        self._near_r[ar0:ar1, ac0:ac1] = np.where(valid, nr + br0, -1)
        self._near_c[ar0:ar1, ac0:ac1] = np.where(valid, nc + bc0, -1)


def trajectory_rmse(estimates: np.ndarray, truths: np.ndarray) -> float:
    """Absolute trajectory error: RMSE of the position differences (rows of x, y, ...)."""
    e = np.asarray(estimates, dtype=float)
    t = np.asarray(truths, dtype=float)
    if len(e) == 0:
        return 0.0
    d = e[:, :2] - t[:, :2]
    return float(np.sqrt(np.mean(np.sum(d * d, axis=1))))
