"""amcl's laser beam models (``likelihood_field``, ``likelihood_field_prob``) as a lookup
table over the map, so that scoring N particles x B beams is one matrix product, one
integer conversion and one table gather."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np

from agv_mission.maps.distance import obstacle_distance
from agv_mission.maps.grid import OccupancyGrid
from agv_mission.maps.map_cache import map_table

LaserModel = Literal["likelihood_field", "likelihood_field_prob"]

#: Cells at or above this value count as occupied (map_server's occupied_thresh 0.65).
OCCUPIED_THRESHOLD = 65
#: Beam end points scored per block (see BeamModel.score).
_BLOCK_ELEMENTS = 32768


@dataclass(frozen=True)
class SensorParams:
    """The likelihood-field parameters (amcl's ``laser_*``)."""

    z_hit: float = 0.5
    z_rand: float = 0.5
    sigma_hit: float = 0.2
    max_beams: int = 180
    max_range: float = 3.5  # <= 0: the scan's range_max
    min_range: float = -1.0  # <= 0: the scan's range_min
    likelihood_max_dist: float = 2.0
    model: LaserModel = "likelihood_field"
    log_scale: float = 1.0  # likelihood_field_prob: each beam's log-likelihood times this


class BeamModel:
    """Per-cell beam scores over a padded copy of the map, for table lookups.

    ``likelihood_field`` (amcl's default) scores a particle ``1 + sum(pz**3)`` over the
    beams; ``likelihood_field_prob`` scores ``sum(log(pz))`` (a log-likelihood), with
    ``pz = z_hit * exp(-d**2 / (2 sigma_hit**2)) + z_rand / range_max`` and ``d`` the
    distance from the beam's end point to the nearest occupied cell.
    """

    def __init__(self, grid: OccupancyGrid, params: SensorParams, range_max: float) -> None:
        self.params = params
        self.range_max = float(range_max)
        self.resolution = float(grid.resolution)
        self.origin = grid.origin
        occupied = grid.data >= OCCUPIED_THRESHOLD
        res = self.resolution
        max_dist = float(params.likelihood_max_dist)
        if occupied.any():
            dist = np.minimum(obstacle_distance(occupied, res), np.float32(max_dist))
        else:
            dist = np.full(occupied.shape, max_dist, dtype=np.float32)
        # Pad by the beam length so that every end point of a particle on the map indexes
        # the table; the pad reads as max_dist (amcl: off-map end points).
        self.pad = int(math.ceil(self.range_max / res)) + 2
        dist = np.pad(dist, self.pad, constant_values=max_dist)
        self.height, self.width = int(dist.shape[0]), int(dist.shape[1])
        self.map_height, self.map_width = occupied.shape
        d64 = dist.astype(np.float64)
        pz = params.z_hit * np.exp(-(d64**2) / (2.0 * params.sigma_hit**2))
        pz += params.z_rand / self.range_max
        pz_far = params.z_hit * math.exp(-(max_dist**2) / (2.0 * params.sigma_hit**2))
        pz_far += params.z_rand / self.range_max
        if params.model == "likelihood_field":
            table, self.far = pz**3, pz_far**3
        else:
            k = params.log_scale
            table, self.far = k * np.log(pz), k * math.log(pz_far)
        self.table = np.ascontiguousarray(table, dtype=np.float32).ravel()
        self.distance = dist  # padded distance field, metres (for plots and tests)
        self.table.flags.writeable = False  # shared between runs (map_cache)
        self.distance.flags.writeable = False

    def to_grid_frame(self, particles: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Particle positions in padded-cell units and yaws in the grid's frame."""
        o = self.origin
        x, y, yaw = particles[:, 0] - o.x, particles[:, 1] - o.y, particles[:, 2]
        if o.yaw != 0.0:
            c, s = math.cos(o.yaw), math.sin(o.yaw)
            x, y = c * x + s * y, -s * x + c * y
            yaw = yaw - o.yaw
        inv = 1.0 / self.resolution
        return x * inv + self.pad, y * inv + self.pad, yaw

    def score(self, particles: np.ndarray, bx: np.ndarray, by: np.ndarray) -> np.ndarray:
        """Scores (N,) float64 of particles (N, 3) for beam end points ``bx, by`` (B,).

        ``bx, by`` are the end points in the robot frame, in cells (``range * cos(angle) /
        resolution``...). Particles off the map get every beam at ``likelihood_max_dist``.
        """
        n, b = len(particles), len(bx)
        base = 1.0 if self.params.model == "likelihood_field" else 0.0
        if b == 0:
            return np.full(n, base)
        u0, v0, yaw = self.to_grid_frame(particles)
        pad = self.pad
        off = (u0 < pad) | (u0 > pad + self.map_width) | (v0 < pad) | (v0 > pad + self.map_height)
        c, s = np.cos(yaw), np.sin(yaw)
        a = np.empty((2 * n, 3), dtype=np.float32)
        a[:n, 0], a[:n, 1], a[:n, 2] = u0, c, -s
        a[n:, 0], a[n:, 1], a[n:, 2] = v0, s, c
        if off.any():
            a[:n, 0][off] = pad  # keep the gather in bounds; the score is overwritten below
            a[n:, 0][off] = pad
        q = np.empty((3, b), dtype=np.float32)
        q[0], q[1], q[2] = 1.0, bx, by
        total = np.empty(n)
        # Blocks small enough to stay in cache and below OpenBLAS's threading threshold
        # (threads on a busy 2-core machine cost milliseconds).
        block = max(32, _BLOCK_ELEMENTS // b)
        for s0 in range(0, n, block):
            s1 = min(n, s0 + block)
            m = s1 - s0
            ab = np.concatenate([a[s0:s1], a[n + s0 : n + s1]])
            cells = (ab @ q).astype(np.int32)  # >= 0, so truncation is floor
            cols, rows = cells[:m], cells[m:]
            rows *= self.width
            rows += cols
            total[s0:s1] = np.take(self.table, rows).sum(axis=1, dtype=np.float64)
        total += base
        if off.any():
            total[off] = base + b * self.far
        return total


def beam_model(grid: OccupancyGrid, params: SensorParams, range_max: float) -> BeamModel:
    """The map's :class:`BeamModel` for ``params``, built once per map content (map_cache)."""
    r = float(range_max)
    return map_table("beam_model", grid, (params, r), lambda: BeamModel(grid, params, r))
