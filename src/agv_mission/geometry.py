"""Planar geometry shared by every layer: poses, angles and quaternions (REP-103), and
robots' footprints (:class:`Footprint`)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

Bounds = tuple[float, float, float, float]  # (xmin, xmax, ymin, ymax) of the map frame, metres


def wrap_angle(angle: float) -> float:
    """Wrap an angle to [-pi, pi)."""
    return (angle + math.pi) % (2.0 * math.pi) - math.pi


def wrap_angles(angles: np.ndarray) -> np.ndarray:
    """Vectorised :func:`wrap_angle`."""
    return (angles + np.pi) % (2.0 * np.pi) - np.pi


def yaw_from_quaternion(x: float, y: float, z: float, w: float) -> float:
    """Yaw of a quaternion (rotation about +z), as ROS ``tf.transformations`` gives it."""
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def quaternion_from_yaw(yaw: float) -> tuple[float, float, float, float]:
    """The (x, y, z, w) quaternion of a rotation by ``yaw`` about +z."""
    return 0.0, 0.0, math.sin(yaw / 2.0), math.cos(yaw / 2.0)


def arc_step(x: float, y: float, yaw: float, d: float, dth: float) -> tuple[float, float, float]:
    """(x, y, yaw) after travelling ``d`` along a circular arc that turns by ``dth``: a
    diff-drive's motion between two reads of constant wheel speeds (plain floats: the
    odometry calls it every control step)."""
    if abs(dth) < 1e-6:  # midpoint heading (second-order exact as dth -> 0)
        mid = yaw + dth / 2.0
        return x + d * math.cos(mid), y + d * math.sin(mid), wrap_angle(yaw + dth)
    radius = d / dth
    return (
        x + radius * (math.sin(yaw + dth) - math.sin(yaw)),
        y - radius * (math.cos(yaw + dth) - math.cos(yaw)),
        wrap_angle(yaw + dth),
    )


@dataclass(frozen=True, slots=True)
class Pose2D:
    """A planar pose: position in metres, yaw in radians counter-clockwise from +x."""

    x: float
    y: float
    yaw: float = 0.0

    def distance_to(self, other: Pose2D) -> float:
        return math.hypot(other.x - self.x, other.y - self.y)

    def heading_error_to(self, other: Pose2D) -> float:
        """Signed yaw difference ``other.yaw - self.yaw`` wrapped to [-pi, pi)."""
        return wrap_angle(other.yaw - self.yaw)

    def compose(self, delta: Pose2D) -> Pose2D:
        """``self (+) delta``: apply a motion expressed in this pose's frame."""
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        return Pose2D(
            self.x + c * delta.x - s * delta.y,
            self.y + s * delta.x + c * delta.y,
            wrap_angle(self.yaw + delta.yaw),
        )

    def driven(self, v: float, w: float, dt: float) -> Pose2D:
        """The pose after driving at constant (v, w) for ``dt`` (exactly on the arc)."""
        return Pose2D(*arc_step(self.x, self.y, self.yaw, v * dt, w * dt))

    def relative_to(self, origin: Pose2D) -> Pose2D:
        """``origin (-) self``: this pose expressed in the frame of ``origin``."""
        c, s = math.cos(origin.yaw), math.sin(origin.yaw)
        dx, dy = self.x - origin.x, self.y - origin.y
        return Pose2D(c * dx + s * dy, -s * dx + c * dy, wrap_angle(self.yaw - origin.yaw))

    def as_array(self) -> np.ndarray:
        return np.array([self.x, self.y, self.yaw], dtype=float)

    @property
    def xy(self) -> tuple[float, float]:
        return self.x, self.y

    def quaternion(self) -> tuple[float, float, float, float]:
        return quaternion_from_yaw(self.yaw)


# -- footprints ------------------------------------------------------------
# A robot's planar footprint: its polygon (Nav2's ``footprint``, robot frame) and the
# figures every layer derives from it.
#
# A round robot's footprint is the circle of ``footprint_radius``. A polygon gives:
#
# * the **inscribed** radius (Nav2's ``inscribed_radius``): the largest circle round the
#   robot's origin inside the polygon. A cell closer than that to an obstacle puts the body
#   in collision whatever the heading, so the costmap and the global planners keep the
#   origin that far out (as Nav2's inflation layer and planners do); the heading-aware
#   check is the local planner's.
# * the **circumscribed** radius: the smallest circle round the origin holding the
#   polygon; layers that do not look at the heading (the fleet's reservations, the people
#   around a robot) use it, so they never under-estimate the body.
# * a **cover of discs** along the robot's x axis (the usual MPC model of a long body):
#   each of its points lies within ``radius`` of one disc centre, so keeping every centre
#   ``radius`` from every obstacle point keeps the whole polygon clear.

#: Disc covers are refined until they overshoot the footprint's width by at most this
#: much (m) on each side, or reach :data:`MAX_DISCS` discs.
COVER_OVERSHOOT = 0.02
#: Farthest (m) a pose, a body or a size may lie from its frame's origin in any input: 10 000
#: km holds any robot's odometry, even a UTM one; beyond it a float64 no longer resolves a
#: millimetre, and 1e300 m is a broken input, not a place (its square overflows).
MAX_COORDINATE = 1e7
MAX_DISCS = 4
CIRCLE_SIDES = 16  # a round footprint drawn or checked as a polygon


@dataclass(frozen=True)
class Footprint:
    """A robot's outline in its own frame (x ahead, y left), counter-clockwise."""

    polygon: np.ndarray  # (k, 2)
    round: bool  # a circle of ``circumscribed`` (the polygon is then its 16-gon)
    inscribed: float
    circumscribed: float

    @classmethod
    def circle(cls, radius: float) -> Footprint:
        a = np.arange(CIRCLE_SIDES) * (2.0 * math.pi / CIRCLE_SIDES)
        poly = radius * np.column_stack([np.cos(a), np.sin(a)])
        return cls(poly, True, float(radius), float(radius))

    @classmethod
    def from_points(cls, points: Sequence[Sequence[float]]) -> Footprint:
        poly = np.asarray(points, dtype=float).reshape(-1, 2)
        if polygon_area(poly) < 0.0:
            poly = poly[::-1].copy()
        return cls(poly, False, inscribed_radius(poly), float(np.hypot(*poly.T).max()))

    def discs(self) -> tuple[tuple[float, ...], float]:
        """Centres (x offsets along the robot's axis) and radius of the disc cover: one
        disc for a round robot; for a polygon the fewest equal discs whose width overshoots
        by at most :data:`COVER_OVERSHOOT` (4 at most)."""
        if self.round:
            return (0.0,), self.circumscribed
        x0, x1 = float(self.polygon[:, 0].min()), float(self.polygon[:, 0].max())
        for n in range(1, MAX_DISCS + 1):
            half = (x1 - x0) / (2 * n)
            centres = tuple(round(x0 + half * (2 * i + 1), 6) for i in range(n))
            radius = disc_cover_radius(self.polygon, centres)
            if radius - self.half_width <= COVER_OVERSHOOT or n == MAX_DISCS:
                return centres, radius
        raise AssertionError("unreachable")

    @property
    def half_width(self) -> float:
        return float(np.abs(self.polygon[:, 1]).max())

    @property
    def front(self) -> float:
        """How far the body reaches ahead of the origin, m."""
        return float(self.polygon[:, 0].max())

    @property
    def back(self) -> float:
        """How far the body reaches behind the origin, m (positive)."""
        return float(-self.polygon[:, 0].min())

    def in_map(self, x: float, y: float, yaw: float) -> np.ndarray:
        """The polygon placed at (x, y, yaw), (k, 2) map-frame points."""
        c, s = math.cos(yaw), math.sin(yaw)
        px, py = self.polygon[:, 0], self.polygon[:, 1]
        return np.column_stack([x + c * px - s * py, y + s * px + c * py])


def polygon_area(poly: np.ndarray) -> float:
    """Signed area (positive: counter-clockwise)."""
    x, y = poly[:, 0], poly[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))


def inscribed_radius(poly: np.ndarray) -> float:
    """Distance from the origin to the nearest edge of ``poly`` (0 when outside it)."""
    a, b = poly, np.roll(poly, -1, axis=0)
    ab = b - a
    t = np.clip(-(a * ab).sum(axis=1) / np.maximum((ab * ab).sum(axis=1), 1e-12), 0.0, 1.0)
    nearest = a + t[:, None] * ab
    return float(np.hypot(*nearest.T).min())


def disc_cover_radius(poly: np.ndarray, centres: Sequence[float]) -> float:
    """The radius discs centred at (c, 0) need to cover ``poly`` (a convex polygon: its
    vertices and, on each edge, the points nearest the boundaries between discs)."""
    pts = [poly]
    a, b = poly, np.roll(poly, -1, axis=0)
    cs = np.asarray(centres)
    for mid in (cs[:-1] + cs[1:]) / 2.0:  # where one disc hands over to the next
        dx = b[:, 0] - a[:, 0]
        ok = np.abs(dx) > 1e-12
        t = np.where(ok, (mid - a[:, 0]) / np.where(ok, dx, 1.0), -1.0)
        on = (t >= 0.0) & (t <= 1.0)
        pts.append(a[on] + t[on, None] * (b[on] - a[on]))
    p = np.vstack(pts)
    d = np.hypot(p[:, 0, None] - cs[None, :], p[:, 1, None])
    return float(d.min(axis=1).max())
