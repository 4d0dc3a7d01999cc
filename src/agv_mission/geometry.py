"""Planar geometry shared by every layer: poses, angles and quaternions (REP-103)."""

from __future__ import annotations

import math
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
