"""The particle filter behind ``amcl``: motion model, beam model, KLD, resampling.

Pure numpy, no plugin glue. It follows ROS amcl (``pf.c``, ``amcl_odom.cpp``,
``amcl_laser.cpp``):

* :meth:`ParticleFilter.motion_update` is the odometry motion model of a differential
  drive (Probabilistic Robotics, table 5.6, with amcl's fixes for reversing and turning
  in place), noise from ``odom_alpha1..4``.
* :class:`~agv_mission.localization.beam_model.BeamModel` precomputes, once per map
  (shared between runs, :mod:`~agv_mission.maps.map_cache`), the per-cell beam
  likelihood from the distance to the nearest occupied cell (clipped at ``laser_likelihood_max_dist``);
  scoring N particles x B beams is then one matrix product, one integer conversion and
  one table gather. Unknown cells count like free ones (distance to the nearest occupied
  cell) and end points off the map get ``laser_likelihood_max_dist``, as in amcl.
* :meth:`ParticleFilter.resample` is KLD sampling (Fox 2003) over amcl's histogram bins
  (0.5 m x 0.5 m x 10 deg) with ``kld_z`` used as the quantile like amcl does, a
  low-variance (systematic) draw of the chosen count, and random-pose injection with
  probability ``max(0, 1 - w_fast / w_slow)``. Three changes from amcl, all because a
  kidnapped robot stayed lost in tests: ``w_slow`` / ``w_fast`` are not reset after an
  injection (Probabilistic Robotics' Augmented MCL; amcl's reset injects once, then waits
  for the likelihood to fall further); they are bias-corrected exponential averages
  (amcl starts both at the first, still unconverged, likelihood, which keeps ``w_slow``
  low for ~1 / recovery_alpha_slow updates); and with ``inject_candidates`` > 1 the
  injected poses are drawn from the last scan's likelihood, not uniformly (see
  :meth:`ParticleFilter.injection_poses`).
* :meth:`ParticleFilter.estimate` is amcl's: the weighted mean (circular for yaw) of the
  heaviest cluster of connected histogram bins.

The histogram's parts (bins, the KLD bound, clusters: amcl's ``pf_kdtree.c``) are in
:mod:`agv_mission.localization.histogram`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from agv_mission.geometry import wrap_angle, wrap_angles
from agv_mission.localization.beam_model import BeamModel, SensorParams, beam_model
from agv_mission.localization.histogram import KldBound, heaviest_cluster, kld_count, weighted_pose
from agv_mission.maps.grid import OccupancyGrid
from agv_mission.sensor_msgs import LaserScan

#: Scan-guided injection (ParticleFilter.injection_poses): the proposal's per-beam
#: log-likelihood scale, the broad field's sigma_hit (m), and the refinement jitter
#: (x/y sd in m, yaw sd in rad), halved in each refinement round.
PROPOSAL_LOG_SCALE = 0.2
PROPOSAL_BROAD_SIGMA = 0.5
PROPOSAL_JITTER = (0.25, 0.15)
PROPOSAL_ROUNDS = 2


@dataclass(frozen=True)
class MotionNoise:
    """amcl's ``odom_alpha1..4`` for the ``diff`` model."""

    alpha1: float = 0.1  # rotation noise from rotation
    alpha2: float = 0.1  # rotation noise from translation
    alpha3: float = 0.1  # translation noise from translation
    alpha4: float = 0.1  # translation noise from rotation


class ParticleFilter:
    """Particles (N, 3) [x, y, yaw] in the map frame with normalised weights."""

    def __init__(
        self,
        grid: OccupancyGrid,
        rng: np.random.Generator,
        *,
        min_particles: int = 500,
        max_particles: int = 3000,
        kld_err: float = 0.02,
        kld_z: float = 0.99,
        motion: MotionNoise | None = None,
        sensor: SensorParams | None = None,
        alpha_slow: float = 0.0,
        alpha_fast: float = 0.0,
        inject_candidates: int = 1,
    ) -> None:
        if not 1 <= min_particles <= max_particles:
            raise ValueError("need 1 <= min_particles <= max_particles")
        self.grid = grid
        self.rng = rng
        self.min_particles, self.max_particles = int(min_particles), int(max_particles)
        self.kld_err, self.kld_z = float(kld_err), float(kld_z)
        self.motion = motion or MotionNoise()
        self.sensor = sensor or SensorParams()
        self.alpha_slow, self.alpha_fast = float(alpha_slow), float(alpha_fast)
        if inject_candidates < 1:
            raise ValueError("need inject_candidates >= 1")
        self.inject_candidates = int(inject_candidates)
        self._kld = KldBound(self.kld_err, self.kld_z, self.min_particles, self.max_particles)
        self._reset_averages()
        self._fields: dict[float, BeamModel] = {}
        self._proposal: dict[float, tuple[BeamModel, BeamModel]] = {}
        free = np.flatnonzero(grid.data.ravel() == 0)
        if free.size == 0:
            raise ValueError("the map has no free cell to put particles on")
        self._free_cells = free
        self.particles = np.zeros((0, 3))
        self.weights = np.zeros(0)
        self.last_w_diff = 0.0
        self.last_injected = 0
        # The last scan's field and beam end points (for scan-guided injection).
        self._last_beams: tuple[BeamModel, np.ndarray, np.ndarray] | None = None
        if self.sensor.max_range > 0.0:
            self.field(self.sensor.max_range)  # the likelihood field, once, up front

    # ------------------------------------------------------------------ initialisation

    @property
    def count(self) -> int:
        return len(self.particles)

    def _set(self, particles: np.ndarray) -> None:
        self.particles = particles
        self.weights = np.full(len(particles), 1.0 / len(particles))

    def init_gaussian(self, mean: np.ndarray, cov: np.ndarray, n: int | None = None) -> None:
        """``n`` (default ``max_particles``) particles around ``mean`` [x, y, yaw]."""
        n = self.max_particles if n is None else int(n)
        p = self.rng.multivariate_normal(np.asarray(mean, float), np.asarray(cov, float), n)
        p[:, 2] = wrap_angles(p[:, 2])
        self._set(p)
        self._reset_averages()

    def init_uniform(self, n: int | None = None) -> None:
        """``n`` (default ``max_particles``) particles uniformly over the free cells."""
        self._set(self.random_poses(self.max_particles if n is None else int(n)))
        self._reset_averages()

    def random_poses(self, n: int) -> np.ndarray:
        """``n`` poses uniform over the free cells, yaw uniform."""
        g = self.grid
        cells = self._free_cells[self.rng.integers(0, self._free_cells.size, n)]
        rows, cols = np.divmod(cells, g.width)
        jitter = self.rng.random((n, 2))
        px = (cols + jitter[:, 0]) * g.resolution
        py = (rows + jitter[:, 1]) * g.resolution
        o = g.origin
        c, s = math.cos(o.yaw), math.sin(o.yaw)
        out = np.empty((n, 3))
        out[:, 0] = o.x + c * px - s * py
        out[:, 1] = o.y + s * px + c * py
        out[:, 2] = self.rng.uniform(-math.pi, math.pi, n)
        return out

    # ------------------------------------------------------------------ motion model

    def motion_update(self, old: np.ndarray, new: np.ndarray) -> None:
        """Move every particle by the odometry motion ``old -> new`` ([x, y, yaw], odom frame)."""
        dx, dy = float(new[0] - old[0]), float(new[1] - old[1])
        dyaw = wrap_angle(float(new[2] - old[2]))
        trans = math.hypot(dx, dy)
        rot1 = 0.0 if trans < 0.01 else wrap_angle(math.atan2(dy, dx) - float(old[2]))
        rot2 = wrap_angle(dyaw - rot1)
        # Reversing is a small rotation, not a half turn (amcl_odom.cpp).
        rot1_n = min(abs(rot1), abs(wrap_angle(rot1 - math.pi)))
        rot2_n = min(abs(rot2), abs(wrap_angle(rot2 - math.pi)))
        m = self.motion
        n = self.count
        sd_rot1 = math.sqrt(m.alpha1 * rot1_n**2 + m.alpha2 * trans**2)
        sd_trans = math.sqrt(m.alpha3 * trans**2 + m.alpha4 * (rot1_n**2 + rot2_n**2))
        sd_rot2 = math.sqrt(m.alpha1 * rot2_n**2 + m.alpha2 * trans**2)
        noise = self.rng.standard_normal((3, n))
        rot1_hat = rot1 - sd_rot1 * noise[0]
        trans_hat = trans - sd_trans * noise[1]
        rot2_hat = rot2 - sd_rot2 * noise[2]
        p = self.particles
        heading = p[:, 2] + rot1_hat
        p[:, 0] += trans_hat * np.cos(heading)
        p[:, 1] += trans_hat * np.sin(heading)
        p[:, 2] = wrap_angles(heading + rot2_hat)

    # ------------------------------------------------------------------ sensor model

    def field(self, range_max: float) -> BeamModel:
        """The likelihood field for beams up to ``range_max`` (built once per range)."""
        key = round(float(range_max), 6)
        f = self._fields.get(key)
        if f is None:
            f = self._fields[key] = beam_model(self.grid, self.sensor, key)
        return f

    def beams(
        self, scan: LaserScan, max_beams: int | None = None
    ) -> tuple[BeamModel, np.ndarray, np.ndarray]:
        """The field and the used beams' robot-frame end points in cells (bx, by):
        ``max_beams`` (default ``laser_max_beams``) evenly spaced beams of ``scan``."""
        sp = self.sensor
        rmax = sp.max_range if sp.max_range > 0.0 else float(scan.range_max)
        rmin = sp.min_range if sp.min_range > 0.0 else float(scan.range_min)
        f = self.field(rmax)
        ranges = scan.ranges
        n = len(ranges)
        nb = sp.max_beams if max_beams is None else max(2, min(int(max_beams), sp.max_beams))
        step = max(1, (n - 1) // max(1, nb - 1))
        idx = np.arange(0, n, step)[:nb]
        r = np.asarray(ranges, dtype=np.float64)[idx]
        ok = np.isfinite(r) & (r < rmax) & (r >= rmin)
        r, a = r[ok], scan.angle_min + scan.angle_increment * idx[ok]
        inv = 1.0 / f.resolution
        return f, (r * np.cos(a) * inv).astype(np.float32), (r * np.sin(a) * inv).astype(np.float32)

    def sensor_update(self, scan: LaserScan, max_beams: int | None = None) -> float:
        """Reweight the particles by a scan (``max_beams`` of its beams, default
        ``laser_max_beams``); returns the average likelihood ``w_avg``.

        Also updates ``w_slow`` / ``w_fast`` (amcl's recovery averages).
        """
        f, bx, by = self.beams(scan, max_beams)
        score = f.score(self.particles, bx, by)
        if self.sensor.model == "likelihood_field":
            w = self.weights * score
            total = float(w.sum())
            w_avg = total  # the prior weights sum to 1: sum(prior * p)
        else:
            # Log-likelihoods: normalise in the log domain; w_avg per beam (and untempered)
            # so that scans with different numbers of valid beams compare.
            log_w = np.log(np.maximum(self.weights, 1e-300)) + score
            top = float(log_w.max())
            w = np.exp(log_w - top)
            total = float(w.sum())
            scale = max(1, len(bx)) * self.sensor.log_scale
            w_avg = math.exp((top + math.log(total)) / scale)
        if not total > 0.0 or not math.isfinite(total):
            self.weights = np.full(self.count, 1.0 / self.count)
            return 0.0
        self.weights = w / total
        self._last_beams = (f, bx, by)
        self._track_average(w_avg)
        return w_avg

    def _track_average(self, w_avg: float) -> None:
        """Exponential averages of ``w_avg``, bias-corrected (started at 0, divided by
        ``1 - (1 - alpha)^t``), so that early updates of a still-spread cloud do not pin
        ``w_slow`` low for ~1 / alpha_slow updates as amcl's "first value" start does."""
        if self.alpha_slow <= 0.0 or self.alpha_fast <= 0.0:
            return  # recovery disabled
        self._avg_count += 1
        self._slow_acc += self.alpha_slow * (w_avg - self._slow_acc)
        self._fast_acc += self.alpha_fast * (w_avg - self._fast_acc)
        t = self._avg_count
        self.w_slow = self._slow_acc / (1.0 - (1.0 - self.alpha_slow) ** t)
        self.w_fast = self._fast_acc / (1.0 - (1.0 - self.alpha_fast) ** t)

    def _reset_averages(self) -> None:
        self.w_slow = self.w_fast = 0.0
        self._slow_acc = self._fast_acc = 0.0
        self._avg_count = 0

    # ------------------------------------------------------------------ resampling

    def kld_limit(self, k: np.ndarray) -> np.ndarray:
        """amcl's ``pf_resample_limit``: particles needed for ``k`` occupied bins."""
        return self._kld(k)

    def systematic(self, n: int) -> np.ndarray:
        """Indices of a low-variance (systematic) draw of ``n`` from the weights."""
        return _systematic(self.weights, n, self.rng)

    def injection_poses(self, n: int) -> np.ndarray:
        """``n`` poses to inject: uniform over the free space, or drawn from the last scan.

        With ``inject_candidates`` = c > 1 (and a scan seen) this is a coarse draw from the
        measurement model (Thrun et al.'s Mixture MCL), by annealed importance sampling:
        ``m = min(c n, max_particles)`` uniform poses are scored on every other beam against
        a broad field (``sigma_hit`` 0.5 m, so a pose 0.5 m off still scores), ``m / 10``
        are resampled by that score, then twice jittered (0.25 m / 0.15 rad, then half),
        rescored with the filter's field and resampled; ``n`` come out. Weights use a
        per-beam log-likelihood scale of 0.2, whatever the filter's tempering.

        Why: the likelihood peak of a 360-beam scan is ~0.15 m / 0.1 rad wide, so uniform
        injection (amcl's) or a one-stage draw from 20000 uniform poses rarely lands a pose
        on a kidnapped robot in a 150 m^2 house, and the first look-alike place found
        (small_house's living and recreation rooms are near 180-degree twins) collects the
        mass. This draw puts most of the injected poses at the few places that fit the scan
        (measured: >= 25 % within 0.2 m / 0.1 rad of the truth for every probe pose).
        """
        if self.inject_candidates <= 1 or self._last_beams is None or n <= 0:
            return self.random_poses(n)
        rng = self.rng
        f, bx, by = self._last_beams
        broad, sharp = self._proposal_fields(f.range_max)
        m = max(n, min(n * self.inject_candidates, self.max_particles))
        keep = max(n, m // 10)
        poses = self.random_poses(m)
        score = broad.score(poses, bx[::2], by[::2])
        poses = poses[_systematic(_softmax(score), keep, rng)]
        sd = np.array([PROPOSAL_JITTER[0], PROPOSAL_JITTER[0], PROPOSAL_JITTER[1]])
        for r in range(PROPOSAL_ROUNDS):
            poses = poses + rng.standard_normal(poses.shape) * (sd * 0.5**r)
            score = sharp.score(poses, bx, by)
            poses = poses[
                _systematic(_softmax(score), n if r == PROPOSAL_ROUNDS - 1 else keep, rng)
            ]
        poses[:, 2] = wrap_angles(poses[:, 2])
        return poses

    def _proposal_fields(self, range_max: float) -> tuple[BeamModel, BeamModel]:
        """The injection proposal's (broad, sharp) fields: likelihood_field_prob models."""
        key = round(float(range_max), 6)
        pair = self._proposal.get(key)
        if pair is None:
            sharp = replace(
                self.sensor, model="likelihood_field_prob", log_scale=PROPOSAL_LOG_SCALE
            )
            broad = replace(sharp, sigma_hit=max(PROPOSAL_BROAD_SIGMA, sharp.sigma_hit))
            pair = self._proposal[key] = (
                beam_model(self.grid, broad, key),
                beam_model(self.grid, sharp, key),
            )
        return pair

    def resample(self, max_count: int | None = None) -> int:
        """KLD-sampling resample with random injection; returns the new particle count
        (at most ``max_count``, default ``max_particles``)."""
        w_diff = 0.0
        if self.w_slow > 0.0:
            w_diff = max(0.0, 1.0 - self.w_fast / self.w_slow)
        self.last_w_diff = w_diff
        self.last_injected = 0
        m = self.max_particles if max_count is None else max(1, min(max_count, self.max_particles))
        # What amcl does one sample at a time: draw from the weighted set (here a shuffled
        # systematic draw, so every prefix is representative), injecting random poses with
        # probability w_diff, until the count exceeds the KLD bound of the bins filled.
        if w_diff <= 0.0 and self.min_particles >= m:
            self._set(self.particles[self.systematic(m)])  # the count is known: no candidates
            return m
        candidates = self.particles[self.systematic(m)][self.rng.permutation(m)]
        inject = np.zeros(m, dtype=bool)
        if w_diff > 0.0:
            inject = self.rng.random(m) < w_diff
            k = int(inject.sum())
            if k:
                candidates[inject] = self.injection_poses(k)
        n = m if self.min_particles >= m else kld_count(candidates, m, self._kld)
        n_rand = self.last_injected = int(inject[:n].sum())
        out = np.empty((n, 3))
        if n_rand:
            out[:n_rand] = candidates[:n][inject[:n]]
        out[n_rand:] = self.particles[self.systematic(n - n_rand)]
        self._set(out)
        return n

    # ------------------------------------------------------------------ estimate

    def mean(self) -> np.ndarray:
        """Weighted mean of all particles, circular for yaw."""
        return weighted_pose(self.particles, self.weights)

    def covariance(self, mean: np.ndarray) -> np.ndarray:
        """Weighted covariance (3x3, yaw differences wrapped) of the particles about ``mean``."""
        d = self.particles - np.asarray(mean, dtype=float)
        d[:, 2] = wrap_angles(d[:, 2])
        w = self.weights / max(float(self.weights.sum()), 1e-300)
        return (d * w[:, None]).T @ d

    def estimate(self) -> tuple[np.ndarray, float]:
        """amcl's pose: the weighted mean of the heaviest cluster of connected histogram
        bins, and that cluster's weight (:func:`~agv_mission.localization.histogram.heaviest_cluster`)."""
        return heaviest_cluster(self.particles, self.weights)


def _systematic(weights: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """Indices of a low-variance (systematic) draw of ``n`` from normalised ``weights``."""
    cum = np.cumsum(weights)
    cum[-1] = 1.0
    u = (rng.random() + np.arange(n)) / n
    return np.minimum(np.searchsorted(cum, u, side="right"), len(weights) - 1)


def _softmax(log_w: np.ndarray) -> np.ndarray:
    w = np.exp(log_w - log_w.max())
    return w / w.sum()
