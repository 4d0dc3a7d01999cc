"""How far along its path a robot knows the way is free: the corridor its body sweeps,
seen by the lidar (neither on an obstacle point nor hidden behind one).

A robot that plans on what its lidar has seen treats unseen space as free; driving no
faster than it can stop within the stretch it has seen free keeps it from meeting a pillar
that was hidden behind another (a Jackal at 2 m/s needs 1 m; in BARN's clutter the lidar
often sees less than that).
"""

from __future__ import annotations

import numpy as np

#: A ray passing this close to a return is taken to end there (the returns of a 0.15 m
#: pillar seen from 1-3 m lie 1-4 cm apart; a pillar hides what lies behind it).
RAY_BLOCK = 0.04


def free_distance(
    samples: np.ndarray,
    step: float,
    origin: tuple[float, float],
    points: np.ndarray,
    half_width: float,
) -> float:
    """Arclength along a path sampled every ``step`` from ``step`` on (``samples``, (n, 2),
    map frame) to the last sample before the corridor of ``half_width`` on each side holds
    an obstacle point, or its middle three quarters are hidden from the lidar at ``origin``
    by one (all n free: n steps)."""
    n = len(samples)
    if not len(points) or not n:
        return n * step
    x, y = samples[:, 0], samples[:, 1]
    # the path's direction at each sample (the lidar's position leads the first)
    tx = np.gradient(np.concatenate(([origin[0]], x)))[1:]
    ty = np.gradient(np.concatenate(([origin[1]], y)))[1:]
    norm = np.maximum(np.hypot(tx, ty), 1e-9)
    nx, ny = -ty / norm, tx / norm
    pts = np.asarray(points, dtype=float).reshape(-1, 2)
    # each sample: its centre and three quarters of the way to both edges, relative to the
    # lidar (a ray grazing a return by the corridor's edge hides nothing that reaches in far)
    w = 0.75 * half_width
    qx = np.stack([x, x + w * nx, x - w * nx], axis=1) - origin[0]
    qy = np.stack([y, y + w * ny, y - w * ny], axis=1) - origin[1]
    px, py = pts[:, 0] - origin[0], pts[:, 1] - origin[1]
    # on an obstacle: a point within the corridor's half-width of the sample
    d2 = (x[:, None] - pts[None, :, 0]) ** 2 + (y[:, None] - pts[None, :, 1]) ** 2
    blocked = (d2 <= half_width * half_width).any(axis=1)
    # hidden: the ray to a corridor point passes within RAY_BLOCK of a nearer return
    q2 = qx * qx + qy * qy  # (n, 3)
    dot = qx[:, :, None] * px[None, None, :] + qy[:, :, None] * py[None, None, :]
    t = dot / np.maximum(q2[:, :, None], 1e-12)
    ex = px[None, None, :] - t * qx[:, :, None]
    ey = py[None, None, :] - t * qy[:, :, None]
    near_ray = (ex * ex + ey * ey <= RAY_BLOCK * RAY_BLOCK) & (t > 0.0) & (t < 1.0)
    hidden = near_ray.any(axis=2).any(axis=1)
    bad = np.flatnonzero(blocked | hidden)
    return float(bad[0] * step) if len(bad) else n * step
