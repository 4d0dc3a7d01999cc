"""A bag's coordinate frames as /tf and /tf_static tell them: rigid transforms, the static
chain from the scan's frame upwards, /tf's links (those that never change are static, as
ROS 1's static_transform_publisher's), and where the lidar sits on the robot's base."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from agv_mission.geometry import Pose2D


@dataclass
class Transform:
    """A 3D rigid transform as a 4x4 matrix (child frame in the parent frame)."""

    matrix: np.ndarray

    @classmethod
    def from_msg(cls, tr: Any) -> Transform:
        t, q = tr.translation, tr.rotation
        return cls(transform_matrix(t.x, t.y, t.z, q.x, q.y, q.z, q.w))

    def planar(self) -> tuple[Pose2D, bool]:
        """The planar pose of the child frame and whether its z axis points down."""
        m = self.matrix
        return Pose2D(float(m[0, 3]), float(m[1, 3]), math.atan2(m[1, 0], m[0, 0])), bool(
            m[2, 2] < 0.0
        )


def transform_matrix(
    x: float, y: float, z: float, qx: float, qy: float, qz: float, qw: float
) -> np.ndarray:
    """The 4x4 matrix of a translation and a quaternion (normalised here)."""
    n = math.sqrt(qx * qx + qy * qy + qz * qz + qw * qw) or 1.0
    qx, qy, qz, qw = qx / n, qy / n, qz / n, qw / n
    m = np.eye(4)
    m[:3, :3] = [
        [1 - 2 * (qy * qy + qz * qz), 2 * (qx * qy - qz * qw), 2 * (qx * qz + qy * qw)],
        [2 * (qx * qy + qz * qw), 1 - 2 * (qx * qx + qz * qz), 2 * (qy * qz - qx * qw)],
        [2 * (qx * qz - qy * qw), 2 * (qy * qz + qx * qw), 1 - 2 * (qx * qx + qy * qy)],
    ]
    m[:3, 3] = [x, y, z]
    return m


def scan_mount(
    chain: list[tuple[str, np.ndarray]], base_frame: str, scan_frame: str
) -> tuple[Pose2D, bool, bool]:
    """The scan frame's planar pose on the base frame (up the static ``chain`` of (frame,
    transform to its parent)), whether it is mounted upside down, and whether the chain
    reaches the base frame at all (else the identity)."""
    mount = np.eye(4)
    found = False
    for frame, parent_tf in chain:
        if frame == base_frame:
            found = True
            break
        mount = parent_tf @ mount
    if not found and scan_frame == base_frame:
        found = True
    mount_pose, flipped = Transform(mount if found else np.eye(4)).planar()
    return mount_pose, flipped, found


def tf_links(
    dynamic: dict[tuple[str, str], list[tuple[float, np.ndarray]]],
    static: dict[str, tuple[str, Transform]],
) -> tuple[dict[tuple[str, str], np.ndarray], dict[tuple[str, str], np.ndarray]]:
    """/tf's links as rows (t, x, y, yaw), and those that move; a link that never changes
    joins ``static`` (ROS 1's static_transform_publisher)."""
    links: dict[tuple[str, str], np.ndarray] = {}
    moving: dict[tuple[str, str], np.ndarray] = {}
    for (parent, child), rows in dynamic.items():
        rows.sort(key=lambda r: r[0])
        values = np.array([r[1] for r in rows])
        links[(parent, child)] = np.array([(t, v[0], v[1], planar_yaw(v[3:])) for t, v in rows])
        if np.ptp(values, axis=0).max() < 1e-9:
            static.setdefault(child, (parent, Transform(transform_matrix(*values[0]))))
        else:
            moving[(parent, child)] = links[(parent, child)]
    return links, moving


def planar_yaw(q: np.ndarray) -> float:
    """The yaw of a quaternion (x, y, z, w)."""
    x, y, z, w = (float(v) for v in q)
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def static_chain(
    frame: str, static: dict[str, tuple[str, Transform]]
) -> list[tuple[str, np.ndarray]]:
    """[(frame, its transform in its parent)] from ``frame`` upwards; the last entry is
    the topmost frame reached (with an identity)."""
    chain: list[tuple[str, np.ndarray]] = []
    seen = set()
    while frame in static and frame not in seen:
        seen.add(frame)
        parent, tf = static[frame]
        chain.append((frame, tf.matrix))
        frame = parent
    chain.append((frame, np.eye(4)))
    return chain
