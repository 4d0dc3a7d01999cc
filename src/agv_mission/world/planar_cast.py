"""Lidar beams against a world of many pillars, cast in the plane.

MuJoCo's ``mj_multiRay`` tests every beam against every geom's bounding volume: in a BARN
world (181-365 pillars) a 1440-beam scan took 9.7 ms on this machine, and a Jackal's
lidar scans 40 times a second. Our walls are vertical prisms (boxes and cylinders standing
on the floor) and a scan is (all but) horizontal, so each wall shadows only the beams
within its bounding circle's angular width: found by a binary search in the beams' sorted bearings, each
candidate pair is then intersected exactly (ray-circle, ray-box slabs), the nearest hit
per beam kept. Side by side in one process, 3.6 ms against mj_multiRay's 10.5 ms for the
same scan (a loaded machine: the ratio is what counts), the same distances to 1e-5 m.

A beam's 3-D length to a wall is its planar length over the cosine of its tilt (a pitching
robot's lidar), as MuJoCo measures it; walls are taken as tall enough for every beam.
"""

from __future__ import annotations

import math

import numpy as np

from agv_mission.world.walls import Walls


class PlanarWalls:
    """The world's static walls as planar shapes, for :meth:`cast`.

    ``box_geoms`` and ``cylinder_geoms``: the MuJoCo geom id of each box and cylinder
    (reported as the geom a beam hit)."""

    def __init__(self, walls: Walls, box_geoms: np.ndarray, cylinder_geoms: np.ndarray) -> None:
        # every wall: centre, bounding radius; boxes also their frame and half extents
        self.n_boxes = len(walls.box_c)
        centres = np.vstack((walls.box_c, walls.cyl[:, :2]))
        bound = np.concatenate((np.hypot(*walls.box_h.T), walls.cyl[:, 2]))
        self.centres, self.bound = centres, bound
        self.box_cs, self.box_h = walls.box_cs, walls.box_h
        self.radius = walls.cyl[:, 2]
        self.geoms = np.concatenate((box_geoms, cylinder_geoms)).astype(np.int32)

    def cast(
        self,
        origin: np.ndarray,
        directions: np.ndarray,
        dist: np.ndarray,
        geomid: np.ndarray,
        cutoff: float,
    ) -> None:
        """Lower ``dist`` (-1: no hit, as ``mj_multiRay`` writes it) to each beam's nearest
        wall hit and set its ``geomid``; ``directions``: unit vectors, flat (3n)."""
        vec = directions.reshape(-1, 3)
        flat = np.hypot(vec[:, 0], vec[:, 1])  # each beam's planar speed (cos of its tilt)
        ok = flat > 1e-9
        bearing = np.arctan2(vec[:, 1], vec[:, 0])
        rel = self.centres - origin[:2]
        gap = np.hypot(rel[:, 0], rel[:, 1])
        near = np.flatnonzero(gap - self.bound < cutoff)
        if not len(near):
            return
        walls, beams = self._candidates(bearing, rel[near], gap[near], self.bound[near])
        walls = near[walls]
        keep = ok[beams]
        walls, beams = walls[keep], beams[keep]
        ux, uy = vec[beams, 0] / flat[beams], vec[beams, 1] / flat[beams]
        t = np.full(len(beams), np.inf)
        is_box = walls < self.n_boxes
        if is_box.any():
            t[is_box] = self._boxes(walls[is_box], rel, ux[is_box], uy[is_box])
        cyl = ~is_box
        if cyl.any():
            t[cyl] = self._cylinders(walls[cyl], rel, ux[cyl], uy[cyl])
        hit = np.isfinite(t)
        walls, beams, t = walls[hit], beams[hit], t[hit] / flat[beams[hit]]
        if not len(t):
            return
        best = np.full(len(dist), np.inf)
        np.minimum.at(best, beams, t)  # each beam's nearest wall
        nearest = t == best[beams]
        beams, t, walls = beams[nearest], t[nearest], walls[nearest]
        closer = (dist[beams] < 0.0) | (t < dist[beams])
        dist[beams[closer]] = t[closer]
        geomid[beams[closer]] = self.geoms[walls[closer]]

    @staticmethod
    def _candidates(
        bearing: np.ndarray, rel: np.ndarray, gap: np.ndarray, bound: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """(wall, beam) pairs whose beam bearing lies within the wall's bounding circle's
        angular width (every beam for a wall whose circle holds the origin)."""
        order = np.argsort(bearing)
        sorted_bearing = bearing[order]
        centre = np.arctan2(rel[:, 1], rel[:, 0])
        inside = gap <= bound
        half = np.where(inside, math.pi, np.arcsin(np.minimum(bound / np.maximum(gap, 1e-12), 1.0)))
        lo, hi = centre - half, centre + half
        idx = np.arange(len(gap))
        # an interval wrapping past -pi or pi is two
        parts_w = [idx, idx[lo < -math.pi], idx[hi > math.pi]]
        parts_lo = [
            np.maximum(lo, -math.pi),
            lo[lo < -math.pi] + 2.0 * math.pi,
            np.full(int((hi > math.pi).sum()), -math.pi),
        ]
        parts_hi = [
            np.minimum(hi, math.pi),
            np.full(int((lo < -math.pi).sum()), math.pi),
            hi[hi > math.pi] - 2.0 * math.pi,
        ]
        w = np.concatenate(parts_w)
        start = np.searchsorted(sorted_bearing, np.concatenate(parts_lo), "left")
        stop = np.searchsorted(sorted_bearing, np.concatenate(parts_hi), "right")
        count = np.maximum(stop - start, 0)
        total = int(count.sum())
        walls = np.repeat(w, count)
        offsets = np.repeat(start - (np.cumsum(count) - count), count)
        beams = order[offsets + np.arange(total)]
        return walls, beams

    def _cylinders(
        self, k: np.ndarray, rel: np.ndarray, ux: np.ndarray, uy: np.ndarray
    ) -> np.ndarray:
        r = self.radius[k - self.n_boxes]
        dx, dy = rel[k, 0], rel[k, 1]
        proj = ux * dx + uy * dy
        perp2 = dx * dx + dy * dy - proj * proj
        inside = r * r - perp2
        root = np.sqrt(np.maximum(inside, 0.0))
        near, far = proj - root, proj + root
        t = np.where(near >= 0.0, near, far)
        return np.where((inside >= 0.0) & (far >= 0.0), t, np.inf)

    def _boxes(self, k: np.ndarray, rel: np.ndarray, ux: np.ndarray, uy: np.ndarray) -> np.ndarray:
        c, s = self.box_cs[k, 0], self.box_cs[k, 1]
        hx, hy = self.box_h[k, 0], self.box_h[k, 1]
        # the origin and the beam in the box's frame (rel: origin -> centre)
        ox, oy = -(c * rel[k, 0] + s * rel[k, 1]), -(-s * rel[k, 0] + c * rel[k, 1])
        bx, by = c * ux + s * uy, -s * ux + c * uy
        with np.errstate(divide="ignore", invalid="ignore"):
            tx1, tx2 = (-hx - ox) / bx, (hx - ox) / bx
            ty1, ty2 = (-hy - oy) / by, (hy - oy) / by
        # a beam parallel to a pair of faces: inside the slab, all t; outside, none
        para_x, para_y = bx == 0.0, by == 0.0
        in_x, in_y = np.abs(ox) <= hx, np.abs(oy) <= hy
        lox = np.where(para_x, np.where(in_x, -np.inf, np.inf), np.minimum(tx1, tx2))
        hix = np.where(para_x, np.where(in_x, np.inf, -np.inf), np.maximum(tx1, tx2))
        loy = np.where(para_y, np.where(in_y, -np.inf, np.inf), np.minimum(ty1, ty2))
        hiy = np.where(para_y, np.where(in_y, np.inf, -np.inf), np.maximum(ty1, ty2))
        enter, leave = np.maximum(lox, loy), np.minimum(hix, hiy)
        t = np.where(enter >= 0.0, enter, leave)
        return np.where((enter <= leave) & (leave >= 0.0), t, np.inf)
