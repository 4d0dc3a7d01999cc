"""The quality of a built map and of a SLAM trajectory against the truth.

:func:`map_quality` compares a built map with the ground truth on the truth grid's cells
(the built map is sampled at each truth cell centre, so any resolution or origin works).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy import ndimage

from agv_mission.geometry import Bounds, Pose2D
from agv_mission.mapping.frontiers import bounds_mask
from agv_mission.maps.grid import FREE, OCCUPIED, OccupancyGrid


def map_quality(
    built: OccupancyGrid,
    truth: OccupancyGrid,
    bounds: Bounds | Sequence[float] | None = None,
    start: tuple[float, float] | Sequence[float] | None = None,
) -> dict[str, float]:
    """Quality of ``built`` against ``truth`` over the truth cells inside ``bounds``.

    ``occupied_iou`` / ``free_iou``: intersection over union of the OCCUPIED / FREE cells;
    ``coverage``: the share of the truth's free cells that are reachable inside the bounds
    (4-connected to ``start`` without leaving them; all truth free cells inside the bounds
    without a start) that the built map shows as FREE. An empty union counts as 1.0.
    """
    inside = bounds_mask(truth, bounds)
    rows, cols = np.indices(truth.data.shape)
    sampled = built.value_at(truth.cell_to_world(rows, cols))
    t_free = (truth.data == FREE) & inside
    t_occ = (truth.data == OCCUPIED) & inside
    b_free = (sampled == FREE) & inside
    b_occ = (sampled == OCCUPIED) & inside

    reach = t_free
    if start is not None:
        sr, sc = truth.world_to_cell(np.asarray(start, dtype=float)[:2])
        sr, sc = int(sr), int(sc)
        if truth.in_bounds(np.array(sr), np.array(sc)) and t_free[sr, sc]:
            comp, _ = ndimage.label(t_free)
            reach = comp == comp[sr, sc]
    n_reach = int(reach.sum())
    return {
        "occupied_iou": _iou(b_occ, t_occ),
        "free_iou": _iou(b_free, t_free),
        "coverage": float((b_free & reach).sum() / n_reach) if n_reach else 1.0,
        "truth_free_cells": float(n_reach),
        "built_free_cells": float(b_free.sum()),
    }


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    union = int((a | b).sum())
    return float((a & b).sum() / union) if union else 1.0


def reference_agreement(
    built: OccupancyGrid,
    reference: OccupancyGrid,
    wall_tolerance: float = 0.15,
    frame: Pose2D | None = None,
) -> dict[str, float]:
    """How far a built map can be trusted against a reference map of the same place.

    ``free_in_reference``: the share of the built map's FREE cells (their centres) that
    the reference shows FREE (a cell cleared through a window, outside the building, is
    not); ``walls_within``: the share of its OCCUPIED cells whose centre lies within
    ``wall_tolerance`` metres of a reference OCCUPIED cell. ``frame``: the built map's
    frame in the reference's (None: the same frame).
    """
    rows, cols = np.indices(built.data.shape)
    centres = built.cell_to_world(rows, cols)
    if frame is not None:
        c, s = np.cos(frame.yaw), np.sin(frame.yaw)
        x, y = centres[..., 0], centres[..., 1]
        centres = np.stack([frame.x + c * x - s * y, frame.y + s * x + c * y], axis=-1)
    free = built.data == FREE
    occ = built.data == OCCUPIED
    ref_at = reference.value_at(centres)
    n_free, n_occ = int(free.sum()), int(occ.sum())
    # Distance (m) from every reference cell to the nearest reference wall.
    ref_walls = reference.data == OCCUPIED
    dist = ndimage.distance_transform_edt(~ref_walls) * reference.resolution
    rr, rc = reference.world_to_cell(centres[occ])
    inside = reference.in_bounds(rr, rc)
    near = np.zeros(len(rr), bool)
    near[inside] = dist[rr[inside], rc[inside]] <= wall_tolerance + 0.5 * reference.resolution
    return {
        "free_in_reference": float((ref_at[free] == FREE).sum() / n_free) if n_free else 1.0,
        "walls_within": float(near.sum() / n_occ) if n_occ else 1.0,
        "free_cells": float(n_free),
        "occupied_cells": float(n_occ),
    }


def reference_coverage(
    built: OccupancyGrid,
    reference: OccupancyGrid,
    wall_tolerance: float = 0.1,
    frame: Pose2D | None = None,
) -> dict[str, float]:
    """How much of a reference map the built map holds: the other side of
    :func:`reference_agreement` (a map of a few sure cells agrees well and shows little).

    ``walls_found``: the share of the reference's OCCUPIED cells within ``wall_tolerance``
    metres of a built OCCUPIED cell; ``free_found``: the share of its FREE cells the built
    map shows FREE. ``frame``: the built map's frame in the reference's (None: the same).
    """
    rows, cols = np.indices(reference.data.shape)
    centres = reference.cell_to_world(rows, cols)
    if frame is not None:  # reference cell centres in the built map's frame
        c, s = np.cos(frame.yaw), np.sin(frame.yaw)
        x, y = centres[..., 0] - frame.x, centres[..., 1] - frame.y
        centres = np.stack([c * x + s * y, -s * x + c * y], axis=-1)
    ref_walls = reference.data == OCCUPIED
    dist = ndimage.distance_transform_edt(built.data != OCCUPIED) * built.resolution
    br, bc = built.world_to_cell(centres[ref_walls])
    inside = built.in_bounds(br, bc)
    near = np.zeros(len(br), bool)
    near[inside] = dist[br[inside], bc[inside]] <= wall_tolerance + 0.5 * built.resolution
    ref_free = reference.data == FREE
    n_free, n_occ = int(ref_free.sum()), int(ref_walls.sum())
    found_free = int((built.value_at(centres[ref_free]) == FREE).sum())
    return {
        "walls_found": float(near.sum() / n_occ) if n_occ else 1.0,
        "free_found": float(found_free / n_free) if n_free else 1.0,
    }


def relative_pose_error(
    estimate: np.ndarray, truth: np.ndarray, delta: float = 1.0
) -> dict[str, float]:
    """The relative pose error of Kümmerle et al. (2009), "On measuring the accuracy of
    SLAM algorithms": how wrong the estimated motion between two poses is, which no
    global frame or early error inflates.

    ``estimate`` and ``truth`` are rows of (t, x, y, yaw). The truth is interpolated at
    the estimate's stamps; poses are taken every ``delta`` metres of true travel, and each
    consecutive pair (i, j) compares the estimated relative motion with the true one:
    translational error |t(δ_ij ⊖ δ*_ij)| (m) and rotational error |yaw(δ_ij ⊖ δ*_ij)|
    (rad), as mean, RMS and max over the pairs. Empty when fewer than two poses overlap.
    """
    est = np.asarray(estimate, dtype=float).reshape(-1, 4)
    gt = np.asarray(truth, dtype=float).reshape(-1, 4)
    if len(est) < 2 or len(gt) < 2:
        return {}
    t = gt[:, 0]
    e = est[(est[:, 0] >= t[0] - 1e-9) & (est[:, 0] <= t[-1] + 1e-9)]
    if len(e) < 2:
        return {}
    g = np.stack(
        [
            np.interp(e[:, 0], t, gt[:, 1]),
            np.interp(e[:, 0], t, gt[:, 2]),
            np.interp(e[:, 0], t, np.unwrap(gt[:, 3])),
        ],
        axis=1,
    )
    travel = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(g[:, :2], axis=0).T))])
    picks = [0]
    for k in range(1, len(travel)):
        if travel[k] - travel[picks[-1]] >= delta:
            picks.append(k)
    if len(picks) < 2:
        return {}
    i, j = np.array(picks[:-1]), np.array(picks[1:])
    rel_e = _relative(e[i, 1:4], e[j, 1:4])
    rel_g = _relative(g[i], g[j])
    err = _relative(rel_g, rel_e)
    trans = np.hypot(err[:, 0], err[:, 1])
    rot = np.abs(np.arctan2(np.sin(err[:, 2]), np.cos(err[:, 2])))
    return {
        "translation_mean": float(trans.mean()),
        "translation_rms": float(np.sqrt(np.mean(trans**2))),
        "translation_max": float(trans.max()),
        "rotation_mean": float(rot.mean()),
        "rotation_rms": float(np.sqrt(np.mean(rot**2))),
        "rotation_max": float(rot.max()),
        "pairs": float(len(i)),
        "delta": float(delta),
    }


def _relative(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Poses ``b`` (n, 3: x, y, yaw) in the frames of poses ``a`` (a⁻¹ ∘ b)."""
    c, s = np.cos(a[:, 2]), np.sin(a[:, 2])
    dx, dy = b[:, 0] - a[:, 0], b[:, 1] - a[:, 1]
    return np.stack([c * dx + s * dy, -s * dx + c * dy, b[:, 2] - a[:, 2]], axis=1)
