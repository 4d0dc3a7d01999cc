"""Scan-to-map matching for the ``grid`` SLAM plugin: correlative search + refinement.

Two stages, as Cartographer's 2D local SLAM does (``RealTimeCorrelativeScanMatcher2D``
followed by the ``CeresScanMatcher2D``):

1. :meth:`CorrelativeMatcher.match` searches a window around the odometry prediction
   (default +-0.2 m, +-10 deg) exhaustively but cheaply: every rotation is scored on a
   coarse grid of translation blocks whose score is an upper bound (a sliding-window
   maximum of the likelihood field, Olson 2009 / Hess et al. 2016), and only the blocks
   whose bound beats the best exact score found so far are split into blocks of half
   the side, level by level down to single cells (:mod:`branch_and_bound`). The result
   is the global optimum of the window at cell / angular-step resolution, so an
   odometry error of centimetres and degrees per scan (a turn in place with slipping
   wheels) never traps it in a local minimum, the weakness of pure gradient matching
   (hector mapping).
2. A sub-cell refinement from that optimum (:mod:`scan_alignment`), a maximum a
   posteriori estimate when the odometry prior's covariance is given:

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
   ``"field"``, lowers its objective). Otherwise the correlative optimum gets the
   covariance of its score surface (:meth:`CorrelativeMatcher._surface_covariance`,
   Olson 2009 / Karto) and, given the odometry prior, is fused with the prediction as a
   Kalman update: a scan that cannot tell where along a wall the robot stands (one wall
   of an open hall, too noisy at 3 m for the refinement's normals) leaves the odometry
   there instead of jumping a cell toward the part of the wall already mapped.

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
from agv_mission.mapping.branch_and_bound import best_cell
from agv_mission.mapping.likelihood_field import (
    LikelihoodField,
    bicubic,
    block_maxima,
    crop_window,
)
from agv_mission.mapping.scan_alignment import (
    PosePrior,
    field_cost,
    gauss_newton,
    icp,
    transform_points,
)

Refinement = Literal["icp", "field", "none"]
#: Candidates scoring within this of the best count in the score surface's spread
#: (Karto's ComputePositionalCovariance uses 0.1 of its response, also in 0..1).
SURFACE_DROP = 0.1
#: Radians past the angular window a refinement's point may swing (its steps overshoot,
#: an angular step): the slack of :meth:`CorrelativeMatcher.read_box`.
_LEVER_SLACK = 0.05


@dataclass
class MatchResult:
    """The matched pose and how good it is."""

    pose: np.ndarray  # (x, y, yaw) in the map frame
    score: float  # mean field value of the scan points at ``pose`` (0..1)
    coarse_pose: np.ndarray  # the correlative optimum before refinement
    refined: bool  # the refinement was accepted
    candidates: int  # exact (cell-level) candidate poses scored
    covariance: np.ndarray | None = None  # (3, 3) of the refined pose, None if not refined


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
    the scan against the prior. ``fast_score`` (mean field value) and ``fast_turn`` (rad,
    None: a quarter of ``angular_window``) gate the search's skip (:meth:`_fast`).
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
        search_max_range: float | None = None,
        fast_score: float | None = None,
        fast_turn: float | None = None,
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
        self.search_max_range = search_max_range
        self.fast_score = fast_score
        self.fast_turn = 0.25 * self.angular_window if fast_turn is None else float(fast_turn)

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
        if self.fast_score is not None and prior_cov is not None:
            fast = self._fast(field, points, guess, prior_cov)
            if fast is not None:
                return fast
        search, reach, step = self._search_setup(points, res)
        coarse_pose, near_guess, evaluated, surface = self._search(
            field, search, guess, reach, step
        )
        pose, refined, cov = self._refine(
            field, points, guess, coarse_pose, near_guess, step, prior_cov
        )
        if not refined:
            pose, cov = fuse(guess, prior_cov, coarse_pose, surface)
        pose = pose.copy()
        pose[2] = wrap_angle(pose[2])
        score = self.score(field, points, pose)
        return MatchResult(pose, score, coarse_pose, refined, evaluated, cov)

    def optimum(self, field: LikelihoodField, points: np.ndarray, guess: np.ndarray) -> np.ndarray:
        """The correlative search's optimum alone (x, y, yaw; to a cell and an angular
        step), without :meth:`match`'s refinement, score and score-surface covariance: a
        loop's wide search refines it on a finer field, and the surface of its hundreds
        of thousands of cells was a fifth of its time."""
        points = np.asarray(points, dtype=np.float64).reshape(-1, 2)
        guess = np.asarray(guess, dtype=np.float64)
        if len(points) == 0:
            return guess.copy()
        search, reach, step = self._search_setup(points, field.resolution)
        pose = self._search(field, search, guess, reach, step, surface=False)[0]
        pose[2] = wrap_angle(pose[2])
        return pose

    def _search_setup(self, points: np.ndarray, res: float) -> tuple[np.ndarray, float, float]:
        """The points the search scores, their reach and its angular step (``angular_step``,
        or the angle that moves the farthest of them by one cell)."""
        search = self._search_points(points, res)
        reach = _farthest(search)
        step = self.angular_step
        if step is None:
            step = math.acos(max(-1.0, 1.0 - res * res / (2.0 * max(reach, res) ** 2)))
        return search, reach, step

    def _fast(
        self, field: LikelihoodField, points: np.ndarray, guess: np.ndarray, prior_cov: np.ndarray
    ) -> MatchResult | None:
        """The refinement alone from the prediction, when it lands well: converged, a
        small correction (a quarter of the linear window, ``fast_turn`` of heading) and a
        mean field value of at least ``fast_score``. Most scans of a real log are such;
        the rest get the search."""
        if self.refinement != "icp" or field.nearest is None or field.anchor is None:
            return None
        cand, cov = icp(
            field,
            points,
            guess,
            PosePrior.of(guess, prior_cov),
            self.iterations,
            self.point_sigma,
            self.huber,
            self.max_correspondence,
        )
        if cand is None:
            return None
        small = (
            math.hypot(cand[0] - guess[0], cand[1] - guess[1]) <= 0.25 * self.linear_window
            and abs(wrap_angle(cand[2] - guess[2])) <= self.fast_turn
        )
        if not small:
            return None
        pose = cand.copy()
        pose[2] = wrap_angle(pose[2])
        score = self.score(field, points, pose)
        if score < self.fast_score:
            return None
        return MatchResult(pose, score, guess.copy(), True, 0, cov)

    def read_box(
        self, points: np.ndarray, guess: np.ndarray, res: float
    ) -> tuple[float, float, float, float]:
        """The map-frame box (x0, y0, x1, y1) a match of ``points`` from ``guess`` reads
        of a field of cells ``res``: the correlative search's crop round the guess (the
        scored points' reach, the linear window and its blocks) and, when it refines,
        where every point lands from any pose of the window (its lever over the angular
        window) plus a correspondence and half a metre for the refinement's steps. A
        field cut to it (:meth:`LikelihoodField.from_points`) matches as the whole one."""
        points = np.asarray(points, dtype=np.float64).reshape(-1, 2)
        search = self._search_points(points, res)
        half = (self._crop_half(_farthest(search), res) + 1) * res
        x0, y0, x1, y1 = guess[0] - half, guess[1] - half, guess[0] + half, guess[1] + half
        if self.refinement == "none" or self.iterations <= 0 or not len(points):
            return x0, y0, x1, y1
        wx, wy = transform_points(points, guess)
        lever = self.angular_window + _LEVER_SLACK
        reach = self.linear_window + self.max_correspondence + 0.5 + lever * np.hypot(*points.T)
        return (
            min(x0, float((wx - reach).min())),
            min(y0, float((wy - reach).min())),
            max(x1, float((wx + reach).max())),
            max(y1, float((wy + reach).max())),
        )

    def _crop_half(self, reach: float, res: float) -> int:
        """Half the side (cells) of :meth:`_search`'s crop round the guess's cell."""
        n_lin = max(int(round(self.linear_window / res)), 0)
        return int(math.ceil(reach / res)) + n_lin + self.coarse_block + 2

    def _search_points(self, points: np.ndarray, res: float) -> np.ndarray:
        """The points the correlative search scores: those within ``search_max_range``
        (all of them when fewer than 50 are), one per cell. Far points of a real
        lidar (40 m down a corridor) would make the search window and its angular steps
        huge for a cell-level result the refinement, which uses every point, improves
        anyway."""
        if self.search_max_range is None:
            return points
        near = points[(points**2).sum(axis=1) <= self.search_max_range**2]
        if len(near) < 50:
            return points
        cells = np.floor(near / res).astype(np.int64)
        _, first = np.unique(cells[:, 0] * 1_000_003 + cells[:, 1], return_index=True)
        return near[np.sort(first)]

    def _search(
        self,
        field: LikelihoodField,
        points: np.ndarray,
        guess: np.ndarray,
        reach: float,
        step: float,
        surface: bool = True,
    ) -> tuple[np.ndarray, bool, int, np.ndarray | None]:
        """The correlative optimum of the window round ``guess`` (branch and bound over
        levels, see the module), whether it lies within a cell and an angular
        ``step`` of ``guess``, how many cell-level candidates were scored and (with
        ``surface``) the optimum's covariance from its score surface."""
        res = field.resolution
        n_lin = max(int(round(self.linear_window / res)), 0)
        n_ang = max(int(math.ceil(self.angular_window / step - 1e-9)), 0)
        block = self.coarse_block

        # A zero-padded crop of the field centred on the guess that holds every candidate.
        half = self._crop_half(reach, res)
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
        best, evaluated = best_cell(
            block_maxima(crop, block), base, (n_lin, size, block), res, dyaw, self._penalty
        )

        _, ai, dy, dx = best
        coarse_pose = np.array([guess[0] + dx * res, guess[1] + dy * res, yaws[ai]])
        # Within a cell and a step of the prediction: refine from the prediction instead.
        near_guess = abs(dx) <= 1 and abs(dy) <= 1 and abs(dyaw[ai]) <= step * 1.0001
        if not surface:
            return coarse_pose, near_guess, evaluated, None
        cov = self._surface_covariance(flat, base, (ai, dy, dx), (n_lin, size), res, dyaw)
        return coarse_pose, near_guess, evaluated, cov

    @staticmethod
    def _surface_covariance(
        flat: np.ndarray,
        base: np.ndarray,
        best: tuple[int, int, int],
        layout: tuple[int, int],
        res: float,
        dyaw: np.ndarray,
    ) -> np.ndarray:
        """(3, 3) covariance of the correlative optimum ``best`` (angle index, dy, dx)
        from its score surface, as Karto's ComputePositionalCovariance and
        ComputeAngularCovariance: the score-weighted spread about the optimum of the
        window's cells at its angle, and of the angles at its cell, that score within
        SURFACE_DROP of the best, plus a cell's (a step's) own uniform variance. Flat
        along a lone wall, so wide there; sharp across it."""
        ai, by, bx = best
        n_lin, size = layout
        n_pts = float(base.shape[1])
        cells = np.arange(-n_lin, n_lin + 1)
        gy, gx = (g.ravel() for g in np.meshgrid(cells, cells, indexing="ij"))
        s = flat[base[ai][None, :] + (gy * size + gx)[:, None]].sum(axis=1) / n_pts
        w = np.where(s >= s.max() - SURFACE_DROP, s, 0.0)
        w = w / max(float(w.sum()), 1e-12)
        ex, ey = (gx - bx) * res, (gy - by) * res
        cell = res * res / 12.0
        cov = np.zeros((3, 3))
        cov[0, 0] = float(w @ (ex * ex)) + cell
        cov[1, 1] = float(w @ (ey * ey)) + cell
        cov[0, 1] = cov[1, 0] = float(w @ (ex * ey))
        sa = flat[base + (by * size + bx)].sum(axis=1) / n_pts
        wa = np.where(sa >= sa.max() - SURFACE_DROP, sa, 0.0)
        wa = wa / max(float(wa.sum()), 1e-12)
        step = float(dyaw[1] - dyaw[0]) if len(dyaw) > 1 else 0.0
        cov[2, 2] = float(wa @ (dyaw - dyaw[ai]) ** 2) + step * step / 12.0 + 1e-12
        return cov

    def _refine(
        self,
        field: LikelihoodField,
        points: np.ndarray,
        guess: np.ndarray,
        coarse_pose: np.ndarray,
        near_guess: bool,
        step: float,
        prior_cov: np.ndarray | None,
    ) -> tuple[np.ndarray, bool, np.ndarray | None]:
        """(pose, refined, covariance): the refinement of ``coarse_pose`` when it is
        accepted (it converges inside the search window and, for ``"field"``, lowers its
        objective), else ``coarse_pose`` with no covariance."""
        mode = self.refinement
        if mode == "icp" and (field.nearest is None or field.anchor is None):
            mode = "field"
        if mode == "none" or self.iterations <= 0:
            return coarse_pose, False, None
        prior = PosePrior.of(guess, prior_cov)
        # The correlative optimum is only good to a cell: within one cell / one step
        # of the prediction, refine from the prediction, so that a direction the scan
        # cannot observe (along a wall) keeps the odometry instead of a noisy cell.
        start = guess if near_guess else coarse_pose
        if mode == "icp":
            cand, cov = icp(
                field,
                points,
                start,
                prior,
                self.iterations,
                self.point_sigma,
                self.huber,
                self.max_correspondence,
            )
            better = cand is not None
        else:
            cand, cov = gauss_newton(field, points, start, prior, self.iterations, self.scan_sigma)
            before = field_cost(field, points, coarse_pose, prior, self.scan_sigma)
            better = field_cost(field, points, cand, prior, self.scan_sigma) < before
        if not better:
            return coarse_pose, False, None
        res = field.resolution
        inside = (
            abs(cand[0] - guess[0]) <= self.linear_window + res
            and abs(cand[1] - guess[1]) <= self.linear_window + res
            and abs(wrap_angle(cand[2] - guess[2])) <= self.angular_window + step
        )
        return (cand, True, cov) if inside else (coarse_pose, False, None)

    @staticmethod
    def score(
        field: LikelihoodField, points: np.ndarray, pose: np.ndarray, interpolate: bool = False
    ) -> float:
        """Mean field value of robot-frame ``points`` seen from ``pose`` (nearest cell, or
        bicubic with ``interpolate``)."""
        if len(points) == 0:
            return 0.0
        wx, wy = transform_points(points, pose)
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


def _farthest(points: np.ndarray) -> float:
    """The largest distance (m) of robot-frame ``points`` from the robot (0 without any)."""
    return float(np.sqrt((points**2).sum(axis=1)).max()) if len(points) else 0.0


def fuse(
    guess: np.ndarray,
    prior_cov: np.ndarray | None,
    measured: np.ndarray,
    measured_cov: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """The Kalman update of the prediction ``guess`` (covariance ``prior_cov``) by the
    pose ``measured`` (covariance ``measured_cov``): the pose and its covariance.
    Without a prior, ``measured`` and its covariance."""
    if prior_cov is None:
        return measured.copy(), measured_cov
    innovation = measured - guess
    innovation[2] = wrap_angle(float(innovation[2]))
    gain = prior_cov @ np.linalg.inv(prior_cov + measured_cov)
    pose = guess + gain @ innovation
    pose[2] = wrap_angle(float(pose[2]))
    cov = (np.eye(3) - gain) @ prior_cov
    return pose, 0.5 * (cov + cov.T)
