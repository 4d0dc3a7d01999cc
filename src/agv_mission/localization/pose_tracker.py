"""Scan-to-map refinement: an iterated Kalman update of a pose against the map's distance field.

The particle filter's estimate is only as fine as its particles (amcl's typical 5-10 cm);
a 360-beam scan matched against the map pins the pose to millimetres wherever the lidar
sees walls. :class:`PoseTracker` keeps a Gaussian pose estimate (mean, 3x3 covariance):

* :meth:`PoseTracker.predict` composes the odometry motion and grows the covariance with
  a motion noise proportional to the distance driven and the angle turned;
* :meth:`PoseTracker.correct` minimises the prior's Mahalanobis term plus the robust sum of
  squared signed distances of the beam end points to the map's walls (Gauss-Newton on a
  :class:`SignedDistanceField`, bilinear), i.e. an iterated EKF update. Directions the scan
  does not constrain (a corridor's axis, an empty hall) keep the prior's uncertainty, so
  the covariance grows there honestly instead of collapsing.

Each scan's information is capped (``floor``, :func:`cap_information`): the beams are not
independent (map discretisation, the same wall seen by many beams), and a robot standing
still sees the same scan again, so counting every beam as an independent 1 cm measurement
would make the covariance far too small. For the same reason the covariance after a
correction never drops below a floor set by how well the scans fit the map: the residual
RMS (smoothed over scans) is the size of the map's own error where the robot is (a wall
drawn half a cell off shifts every scan matched to it), measured (with a constant 1 cm
lidar noise) 0.9 cm on the AWS small house map (walls exactly on cells) and 2.3 cm on
turtlebot3_world (a
conservative rasterisation of a hexagon and round pillars, errors up to a cell).

Real maps are not the world (furniture moved since mapping, a SLAM map's own error), and a
real lidar's noise grows with the range: each beam is weighted by its own noise
(``sigma_fraction``), a scan whose fitting beams are enough though many others see
unmapped obstacles still corrects (``min_inlier_beams``), and a correction the odometry
makes implausible (``max_innovation``) is refused, so where scans say little or something
else than the map, the estimate follows odometry and its covariance grows.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from agv_mission.geometry import wrap_angle
from agv_mission.localization.distance_field import signed_distance_field
from agv_mission.maps.grid import OccupancyGrid


@dataclass(frozen=True)
class RefineParams:
    """Scan-to-map refinement settings (AmclConfig's ``refine_*`` keys)."""

    sigma: float = 0.02  # m, per-beam range noise used for the beam information
    # The lidar's noise grows with the range (the LDS-01: 1.75 % of it, see the robots'
    # LidarSpec): a beam's sigma, Huber width and inlier distance are scaled by
    # max(1, sigma_fraction * range / sigma), so far beams count less and fit looser.
    sigma_fraction: float = 0.0175
    huber: float = 0.03  # m, residuals beyond this are down-weighted (Huber)
    outlier: float = 0.25  # m, residuals beyond this are ignored (unmapped obstacles)
    # Mahalanobis distance (of the prior's covariance) beyond which a correction is not
    # believed: the scan matched something else (a moved box, a look-alike wall) than
    # odometry allows. 0 disables.
    max_innovation: float = 5.0
    inlier: float = 0.05  # m, a beam within this of a wall counts as fitting
    min_inlier_fraction: float = 0.6  # gate: at least this share of the beams must fit,
    min_inlier_beams: int = 15  # or this many and half that share (unmapped obstacles)
    min_beams: int = 20  # fewer valid beams: no correction (prediction only)
    max_beams: int = 360
    floor_xy: float = 0.01  # m, no single scan pins x or y tighter than this
    floor_yaw: float = 0.005  # rad, nor the yaw
    iterations: int = 12
    # Gauss-Newton stops at a step below this (m in x + y, rad in yaw): a thirtieth of the
    # information floor, where the remaining steps shrink by ~3x per iteration.
    step_tolerance: float = 3e-4
    # Covariance floor from the fit: the accepted scans' residual RMS (smoothed) times
    # ``map_error_scale`` in x and y, divided by ``map_error_lever`` (m) for the yaw.
    map_error_scale: float = 1.0
    map_error_lever: float = 2.0
    # Or (> 0) the floor from how far the scan's two halves (left and right of the robot)
    # disagree on the pose: each half solved alone at the fit, their difference smoothed
    # over scans, this many times the spread it implies for the whole scan's pose. Where
    # the map is the world (a surveyed map, the world's own grid) the halves agree to
    # millimetres, where its walls are drawn off (a rasterised curve, a SLAM map's blur)
    # they disagree by as much: the floor follows the error the map makes, not the
    # lidar's noise (which the residual RMS mostly is). 0: the residual RMS floor.
    split_scale: float = 0.0
    split_min: float = 0.0015  # m, the floor's least x, y standard deviation
    # The walls' faces as the lidar sees them, relative to the map's cell faces: the median
    # signed distance of the fitting end points, smoothed at this rate over accepted scans
    # (within half a cell; 0 disables). A map that marks every cell a wall touches (a
    # conservative rasterisation, map_saver's hit cells) draws walls on average half a cell
    # thick; a map built cell for cell reads 0.
    wall_offset_rate: float = 0.05
    adaptive_noise: bool = True  # scale the odometry noise by the corrections' size
    # Odometry noise of the prediction, as random walks: the standard deviation after one
    # metre driven along (m), sideways (m), one radian turned (rad), and of the yaw after
    # one metre driven (rad); variances grow in proportion to the motion.
    noise_along: float = 0.02
    noise_lateral: float = 0.01
    noise_turn: float = 0.02
    noise_yaw_per_m: float = 0.01


@dataclass(frozen=True)
class Correction:
    """One scan's outcome: accepted or not, and how well the scan fitted the map."""

    accepted: bool
    mean: np.ndarray
    cov: np.ndarray
    beams: int
    inlier_fraction: float
    rms: float
    iterations: int


def cap_information(h: np.ndarray, floor: np.ndarray) -> np.ndarray:
    """``h`` with its eigenvalues (scaled by ``floor``) capped at 1.

    In coordinates scaled by ``floor`` (x, y in floor_xy units, yaw in floor_yaw units),
    no direction may carry more information than one measurement of standard deviation 1.
    """
    d = np.diag(floor)
    hs = d @ h @ d
    hs = 0.5 * (hs + hs.T)
    vals, vecs = np.linalg.eigh(hs)
    vals = np.clip(vals, 0.0, 1.0)
    capped = (vecs * vals) @ vecs.T
    dinv = np.diag(1.0 / floor)
    return dinv @ capped @ dinv


@dataclass
class _Fit:
    """What :meth:`PoseTracker._fit` found: the pose, its information, the last
    iteration's Jacobian rows and residuals (``system``), their weights, each beam's noise
    scale, the iterations taken and the weight of a beam."""

    pose: np.ndarray
    info: np.ndarray
    system: np.ndarray
    weights: np.ndarray
    scale: np.ndarray
    iterations: int
    w_beam: float


class PoseTracker:
    """A Gaussian pose estimate kept by odometry and refined by scans against the map."""

    def __init__(self, grid: OccupancyGrid, params: RefineParams | None = None) -> None:
        self.params = params or RefineParams()
        self.sdf = signed_distance_field(grid, max(1.0, 3.0 * self.params.outlier))
        self.mean = np.zeros(3)
        self.cov = np.eye(3)
        self.active = False
        self.last: Correction | None = None
        self.fit_rms = math.nan  # smoothed residual RMS of the accepted scans, m
        self.split_cov = np.full((3, 3), math.nan)  # smoothed half-scan disagreement
        self.wall_offset = 0.0  # m, where the scans see the walls' faces (see RefineParams)
        self.noise_scale = 1.0  # adaptive factor on the odometry noise (see correct)
        self._floor = np.array([self.params.floor_xy, self.params.floor_xy, self.params.floor_yaw])
        self._scaled = np.outer(self._floor, self._floor)  # H in floor units: H * scaled
        self._saturated_info = np.diag(1.0 / self._floor**2)

    def start(self, mean: np.ndarray, cov: np.ndarray) -> None:
        self.noise_scale = 1.0
        self.mean = np.asarray(mean, dtype=float).copy()
        self.cov = 0.5 * (np.asarray(cov, dtype=float) + np.asarray(cov, dtype=float).T)
        self.active = True

    def stop(self) -> None:
        self.active = False

    def predict(self, delta: np.ndarray) -> None:
        """Compose an odometry motion ``delta`` [dx, dy, dyaw] (robot frame)."""
        dx, dy, dth = (float(v) for v in delta)
        if dx == 0.0 and dy == 0.0 and dth == 0.0:
            return
        p = self.params
        th = float(self.mean[2])
        c, s = math.cos(th), math.sin(th)
        dist = math.hypot(dx, dy)
        # Random-walk noise (variance proportional to the motion), so the growth does not
        # depend on how finely the motion is chopped into control steps: Q = diag(along,
        # lateral, yaw) in the robot frame, rotated into the map frame (G Q G^T).
        ns = self.noise_scale
        q0, q1 = ns * p.noise_along**2 * dist, ns * p.noise_lateral**2 * dist
        q2 = ns * (p.noise_turn**2 * abs(dth) + p.noise_yaw_per_m**2 * dist)
        # F P F^T with F the motion's Jacobian [[1, 0, fa], [0, 1, fb], [0, 0, 1]], written
        # out (3x3 numpy calls cost more than the arithmetic).
        fa, fb = -s * dx - c * dy, c * dx - s * dy
        (p00, p01, p02), (_, p11, p12), (_, _, p22) = self.cov.tolist()
        x02, x12 = p02 + fa * p22, p12 + fb * p22
        cs = c * s * (q0 - q1)
        n00 = p00 + fa * p02 + fa * x02 + c * c * q0 + s * s * q1
        n01 = p01 + fa * p12 + fb * x02 + cs
        n11 = p11 + fb * p12 + fb * x12 + s * s * q0 + c * c * q1
        self.mean = np.array(
            [self.mean[0] + c * dx - s * dy, self.mean[1] + s * dx + c * dy, wrap_angle(th + dth)]
        )
        self.cov = np.array([[n00, n01, x02], [n01, n11, x12], [x02, x12, p22 + q2]])

    def _adapt_noise(self, delta: np.ndarray, prior_info: np.ndarray) -> None:
        """Scale the odometry noise by how far the scans move the prediction.

        With honest noise the correction ``delta`` is within the prior's ellipse
        (``delta^T P^-1 delta`` about 3 on average, chi-square with 3 degrees of freedom);
        when scans keep moving the estimate farther (wheels slipping more than the noise
        says), the noise is scaled up, smoothed over about 5 scans, within 1..100.
        """
        nis = _nis(delta, prior_info)
        target = min(100.0, max(1.0, self.noise_scale * nis / 3.0))
        self.noise_scale = 0.8 * self.noise_scale + 0.2 * target

    def correct(self, points: np.ndarray, commit: bool = True) -> Correction:
        """Refine the pose with scan end points ``points`` (M, 2) in the robot frame.

        The update is kept (``commit``) only when enough beams fit the map afterwards.
        """
        p = self.params
        pts = np.asarray(points, dtype=np.float64)
        if len(pts) > p.max_beams:
            pts = pts[np.linspace(0, len(pts) - 1, p.max_beams).astype(np.int64)]
        if len(pts) < p.min_beams:
            out = Correction(False, self.mean, self.cov, len(pts), 0.0, math.nan, 0)
            self.last = out
            return out
        prior = self.mean
        prior_info = _inverse3(self.cov)
        fit = self._fit(pts, prior_info)
        x, post_info, system, w, scale = fit.pose, fit.info, fit.system, fit.weights, fit.scale
        iterations, w_beam, r = fit.iterations, fit.w_beam, fit.system[3]
        a = np.abs(r)
        fits = a < p.inlier * scale
        fitting = np.count_nonzero(fits)
        inlier = fitting / len(r)
        rv = r[a < p.outlier]
        rms = math.sqrt(float(rv @ rv) / len(rv)) if len(rv) else math.nan
        cov = _inverse3(post_info)
        # Furniture the map lacks hides walls from some beams: a scan whose fitting beams
        # are many enough (and at least half the gate's share) still corrects.
        accepted = inlier >= p.min_inlier_fraction or (
            fitting >= p.min_inlier_beams and inlier >= 0.5 * p.min_inlier_fraction
        )
        if (
            accepted
            and p.max_innovation > 0.0
            and _nis(x - prior, prior_info) > (p.max_innovation**2)
        ):
            accepted = False
            if commit and p.adaptive_noise:  # odometry may slip more than its noise says
                self._adapt_noise(x - prior, prior_info)
        if accepted and commit and p.adaptive_noise:
            self._adapt_noise(x - prior, prior_info)
        if accepted and commit and math.isfinite(rms):
            self.fit_rms = (
                rms if not math.isfinite(self.fit_rms) else 0.8 * self.fit_rms + 0.2 * rms
            )
            if p.wall_offset_rate > 0.0 and fits.any():
                step = _median(r[fits])  # where the fitting end points see the walls
                limit = 0.5 * self.sdf.resolution
                moved = self.wall_offset + p.wall_offset_rate * step
                self.wall_offset = max(-limit, min(limit, moved))
            if p.split_scale > 0.0:
                cov = floor_covariance(cov, self._split_floor(system, w, w_beam))
            else:
                err = p.map_error_scale * self.fit_rms
                cov = floor_covariance(cov, np.array([err, err, err / p.map_error_lever]))
        out = Correction(accepted, x, cov, len(pts), inlier, rms, iterations)
        if accepted and commit:
            self.mean, self.cov = x, cov
        self.last = out
        return out

    def _fit(self, pts: np.ndarray, prior_info: np.ndarray) -> _Fit:
        """Gauss-Newton on the prior's Mahalanobis term plus the robust (Huber) sum of the
        end points' squared distances to the walls, from the prior (``self.mean``)."""
        p = self.params
        px, py, pyaw = self.mean.tolist()
        x = (px, py, pyaw)
        post_info = prior_info
        pts_rows = np.ascontiguousarray(pts.T)
        # Per-beam noise scale (>= 1): far beams of a range-proportional lidar count less.
        scale = np.hypot(pts_rows[0], pts_rows[1])
        scale *= p.sigma_fraction / p.sigma
        np.maximum(scale, 1.0, out=scale)
        inv_var = 1.0 / (scale * scale)
        system = np.empty((4, len(pts)))  # Jacobian rows (x, y, yaw) and the residuals
        r = system[3]
        iterations = 0
        # The wide kernel is for priors far enough off that end points miss the narrow
        # gate; a prior whose 3-sigma end point error (position plus yaw at the farthest
        # beam) is inside ``outlier`` (a tracked robot's) starts narrow, which saves the
        # one or two wide iterations per scan.
        reach = math.sqrt(2.0) * float(np.abs(pts).max())
        spread = math.sqrt(max(self.cov[0, 0], self.cov[1, 1])) + reach * math.sqrt(self.cov[2, 2])
        converged = 3.0 * spread <= p.outlier
        floor, scaled = self._floor, self._scaled
        # The posterior information when the scan pins every direction (its capped
        # information is then diag(floor^-2), see _saturated_step).
        capped_post = prior_info + self._saturated_info
        tol = p.step_tolerance
        w_beam = 1.0 / p.sigma**2
        for it in range(1, p.iterations + 1):
            iterations = it
            self.sdf.scan_system(pts_rows, x, self.wall_offset, system)
            a = np.abs(r)
            # The first iterations use a wide kernel: from a prior a decimetre or a few
            # degrees off, most end points are farther than ``outlier`` from their wall.
            wide = it <= p.iterations // 2 and not converged
            huber, outlier = (4.0 * p.huber, 2.0 * p.outlier) if wide else (p.huber, p.outlier)
            # Huber weights on the residual in units of the beam's noise: 1 within
            # ``huber`` (scaled), times the beam's information.
            w = huber * inv_var / np.maximum(a / scale, huber)
            w[a > outlier] = 0.0
            normal = (system * w) @ system.T  # [[H, g], [g^T, r^T W r]] / w_beam
            normal *= w_beam
            h_full, g_full = normal[:3, :3], normal[:3, 3]
            dx_prior = (x[0] - px, x[1] - py, wrap_angle(x[2] - pyaw))
            step = _saturated_step(h_full, g_full, dx_prior, prior_info, floor, capped_post)
            if step is None:  # a direction the scan does not pin: cap it (eigenvalues)
                h, gvec = _capped_step(h_full, g_full, floor, scaled)
                post_info = prior_info + h
                rhs = prior_info @ np.array(dx_prior) + gvec
                step = tuple((-np.linalg.solve(post_info, rhs)).tolist())
            else:
                post_info = capped_post
            x = (x[0] + step[0], x[1] + step[1], wrap_angle(x[2] + step[2]))
            small = abs(step[0]) + abs(step[1]) < tol and abs(step[2]) < tol
            if small and not wide:
                break
            converged = converged or abs(step[0]) + abs(step[1]) < 1e-3 and abs(step[2]) < 1e-3
        return _Fit(np.array(x), post_info, system, w, scale, iterations, w_beam)

    def _split_floor(self, system: np.ndarray, w: np.ndarray, w_beam: float) -> np.ndarray:
        """The covariance floor (x, y, yaw standard deviations) from the disagreement of
        the scan's two halves (see RefineParams.split_scale), smoothed over scans."""
        p = self.params
        n = system.shape[1]
        steps = []
        weak = np.diag([1.0 / 0.05**2, 1.0 / 0.05**2, 1.0 / 0.05**2])  # a half blind along
        for part in (slice(0, n // 2), slice(n // 2, n)):
            rows = system[:, part]
            normal = (rows * w[part]) @ rows.T
            normal *= w_beam
            steps.append(np.linalg.solve(normal[:3, :3] + weak, normal[:3, 3]))
        d = steps[0] - steps[1]
        d[2] = wrap_angle(float(d[2]))
        spread = np.outer(d, d) / 4.0  # the whole scan's error: half the halves' difference
        if np.isfinite(self.split_cov).all():
            self.split_cov = 0.9 * self.split_cov + 0.1 * spread
        else:
            self.split_cov = spread
        c = self.split_cov
        sd_xy = max(p.split_scale * math.sqrt(max(c[0, 0], c[1, 1])), p.split_min)
        sd_yaw = max(p.split_scale * math.sqrt(c[2, 2]), p.split_min / p.map_error_lever)
        return np.array([sd_xy, sd_xy, sd_yaw])


def _median(values: np.ndarray) -> float:
    """``np.median`` of a non-empty 1-D array, by one partition (a tenth of its overhead)."""
    n = len(values)
    k = n // 2
    if n % 2:
        return float(np.partition(values, k)[k])
    part = np.partition(values, (k - 1, k))
    return float((part[k - 1] + part[k]) / 2.0)


def _nis(delta: np.ndarray, info: np.ndarray) -> float:
    d = delta.copy()
    d[2] = wrap_angle(float(d[2]))
    return float(d @ info @ d)


def floor_covariance(cov: np.ndarray, floor: np.ndarray) -> np.ndarray:
    """``cov`` with its eigenvalues (in coordinates scaled by ``floor``) raised to 1."""
    if not np.all(floor > 0.0):
        return cov
    f0, f1, f2 = floor.tolist()
    (a, b, c), (_, d, e), (_, _, f) = cov.tolist()
    # I - cov in floor units positive definite (leading minors): every eigenvalue is raised
    # to 1, so the result is diag(floor^2) whatever the eigenvectors (the usual case: a
    # well-fitting scan pins the pose tighter than the map's error).
    a1, b1, c1 = 1.0 - a / (f0 * f0), -b / (f0 * f1), -c / (f0 * f2)
    d1, e1, f1_ = 1.0 - d / (f1 * f1), -e / (f1 * f2), 1.0 - f / (f2 * f2)
    if a1 > 0.0 and a1 * d1 - b1 * b1 > 0.0 and _det3(a1, b1, c1, d1, e1, f1_) > 0.0:
        return np.diag(floor * floor)
    dinv = np.diag(1.0 / floor)
    cs = dinv @ cov @ dinv
    vals, vecs = np.linalg.eigh(0.5 * (cs + cs.T))
    d = np.diag(floor)
    return d @ ((vecs * np.maximum(vals, 1.0)) @ vecs.T) @ d


def _saturated_step(
    h_full: np.ndarray,
    g_full: np.ndarray,
    dx_prior: tuple[float, float, float],
    prior_info: np.ndarray,
    floor: np.ndarray,
    capped_post: np.ndarray,
) -> tuple[float, float, float] | None:
    """The Gauss-Newton step when the scan's information exceeds the cap in every
    direction, else None (then :func:`_capped_step` decomposes it).

    Why: with every eigenvalue of ``h_full`` in floor units at or above 1 (a scan that sees
    walls around the robot: every scan of the demo patrol), :func:`cap_information` gives
    ``diag(floor^-2)`` whatever the eigenvectors, and the scaled gradient is
    ``floor^-2 * h_full^-1 g_full``; the test (leading minors of ``H - I`` in floor units)
    and the two 3x3 solves are a few dozen float operations, where the eigendecomposition
    and numpy's small-matrix calls cost most of an iteration.
    """
    f0, f1, f2 = floor.tolist()
    (a, b, c), (_, d, e), (_, _, f) = h_full.tolist()
    # H - I in floor units (symmetric): positive definite iff its leading minors are.
    a1, b1, c1 = a * f0 * f0 - 1.0, b * f0 * f1, c * f0 * f2
    d1, e1, f1_ = d * f1 * f1 - 1.0, e * f1 * f2, f * f2 * f2 - 1.0
    m2 = a1 * d1 - b1 * b1
    if a1 <= 0.0 or m2 <= 0.0 or _det3(a1, b1, c1, d1, e1, f1_) <= 0.0:
        return None
    g0, g1, g2 = g_full.tolist()
    u0, u1, u2 = _solve3(a, b, c, d, e, f, g0, g1, g2)
    pi = prior_info.tolist()
    dx0, dx1, dx2 = dx_prior
    rhs = [
        pi[k][0] * dx0 + pi[k][1] * dx1 + pi[k][2] * dx2 + u / (fk * fk)
        for k, (u, fk) in enumerate(((u0, f0), (u1, f1), (u2, f2)))
    ]
    (pa, pb, pc), (_, pd, pe), (_, _, pf) = capped_post.tolist()
    s0, s1, s2 = _solve3(pa, pb, pc, pd, pe, pf, *rhs)
    return (-s0, -s1, -s2)


def _inverse3(m: np.ndarray) -> np.ndarray:
    """Inverse of a symmetric positive definite 3x3 matrix (adjugate over determinant:
    exactly symmetric, and a tenth of ``np.linalg.inv``'s call overhead)."""
    (a, b, c), (_, d, e), (_, _, f) = m.tolist()
    c00, c01, c02 = d * f - e * e, c * e - b * f, b * e - c * d
    c11, c12, c22 = a * f - c * c, b * c - a * e, a * d - b * b
    inv = 1.0 / (a * c00 + b * c01 + c * c02)
    return np.array(
        [
            [c00 * inv, c01 * inv, c02 * inv],
            [c01 * inv, c11 * inv, c12 * inv],
            [c02 * inv, c12 * inv, c22 * inv],
        ]
    )


def _det3(a: float, b: float, c: float, d: float, e: float, f: float) -> float:
    """Determinant of the symmetric matrix [[a, b, c], [b, d, e], [c, e, f]]."""
    return a * (d * f - e * e) - b * (b * f - e * c) + c * (b * e - d * c)


def _solve3(
    a: float, b: float, c: float, d: float, e: float, f: float, y0: float, y1: float, y2: float
) -> tuple[float, float, float]:
    """``M^-1 y`` for the symmetric positive definite M = [[a, b, c], [b, d, e], [c, e, f]]
    (adjugate over determinant)."""
    c00, c01, c02 = d * f - e * e, c * e - b * f, b * e - c * d
    c11, c12, c22 = a * f - c * c, b * c - a * e, a * d - b * b
    det = a * c00 + b * c01 + c * c02
    return (
        (c00 * y0 + c01 * y1 + c02 * y2) / det,
        (c01 * y0 + c11 * y1 + c12 * y2) / det,
        (c02 * y0 + c12 * y1 + c22 * y2) / det,
    )


def _capped_step(
    h_full: np.ndarray, g_full: np.ndarray, floor: np.ndarray, scaled: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """One scan's capped information (:func:`cap_information`) and its gradient scaled
    like it (``h_capped @ pinv(h_full) @ g_full``, so the step stays a Gauss-Newton step),
    from one eigendecomposition in floor units."""
    hs = h_full * scaled
    vals, vecs = np.linalg.eigh(0.5 * (hs + hs.T))
    capped = np.maximum(np.minimum(vals, 1.0), 0.0)
    keep = vals > 1e-9 * max(abs(float(vals[0])), abs(float(vals[-1])), 1e-300)
    ratio = np.where(keep, capped / np.where(keep, vals, 1.0), 0.0)
    h = ((vecs * capped) @ vecs.T) / scaled
    gvec = (vecs @ (ratio * (vecs.T @ (g_full * floor)))) / floor
    return h, gvec
