"""``amcl``: adaptive Monte Carlo localisation on the mission's map, like ROS amcl.

The filter (:mod:`agv_mission.localization.particle_filter`) runs on a scan only after
``update_min_d`` metres or ``update_min_a`` radians of odometry motion since its last
update (and once on the first scan). Between updates the estimate is the last filter pose
composed with the odometry motion since then, i.e. amcl's ``map -> odom`` transform
applied to the current odometry, so it moves smoothly at the control rate.

The default ``profile: accurate`` adds scan-to-map refinement
(:mod:`agv_mission.localization.pose_tracker`): every scan corrects a Kalman pose estimate
against the map's signed distance field, the estimate and its covariance come from that,
and the particle cloud is moved onto it at each filter update; the filter stays the
fallback (and the start) when scans stop fitting. While the refinement tracks, the filter
runs coarse (``refine_filter_particles`` 500 particles, amcl's ``min_particles``, instead of
the KLD count, and ``refine_filter_beams`` 30 beams, amcl's default ``laser_max_beams``):
its cloud is moved onto the tracked pose at every update anyway, so the KLD count measured
the spread the filter's own noise kept up (~1000 particles), not the pose's uncertainty;
it is full again from the first update after the refinement lets go. Measured on the demo
patrol (benchmarks/bench_breakdown.py): localisation 0.4x the cost per simulated second of
the filter at the KLD count and 180 beams with the refinement before its speed-ups, the
same accuracy (benchmarks/bench_localization.py). Measured with the robots' realistic
sensors (benchmarks/bench_localization.py): 7 mm RMSE on the real AWS small house map
(amcl alone 7 cm), 1.3 cm in the built-in small house, 3 cm in a 30 x 50 m warehouse (amcl
alone 23 cm, 0.98 m maximum), 1.3 cm with furniture moved since the map was made, with the
true error inside the reported 2-sigma ellipse on more than 99 % of the steps.

The field defaults are TurtleBot3's ``amcl.launch`` (``profile: turtlebot3``). Measured here
(tests/test_amcl.py): they track the demo patrol to ~0.03 m / 0.02 rad RMSE from a start
0.3 m / 0.2 rad off, but amcl's default ``likelihood_field`` score (``1 + sum(pz**3)``) is
too flat to localise globally in the small house, and recovery is off, so a kidnapped
robot stays lost. ``profile: recovery`` does all three (keys set next to it win)::

    laser_model_type: likelihood_field_prob   # amcl's product of beam likelihoods
    laser_log_likelihood_scale: 0.1           # tempered: the beams are not independent
    max_particles: 20000                      # global start; KLD drops to ~500 when found
    recovery_alpha_slow: 0.001                # kidnap recovery (pose injection)
    recovery_alpha_fast: 0.1

It tracks the demo patrol to ~0.02 m / 0.01 rad. Injected poses are drawn from the scan
(``recovery_candidates``, see ParticleFilter.injection_poses), not uniformly as in amcl:
with uniform injection a robot kidnapped in the small house (tests/test_faults_amcl.py:
20 % lidar dropout, 10 % wheel slip, scale 0.05) was found again 2.6-26 s later (median
5.6 s, seeds 1-21; on some seeds not before the mission ended), because the first
look-alike place found (the living and recreation rooms are near 180-degree twins) took
the particles; with the scan-guided draw 0.6-6.4 s (median 1.6 s; 0.4-7.8 s over 41
seeds), and 0.2-7.0 s with this profile (40 seeds).

For plots the plugin keeps ``snapshots`` (``(time, particles)`` every
``snapshot_interval`` filter updates, thinned to at most ``max_snapshots``) and
``particle_counts`` (``(time, count)`` per filter update).
"""

from __future__ import annotations

import functools
import math

import numpy as np

from agv_mission.geometry import Pose2D, wrap_angle, wrap_angles
from agv_mission.localization.base import LocalizerDiagnostics
from agv_mission.localization.beam_model import SensorParams
from agv_mission.localization.configs import AmclConfig
from agv_mission.localization.particle_filter import MotionNoise, ParticleFilter
from agv_mission.localization.pose_tracker import Correction, PoseTracker, RefineParams
from agv_mission.maps.grid import OccupancyGrid
from agv_mission.sensor_msgs import LaserScan


class AmclLocalizer:
    """Adaptive Monte Carlo localisation; never looks at the true pose."""

    Config = AmclConfig

    def __init__(self, config: AmclConfig, grid: OccupancyGrid, rng: np.random.Generator) -> None:
        if config.min_particles > config.max_particles:
            raise ValueError("amcl: min_particles must not exceed max_particles")
        self.config = config
        c = config
        self.filter = ParticleFilter(
            grid,
            rng,
            min_particles=c.min_particles,
            max_particles=c.max_particles,
            kld_err=c.kld_err,
            kld_z=c.kld_z,
            motion=MotionNoise(c.odom_alpha1, c.odom_alpha2, c.odom_alpha3, c.odom_alpha4),
            sensor=SensorParams(
                z_hit=c.laser_z_hit,
                z_rand=c.laser_z_rand,
                sigma_hit=c.laser_sigma_hit,
                max_beams=c.laser_max_beams,
                max_range=c.laser_max_range,
                min_range=c.laser_min_range,
                likelihood_max_dist=c.laser_likelihood_max_dist,
                model=c.laser_model_type,
                log_scale=c.laser_log_likelihood_scale,
            ),
            alpha_slow=c.recovery_alpha_slow,
            alpha_fast=c.recovery_alpha_fast,
            inject_candidates=c.recovery_candidates,
        )
        self.tracker = (
            PoseTracker(
                grid,
                RefineParams(
                    sigma=c.refine_sigma,
                    sigma_fraction=c.refine_sigma_fraction,
                    max_innovation=c.refine_max_innovation,
                    huber=c.refine_huber,
                    outlier=c.refine_outlier,
                    inlier=c.refine_inlier,
                    min_inlier_fraction=c.refine_min_inlier_fraction,
                    min_inlier_beams=c.refine_min_inlier_beams,
                    min_beams=c.refine_min_beams,
                    max_beams=c.refine_max_beams,
                    floor_xy=c.refine_floor_xy,
                    floor_yaw=c.refine_floor_yaw,
                    noise_along=c.refine_noise_along,
                    noise_lateral=c.refine_noise_lateral,
                    noise_turn=c.refine_noise_turn,
                    noise_yaw_per_m=c.refine_noise_yaw_per_m,
                    map_error_scale=c.refine_map_error_scale,
                    map_error_lever=c.refine_map_error_lever,
                    split_scale=c.refine_split_scale,
                    adaptive_noise=c.refine_adaptive_noise,
                ),
            )
            if c.refine
            else None
        )
        self.refine_stats = {"scans": 0, "accepted": 0, "rejected": 0, "starts": 0, "restarts": 0}
        self._track_odom = Pose2D(0.0, 0.0, 0.0)
        self._refine_odom = Pose2D(0.0, 0.0, 0.0)  # odometry at the last refinement
        self._failures = 0
        self._pf_cov = np.diag([c.initial_cov_xx, c.initial_cov_yy, c.initial_cov_aa])
        self._estimate = Pose2D(0.0, 0.0, 0.0)
        self.snapshots: list[tuple[float, np.ndarray]] = []
        self.particle_counts: list[tuple[float, int]] = []
        self.filter_updates = 0
        self._snapshot_every = c.snapshot_interval
        self._pose = Pose2D(0.0, 0.0, 0.0)  # filter pose at its last update
        self._odom = Pose2D(0.0, 0.0, 0.0)  # odometry at the last filter update
        self._initialised = False
        self._resample_count = 0
        self._force_update = False

    # ------------------------------------------------------------------ runner API

    @property
    def particles(self) -> np.ndarray:
        """(N, 3) particles [x, y, yaw] in the map frame."""
        return self.filter.particles

    @property
    def weights(self) -> np.ndarray:
        return self.filter.weights

    @property
    def particle_count(self) -> int:
        return self.filter.count

    @property
    def map_to_odom(self) -> Pose2D:
        """amcl's ``map -> odom`` transform (of the current estimate)."""
        return self._estimate.compose(Pose2D(0.0, 0.0, 0.0).relative_to(self._track_odom))

    @property
    def covariance(self) -> np.ndarray:
        """3x3 covariance (x, y, yaw) of the current estimate.

        The refinement's Kalman covariance while it tracks, else the particle cloud's
        weighted covariance at the last filter update.
        """
        if self.tracker is not None and self.tracker.active:
            return self.tracker.cov.copy()
        return self._pf_cov.copy()

    @property
    def refining(self) -> bool:
        """True while the scan-to-map refinement gives the estimate."""
        return self.tracker is not None and self.tracker.active

    def reset(self, pose: Pose2D, odom: Pose2D) -> None:
        c = self.config
        start = (
            pose
            if c.initial_pose is None
            else Pose2D(c.initial_pose.x, c.initial_pose.y, c.initial_pose.yaw)
        )
        if c.global_localization:
            self.filter.init_uniform()
        else:
            cov = np.diag([c.initial_cov_xx, c.initial_cov_yy, c.initial_cov_aa])
            self.filter.init_gaussian(start.as_array(), cov)
        self._pose, self._odom = start, odom
        self._estimate, self._track_odom = start, odom
        self._refine_odom = odom
        self._pf_cov = self.filter.covariance(start.as_array())
        self._failures = 0
        self.refine_stats = {"scans": 0, "accepted": 0, "rejected": 0, "starts": 0, "restarts": 0}
        if self.tracker is not None:
            self.tracker.stop()
        self._initialised = False
        self._resample_count = 0
        self._force_update = False
        self.snapshots.clear()
        self.particle_counts.clear()
        self.filter_updates = 0
        self._snapshot_every = c.snapshot_interval

    def update(self, odom: Pose2D, scan: LaserScan | None, truth: Pose2D, time: float) -> Pose2D:
        if self.filter.count == 0:
            raise RuntimeError("amcl: reset(pose, odom) must come before update()")
        delta = odom.relative_to(self._track_odom)
        self._track_odom = odom
        tracker = self.tracker
        if tracker is not None and tracker.active:
            tracker.predict(delta.as_array())
        filtered = False
        forced = self._force_update
        if scan is not None:
            delta = odom.relative_to(self._odom)
            moved = (
                math.hypot(delta.x, delta.y) >= self.config.update_min_d
                or abs(delta.yaw) >= self.config.update_min_a
            )
            if moved or self._force_update or not self._initialised:
                self._filter_update(odom, scan, time, moved or self._force_update)
                self._force_update = False
                filtered = True
        pf_pose = self._pose.compose(odom.relative_to(self._odom))
        if tracker is not None and scan is not None and self._refine_due(tracker, odom, forced):
            self._refine(tracker, scan, pf_pose, filtered)
            self._refine_odom = odom
        if tracker is not None and tracker.active:
            m = tracker.mean
            self._estimate = Pose2D(float(m[0]), float(m[1]), float(m[2]))
        else:
            self._estimate = pf_pose
        return self._estimate

    def diagnostics(self) -> LocalizerDiagnostics:
        """Filter statistics; ``covariance`` is the estimate's (see :attr:`covariance`)."""
        return LocalizerDiagnostics(
            filter_updates=self.filter_updates,
            particle_counts=self.particle_counts,
            snapshots=self.snapshots,
            particles=self.filter.particles,
            covariance=self.covariance,
        )

    def request_nomotion_update(self) -> None:
        """Update the filter with the next scan although the robot has not moved far enough.

        amcl's ``request_nomotion_update`` service: a robot standing still gets no filter
        updates, so the cloud a turn in place spread out stays spread until it drives.
        """
        self._force_update = True

    # ------------------------------------------------------------------ internals

    def _refine_due(self, tracker: PoseTracker, odom: Pose2D, forced: bool) -> bool:
        """Whether a scan should refine the tracked pose: always while it does not track,
        else once odometry has moved (1 mm or 1 mrad) since the last refinement, or on a
        no-motion request. A robot standing still sees the same walls again: matching
        each new scan's noise would only make its estimate jitter."""
        if not tracker.active or forced:
            return True
        moved = odom.relative_to(self._refine_odom)
        return math.hypot(moved.x, moved.y) >= 1e-3 or abs(moved.yaw) >= 1e-3

    def _refine(
        self, tracker: PoseTracker, scan: LaserScan, pf_pose: Pose2D, filtered: bool
    ) -> None:
        """Correct the tracked pose with ``scan``; start, stop and recentre as the fit says.

        The tracker starts from the filter's pose once the cloud is tight (position sd below
        ``refine_start_std_xy``), or, with a tracking-sized cloud (sd below 0.6 m, e.g. the
        initial pose's), when the scan fits the map from there almost perfectly; never
        from a globally spread cloud, whose heaviest cluster may be a look-alike place. It
        stops (the filter's estimate takes over) after ``refine_max_failures`` scans in a
        row that see walls but do not fit them, and restarts from the filter when a tight
        cloud's estimate jumps more than ``refine_jump`` away from it (the filter switched
        to another mode). While it tracks, the particle cloud is moved rigidly onto its pose
        at every filter update, so the filter does not drift away from a centimetre
        estimate in long stretches with little to see.
        """
        c = self.config
        points = _scan_points(scan, c.laser_min_range, c.laser_max_range)
        self.refine_stats["scans"] += 1
        pf_std = math.sqrt(max(self._pf_cov[0, 0], self._pf_cov[1, 1]))
        sure = pf_std <= c.refine_start_std_xy
        if tracker.active and filtered and sure:
            m = tracker.mean
            jump = math.hypot(m[0] - self._pose.x, m[1] - self._pose.y) > c.refine_jump or abs(
                wrap_angle(float(m[2]) - self._pose.yaw)
            ) > max(c.refine_jump, 0.3)
            if jump:
                tracker.stop()
                self.refine_stats["restarts"] += 1
        if tracker.active:
            corr = tracker.correct(points)
            self._count(corr)
            if corr.beams >= c.refine_min_beams:
                self._failures = 0 if corr.accepted else self._failures + 1
            if self._failures >= c.refine_max_failures:
                tracker.stop()
                self._failures = 0
        elif sure or pf_std <= 0.6:
            cov = self._pf_cov + np.diag([0.02**2, 0.02**2, 0.02**2])
            tracker.start(pf_pose.as_array(), cov)
            corr = tracker.correct(points)
            if not (corr.accepted and (sure or corr.inlier_fraction >= 0.9)):
                tracker.stop()
                return
            self._count(corr)
            self.refine_stats["starts"] += 1
            self._failures = 0
        if tracker.active and filtered and tracker.last is not None and tracker.last.accepted:
            self._recentre(tracker.mean)

    def _count(self, corr: Correction) -> None:
        self.refine_stats["accepted" if corr.accepted else "rejected"] += 1

    def _recentre(self, mean: np.ndarray) -> None:
        """Move the particle cloud (rigidly about its estimate) onto the tracked pose."""
        p = self.filter.particles
        est = self._pose.as_array()
        dyaw = wrap_angle(float(mean[2] - est[2]))
        c, s = math.cos(dyaw), math.sin(dyaw)
        rx, ry = p[:, 0] - est[0], p[:, 1] - est[1]
        p[:, 0] = mean[0] + c * rx - s * ry
        p[:, 1] = mean[1] + s * rx + c * ry
        p[:, 2] = wrap_angles(p[:, 2] + dyaw)
        self._pose = Pose2D(float(mean[0]), float(mean[1]), float(mean[2]))

    def _filter_update(self, odom: Pose2D, scan: LaserScan, time: float, moved: bool) -> None:
        pf = self.filter
        if moved:
            pf.motion_update(self._odom.as_array(), odom.as_array())
        c = self.config
        # While the refinement tracks, the estimate is its own and the cloud is moved onto
        # it at every update: the filter is the fallback, a coarse cloud is enough.
        last = self.tracker.last if self.tracker is not None and self.tracker.active else None
        tracking = last is not None and last.accepted
        pf.sensor_update(scan, c.refine_filter_beams if tracking else None)
        self._resample_count += 1
        if self._resample_count % c.resample_interval == 0:
            pf.resample(c.refine_filter_particles if tracking else None)
        est, _ = pf.estimate()
        self._pose = Pose2D(float(est[0]), float(est[1]), float(est[2]))
        self._pf_cov = pf.covariance(est)
        self._odom = odom
        self._initialised = True
        self.filter_updates += 1
        self.particle_counts.append((float(time), pf.count))
        if (self.filter_updates - 1) % self._snapshot_every == 0:
            self.snapshots.append((float(time), pf.particles.astype(np.float32)))
            if len(self.snapshots) > self.config.max_snapshots:
                del self.snapshots[1::2]  # keep the first, thin evenly
                self._snapshot_every *= 2


def _scan_points(scan: LaserScan, min_range: float, max_range: float) -> np.ndarray:
    """Robot-frame end points (M, 2) of the valid beams within amcl's laser range limits."""
    r = np.asarray(scan.ranges, dtype=np.float64)
    rmin = min_range if min_range > 0.0 else scan.range_min
    rmax = max_range if max_range > 0.0 else scan.range_max
    ok = (r >= rmin) & (r < rmax)  # False for nan; inf is not below rmax
    directions = _beam_directions(scan.angle_min, scan.angle_increment, len(r))
    return directions[ok] * r[ok, None]


@functools.lru_cache(maxsize=16)
def _beam_directions(angle_min: float, angle_increment: float, n: int) -> np.ndarray:
    """Unit vectors (n, 2) of a scan's beams: the same for every scan of a lidar."""
    a = angle_min + angle_increment * np.arange(n)
    out = np.stack([np.cos(a), np.sin(a)], axis=1)
    out.flags.writeable = False
    return out
