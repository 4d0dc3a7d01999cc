"""Helpers shared by the local planners: projection on a polyline and reference sampling.

All functions work on map-frame (N, 2) polylines and are pure numpy (no solver).
The speed profile is the usual trapezoid-with-limits: a per-point speed cap (max speed,
curvature, stop at the goal), a backward pass for braking and a forward pass for
acceleration, then integrated in time to give one arclength per model step.
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass

import numpy as np

from agv_mission.geometry import Pose2D


def clean_path(path: np.ndarray) -> np.ndarray:
    """``path`` as a float (N, 2) array without consecutive duplicate points."""
    pts = np.asarray(path, dtype=float).reshape(-1, 2)
    if len(pts) < 2:
        return pts
    keep = np.ones(len(pts), dtype=bool)
    keep[1:] = np.linalg.norm(np.diff(pts, axis=0), axis=1) > 1e-9
    return pts[keep]


def cumulative_length(path: np.ndarray) -> np.ndarray:
    """Arclength at every vertex, starting at 0."""
    if len(path) < 2:
        return np.zeros(len(path))
    return np.concatenate(([0.0], np.cumsum(np.linalg.norm(np.diff(path, axis=0), axis=1))))


@dataclass(frozen=True)
class Projection:
    """The closest point of a polyline to a query point."""

    s: float  # arclength of the closest point
    point: np.ndarray  # (2,) closest point
    segment: int  # index of the segment [segment, segment + 1]
    distance: float


@dataclass(frozen=True)
class Segments:
    """A polyline's segments as arrays (what every projection on it needs)."""

    path: np.ndarray
    cumlen: np.ndarray
    start: np.ndarray  # (K, 2) first point of each segment
    delta: np.ndarray  # (K, 2) segment vectors
    length2: np.ndarray  # (K,) squared lengths
    length: np.ndarray  # (K,)

    @staticmethod
    def of(path: np.ndarray, cumlen: np.ndarray | None = None) -> Segments:
        if cumlen is None:
            cumlen = cumulative_length(path)
        d = np.diff(path, axis=0)
        length2 = np.einsum("ij,ij->i", d, d)
        return Segments(path, cumlen, path[:-1], d, length2, np.sqrt(length2))


def closest_point(
    path: np.ndarray,
    point: np.ndarray | tuple[float, float],
    cumlen: np.ndarray | None = None,
    s_min: float | None = None,
    s_max: float | None = None,
    segments: Segments | None = None,
) -> Projection:
    """Project ``point`` on the polyline, optionally only on the arclength window [s_min, s_max].

    Ties go to the lowest arclength, so a path that comes back near itself is
    followed in order when a window around the previous progress is given.
    ``segments`` (of this path) saves recomputing them.
    """
    p = np.asarray(point, dtype=float)
    if len(path) == 1:
        return Projection(0.0, path[0].copy(), 0, float(np.linalg.norm(p - path[0])))
    seg = segments if segments is not None else Segments.of(path, cumlen)
    cumlen, a, d, seg_len = seg.cumlen, seg.start, seg.delta, seg.length
    t = np.einsum("ij,ij->i", p - a, d) / np.maximum(seg.length2, 1e-18)
    if s_min is None and s_max is None:  # the whole path (the navigator's every step)
        t = np.minimum(np.maximum(t, 0.0), 1.0)
        proj = a + t[:, None] * d
        off = proj - p
        dist2 = np.einsum("ij,ij->i", off, off)
        i = int(dist2.argmin())
        return Projection(
            s=float(cumlen[i] + t[i] * seg_len[i]),
            point=proj[i],
            segment=i,
            distance=float(math.sqrt(dist2[i])),
        )
    lo = np.zeros_like(t)
    hi = np.ones_like(t)
    if s_min is not None:
        lo = np.maximum(lo, (s_min - cumlen[:-1]) / np.maximum(seg_len, 1e-18))
    if s_max is not None:
        hi = np.minimum(hi, (s_max - cumlen[:-1]) / np.maximum(seg_len, 1e-18))
    valid = lo <= hi
    if not np.any(valid):  # empty window: fall back to the whole path
        lo, hi, valid = np.zeros_like(t), np.ones_like(t), np.ones_like(t, dtype=bool)
    t = np.minimum(np.maximum(t, lo), hi)
    proj = a + t[:, None] * d
    dist2 = np.einsum("ij,ij->i", proj - p, proj - p)
    dist2[~valid] = np.inf
    i = int(np.argmin(dist2))
    return Projection(
        s=float(cumlen[i] + t[i] * seg_len[i]),
        point=proj[i],
        segment=i,
        distance=float(math.sqrt(dist2[i])),
    )


def interpolate(
    path: np.ndarray, cumlen: np.ndarray, s: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Points (K, 2) and tangent headings (K,) at arclengths ``s`` (clamped to the path)."""
    s = np.minimum(np.maximum(np.asarray(s, dtype=float), 0.0), cumlen[-1])
    if len(path) < 2:
        return np.repeat(path[:1], len(s), axis=0), np.zeros(len(s))
    i = np.searchsorted(cumlen, s, side="right") - 1
    i = np.minimum(np.maximum(i, 0), len(path) - 2)
    seg = path[i + 1] - path[i]
    seg_len = cumlen[i + 1] - cumlen[i]
    t = (s - cumlen[i]) / np.maximum(seg_len, 1e-18)
    pts = path[i] + t[:, None] * seg
    return pts, np.arctan2(seg[:, 1], seg[:, 0])


def curvature_speed_limit(
    path: np.ndarray,
    cumlen: np.ndarray,
    s: np.ndarray,
    max_v: float,
    max_w: float,
    window: float,
    turn_fraction: float = 0.7,
) -> np.ndarray:
    """Speed cap at arclengths ``s`` so that turning the path there needs <= turn_fraction * max_w.

    Curvature is the heading change over [s - window, s + window] divided by its length,
    which smooths polyline corners into arcs of about the window's size.
    """
    s = np.asarray(s, dtype=float)
    _, h = interpolate(path, cumlen, np.concatenate((s - window, s + window)))
    h_back, h_fwd = h[: len(s)], h[len(s) :]
    dpsi = np.abs((h_fwd - h_back + np.pi) % (2.0 * np.pi) - np.pi)
    kappa = dpsi / (2.0 * window)
    with np.errstate(divide="ignore"):
        cap = np.where(kappa > 1e-9, turn_fraction * max_w / np.maximum(kappa, 1e-9), max_v)
    return np.minimum(cap, max_v)


class ReferenceProfile:
    """A path prepared once for time-sampled references (what the MPC asks every step).

    The speed cap (curvature, stop at the end) and its backward braking pass are
    computed over the whole path on a fixed 1 cm grid of squared speeds, and every
    segment's tangent heading is made continuous along the path. While the navigator
    keeps the path, a reference then costs one short loop over the horizon instead of a
    new profile per step. Compared with a profile built from the robot's arclength every
    step (5 cm grid, speeds interpolated linearly), the final approach brakes on the exact
    constant-deceleration curve: smaller goal errors, the same or better tracking.
    """

    def __init__(
        self,
        path: np.ndarray,
        cumlen: np.ndarray,
        max_v: float,
        max_w: float,
        acc: float,
        dec: float,
        curvature_window: float = 0.15,
        turn_fraction: float = 0.7,
        min_v: float = 0.0,
        spacing: float = 0.01,
    ) -> None:
        self.path, self.cumlen = path, cumlen
        self.total = float(cumlen[-1])
        self.max_v, self.min_v, self.acc, self.dec = max_v, max(min_v, 0.0), acc, dec
        seg = Segments.of(path, cumlen)
        heading = np.unwrap(np.arctan2(seg.delta[:, 1], seg.delta[:, 0]))
        # Per segment, as plain floats (a lookup is a bisect and a few multiplications):
        # start, direction, 1 / length, continuous heading, arclength at its start.
        self._cum = cumlen.tolist()
        self._segments = list(
            zip(
                *seg.start.T.tolist(),
                *seg.delta.T.tolist(),
                (1.0 / np.maximum(seg.length, 1e-18)).tolist(),
                heading.tolist(),
                self._cum,
                strict=False,
            )
        )
        n_grid = max(2, int(math.ceil(self.total / spacing)) + 1)
        grid = np.linspace(0.0, self.total, n_grid)
        cap = curvature_speed_limit(
            path, cumlen, grid, max_v, max_w, curvature_window, turn_fraction
        )
        cap[-1] = 0.0
        self.step = self.total / (n_grid - 1)
        # Squared speeds: braking at constant deceleration is linear in v^2, so the
        # backward pass and the lookups between grid points are exact for it.
        v2 = (cap * cap).tolist()
        for i in range(n_grid - 2, -1, -1):
            v2[i] = min(v2[i], v2[i + 1] + 2.0 * dec * self.step)
        self.speed_sq = v2

    def sample(
        self, s0: float, v0: float, steps: int, dt: float, stop_at: float = math.inf
    ) -> tuple[list, list]:
        """Arclengths and speeds (``steps + 1`` each) of a reference sampled every ``dt``
        from ``s0`` at speed ``v0`` (clipped to [min_v, max_v]): it accelerates at ``acc``
        at most, keeps under the profile (the cap looked up where a step would end),
        brakes at ``dec`` to stand at ``stop_at`` (an arclength) and waits at the end of
        the path."""
        v_cur = min(max(float(v0), self.min_v), self.max_v)
        s_cur, total, vg, last = s0, self.total, self.speed_sq, len(self.speed_sq) - 2
        inv_step = 1.0 / self.step if self.step > 0 else 0.0
        up, down = self.acc * dt, self.dec * dt
        s_out, v_out = [s0], [v_cur]
        for _ in range(steps):
            u = (s_cur + v_cur * dt) * inv_step
            i = min(max(int(u), 0), last)
            t = min(max(u - i, 0.0), 1.0)
            cap = math.sqrt(max(vg[i] + t * (vg[i + 1] - vg[i]), 0.0))
            if stop_at < total:
                room = stop_at - (s_cur + v_cur * dt)
                cap = min(cap, math.sqrt(2.0 * self.dec * room) if room > 0.0 else 0.0)
            v_new = min(v_cur + up, max(cap, v_cur - down))
            s_cur = min(s_cur + 0.5 * (v_cur + v_new) * dt, total)
            v_cur = 0.0 if s_cur >= total else v_new
            s_out.append(s_cur)
            v_out.append(v_cur)
        return s_out, v_out

    def point(self, s: float) -> tuple[float, float, float]:
        """The point (x, y) and continuous tangent heading at arclength ``s`` (clamped to
        the path)."""
        s = min(max(s, 0.0), self.total)
        i = min(max(bisect.bisect_right(self._cum, s) - 1, 0), len(self._segments) - 1)
        ax, ay, dx, dy, inv_len, heading, start = self._segments[i]
        t = (s - start) * inv_len
        return ax + t * dx, ay + t * dy, heading

    def in_frame(self, s: list[float], v: list[float], frame: Pose2D) -> list[float]:
        """Rows (x, y, heading, speed) at arclengths ``s`` with speeds ``v``, flattened, in
        ``frame`` (the robot's): headings relative to its yaw, continuous, the first one
        within pi of 0."""
        c, sn, yaw = math.cos(frame.yaw), math.sin(frame.yaw), frame.yaw
        out: list[float] = []
        shift = None
        for s_k, v_k in zip(s, v, strict=True):
            x, y, heading = self.point(s_k)
            x, y, heading = x - frame.x, y - frame.y, heading - yaw
            if shift is None:
                shift = 2.0 * math.pi * round(-heading / (2.0 * math.pi))
            out += (c * x + sn * y, c * y - sn * x, heading + shift, v_k)
        return out
