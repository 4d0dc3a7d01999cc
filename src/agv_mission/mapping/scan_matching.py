"""Scan-to-map matching for the ``grid`` SLAM plugin: correlative search + refinement.

Two stages, as Cartographer's 2D local SLAM does (``RealTimeCorrelativeScanMatcher2D``
followed by the ``CeresScanMatcher2D``):

1. :meth:`CorrelativeMatcher.match` searches a window around the odometry prediction
   (default +-0.2 m, +-10 deg) exhaustively but cheaply: every rotation is scored on a
   coarse grid of translation blocks whose score is an upper bound (a sliding-window
   maximum of the likelihood field, Olson 2009 / Hess et al. 2016), and only the blocks
   whose bound beats the best exact score found so far are expanded to single cells
   (branch and bound over two levels). The result is the global optimum of the window at
   cell / angular-step resolution, so an odometry error of centimetres and degrees per
   scan (a turn in place with slipping wheels) never traps it in a local minimum, the
   weakness of pure gradient matching (hector mapping).
2. A sub-cell refinement from that optimum, a maximum a posteriori estimate when the
   odometry prior's covariance is given:

   * ``"icp"`` (default): point-to-line Gauss-Newton. Each scan point's partner is the
     closest *anchor* (the mean of the scan end points that fell in a cell) among the
     occupied cells around it (its 3 x 3 neighbourhood and its nearest occupied cell,
     so a point on one face of a thin wall is not paired with the other face) that were
     seen from the same side as the point (when the field has ``view``), and its
     residual is measured along the scan's local normal (PCA over neighbouring beams),
     with Huber weights. Walls constrain only across themselves, so sliding along a
     wall is left to the odometry prior instead of to the ripples of a discretised
     field. On a correct map this gives about 2 mm / 1 mrad (the field refinement about
     5 mm / 3 mrad), and that is what keeps a growing map from bending.
   * ``"field"``: hector mapping's objective ``mean (1 - M(T p))^2`` on the bicubic
     (Catmull-Rom) interpolated likelihood field.

   The refinement is accepted when it converges inside the search window (and, for
   ``"field"``, lowers its objective); otherwise the correlative pose stands.

The field is ``exp(-d^2 / (2 sigma^2))`` of the distance ``d`` to the nearest occupied
cell's obstacle point, truncated at ``4 sigma`` (:func:`field_values`). Everything is
vectorised numpy.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np

from agv_mission.geometry import wrap_angle
from agv_mission.mapping.likelihood_field import (
    LikelihoodField,
    bicubic,
    crop_window,
    sliding_max,
)

Refinement = Literal["icp", "field", "none"]


@dataclass
class MatchResult:
    """The matched pose and how good it is."""

    pose: np.ndarray  # (x, y, yaw) in the map frame
    score: float  # mean field value of the scan points at ``pose`` (0..1)
    coarse_pose: np.ndarray  # the correlative optimum before refinement
    refined: bool  # the refinement was accepted
    candidates: int  # exact (cell-level) candidate poses scored
    covariance: np.ndarray | None = None  # (3, 3) of the refined pose, None if not refined


def scan_normals(
    points: np.ndarray, half_window: int = 2, max_spread: float = 0.25, max_ratio: float = 0.05
) -> tuple[np.ndarray, np.ndarray]:
    """Unit normals (N, 2) of angle-ordered scan points by PCA over ``2 half_window + 1``
    neighbours (cyclic), and which are valid: the neighbours lie within ``max_spread`` m
    of the point and on a line (smallest / largest eigenvalue below ``max_ratio``)."""
    n = len(points)
    normals = np.zeros((n, 2))
    if n < 2 * half_window + 1:
        return normals, np.zeros(n, bool)
    idx = (np.arange(n)[None, :] + np.arange(-half_window, half_window + 1)[:, None]) % n
    nb = points[idx]  # (K, N, 2)
    spread_ok = (np.hypot(*(nb - points[None]).transpose(2, 0, 1)) <= max_spread).all(axis=0)
    mean = nb.mean(axis=0)
    d = nb - mean[None]
    sxx = (d[..., 0] ** 2).mean(axis=0)
    syy = (d[..., 1] ** 2).mean(axis=0)
    sxy = (d[..., 0] * d[..., 1]).mean(axis=0)
    half_tr = 0.5 * (sxx + syy)
    root = np.sqrt(0.25 * (sxx - syy) ** 2 + sxy**2)
    lmax, lmin = half_tr + root, half_tr - root
    phi = 0.5 * np.arctan2(2.0 * sxy, sxx - syy)  # major axis
    normals[:, 0], normals[:, 1] = -np.sin(phi), np.cos(phi)
    ok = spread_ok & (lmin <= max_ratio * np.maximum(lmax, 1e-12)) & (lmax > 0)
    return normals, ok


class CorrelativeMatcher:
    """Multi-resolution correlative scan matcher with sub-cell refinement.

    ``linear_window`` (m) and ``angular_window`` (rad) bound the search around the guess;
    ``angular_step`` (rad, ``None``: the angle that moves the farthest point by one cell);
    ``coarse_block`` (cells, power of two) is the size of the translation blocks of the
    first level; ``translation_weight`` (1/m) and ``rotation_weight`` (1/rad) multiply each
    candidate's score by ``exp(-(wt |dt| + wr |dyaw|)^2)`` (Cartographer's delta cost
    weights), which breaks ties toward the prediction where the scan is ambiguous, e.g.
    along a single wall. ``refinement`` picks the second stage (see the module);
    ``point_sigma`` (m) is the std of an ``"icp"`` residual and ``scan_sigma`` that of a
    ``"field"`` residual (``1 - M``) times the square root of the point count: they weigh
    the scan against the prior.
    """

    def __init__(
        self,
        linear_window: float = 0.2,
        angular_window: float = math.radians(10.0),
        angular_step: float | None = None,
        coarse_block: int = 4,
        translation_weight: float = 1.0,
        rotation_weight: float = 1.0,
        refinement: Refinement = "icp",
        iterations: int = 6,
        point_sigma: float = 0.03,
        huber: float = 0.03,
        max_correspondence: float = 0.15,
        scan_sigma: float = 0.1,
    ) -> None:
        if coarse_block & (coarse_block - 1) or coarse_block < 1:
            raise ValueError(f"coarse_block must be a power of two, got {coarse_block}")
        self.linear_window = float(linear_window)
        self.angular_window = float(angular_window)
        self.angular_step = angular_step
        self.coarse_block = int(coarse_block)
        self.translation_weight = float(translation_weight)
        self.rotation_weight = float(rotation_weight)
        self.refinement = refinement
        self.iterations = int(iterations)
        self.point_sigma = float(point_sigma)
        self.huber = float(huber)
        self.max_correspondence = float(max_correspondence)
        self.scan_sigma = float(scan_sigma)

    # ------------------------------------------------------------------ public

    def match(
        self,
        field: LikelihoodField,
        points: np.ndarray,
        guess: np.ndarray,
        prior_cov: np.ndarray | None = None,
    ) -> MatchResult:
        """Best pose of the robot-frame, angle-ordered ``points`` (N, 2) in ``field`` near
        ``guess``.

        ``prior_cov`` (3x3, x / y / yaw) makes the refinement a maximum a posteriori
        estimate with ``guess`` as the prior mean (the odometry prediction and its
        uncertainty); without it the refinement fits the scan alone.
        """
        points = np.asarray(points, dtype=np.float64).reshape(-1, 2)
        guess = np.asarray(guess, dtype=np.float64)
        res = field.resolution
        if len(points) == 0:
            return MatchResult(guess.copy(), 0.0, guess.copy(), False, 0)
        reach = float(np.sqrt((points**2).sum(axis=1)).max())
        n_lin = max(int(round(self.linear_window / res)), 0)
        step = self.angular_step
        if step is None:
            step = math.acos(max(-1.0, 1.0 - res * res / (2.0 * max(reach, res) ** 2)))
        n_ang = max(int(math.ceil(self.angular_window / step - 1e-9)), 0)
        block = self.coarse_block

        # A zero-padded crop of the field centred on the guess that holds every candidate.
        half = int(math.ceil(reach / res)) + n_lin + block + 2
        gr = int(math.floor((guess[1] - field.origin[1]) / res))
        gc = int(math.floor((guess[0] - field.origin[0]) / res))
        size = 2 * half + 1
        crop = crop_window(field.values, gr - half, gc - half, size, size)
        cox = field.origin[0] + (gc - half) * res
        coy = field.origin[1] + (gr - half) * res
        flat = crop.ravel()

        # Rotated points -> flat cell indices, (A, N).
        dyaw = step * np.arange(-n_ang, n_ang + 1)
        yaws = guess[2] + dyaw
        c, s = np.cos(yaws)[:, None], np.sin(yaws)[:, None]
        px, py = points[:, 0][None, :], points[:, 1][None, :]
        wx = guess[0] + c * px - s * py
        wy = guess[1] + s * px + c * py
        cols = np.clip(np.floor((wx - cox) / res).astype(np.int64), n_lin, size - n_lin - block)
        rows = np.clip(np.floor((wy - coy) / res).astype(np.int64), n_lin, size - n_lin - block)
        base = rows * size + cols  # (A, N)
        n_pts = float(len(points))

        # Level 1: translation blocks scored with the sliding max (an upper bound).
        starts = np.arange(-n_lin, n_lin + 1, block)
        sy, sx = np.meshgrid(starts, starts, indexing="ij")
        sy, sx = sy.ravel(), sx.ravel()
        coarse = sliding_max(crop, block).ravel()
        offsets = sy * size + sx  # (K,)
        bound = coarse[base[:, None, :] + offsets[None, :, None]].sum(axis=2) / n_pts  # (A, K)
        # Smallest |offset| per axis within each block, for the penalty bound.
        ends = np.minimum(starts + block - 1, n_lin)
        nearest = np.where((starts <= 0) & (ends >= 0), 0, np.minimum(abs(starts), abs(ends)))
        ny, nx = np.meshgrid(nearest, nearest, indexing="ij")
        t_min = np.hypot(ny.ravel(), nx.ravel()) * res  # (K,)
        bound = bound * self._penalty(t_min[None, :], dyaw[:, None])
        order = np.argsort(bound, axis=None)[::-1]
        bound_sorted = bound.ravel()[order]

        # Level 0: expand blocks in order of their bound until none can beat the best.
        inner = np.arange(block)
        iy, ix = np.meshgrid(inner, inner, indexing="ij")
        iy, ix = iy.ravel(), ix.ravel()
        best = (-1.0, 0, 0, 0)  # score, angle index, dy, dx
        evaluated = 0
        pos, batch = 0, 4
        while pos < len(order) and bound_sorted[pos] > best[0]:
            chunk = order[pos : pos + batch]
            chunk = chunk[bound.ravel()[chunk] > best[0]]
            pos += batch
            if len(chunk) == 0:
                break
            a_idx, k_idx = np.divmod(chunk, len(sy))
            dy = sy[k_idx][:, None] + iy[None, :]  # (C, B*B)
            dx = sx[k_idx][:, None] + ix[None, :]
            valid = (dy <= n_lin) & (dx <= n_lin)
            off = dy * size + dx
            scores = flat[base[a_idx][:, None, :] + off[:, :, None]].sum(axis=2) / n_pts
            scores = scores * self._penalty(np.hypot(dy, dx) * res, dyaw[a_idx][:, None])
            scores[~valid] = -1.0
            evaluated += int(valid.sum())
            i = int(np.argmax(scores))
            ci, bi = divmod(i, scores.shape[1])
            if scores[ci, bi] > best[0]:
                best = (float(scores[ci, bi]), int(a_idx[ci]), int(dy[ci, bi]), int(dx[ci, bi]))

        _, ai, dy, dx = best
        coarse_pose = np.array([guess[0] + dx * res, guess[1] + dy * res, yaws[ai]])
        pose, refined, cov = coarse_pose, False, None
        mode = self.refinement
        if mode == "icp" and (field.nearest is None or field.anchor is None):
            mode = "field"
        if mode != "none" and self.iterations > 0:
            prior_info = None if prior_cov is None else np.linalg.inv(prior_cov)
            # The correlative optimum is only good to a cell: within one cell / one step
            # of the prediction, refine from the prediction, so that a direction the scan
            # cannot observe (along a wall) keeps the odometry instead of a noisy cell.
            start = coarse_pose
            if abs(dx) <= 1 and abs(dy) <= 1 and abs(dyaw[ai]) <= step * 1.0001:
                start = guess
            if mode == "icp":
                cand, cov_cand = self._icp(field, points, start, guess, prior_info)
                better = cand is not None
            else:
                cand, cov_cand = self._gauss_newton(field, points, start, guess, prior_info)
                before = self._field_cost(field, points, coarse_pose, guess, prior_info)
                better = self._field_cost(field, points, cand, guess, prior_info) < before
            if better:
                inside = (
                    abs(cand[0] - guess[0]) <= self.linear_window + res
                    and abs(cand[1] - guess[1]) <= self.linear_window + res
                    and abs(wrap_angle(cand[2] - guess[2])) <= self.angular_window + step
                )
                if inside:
                    pose, refined, cov = cand, True, cov_cand
        pose = pose.copy()
        pose[2] = wrap_angle(pose[2])
        score = self.score(field, points, pose)
        return MatchResult(pose, score, coarse_pose, refined, evaluated, cov)

    @staticmethod
    def score(
        field: LikelihoodField, points: np.ndarray, pose: np.ndarray, interpolate: bool = False
    ) -> float:
        """Mean field value of robot-frame ``points`` seen from ``pose`` (nearest cell, or
        bicubic with ``interpolate``)."""
        if len(points) == 0:
            return 0.0
        wx, wy = _transform(points, pose)
        if interpolate:
            m, _, _ = bicubic(field, wx, wy)
        else:
            res = field.resolution
            cols = np.floor((wx - field.origin[0]) / res).astype(np.int64)
            rows = np.floor((wy - field.origin[1]) / res).astype(np.int64)
            h, w = field.values.shape
            inside = (rows >= 0) & (rows < h) & (cols >= 0) & (cols < w)
            m = np.zeros(len(wx), np.float32)
            m[inside] = field.values[rows[inside], cols[inside]]
        return float(np.mean(m))

    # ------------------------------------------------------------------ internals

    def _penalty(self, translation: np.ndarray, rotation: np.ndarray) -> np.ndarray:
        cost = self.translation_weight * translation + self.rotation_weight * np.abs(rotation)
        return np.exp(-(cost**2))

    def _icp(
        self,
        field: LikelihoodField,
        points: np.ndarray,
        start: np.ndarray,
        prior_mean: np.ndarray,
        prior_info: np.ndarray | None,
    ) -> tuple[np.ndarray | None, np.ndarray | None]:
        """Point-to-line Gauss-Newton against the map's obstacle points (see the module);
        ``(None, None)`` when too few points find a partner."""
        assert field.nearest is not None and field.anchor is not None
        normals, ok = scan_normals(points)
        if ok.sum() < 10:
            return None, None
        p, nrm = points[ok], normals[ok]
        # Normals point back at the scanner (the robot frame's origin): the side of the
        # surface the point was seen from.
        nrm = np.where(((nrm * p).sum(axis=1) > 0.0)[:, None], -nrm, nrm)
        info = np.zeros((3, 3)) if prior_info is None else prior_info
        x = start.astype(np.float64).copy()
        hess = None
        for _ in range(self.iterations):
            c, s = math.cos(x[2]), math.sin(x[2])
            wx = x[0] + c * p[:, 0] - s * p[:, 1]
            wy = x[1] + s * p[:, 0] + c * p[:, 1]
            side = (c * nrm[:, 0] - s * nrm[:, 1], s * nrm[:, 0] + c * nrm[:, 1])
            qx, qy, has = _partners(field, wx, wy, side)
            if has.sum() < 10:
                return None, None
            ex, ey = wx[has] - qx[has], wy[has] - qy[has]
            keep = ex * ex + ey * ey <= self.max_correspondence**2
            if keep.sum() < 10:
                return None, None
            ex, ey = ex[keep], ey[keep]
            nx_r, ny_r = nrm[has][keep, 0], nrm[has][keep, 1]
            px, py = p[has][keep, 0], p[has][keep, 1]
            nx, ny = c * nx_r - s * ny_r, s * nx_r + c * ny_r
            r = nx * ex + ny * ey
            a = np.abs(r)
            weight = np.where(a <= self.huber, 1.0, self.huber / np.maximum(a, 1e-12))
            weight /= self.point_sigma**2
            jac = np.stack([nx, ny, nx * (-s * px - c * py) + ny * (c * px - s * py)], axis=1)
            e = x - prior_mean
            e[2] = wrap_angle(e[2])
            hess = (jac * weight[:, None]).T @ jac + info
            g = jac.T @ (weight * r) + info @ e
            try:
                delta = -np.linalg.solve(hess + 1e-9 * np.eye(3), g)
            except np.linalg.LinAlgError:
                return None, None
            x += delta
            if abs(delta[0]) < 1e-4 and abs(delta[1]) < 1e-4 and abs(delta[2]) < 1e-4:
                break
        if hess is None:
            return None, None
        try:
            cov = np.linalg.inv(hess)
        except np.linalg.LinAlgError:
            cov = None
        return x, cov

    def _field_cost(
        self,
        field: LikelihoodField,
        points: np.ndarray,
        pose: np.ndarray,
        prior_mean: np.ndarray,
        prior_info: np.ndarray | None,
    ) -> float:
        wx, wy = _transform(points, pose)
        m, _, _ = bicubic(field, wx, wy)
        cost = float(np.mean((1.0 - m) ** 2)) / self.scan_sigma**2
        if prior_info is not None:
            e = pose - prior_mean
            e[2] = wrap_angle(e[2])
            cost += float(e @ prior_info @ e)
        return cost

    def _gauss_newton(
        self,
        field: LikelihoodField,
        points: np.ndarray,
        start: np.ndarray,
        prior_mean: np.ndarray,
        prior_info: np.ndarray | None,
    ) -> tuple[np.ndarray, np.ndarray | None]:
        """Gauss-Newton on ``mean (1 - M(T p))^2 / scan_sigma^2 + prior`` (hector mapping's
        objective plus the odometry prior, as Cartographer's Ceres matcher); returns the
        pose and its covariance (the inverse Gauss-Newton Hessian)."""
        x = start.astype(np.float64).copy()
        px, py = points[:, 0], points[:, 1]
        w = 1.0 / (len(points) * self.scan_sigma**2)
        info = np.zeros((3, 3)) if prior_info is None else prior_info
        h = info
        for _ in range(self.iterations):
            wx, wy = _transform(points, x)
            m, gx, gy = bicubic(field, wx, wy)
            r = 1.0 - m
            c, s = math.cos(x[2]), math.sin(x[2])
            dth = gx * (-s * px - c * py) + gy * (c * px - s * py)
            jac = -np.stack([gx, gy, dth], axis=1)  # d r / d (x, y, yaw)
            e = x - prior_mean
            e[2] = wrap_angle(e[2])
            h = w * (jac.T @ jac) + info
            g = w * (jac.T @ r) + info @ e
            damping = 1e-6 * np.trace(h) / 3.0 + 1e-12
            try:
                delta = -np.linalg.solve(h + damping * np.eye(3), g)
            except np.linalg.LinAlgError:
                break
            x += delta
            if abs(delta[0]) < 1e-5 and abs(delta[1]) < 1e-5 and abs(delta[2]) < 1e-5:
                break
        try:
            cov = np.linalg.inv(h)
        except np.linalg.LinAlgError:
            cov = None
        return x, cov


_NEIGHBOURS = np.array([(dr, dc) for dr in (-1, 0, 1) for dc in (-1, 0, 1)])


def _partners(
    field: LikelihoodField,
    wx: np.ndarray,
    wy: np.ndarray,
    side: tuple[np.ndarray, np.ndarray] | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The map obstacle point (anchor) closest to each map-frame point among the
    occupied cells of its 3 x 3 neighbourhood and its nearest occupied cell, and whether
    one exists. Looking at the neighbourhood matters at thin walls: the nearest cell by
    centre distance may hold the far face of the wall.

    With ``side`` (map-frame normals of the points, facing the scanner) and the field's
    ``view``, cells whose surface was seen from the other side are no partners: the
    first time a thin wall is seen from its second side only its first face is in the
    map, a wall's thickness away, and pairing with it would shift the pose by that
    much (and the map with it)."""
    assert field.nearest is not None and field.anchor is not None
    near_r, near_c = field.nearest
    ax, ay = field.anchor
    h, w = near_r.shape
    res, (ox, oy) = field.resolution, field.origin
    cols = np.floor((wx - ox) / res).astype(np.int64)
    rows = np.floor((wy - oy) / res).astype(np.int64)
    inside = (rows >= 1) & (rows < h - 1) & (cols >= 1) & (cols < w - 1)
    rows, cols = np.where(inside, rows, 1), np.where(inside, cols, 1)
    cr = rows[:, None] + _NEIGHBOURS[None, :, 0]  # (N, 9)
    cc = cols[:, None] + _NEIGHBOURS[None, :, 1]
    occ = (near_r[cr, cc] == cr) & (near_c[cr, cc] == cc)
    nr, nc = near_r[rows, cols][:, None], near_c[rows, cols][:, None]
    cr = np.concatenate([cr, np.maximum(nr, 0)], axis=1)  # (N, 10)
    cc = np.concatenate([cc, np.maximum(nc, 0)], axis=1)
    occ = np.concatenate([occ, nr >= 0], axis=1) & inside[:, None]
    if side is not None and field.view is not None:
        facing = field.view[0][cr, cc] * side[0][:, None] + field.view[1][cr, cc] * side[1][:, None]
        occ &= facing >= 0.0
    qx = ox + (cc + 0.5) * res + ax[cr, cc]
    qy = oy + (cr + 0.5) * res + ay[cr, cc]
    d2 = np.where(occ, (qx - wx[:, None]) ** 2 + (qy - wy[:, None]) ** 2, np.inf)
    best = np.argmin(d2, axis=1)
    k = np.arange(len(wx))
    return qx[k, best], qy[k, best], occ.any(axis=1)


def _transform(points: np.ndarray, pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    c, s = math.cos(pose[2]), math.sin(pose[2])
    px, py = points[:, 0], points[:, 1]
    return pose[0] + c * px - s * py, pose[1] + s * px + c * py
