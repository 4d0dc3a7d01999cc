"""The likelihood field scans are matched against, and how to read it.

``exp(-d^2 / (2 sigma^2))`` of the distance ``d`` to the nearest occupied cell's obstacle
point, truncated at ``4 sigma`` (:func:`field_values`); its maxima over blocks
of cells (:func:`block_maxima`, for branch and bound) and its Catmull-Rom bicubic value and
gradient (:func:`bicubic`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.ndimage import distance_transform_edt


@dataclass
class LikelihoodField:
    """A likelihood field on a grid: ``values[row, col]`` in [0, 1], row 0 at the lowest y.

    ``origin`` is the map-frame (x, y) of the lower-left corner of cell (0, 0).
    ``nearest`` (rows, cols; int32, -1 where none lies within the field's cutoff) names
    each cell's nearest occupied cell and ``anchor`` (x, y offsets from a cell's centre,
    metres) where in an occupied cell its obstacle lies; both are needed by the ``"icp"``
    refinement only. ``view`` (x, y arrays, optional): the sum of the unit vectors from
    the scan end points that fell in each cell towards the scanner, i.e. which side the
    cell's surface was seen from; with it the ``"icp"`` refinement never pairs a point
    with a surface seen from the other side (the far face of a thin wall).
    """

    values: np.ndarray  # float32 (H, W)
    resolution: float
    origin: tuple[float, float]
    nearest: tuple[np.ndarray, np.ndarray] | None = None
    anchor: tuple[np.ndarray, np.ndarray] | None = None
    view: tuple[np.ndarray, np.ndarray] | None = None

    @classmethod
    def from_occupied(
        cls,
        occupied: np.ndarray,
        resolution: float,
        origin: tuple[float, float],
        sigma: float,
        anchor: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> LikelihoodField:
        """The field of a boolean occupancy mask (``anchor``: see the class)."""
        if anchor is None:
            zero = np.zeros(occupied.shape, np.float32)
            anchor = (zero, zero)
        values, nearest = field_values(occupied, resolution, sigma, anchor, return_nearest=True)
        return cls(values, float(resolution), origin, nearest, anchor)

    @classmethod
    def from_points(
        cls,
        xy: np.ndarray,
        resolution: float,
        sigma: float,
        box: tuple[float, float, float, float] | None = None,
    ) -> LikelihoodField:
        """The field of map-frame obstacle points ``xy`` (N, 2), each cell's anchor where
        its points fell (sub-cell walls, as a scan-built map has them); with ``box``
        (x0, y0, x1, y1), the field a lookup inside that box reads: of the points within
        the field's reach of it. The grid reaches as far past the points as the field is
        not zero: a matched point landing beyond reads zero either way, and a wider grid
        only costs the distance transform."""
        res = float(resolution)
        margin = 4.0 * sigma + 3.0 * res
        if box is not None:
            x0, y0, x1, y1 = box
            keep = (xy[:, 0] >= x0 - margin) & (xy[:, 0] <= x1 + margin)
            keep &= (xy[:, 1] >= y0 - margin) & (xy[:, 1] <= y1 + margin)
            xy = xy[keep]
            if not len(xy):
                return cls.from_occupied(np.zeros((1, 1), bool), res, (x0, y0), sigma)
        ox = math.floor((xy[:, 0].min() - margin) / res) * res
        oy = math.floor((xy[:, 1].min() - margin) / res) * res
        w = int(math.ceil((xy[:, 0].max() + margin - ox) / res))
        h = int(math.ceil((xy[:, 1].max() + margin - oy) / res))
        cols = np.floor((xy[:, 0] - ox) / res).astype(int)
        rows = np.floor((xy[:, 1] - oy) / res).astype(int)
        flat = rows * w + cols
        count = np.bincount(flat, minlength=h * w)
        occupied = (count > 0).reshape(h, w)
        safe = np.maximum(count, 1)
        ax = np.bincount(flat, xy[:, 0] - (ox + (cols + 0.5) * res), h * w) / safe
        ay = np.bincount(flat, xy[:, 1] - (oy + (rows + 0.5) * res), h * w) / safe
        anchor = (ax.reshape(h, w).astype(np.float32), ay.reshape(h, w).astype(np.float32))
        return cls.from_occupied(occupied, res, (ox, oy), sigma, anchor=anchor)


def field_values(
    occupied: np.ndarray,
    resolution: float,
    sigma: float,
    anchor: tuple[np.ndarray, np.ndarray] | None = None,
    return_nearest: bool = False,
):
    """``exp(-d^2 / 2 sigma^2)`` of each cell's distance ``d`` to the nearest occupied
    cell, zero beyond ``4 sigma`` (float32).

    With ``anchor`` (x and y arrays, metres: where in each occupied cell its obstacle lies,
    relative to the cell centre, e.g. the mean of the scan end points that fell in it),
    ``d`` is measured to that point of the nearest occupied cell instead of to its centre,
    so the field keeps sub-cell detail. With ``return_nearest`` also returns the (rows,
    cols) of each cell's nearest occupied cell (int32, -1 beyond the cutoff).
    """
    shape = occupied.shape
    if not occupied.any():
        values = np.zeros(shape, np.float32)
        if return_nearest:
            none = np.full(shape, -1, np.int32)
            return values, (none, none.copy())
        return values
    cutoff = 4.0 * sigma
    res = np.float32(resolution)
    if anchor is None and not return_nearest:
        d = distance_transform_edt(~occupied).astype(np.float32) * res
    else:
        # The nearest cells alone (scipy's distances would be a second pass, unused).
        ri, ci = distance_transform_edt(~occupied, return_distances=False, return_indices=True)
        # In place where a temporary per operation would be made (the map refreshes
        # its field around every scan): the same float32 arithmetic.
        dx = (ci - np.arange(shape[1])[None, :]).astype(np.float32)
        dx *= res
        dy = (ri - np.arange(shape[0])[:, None]).astype(np.float32)
        dy *= res
        if anchor is not None:
            nearest = ri * np.int64(shape[1]) + ci
            dx += np.ascontiguousarray(anchor[0]).reshape(-1).take(nearest)
            dy += np.ascontiguousarray(anchor[1]).reshape(-1).take(nearest)
        dx *= dx
        dy *= dy
        dx += dy
        d = np.sqrt(dx, out=dx)
    far = d > cutoff
    # d (float32, a new array) becomes the values: exp(-0.5 (d / sigma)^2).
    values = np.divide(d, np.float32(sigma), out=d)
    values *= values
    values *= -0.5
    np.exp(values, out=values)
    values[far] = 0.0
    if not return_nearest:
        return values
    ri[far] = -1
    ci[far] = -1
    return values, (ri, ci)


def block_maxima(values: np.ndarray, block: int) -> dict[int, np.ndarray]:
    """For each power of two ``b`` up to ``block``, ``out[b][r * W + c] = max(values[r : r
    + b, c : c + b])`` (zero past the edges), flattened: the bounds of a branch and bound
    over translation blocks. Computed by repeated doubling, exact."""
    if block & (block - 1) or block < 1:
        raise ValueError(f"block must be a power of two, got {block}")
    out = values
    levels = {1: out.ravel()}
    width = 1
    while width < block:
        shifted = np.zeros_like(out)
        shifted[:-width, :] = out[width:, :]
        out = np.maximum(out, shifted)
        shifted = np.zeros_like(out)
        shifted[:, :-width] = out[:, width:]
        out = np.maximum(out, shifted)
        width *= 2
        levels[width] = out.ravel()
    return levels


def crop_window(values: np.ndarray, r0: int, c0: int, h: int, w: int) -> np.ndarray:
    """``values[r0 : r0 + h, c0 : c0 + w]`` with zeros where it leaves the array."""
    out = np.zeros((h, w), dtype=values.dtype)
    rs0, cs0 = max(r0, 0), max(c0, 0)
    rs1, cs1 = min(r0 + h, values.shape[0]), min(c0 + w, values.shape[1])
    if rs1 > rs0 and cs1 > cs0:
        out[rs0 - r0 : rs1 - r0, cs0 - c0 : cs1 - c0] = values[rs0:rs1, cs0:cs1]
    return out


def bicubic(
    field: LikelihoodField, wx: np.ndarray, wy: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Catmull-Rom bicubic value and map-frame gradient of the field (cell centres as
    samples, zero outside). Unlike bilinear interpolation it peaks between two equal
    samples, so a wall whose hits fill two cells still has a sharp optimum at its face."""
    res = field.resolution
    v = field.values
    h, w = v.shape
    u = (wx - field.origin[0]) / res - 0.5
    t = (wy - field.origin[1]) / res - 0.5
    j1 = np.floor(u).astype(np.int64)
    i1 = np.floor(t).astype(np.int64)
    wu, du = catmull_rom(u - j1)  # (N, 4)
    wt, dt = catmull_rom(t - i1)
    inside = (i1 >= 1) & (i1 < h - 2) & (j1 >= 1) & (j1 < w - 2)
    i1 = np.where(inside, i1, 1)
    j1 = np.where(inside, j1, 1)
    k = np.arange(-1, 3)
    patch = v[(i1[:, None] + k)[:, :, None], (j1[:, None] + k)[:, None, :]]  # (N, 4, 4)
    patch = patch * inside[:, None, None]
    rows = np.einsum("nij,nj->ni", patch, wu)  # interpolated along x, per row
    m = np.einsum("ni,ni->n", rows, wt)
    gt = np.einsum("ni,ni->n", rows, dt)
    gu = np.einsum("nij,nj,ni->n", patch, du, wt)
    return m, gu / res, gt / res


def catmull_rom(f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Weights (N, 4) of samples -1, 0, 1, 2 at fraction ``f``, and their derivatives."""
    f2, f3 = f * f, f * f * f
    wts = 0.5 * np.stack([-f3 + 2 * f2 - f, 3 * f3 - 5 * f2 + 2, -3 * f3 + 4 * f2 + f, f3 - f2], 1)
    der = 0.5 * np.stack(
        [-3 * f2 + 4 * f - 1, 9 * f2 - 10 * f, -9 * f2 + 8 * f + 1, 3 * f2 - 2 * f], 1
    )
    return wts, der
