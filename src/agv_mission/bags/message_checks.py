"""A bag's messages checked before mapping trusts them: a scan, a pose or a transform
whose numbers cannot be a recording's (a ``nan`` or infinite position, a zero or
``nan`` quaternion, a scan whose beams share one angle, 10^6 beams, a range limit
that is not a number) is a :class:`~agv_mission.bags.recording.BagError` naming the
file, the topic, the message's index on it and the field:

    run.bag: /scan message 12: angle_increment: 0 with 360 beams (all at one angle)

instead of a traceback deep in the SLAM, or a map of nonsense. ``nan`` and ``inf``
*ranges* are REP-117's (invalid, no return) and stay.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from agv_mission.bags.carmen import MAX_BEAMS
from agv_mission.bags.recording import BagError
from agv_mission.geometry import MAX_COORDINATE

#: Shortest quaternion (its norm) that still names a rotation: ``(0, 0, 0, 0)``, an
#: unset orientation, names none (tf2 refuses it too).
MIN_QUATERNION_NORM = 1e-6
#: How far a quaternion's squared length may be from 1 (tf2's ``setTransform`` refuses a
#: "denormalized quaternion" beyond this).
QUATERNION_TOLERANCE = 0.01


class Where:
    """A message's place in the bag, for the errors that name it."""

    def __init__(self, path: Path, topic: str, index: int) -> None:
        self.path, self.topic, self.index = path, topic, index

    def error(self, field: str, what: str) -> BagError:
        return BagError(f"{self.path}: {self.topic} message {self.index}: {field}: {what}")


def _finite(where: Where, field: str, value: Any) -> float:
    v = float(value)
    if not math.isfinite(v):
        raise where.error(field, f"is not finite ({v!r})")
    return v


def check_stamp(where: Where, field: str, stamp: Any) -> None:
    """A ``builtin_interfaces/Time``: its nanoseconds below 10^9 (4e9 would move the
    message four seconds on, out of its order)."""
    nanosec = getattr(stamp, "nanosec", None)
    nanosec = stamp.nsecs if nanosec is None else nanosec  # ROS 1 genpy-style names
    if not 0 <= int(nanosec) < 1_000_000_000:
        raise where.error(f"{field}.nanosec", f"{int(nanosec)} is not below 10^9")


def check_position(where: Where, field: str, p: Any) -> None:
    """A position (``.x``, ``.y``, ``.z``): finite and within :data:`MAX_COORDINATE`."""
    for axis in ("x", "y", "z"):
        v = _finite(where, f"{field}.{axis}", getattr(p, axis))
        if abs(v) > MAX_COORDINATE:
            raise where.error(
                f"{field}.{axis}", f"{v:.4g} m is farther than {MAX_COORDINATE:.0e} m"
            )


def check_quaternion(where: Where, field: str, q: Any) -> None:
    """A quaternion (``.x`` .. ``.w``): finite and of unit length, as tf2 takes it (its
    squared length within :data:`QUATERNION_TOLERANCE` of 1: ``(0, 0, 0, 0)``, an unset
    orientation, names no rotation, and 1e300's overflow every product of them)."""
    values = [_finite(where, f"{field}.{a}", getattr(q, a)) for a in ("x", "y", "z", "w")]
    norm = math.hypot(*values)
    if norm < MIN_QUATERNION_NORM:
        raise where.error(field, "a quaternion of zero length names no rotation")
    if abs(norm * norm - 1.0) > QUATERNION_TOLERANCE:
        raise where.error(field, f"not a unit quaternion (length {norm:.4g}; tf2 refuses it too)")


def check_pose(where: Where, field: str, pose: Any) -> None:
    """A ``geometry_msgs/Pose``: its position and orientation."""
    check_position(where, f"{field}.position", pose.position)
    check_quaternion(where, f"{field}.orientation", pose.orientation)


def check_transform(where: Where, field: str, tr: Any) -> None:
    """A ``geometry_msgs/Transform``: its translation and rotation."""
    check_position(where, f"{field}.translation", tr.translation)
    check_quaternion(where, f"{field}.rotation", tr.rotation)


def check_scan(where: Where, msg: Any) -> None:
    """A ``sensor_msgs/LaserScan``'s geometry: at most :data:`MAX_BEAMS` beams, finite
    angles whose beams span at most a turn and do not share one angle, and
    ``0 <= range_min < range_max`` (``range_max`` may be ``inf``)."""
    n = len(msg.ranges)
    if n > MAX_BEAMS:
        raise where.error("ranges", f"{n} beams, more than {MAX_BEAMS}")
    amin = _finite(where, "angle_min", msg.angle_min)
    inc = _finite(where, "angle_increment", msg.angle_increment)
    if abs(amin) > 2.0 * math.pi:
        raise where.error("angle_min", f"{amin:.4g} rad is more than a turn")
    if n > 1 and inc == 0.0:
        raise where.error("angle_increment", f"0 with {n} beams (all at one angle)")
    if abs(inc) * (n - 1) > 2.0 * math.pi + 1e-3:
        raise where.error(
            "angle_increment",
            f"{inc:.4g} rad x {n - 1} beams spans {abs(inc) * (n - 1):.4g} rad, more than a turn",
        )
    rmin = float(msg.range_min)
    rmax = float(msg.range_max)
    if not (math.isfinite(rmin) and rmin >= 0.0):
        raise where.error("range_min", f"must be a finite distance >= 0, not {rmin!r}")
    if math.isnan(rmax) or rmax <= rmin:
        raise where.error("range_max", f"must be more than range_min ({rmin:g}), not {rmax!r}")
