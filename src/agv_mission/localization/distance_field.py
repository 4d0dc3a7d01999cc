"""The map's signed distance field, bilinear: what scan-to-map refinement matches against.

Apart from :mod:`agv_mission.localization.pose_tracker` because it is a per-map table
(built once per map, :func:`signed_distance_field` caches it), not the tracker's logic.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import ndimage

from agv_mission.maps.grid import OccupancyGrid
from agv_mission.maps.map_cache import map_table

#: Cells at or above this value count as occupied (map_server's occupied_thresh 0.65).
OCCUPIED_THRESHOLD = 65


class SignedDistanceField:
    """Signed distance (m) to the boundary of the occupied cells, bilinear between centres.

    Positive in free (and unknown) space, negative inside walls and in the unknown space
    right behind them, zero on a wall's face:
    a free cell next to a wall holds ``+res / 2`` and the wall cell ``-res / 2``, so the
    interpolated zero lies on the face the simulated lidar (walls built from the same
    cells) hits. Clipped at ``max_distance``; points off the map read ``max_distance``
    with no gradient.
    """

    def __init__(self, grid: OccupancyGrid, max_distance: float = 1.0) -> None:
        res = float(grid.resolution)
        occupied = grid.data >= OCCUPIED_THRESHOLD
        self.resolution = res
        self.origin = grid.origin
        self.max_distance = float(max_distance)
        free = (grid.data >= 0) & ~occupied
        if occupied.any() and free.any():
            to_wall = ndimage.distance_transform_edt(~occupied)
            to_free = ndimage.distance_transform_edt(~free)
            # Unknown cells closer to a wall than to free space lie behind that wall (the
            # far side of a thin wall): inside, so an end point pushed through a wall is
            # pulled back rather than out. Other unknown cells count as free, as in amcl.
            inside = occupied | ((grid.data < 0) & (to_wall < to_free))
            sdf = np.where(inside, -(to_free - 0.5), to_wall - 0.5) * res
        else:
            sdf = np.full(occupied.shape, -max_distance if occupied.any() else max_distance)
        sdf = np.clip(sdf, -max_distance, max_distance)
        # One cell of padding so that the four corners of every in-map point exist.
        self.values = np.pad(sdf, 1, constant_values=max_distance).astype(np.float64)
        self.height, self.width = self.values.shape
        c, s = math.cos(grid.origin.yaw), math.sin(grid.origin.yaw)
        self._rot = np.array([[c, -s], [s, c]])
        # The bilinear patch of every cell as [s00, s01 - s00, s10 - s00, s11 - s10 - s01
        # + s00] over a second ring of padding: a lookup is one gather, and a point off the
        # map, clamped onto the outer ring, reads max_distance with no gradient.
        v = np.pad(self.values, 1, constant_values=max_distance)
        s00, s01, s10, s11 = v[:-1, :-1], v[:-1, 1:], v[1:, :-1], v[1:, 1:]
        # Stored as four rows (coefficient, cell): a gather of M cells gives four contiguous
        # rows of M, which the scan matching works on without strided copies.
        self._patches = np.stack((s00, s01 - s00, s10 - s00, s11 - s10 - s01 + s00)).reshape(4, -1)
        self.values.flags.writeable = False  # shared between runs (map_cache)
        self._patches.flags.writeable = False
        self._patch_cols = v.shape[1] - 1
        self._last_patch = np.array([v.shape[1] - 2, v.shape[0] - 2], dtype=np.float64)
        self._last_patch_col = self._last_patch[:, None]
        self._patch_stride = np.array([1.0, float(self._patch_cols)])

    def lookup(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Distances (N,) and map-frame gradients (N, 2) at map-frame points ``xy`` (N, 2)."""
        o = self.origin
        p = np.asarray(xy, dtype=np.float64) - (o.x, o.y)
        if o.yaw != 0.0:
            p = p @ self._rot  # into the grid frame (R^T p, row-wise)
        inv = 1.0 / self.resolution
        uv = p * inv + 1.5  # cell-centre coordinates in the twice padded grid
        cell = np.floor(uv)
        np.maximum(np.minimum(cell, self._last_patch, out=cell), 0.0, out=cell)
        frac = uv - cell
        np.maximum(np.minimum(frac, 1.0, out=frac), 0.0, out=frac)
        idx = cell.astype(np.intp)
        s00, du, dv, t = np.take(self._patches, idx[:, 1] * self._patch_cols + idx[:, 0], axis=1)
        fu, fv = frac[:, 0], frac[:, 1]
        d = s00 + du * fu + (dv + t * fu) * fv
        grad = np.empty_like(p)
        grad[:, 0] = (du + t * fv) * inv
        grad[:, 1] = (dv + t * fu) * inv
        if o.yaw != 0.0:
            grad = grad @ self._rot.T
        return d, grad

    def scan_system(
        self, pts: np.ndarray, pose: tuple[float, float, float], offset: float, out: np.ndarray
    ) -> np.ndarray:
        """Fill ``out`` (4, M) with the Jacobian rows (3, M) of the distances at robot-frame
        points ``pts`` (2, M) seen from ``pose`` (x, y, yaw) with respect to the pose, and
        the distances minus ``offset``: one scan-matching iteration's :meth:`lookup` and
        chain rule in few numpy calls on contiguous rows (at 360 points the calls'
        overhead is the cost).

        Worked in the grid's cells: the points turned by the pose's yaw relative to the
        grid (``q``) and shifted onto the pose give the cells; the yaw row is the gradient
        (per cell) dotted with the turned point's derivative, ``(-q_y, q_x)``.
        """
        o = self.origin
        inv = 1.0 / self.resolution
        phi = pose[2] - o.yaw
        c, s = math.cos(phi) * inv, math.sin(phi) * inv
        q = np.array([[c, -s], [s, c]]) @ pts  # turned into the grid frame, in cells
        dx, dy = pose[0] - o.x, pose[1] - o.y
        co, so = math.cos(o.yaw), math.sin(o.yaw)
        shift = [[(co * dx + so * dy) * inv + 1.5], [(co * dy - so * dx) * inv + 1.5]]
        uv = q + shift  # cell-centre coordinates in the twice padded grid
        cell = np.floor(uv)
        np.maximum(np.minimum(cell, self._last_patch_col, out=cell), 0.0, out=cell)
        frac = np.subtract(uv, cell, out=uv)
        np.maximum(np.minimum(frac, 1.0, out=frac), 0.0, out=frac)
        flat = (self._patch_stride @ cell).astype(np.intp)
        s00, du, dv, t = np.take(self._patches, flat, axis=1)
        fu, fv = frac
        gu, gv, gyaw, d = out
        # Per-cell gradient (du + t fv, dv + t fu); the distance s00 + du fu + (dv + t fu) fv.
        np.multiply(t, fv, out=gu)
        gu += du
        np.multiply(t, fu, out=gv)
        gv += dv
        np.multiply(gv, fv, out=d)
        d += s00
        du *= fu
        d += du
        d -= offset
        np.multiply(gv, q[0], out=gyaw)
        gu_qy = np.multiply(gu, q[1], out=fv)
        gyaw -= gu_qy
        grad = out[0:2]
        grad *= inv  # per metre
        if o.yaw != 0.0:
            grad[:] = self._rot @ grad  # into the map frame
        return out


def signed_distance_field(grid: OccupancyGrid, max_distance: float = 1.0) -> SignedDistanceField:
    """The map's :class:`SignedDistanceField`, built once per map content (map_cache)."""
    d = float(max_distance)
    return map_table("signed_distance", grid, d, lambda: SignedDistanceField(grid, d))
