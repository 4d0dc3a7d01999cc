"""HuNavSim's social-navigation metrics (Pérez-Higueras et al., "HuNavSim", IROS 2023) of one
run, from arrays: the robot's true trajectory and where each person was at each step."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

INTIMATE = 0.45  # m: Hall's intimate space (HuNavSim's threshold)
PERSONAL = 1.2  # m: Hall's personal space
# HuNavSim's "time not moving": the robot slower than 0.01 m/s and turning slower than
# 0.02 rad/s (hunav_evaluator's hunav_metrics.py): one turning on the spot moves
NOT_MOVING = 0.01  # m/s
NOT_TURNING = 0.02  # rad/s


def people_metrics(
    t: np.ndarray,
    robot_xy: np.ndarray,
    people_xy: np.ndarray,
    robot_radius: float,
    people_radii: np.ndarray,
    legs: Sequence[tuple[float, float]] = (),
    touching: np.ndarray | None = None,
    robot_yaw: np.ndarray | None = None,
) -> dict[str, Any]:
    """``metrics.people`` of result.json.

    ``t`` (m,) sample times; ``robot_xy`` (m, 2); ``people_xy`` (m, n, 2), NaN where a person
    is not in the world yet; ``robot_radius`` the footprint's; ``people_radii`` (n,); ``legs``
    the navigation legs as (start, end) times; ``touching`` (m, n), when given, says who
    the robot's body touched at each sample (the world's contacts), else bodies closer
    than 0 touch; ``robot_yaw`` (m,), when given, the robot's heading (a robot turning on
    the spot is moving). Distances are edge to edge (footprint to a person's body); each
    sample counts for the time to the next one.
    """
    t = np.asarray(t, dtype=float)
    robot_xy = np.asarray(robot_xy, dtype=float).reshape(-1, 2)
    radii = np.asarray(people_radii, dtype=float).reshape(-1)
    people_xy = np.asarray(people_xy, dtype=float).reshape(len(t), len(radii), 2)
    m = len(t)
    dt = np.diff(t) if m > 1 else np.zeros(0)
    weights = np.append(dt, dt[-1]) if m > 1 else np.zeros(m)  # the last as long as the one before

    if people_xy.shape[1] and m:
        centre = np.hypot(*(people_xy - robot_xy[:, None, :]).transpose(2, 0, 1))
        gap = centre - robot_radius - radii[None, :]  # (m, n), NaN when absent
        nearest = np.min(np.where(np.isnan(gap), np.inf, gap), axis=1)
    else:
        gap = np.full((m, 0), np.nan)
        nearest = np.full(m, np.inf)
    seen = np.isfinite(nearest)
    if touching is None:
        touching = np.nan_to_num(gap, nan=np.inf) <= 0.0
    touching = np.asarray(touching, dtype=bool).reshape(m, len(radii))
    before = np.vstack([np.zeros((1, touching.shape[1]), bool), touching[:-1]])
    onsets = int(np.count_nonzero(touching & ~before))

    speed = np.zeros(m)
    turn = np.zeros(m)
    if m > 1:
        speed[:-1] = np.hypot(*np.diff(robot_xy, axis=0).T) / np.maximum(dt, 1e-12)
        speed[-1] = speed[-2]
        if robot_yaw is not None:
            yaw = np.unwrap(np.asarray(robot_yaw, dtype=float).reshape(-1))
            turn[:-1] = np.abs(np.diff(yaw)) / np.maximum(dt, 1e-12)
            turn[-1] = turn[-2]
    return {
        "people": int(people_xy.shape[1]),
        "min_distance": float(nearest[seen].min()) if seen.any() else None,
        "intimate_time": float(weights[seen & (nearest < INTIMATE)].sum()),
        "personal_time": float(weights[seen & (nearest < PERSONAL)].sum()),
        "collisions": onsets,
        "time_not_moving": float(weights[(speed < NOT_MOVING) & (turn < NOT_TURNING)].sum()),
        "legs": [_leg(t, robot_xy, start, end) for start, end in legs],
    }


def _leg(t: np.ndarray, xy: np.ndarray, start: float, end: float) -> dict[str, float]:
    """The distance the robot drove and the time it took between ``start`` and ``end``."""
    inside = (t >= start - 1e-9) & (t <= end + 1e-9)
    path = xy[inside]
    length = float(np.sum(np.hypot(*np.diff(path, axis=0).T))) if len(path) > 1 else 0.0
    return {"path_length": length, "time": float(end - start)}
