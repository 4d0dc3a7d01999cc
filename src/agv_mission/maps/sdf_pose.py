"""SDF poses as 3-D transforms: ``<pose>`` values (``x y z roll pitch yaw``, or a
quaternion in SDF 1.9) and their composition, parent frame first."""

from __future__ import annotations

import math

import numpy as np

Transform = tuple[np.ndarray, np.ndarray]  # rotation (3, 3), translation (3,)


def rotation_rpy(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """SDF's rpy: about fixed x, then y, then z (R = Rz Ry Rx)."""
    cr, sr, cp, sp, cy, sy = (
        math.cos(roll),
        math.sin(roll),
        math.cos(pitch),
        math.sin(pitch),
        math.cos(yaw),
        math.sin(yaw),
    )
    return np.array(
        [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ]
    )


def rotation_quaternion(x: float, y: float, z: float, w: float) -> np.ndarray:
    n = math.hypot(x, y, z, w)  # no overflow: 1e300 components are a direction too
    x, y, z, w = x / n, y / n, z / n, w / n
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


IDENTITY: Transform = (np.eye(3), np.zeros(3))


def compose(a: Transform, b: Transform) -> Transform:
    return a[0] @ b[0], a[0] @ b[1] + a[1]
