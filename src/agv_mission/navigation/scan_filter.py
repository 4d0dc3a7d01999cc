"""Which lidar returns are not obstacles to mark: those on tracked people (the controller
avoids where they go; the localiser and the obstacle layer leave them out) and those on
other robots' bodies (the traffic layer keeps robots apart): a laser filter, as ROS's
``laser_filters`` chain runs before the costmap and the localiser.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from agv_mission.geometry import Pose2D
from agv_mission.sensor_msgs import LaserScan

#: A lidar return this close beyond another robot's footprint is that robot's.
BODY_SLACK = 0.1


PERSON_TOLERANCE = 0.15  # m beyond a tracked person's radius: a lidar return is theirs
# s a person must have stood before the costmap marks them: someone pausing a moment (to
# let the robot by, held up in a crowd) is left to the controller, which predicts them, so
# the plan is not thrown around by it (the obstacle layer marked 40-85 stops a 120 s
# warehouse patrol among 50 people when they counted at once)
STILL_TIME = 1.0
PEOPLE_REACH = 5.0  # m beyond the obstacle range: people farther cannot matter this horizon


def on_people(points: np.ndarray, people: np.ndarray) -> np.ndarray:
    """Which of ``points`` (n, 2) lie on a tracked person (rows x, y, radius, ...)."""
    pts = np.asarray(points, dtype=float).reshape(-1, 2)
    rows = np.asarray(people, dtype=float)
    d2 = (pts[:, None, 0] - rows[None, :, 0]) ** 2 + (pts[:, None, 1] - rows[None, :, 1]) ** 2
    reach = rows[:, 2] + PERSON_TOLERANCE
    return (d2 <= (reach * reach)[None, :]).any(axis=1)


def beams_on_people(scan: LaserScan, pose: Pose2D, people: np.ndarray) -> np.ndarray | None:
    """Which beams of ``scan`` seen from ``pose`` end on a tracked person (rows x, y,
    radius, ...): the localiser and the obstacle layer leave them out. None when no person
    is within the lidar's reach. Only the beams pointing at someone (each person's angular
    window) are looked at: a few of the scan's hundreds."""
    if not len(people):
        return None
    people = np.asarray(people, dtype=float)
    reach = scan.range_max + people[:, 2] + PERSON_TOLERANCE
    dx, dy = people[:, 0] - pose.x, people[:, 1] - pose.y
    near = dx * dx + dy * dy <= reach * reach
    if not near.any():
        return None
    people = people[near]
    n, inc = len(scan.ranges), scan.angle_increment
    beams = _beams_towards(people, pose, scan.angle_min, inc, n) if inc > 0.0 else None
    if beams is None:
        beams = np.arange(n)
    r = scan.ranges[beams]
    returned = np.isfinite(r)  # no-return beams (inf or nan) end on nobody
    beams, r = beams[returned], r[returned].astype(float)
    a = (scan.angle_min + inc * beams) + pose.yaw  # as ``scan.angles`` has them
    ex, ey = pose.x + r * np.cos(a), pose.y + r * np.sin(a)
    hit = np.zeros(len(beams), dtype=bool)
    for x, y, radius in people[:, 0:3].tolist():  # as :func:`on_people`, a person at a time
        reach = radius + PERSON_TOLERANCE
        hit |= (ex - x) ** 2 + (ey - y) ** 2 <= reach * reach
    mask = np.zeros(n, dtype=bool)
    mask[beams] = hit
    return mask


def _beams_towards(
    people: np.ndarray, pose: Pose2D, angle_min: float, inc: float, n: int
) -> np.ndarray | None:
    """Indices of the beams whose direction passes within a person's reach (a beam more
    either side); None when the lidar is inside someone's reach (every beam may)."""
    towards = np.zeros(n, dtype=bool)
    for x, y, radius in people[:, 0:3].tolist():
        dx, dy, reach = x - pose.x, y - pose.y, radius + PERSON_TOLERANCE
        dist = math.hypot(dx, dy)
        if dist <= reach:
            return None
        half = math.asin(reach / dist)
        centre = (math.atan2(dy, dx) - pose.yaw - angle_min) % math.tau
        for shift in (-math.tau, 0.0, math.tau):  # a window across the scan's start
            lo = max(0, math.floor((centre + shift - half) / inc) - 1)
            hi = min(n - 1, math.ceil((centre + shift + half) / inc) + 1)
            if lo <= hi:
                towards[lo : hi + 1] = True
    return np.flatnonzero(towards)


def standing_people(pose: Pose2D, seen: float, people: np.ndarray, grow: float) -> np.ndarray:
    """Discs (x, y, radius) of the tracked people within ``seen`` who have stood
    :data:`STILL_TIME`, grown by ``grow`` (the room the controller keeps from people): a
    plan round them that the controller can follow. Marked from their lidar returns alone, a person standing by
    a wall left a 0.65 m gap a plan went through and a waffle keeping 0.2 m more from
    them could not: it stood 75 s there."""
    rows = np.asarray(people, dtype=float)
    if not len(rows):
        return np.zeros((0, 3))
    near = np.hypot(rows[:, 0] - pose.x, rows[:, 1] - pose.y) <= seen + rows[:, 2]
    rows = rows[near & (rows[:, 5] >= STILL_TIME)]
    return np.column_stack([rows[:, 0], rows[:, 1], rows[:, 2] + grow])


def without_bodies(pose: Pose2D, scan: LaserScan, bodies: np.ndarray) -> LaserScan:
    """``scan`` with the returns off other robots' ``bodies`` (rows x, y, radius) made 'no
    return': neither the obstacle layer nor a localiser should take a robot for a wall."""
    if not len(bodies):
        return scan
    reach = scan.range_max + bodies[:, 2] + BODY_SLACK
    bodies = bodies[np.hypot(bodies[:, 0] - pose.x, bodies[:, 1] - pose.y) <= reach]
    if not len(bodies):  # nobody within the scan's reach
        return scan
    r = scan.ranges.astype(float)
    beams = np.flatnonzero(np.isfinite(r))
    a = scan.angle_min + scan.angle_increment * beams + pose.yaw
    x, y = pose.x + r[beams] * np.cos(a), pose.y + r[beams] * np.sin(a)
    d = np.hypot(x[:, None] - bodies[None, :, 0], y[:, None] - bodies[None, :, 1])
    theirs = beams[np.any(d <= bodies[None, :, 2] + BODY_SLACK, axis=1)]
    if not len(theirs):
        return scan
    ranges = scan.ranges.copy()
    ranges[theirs] = np.inf
    return replace(scan, ranges=ranges)
