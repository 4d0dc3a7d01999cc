"""The quality of a built map against the truth.

:func:`map_quality` compares a built map with the ground truth on the truth grid's cells
(the built map is sampled at each truth cell centre, so any resolution or origin works).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy import ndimage

from agv_mission.geometry import Bounds
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
