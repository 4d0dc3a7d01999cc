"""Branch and bound over translation blocks: the exact optimum of a correlative scan
search without scoring every candidate.

For each angle of the search, the window's translations are tiled by blocks of
``coarse_block`` cells. A block's bound is the sum of its points' maxima over the block
(:func:`~agv_mission.mapping.likelihood_field.block_maxima`), times the penalty of its
offset nearest the guess: no cell of the block can score more. A block is split into
quarters only while its bound beats the best cell scored so far, down to single cells,
whose bound is their score (Olson 2009; Hess et al. 2016, Cartographer's
``FastCorrelativeScanMatcher2D``). Before each level is split, the best-bounded block's
way down to a cell gives a good best cell early; each level is split at once, in a few numpy calls rather than one per
block: the coarse levels are cheap where a wide window holds hundreds of blocks per
angle, the fine ones prune a block's cells before they are scored.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

#: The candidates' penalty factor of their translation (m) and rotation (rad).
Penalty = Callable[[np.ndarray, np.ndarray], np.ndarray]


def best_cell(
    maxima: dict[int, np.ndarray],
    base: np.ndarray,
    layout: tuple[int, int, int],
    res: float,
    dyaw: np.ndarray,
    penalty: Penalty,
) -> tuple[tuple[float, int, int, int], int]:
    """The window's best cell: (score, angle index, dy, dx), and how many cells were
    scored. ``maxima[b]``: the field's maximum over each ``b`` x ``b`` block, flattened;
    ``base`` (A, N): each angle's points' flat cells at the window's centre; ``layout``:
    the window's half width, the crop's side and the top block's size (cells);
    ``dyaw``: each angle's rotation from the guess."""
    n_lin, size, top = layout
    starts = np.arange(-n_lin, n_lin + 1, top)
    sy, sx = (g.ravel() for g in np.meshgrid(starts, starts, indexing="ij"))
    n_ang = base.shape[0]
    a = np.repeat(np.arange(n_ang), len(sy))
    sy, sx = np.tile(sy, n_ang), np.tile(sx, n_ang)
    blocks = TranslationBlocks(penalty, maxima, base, n_lin, size, res, dyaw)
    bound = blocks.bound(top, a, sy, sx)
    b = top
    while b > 1:
        blocks.descend(b, a, sy, sx, bound)
        live = bound > blocks.best[0]
        a, sy, sx = blocks.split(b, a[live], sy[live], sx[live])
        b //= 2
        bound = blocks.bound(b, a, sy, sx)
    blocks.take(a, sy, sx, bound)
    return blocks.best, blocks.evaluated


class TranslationBlocks:
    """The translation blocks of one :func:`best_cell`: their bounds, their split into
    quarters, the best cell so far and the count of cells scored."""

    def __init__(
        self,
        penalty: Penalty,
        maxima: dict[int, np.ndarray],
        base: np.ndarray,
        n_lin: int,
        size: int,
        res: float,
        dyaw: np.ndarray,
    ) -> None:
        self.penalty, self.maxima, self.base = penalty, maxima, base
        self.n_lin, self.size, self.res, self.dyaw = n_lin, size, res, dyaw
        self.n_pts = float(base.shape[1])
        self.best = (-1.0, 0, 0, 0)  # score, angle index, dy, dx
        self.evaluated = 0

    def bound(self, b: int, a: np.ndarray, sy: np.ndarray, sx: np.ndarray) -> np.ndarray:
        """Each block's bound (of ``b`` cells from rows ``sy``, columns ``sx``, at angle
        index ``a``); a single cell's (``b`` = 1) is its exact score."""
        values = self.maxima[b]
        score = values[self.base[a] + (sy * self.size + sx)[:, None]].sum(axis=1) / self.n_pts
        if b == 1:
            t_min = np.hypot(sy, sx) * self.res
        else:
            # The block's offset nearest the guess, per axis (blocks end at the window).
            ey, ex = np.minimum(sy + b - 1, self.n_lin), np.minimum(sx + b - 1, self.n_lin)
            ny = np.where((sy <= 0) & (ey >= 0), 0, np.minimum(abs(sy), abs(ey)))
            nx = np.where((sx <= 0) & (ex >= 0), 0, np.minimum(abs(sx), abs(ex)))
            t_min = np.hypot(ny, nx) * self.res
        return score * self.penalty(t_min, self.dyaw[a])

    def split(
        self, b: int, a: np.ndarray, sy: np.ndarray, sx: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The quarters (of ``b // 2`` cells) of blocks of ``b`` cells that lie in the window."""
        h = b // 2
        ka = np.repeat(a, 4)
        ky = (sy[:, None] + np.array([0, 0, h, h])).ravel()
        kx = (sx[:, None] + np.array([0, h, 0, h])).ravel()
        inside = (ky <= self.n_lin) & (kx <= self.n_lin)
        return ka[inside], ky[inside], kx[inside]

    def descend(
        self, b: int, a: np.ndarray, sy: np.ndarray, sx: np.ndarray, bound: np.ndarray
    ) -> None:
        """From the best-bounded block of ``b`` cells, the best-bounded quarter down to a
        cell: a good cell early, whose score prunes the level's other blocks."""
        if not len(bound):
            return
        i = int(np.argmax(bound))
        if bound[i] <= self.best[0]:
            return
        a, sy, sx = a[i : i + 1], sy[i : i + 1], sx[i : i + 1]
        while b > 1:
            a, sy, sx = self.split(b, a, sy, sx)
            b //= 2
            bound = self.bound(b, a, sy, sx)
            i = int(np.argmax(bound))
            a, sy, sx, bound = a[i : i + 1], sy[i : i + 1], sx[i : i + 1], bound[i : i + 1]
        self.take(a, sy, sx, bound)

    def take(self, a: np.ndarray, sy: np.ndarray, sx: np.ndarray, score: np.ndarray) -> None:
        """The best of single cells and their ``score``s, if it beats the best so far."""
        self.evaluated += len(score)
        if not len(score):
            return
        i = int(np.argmax(score))
        if score[i] > self.best[0]:
            self.best = (float(score[i]), int(a[i]), int(sy[i]), int(sx[i]))
