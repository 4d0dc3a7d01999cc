"""``grid`` SLAM: log-odds occupancy-grid mapping with scan-to-map matching.

Like hector mapping / Cartographer's local SLAM (without loop closure): every scan after
the robot has moved is matched against the map built so far, starting from the last
corrected pose composed with the odometry motion since
(:class:`~agv_mission.mapping.scan_matching.CorrelativeMatcher`: correlative
branch and bound over +-0.2 m / +-10 deg, then a point-to-line refinement fused with the
odometry prior); the scan is then integrated into the map at the corrected pose once the
robot has moved ``update_min_d`` / ``update_min_a`` since the last integration. The true
pose is never used.

Map (:class:`~agv_mission.mapping.log_odds_map.LogOddsMap`): log-odds per cell
(``resolution`` 0.05 m), updated once per integrated scan for every cell a beam ends in
(occupied) or crosses (free). Each cell also keeps the mean of the end points that fell
in it, its *anchor*: the matcher
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
to date incrementally around each integrated scan. The map grows when a scan reaches
past its edge.

The pose estimate keeps a covariance (relative to the map): odometry motion adds
``odom_*_noise``, each refined match replaces it by the match's, and one the refinement
could not refine by the correlative optimum's fusion with the prediction (see
:mod:`scan_matching`). A scan of fewer than ``min_points`` returns is not matched: the
odometry alone moves the estimate. Between scans the
estimate is the last corrected pose composed with the odometry motion since, so it moves
smoothly at the control rate (SLAM's ``map -> odom``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from time import perf_counter

import numpy as np

from agv_mission.geometry import Bounds, Pose2D, wrap_angle
from agv_mission.mapping.base import Slam
from agv_mission.mapping.configs import GridSlamConfig
from agv_mission.mapping.likelihood_field import LikelihoodField
from agv_mission.mapping.log_odds_map import LogOddsMap
from agv_mission.mapping.scan_matching import CorrelativeMatcher, MatchResult
from agv_mission.maps.grid import OccupancyGrid
from agv_mission.sensor_msgs import LaserScan

_TINY_COV = np.diag([1e-6, 1e-6, 1e-6])


class GridSlam(Slam):
    """Occupancy-grid SLAM with correlative + point-to-line scan-to-map matching.

    It keeps no scans, only its grid: :meth:`~agv_mission.mapping.base.Slam.reframe`
    is the protocol's (the map stays in the frame it started in)."""

    Config = GridSlamConfig

    def __init__(
        self,
        config: GridSlamConfig,
        bounds: Bounds | Sequence[float] | None = None,
        rng: np.random.Generator | None = None,
    ) -> None:
        c = config
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
            search_max_range=c.search_max_range,
            fast_score=c.fast_match_score,
            fast_turn=c.fast_match_turn,
        )
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
        self.gated_matches = 0  # of the rejected: too far from the odometry prediction
        self._pose = Pose2D(0.0, 0.0, 0.0)
        self._odom = Pose2D(0.0, 0.0, 0.0)
        #: The odometry's distances times this are the robot's (``odom_scale_std``).
        self.odom_scale = 1.0
        self._scale_info = self._scale_sum = 0.0
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
        return self.map.logodds

    @property
    def origin(self) -> tuple[float, float]:
        """Map-frame (x, y) of the lower-left corner of cell (0, 0)."""
        return self.map.ox, self.map.oy

    def reset(self, pose: Pose2D, odom: Pose2D) -> None:
        """Start a new map with the robot at ``pose`` (map frame) and odometry ``odom``."""
        self._pose, self._odom = pose, odom
        self._cov = _TINY_COV.copy()
        self._last_integrated = None
        self.trajectory.clear()
        self.integrate_times.clear()
        self.match_times.clear()
        self.last_match = None
        self.integrations = self.matches = self.rejected_matches = self.gated_matches = 0
        self.odom_scale = 1.0
        self._scale_info = self._scale_sum = 0.0
        self._allocate(pose)

    def update(self, odom: Pose2D, scan: LaserScan | None, truth: Pose2D, time: float) -> Pose2D:
        """Corrected pose; matches and integrates ``scan`` when due. ``truth`` is unused."""
        c = self.config
        raw = odom.relative_to(self._odom)
        delta = Pose2D(raw.x * self.odom_scale, raw.y * self.odom_scale, raw.yaw)
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
            "gated_matches": self.gated_matches,
        }

    def occupancy_grid(self) -> OccupancyGrid:
        """The current map, trinary (``FREE`` / ``OCCUPIED`` / ``UNKNOWN``). The same
        object is returned until the next integration: do not modify it."""
        if self._grid_cache is not None and self._grid_cache[0] == self.integrations:
            return self._grid_cache[1]
        grid = self.map.occupancy_grid()
        self._grid_cache = (self.integrations, grid)
        return grid

    def likelihood_field(self) -> LikelihoodField:
        """The field scans are matched against (shares memory with the plugin)."""
        return self.map.likelihood_field()

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
        sa = (
            c.odom_rotation_noise * abs(delta.yaw)
            + c.odom_rotation_per_metre * d
            + c.odom_rotation_floor
        )
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
        if result.score < c.min_score or self._disagrees(result, predicted, cov):
            self.rejected_matches += 1
            self._cov = cov
            return predicted
        if result.covariance is not None and c.odom_prior:
            # the refinement's, or the correlative optimum fused with the prediction
            self._cov = 0.5 * (result.covariance + result.covariance.T)
            self._calibrate(delta, result.pose, cov, self._cov)
        else:
            self._cov = _TINY_COV.copy() if result.refined else cov
        x, y, yaw = (float(v) for v in result.pose)
        return Pose2D(x, y, yaw)

    def _calibrate(
        self, delta: Pose2D, matched: np.ndarray, prior: np.ndarray, post: np.ndarray
    ) -> None:
        """Learn the odometry's scale from a match (``odom_scale_std``): the distance the
        match moved along the odometry's motion ``delta`` (scaled), weighed by what the
        scan added to the prior's information in that direction (nothing in a corridor,
        where the match only repeats the odometry; much in a room). A wheel's radius
        off by 1 % makes a 50 m corridor 0.5 m long, and loop closures cannot see it."""
        std = self.config.odom_scale_std
        d = math.hypot(delta.x, delta.y)
        if std is None or d < 0.05:
            return
        c, s = math.cos(self._pose.yaw), math.sin(self._pose.yaw)
        u = np.array([c * delta.x - s * delta.y, s * delta.x + c * delta.y]) / d
        moved = float(u @ (matched[:2] - np.array([self._pose.x, self._pose.y])))
        try:
            info = 1.0 / float(u @ post[:2, :2] @ u)
            gain = info - 1.0 / float(u @ prior[:2, :2] @ u)
        except ZeroDivisionError:
            return
        if gain <= 1.0:
            return
        # The match fused the prediction: the scan's own distance, undoing that pull.
        seen = d + (info / gain) * (moved - d)
        gain = min(gain, 1.0 / 0.02**2)  # no match is better than 2 cm
        raw = d / self.odom_scale
        self._scale_info += gain * raw * raw
        self._scale_sum += gain * raw * seen
        k = (std**-2 + self._scale_sum) / (std**-2 + self._scale_info)
        self.odom_scale = float(np.clip(k, 1.0 - 5.0 * std, 1.0 + 5.0 * std))

    def _disagrees(self, result: MatchResult, predicted: Pose2D, cov: np.ndarray) -> bool:
        """Whether the match lies outside ``match_gate`` of the odometry prediction (its
        covariance ``cov`` plus the match's own): a wrong optimum of the search (a
        doorway taken for another, a wall seen through a gap), not a correction."""
        gate = self.config.match_gate
        if gate is None:
            return False
        e = result.pose - predicted.as_array()
        e[2] = wrap_angle(float(e[2]))
        total = cov + (result.covariance if result.covariance is not None else 0.0)
        try:
            d2 = float(e @ np.linalg.solve(total, e))
        except np.linalg.LinAlgError:
            return False
        if d2 <= gate:
            return False
        self.gated_matches += 1
        return True

    # ------------------------------------------------------------------ mapping

    def _allocate(self, start: Pose2D | None) -> None:
        """A new, empty map (see :class:`LogOddsMap`)."""
        self.map = LogOddsMap(self.config, self.bounds, start)
        self._grid_cache = None

    def _integrate(self, scan: LaserScan, pose: Pose2D, refresh: bool = True) -> None:
        t0 = perf_counter()
        if self.map.integrate(scan, pose, refresh):
            self.integrations += 1
            self.integrate_times.append(perf_counter() - t0)
        self._last_integrated = pose


def trajectory_rmse(estimates: np.ndarray, truths: np.ndarray) -> float:
    """Absolute trajectory error: RMSE of the position differences (rows of x, y, ...)."""
    e = np.asarray(estimates, dtype=float)
    t = np.asarray(truths, dtype=float)
    if len(e) == 0:
        return 0.0
    d = e[:, :2] - t[:, :2]
    return float(np.sqrt(np.mean(np.sum(d * d, axis=1))))
