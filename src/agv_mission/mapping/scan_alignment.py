"""The second stage of scan matching: a sub-cell refinement of the correlative optimum
(see :mod:`scan_matching`), a maximum a posteriori estimate when the odometry prior is
given (:class:`PosePrior`).

* :func:`icp`: point-to-line Gauss-Newton against the map's obstacle points (anchors),
  each scan point paired along its local normal (:func:`scan_normals`) with the closest
  anchor seen from the same side (:class:`Partners`), with Huber weights.
* :func:`gauss_newton`: hector mapping's objective ``mean (1 - M(T p))^2`` on the
  bicubic interpolated likelihood field (:func:`field_cost`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from agv_mission.geometry import wrap_angle
from agv_mission.mapping.likelihood_field import LikelihoodField, bicubic


@dataclass(frozen=True)
class PosePrior:
    """The odometry prediction a refinement is pulled toward: its mean pose and its
    information matrix (zeros when there is none: the scan alone decides)."""

    mean: np.ndarray  # (x, y, yaw)
    info: np.ndarray  # (3, 3)
    given: bool

    @classmethod
    def of(cls, mean: np.ndarray, cov: np.ndarray | None) -> PosePrior:
        """The prior of mean ``mean`` and covariance ``cov`` (None: no prior)."""
        info = np.zeros((3, 3)) if cov is None else inverse3(cov)
        return cls(mean, info, cov is not None)

    def error(self, pose: np.ndarray) -> np.ndarray:
        """``pose - mean`` with the yaw difference wrapped."""
        e = pose - self.mean
        e[2] = wrap_angle(e[2])
        return e

    def cost(self, pose: np.ndarray) -> float:
        """The prior's term of the objective at ``pose`` (0 without a prior)."""
        if not self.given:
            return 0.0
        e = self.error(pose)
        return float(e @ self.info @ e)


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
    k = 2 * half_window + 1
    d = nb - _mean0(nb, k)[None]
    sxx = _mean0(d[..., 0] ** 2, k)
    syy = _mean0(d[..., 1] ** 2, k)
    sxy = _mean0(d[..., 0] * d[..., 1], k)
    half_tr = 0.5 * (sxx + syy)
    root = np.sqrt(0.25 * (sxx - syy) ** 2 + sxy**2)
    lmax, lmin = half_tr + root, half_tr - root
    phi = 0.5 * np.arctan2(2.0 * sxy, sxx - syy)  # major axis
    normals[:, 0], normals[:, 1] = -np.sin(phi), np.cos(phi)
    ok = spread_ok & (lmin <= max_ratio * np.maximum(lmax, 1e-12)) & (lmax > 0)
    return normals, ok


def _mean0(values: np.ndarray, count: int) -> np.ndarray:
    """``values.mean(axis=0)`` of ``count`` rows, the same sum and division without the
    method's generic wrapper (called per refinement, it cost as much as the sums)."""
    total = np.add.reduce(values, axis=0)
    total /= count
    return total


def icp(
    field: LikelihoodField,
    points: np.ndarray,
    start: np.ndarray,
    prior: PosePrior,
    iterations: int,
    point_sigma: float,
    huber: float,
    max_correspondence: float,
) -> tuple[np.ndarray | None, np.ndarray | None]:
    """Point-to-line Gauss-Newton against the map's obstacle points (see the module) from
    ``start``; the pose and its covariance, ``(None, None)`` when too few points find a
    partner. ``point_sigma`` is the std of a residual, ``huber`` its Huber threshold."""
    assert field.nearest is not None and field.anchor is not None
    normals, ok = scan_normals(points)
    if ok.sum() < 10:
        return None, None
    p, nrm = points[ok], normals[ok]
    # Normals point back at the scanner (the robot frame's origin): the side of the
    # surface the point was seen from.
    nrm = np.where(((nrm * p).sum(axis=1) > 0.0)[:, None], -nrm, nrm)
    info = prior.info
    px_all, py_all = p[:, 0].copy(), p[:, 1].copy()
    nx_all, ny_all = nrm[:, 0].copy(), nrm[:, 1].copy()
    x = start.astype(np.float64).copy()
    hess = None
    find = Partners(field)
    for _ in range(iterations):
        c, s = math.cos(x[2]), math.sin(x[2])
        wx = x[0] + c * px_all - s * py_all
        wy = x[1] + s * px_all + c * py_all
        side = (c * nx_all - s * ny_all, s * nx_all + c * ny_all)
        qx, qy, has = find(wx, wy, side)
        idx = np.flatnonzero(has)
        if len(idx) < 10:
            return None, None
        ex, ey = wx[idx] - qx[idx], wy[idx] - qy[idx]
        keep = ex * ex + ey * ey <= max_correspondence**2
        idx = idx[keep]
        if len(idx) < 10:
            return None, None
        ex, ey = ex[keep], ey[keep]
        # The rotated normals of the pairs: ``side`` at them (the same arithmetic).
        nx, ny = side[0][idx], side[1][idx]
        px, py = px_all[idx], py_all[idx]
        r = nx * ex + ny * ey
        a = np.abs(r)
        weight = np.where(a <= huber, 1.0, huber / np.maximum(a, 1e-12))
        weight /= point_sigma**2
        jac = np.empty((len(idx), 3))  # what np.stack(..., axis=1) makes, at less cost
        jac[:, 0], jac[:, 1] = nx, ny
        jac[:, 2] = nx * (-s * px - c * py) + ny * (c * px - s * py)
        e = prior.error(x)
        hess = (jac * weight[:, None]).T @ jac + info
        g = jac.T @ (weight * r) + info @ e
        try:
            delta = -(inverse3(hess + _DAMPING) @ g)
        except np.linalg.LinAlgError:
            return None, None
        x += delta
        if abs(delta[0]) < 1e-4 and abs(delta[1]) < 1e-4 and abs(delta[2]) < 1e-4:
            break
    if hess is None:
        return None, None
    try:
        cov = inverse3(hess)
    except np.linalg.LinAlgError:
        cov = None
    return x, cov


_DAMPING = 1e-9 * np.eye(3)


def inverse3(m: np.ndarray) -> np.ndarray:
    """The inverse of a 3 x 3 matrix by its adjugate: what ``np.linalg.inv`` gives (to
    rounding) at a tenth of its cost, which on 3 x 3 matrices is all call overhead (the
    matcher solves one per iteration, thousands per log). Raises ``LinAlgError`` when
    ``m`` is singular."""
    (a, b, c), (d, e, f), (g, h, i) = m.tolist()
    c00, c01, c02 = e * i - f * h, f * g - d * i, d * h - e * g
    det = a * c00 + b * c01 + c * c02
    if det == 0.0 or not math.isfinite(det):
        raise np.linalg.LinAlgError("singular 3 x 3 matrix")
    r = 1.0 / det
    return np.array(
        [
            [c00 * r, (c * h - b * i) * r, (b * f - c * e) * r],
            [c01 * r, (a * i - c * g) * r, (c * d - a * f) * r],
            [c02 * r, (b * g - a * h) * r, (a * e - b * d) * r],
        ]
    )


def field_cost(
    field: LikelihoodField,
    points: np.ndarray,
    pose: np.ndarray,
    prior: PosePrior,
    scan_sigma: float,
) -> float:
    """The objective :func:`gauss_newton` lowers, at ``pose``."""
    wx, wy = transform_points(points, pose)
    m, _, _ = bicubic(field, wx, wy)
    return float(np.mean((1.0 - m) ** 2)) / scan_sigma**2 + prior.cost(pose)


def gauss_newton(
    field: LikelihoodField,
    points: np.ndarray,
    start: np.ndarray,
    prior: PosePrior,
    iterations: int,
    scan_sigma: float,
) -> tuple[np.ndarray, np.ndarray | None]:
    """Gauss-Newton on ``mean (1 - M(T p))^2 / scan_sigma^2 + prior`` (hector mapping's
    objective plus the odometry prior, as Cartographer's Ceres matcher); returns the
    pose and its covariance (the inverse Gauss-Newton Hessian)."""
    x = start.astype(np.float64).copy()
    px, py = points[:, 0], points[:, 1]
    w = 1.0 / (len(points) * scan_sigma**2)
    info = prior.info
    h = info
    for _ in range(iterations):
        wx, wy = transform_points(points, x)
        m, gx, gy = bicubic(field, wx, wy)
        r = 1.0 - m
        c, s = math.cos(x[2]), math.sin(x[2])
        dth = gx * (-s * px - c * py) + gy * (c * px - s * py)
        jac = -np.stack([gx, gy, dth], axis=1)  # d r / d (x, y, yaw)
        e = prior.error(x)
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


class Partners:
    """Each map-frame point's partner for :func:`icp`: the map obstacle point (anchor)
    closest to it among the occupied cells of its 3 x 3 neighbourhood and its nearest
    occupied cell. Looking at the neighbourhood matters at thin walls: the nearest cell
    by centre distance may hold the far face of the wall.

    With the points' ``side`` (map-frame normals, facing the scanner) and the field's
    ``view``, cells whose surface was seen from the other side are no partners: the
    first time a thin wall is seen from its second side only its first face is in the
    map, a wall's thickness away, and pairing with it would shift the pose by that
    much (and the map with it).

    One per refinement against one field: what a point's candidates are (the ten cells,
    which hold an obstacle, their anchors' map-frame points and view sides) depends on
    its cell alone, and between two Gauss-Newton iterations only about one point in ten
    changes cell: those are looked up again, the rest keep theirs, so that an iteration
    costs the side test and the distances only (the matcher's hottest loop). The tables
    are read by flat index (``take``): numpy's two-index gathers cost several times
    more."""

    def __init__(self, field: LikelihoodField) -> None:
        assert field.nearest is not None and field.anchor is not None
        self.near_r, self.near_c = (a.reshape(-1) for a in field.nearest)
        self.h, self.w = h, w = field.nearest[0].shape
        self.res, (self.ox, self.oy) = field.resolution, field.origin
        self.anchor = tuple(a.reshape(-1) for a in field.anchor)
        self.view = None if field.view is None else tuple(v.reshape(-1) for v in field.view)
        # Cell centres by column and by row: ``ox + (col + 0.5) res`` as a table.
        self.centre_x = self.ox + (np.arange(w) + 0.5) * self.res
        self.centre_y = self.oy + (np.arange(h) + 0.5) * self.res
        self.offsets = _NEIGHBOURS[:, 0] * w + _NEIGHBOURS[:, 1]
        self._key: tuple[np.ndarray, np.ndarray] | None = None  # the points' cells
        # Per point (N, 10): candidate holds an obstacle, its x, y, view x, y (see _lookup).
        self._found: tuple[np.ndarray | None, ...] = ()
        self._stride = np.zeros(0, np.int64)  # each point's first flat index in (N, 10)

    def __call__(
        self, wx: np.ndarray, wy: np.ndarray, side: tuple[np.ndarray, np.ndarray] | None = None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The partners' x and y of these map-frame points, and whether each has one."""
        cols = np.floor((wx - self.ox) / self.res).astype(np.int64)
        rows = np.floor((wy - self.oy) / self.res).astype(np.int64)
        n = len(wx)
        if self._key is None or len(self._key[0]) != n:
            self._found = self._lookup(rows, cols)
            self._stride = np.arange(0, 10 * n, 10)
        else:
            moved = np.flatnonzero((rows != self._key[0]) | (cols != self._key[1]))
            if len(moved):
                for table, new in zip(
                    self._found, self._lookup(rows[moved], cols[moved]), strict=True
                ):
                    if table is not None:
                        table[moved] = new
        self._key = (rows, cols)
        occ, qx, qy, vx, vy = self._found
        if side is not None and vx is not None:
            occ = occ & (vx * side[0][:, None] + vy * side[1][:, None] >= 0.0)
        dx = qx - wx[:, None]
        dx **= 2
        dy = qy - wy[:, None]
        dy **= 2
        dx += dy
        best = np.argmin(np.where(occ, dx, np.inf), axis=1) + self._stride
        return qx.reshape(-1).take(best), qy.reshape(-1).take(best), occ.any(axis=1)

    def _lookup(self, rows: np.ndarray, cols: np.ndarray) -> tuple[np.ndarray | None, ...]:
        """Per point of cell (``rows``, ``cols``): which of its ten candidate cells hold
        an obstacle, their anchors' map-frame x and y, their view sides (None without
        views); (N, 10) each."""
        h, w = self.h, self.w
        inside = (rows >= 1) & (rows < h - 1) & (cols >= 1) & (cols < w - 1)
        rows, cols = np.where(inside, rows, 1), np.where(inside, cols, 1)
        n = len(rows)
        cr = np.empty((n, 10), np.int64)
        cc = np.empty((n, 10), np.int64)
        np.add(rows[:, None], _NEIGHBOURS[None, :, 0], out=cr[:, :9])
        np.add(cols[:, None], _NEIGHBOURS[None, :, 1], out=cc[:, :9])
        own = rows * w + cols
        cells = np.empty((n, 10), np.int64)
        np.add(own[:, None], self.offsets[None, :], out=cells[:, :9])
        occ = np.empty((n, 10), bool)
        np.equal(self.near_r.take(cells[:, :9]), cr[:, :9], out=occ[:, :9])
        occ[:, :9] &= self.near_c.take(cells[:, :9]) == cc[:, :9]
        nr, nc = self.near_r.take(own), self.near_c.take(own)
        occ[:, 9] = nr >= 0
        cr[:, 9], cc[:, 9] = np.maximum(nr, 0), np.maximum(nc, 0)
        cells[:, 9] = cr[:, 9] * w + cc[:, 9]
        occ &= inside[:, None]
        qx = self.centre_x.take(cc) + self.anchor[0].take(cells)
        qy = self.centre_y.take(cr) + self.anchor[1].take(cells)
        if self.view is None:
            return occ, qx, qy, None, None
        return occ, qx, qy, self.view[0].take(cells), self.view[1].take(cells)


def transform_points(points: np.ndarray, pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Map-frame (x, y) of robot-frame ``points`` (N, 2) seen from ``pose``."""
    c, s = math.cos(pose[2]), math.sin(pose[2])
    px, py = points[:, 0], points[:, 1]
    return pose[0] + c * px - s * py, pose[1] + s * px + c * py
