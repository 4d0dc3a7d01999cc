"""amcl's pose histogram (``pf_kdtree.c``): bins, the KLD bound, the heaviest cluster.

Apart from the filter (:mod:`agv_mission.localization.particle_filter`, amcl's ``pf.c``):
what the histogram of particles over 0.5 m x 0.5 m x 10 deg bins is used for, the number
of particles KLD sampling keeps (Fox 2003) and amcl's pose estimate, the weighted mean of
the heaviest cluster of connected bins.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import ndimage
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

#: amcl's histogram bin sizes (pf_kdtree): x, y in metres, yaw in radians.
BIN_SIZE = (0.5, 0.5, math.radians(10.0))
_YAW_BINS = 36


def bin_keys(particles: np.ndarray) -> np.ndarray:
    """amcl's histogram bin of each particle as one int64 key."""
    kx = np.floor(particles[:, 0] / BIN_SIZE[0]).astype(np.int64) + (1 << 20)
    ky = np.floor(particles[:, 1] / BIN_SIZE[1]).astype(np.int64) + (1 << 20)
    ka = np.floor(particles[:, 2] / BIN_SIZE[2]).astype(np.int64) + 64
    return (kx << 32) | (ky << 8) | ka


def kld_limit(
    k: np.ndarray, err: float, z: float, min_particles: int, max_particles: int
) -> np.ndarray:
    """amcl's ``pf_resample_limit``: particles needed for ``k`` occupied bins."""
    k = np.asarray(k, dtype=np.float64)
    km1 = np.maximum(k - 1.0, 1.0)
    b = 2.0 / (9.0 * km1)
    x = 1.0 - b + np.sqrt(b) * z
    n = np.ceil(km1 / (2.0 * err) * x**3)
    n = np.where(k <= 1, max_particles, n)
    return np.clip(n, min_particles, max_particles).astype(np.int64)


def kld_count(candidates: np.ndarray, limit: int, bound: KldBound) -> int:
    """How many of ``candidates`` (in draw order) KLD sampling keeps: the first count that
    exceeds the bound of the bins filled so far, at most ``limit``.

    Prefixes are examined in doubling chunks: the answer is usually a fraction of the
    candidates (the cloud fills few bins), and the bins of a prefix do not depend on what
    follows it.
    """
    m = min(limit, len(candidates))
    size = min(m, max(256, bound.min_particles))
    while True:
        keys = bin_keys(candidates[:size])
        _, first = np.unique(keys, return_index=True)
        is_first = np.zeros(size, dtype=np.int64)
        is_first[first] = 1
        bins = np.cumsum(is_first)
        over = np.flatnonzero(np.arange(1, size + 1) > bound(bins))
        if over.size:
            return int(over[0]) + 1
        if size >= m:
            return m
        size = min(m, 2 * size)


class KldBound:
    """:func:`kld_limit` with the filter's settings."""

    def __init__(self, err: float, z: float, min_particles: int, max_particles: int) -> None:
        self.err, self.z = err, z
        self.min_particles, self.max_particles = min_particles, max_particles

    def __call__(self, k: np.ndarray) -> np.ndarray:
        return kld_limit(k, self.err, self.z, self.min_particles, self.max_particles)


def weighted_pose(p: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Weighted mean [x, y, yaw] of poses ``p`` (N, 3), circular for yaw."""
    total = float(w.sum())
    if total <= 0.0:
        w = np.full(len(p), 1.0 / len(p))
        total = 1.0
    x = float(w @ p[:, 0]) / total
    y = float(w @ p[:, 1]) / total
    yaw = math.atan2(float(w @ np.sin(p[:, 2])), float(w @ np.cos(p[:, 2])))
    return np.array([x, y, yaw])


def heaviest_cluster(p: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, float]:
    """amcl's pose: the weighted mean of the heaviest cluster, and that cluster's weight.

    Clusters are connected components (26-neighbourhood, yaw wrapping) of the occupied
    histogram bins.
    """
    kx = np.floor(p[:, 0] / BIN_SIZE[0]).astype(np.int64)
    ky = np.floor(p[:, 1] / BIN_SIZE[1]).astype(np.int64)
    ka = np.floor((p[:, 2] + math.pi) / BIN_SIZE[2]).astype(np.int64) % _YAW_BINS
    kx -= kx.min()
    ky -= ky.min()
    nx, ny = int(kx.max()) + 1, int(ky.max()) + 1
    if nx * ny * _YAW_BINS > 4_000_000:
        return weighted_pose(p, w), 1.0
    used = np.zeros(_YAW_BINS, dtype=bool)
    used[ka] = True
    wrap = bool(used.all())
    if not wrap:
        # Turn the yaw axis so that an empty yaw bin is the last: no cluster then crosses
        # the seam, and the histogram only needs the yaw bins between the occupied ones.
        ka = (ka - (int(np.argmin(used)) + 1)) % _YAW_BINS
        ka -= ka.min()
    occ = np.zeros((nx, ny, _YAW_BINS if wrap else int(ka.max()) + 1), dtype=bool)
    occ[kx, ky, ka] = True
    labels, count = ndimage.label(occ, structure=np.ones((3, 3, 3), dtype=bool))
    if wrap and count > 1:
        labels = _merge_yaw_wrap(labels, count)
    lab = labels[kx, ky, ka]
    totals = np.bincount(lab, weights=w)
    best = int(np.argmax(totals))
    sel = lab == best
    return weighted_pose(p[sel], w[sel]), float(totals[best])


def _merge_yaw_wrap(labels: np.ndarray, count: int) -> np.ndarray:
    """Join components that touch across the yaw seam (bin 35 next to bin 0)."""
    first, last = labels[:, :, 0], labels[:, :, -1]
    pairs = []
    nx, ny = first.shape
    for dx in (-1, 0, 1):
        for dy in (-1, 0, 1):
            a = first[max(0, dx) : nx + min(0, dx), max(0, dy) : ny + min(0, dy)]
            b = last[max(0, -dx) : nx + min(0, -dx), max(0, -dy) : ny + min(0, -dy)]
            both = (a > 0) & (b > 0)
            if both.any():
                pairs.append(np.stack([a[both], b[both]]))
    if not pairs:
        return labels
    ab = np.concatenate(pairs, axis=1)
    graph = coo_matrix((np.ones(ab.shape[1]), (ab[0], ab[1])), shape=(count + 1, count + 1))
    _, comp = connected_components(graph, directed=False)
    # Component 0 must stay "background": relabel so that label 0 maps to 0.
    comp = comp + 1
    comp[0] = 0
    return comp[labels]
