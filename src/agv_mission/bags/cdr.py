"""CDR bytes of the messages a run writes every step, packed without message objects.

A particle cloud of a thousand poses costs ~12 ms as rosbags message objects and ~0.05 ms
as one array (:func:`pose_array_cdr`); the fixed-layout messages (clock, tf, odometry,
pose, twist, the scan's header) are packed from layouts compiled once (:class:`FixedCdr`).
``tests/test_bags.py`` checks every one byte for byte against rosbags' own serialiser.
"""

from __future__ import annotations

import math
import struct
from functools import cache
from typing import Any

import numpy as np

from agv_mission.bags.ros_messages import nanoseconds
from agv_mission.geometry import Pose2D
from agv_mission.sensor_msgs import LaserScan


def pose_array_cdr(t: float, frame: str, poses: np.ndarray) -> bytes:
    """CDR (little endian) of a ``geometry_msgs/PoseArray`` of planar (n, 3) poses.

    Layout: encapsulation header, Header (stamp, frame_id string), uint32 count, then
    each Pose as 7 float64 aligned to 8 bytes of the payload (after the 4-byte header).
    """
    sec, nsec = divmod(nanoseconds(t), 1_000_000_000)
    name = frame.encode() + b"\0"
    head = struct.pack("<iiI", int(sec), int(nsec), len(name)) + name
    head += b"\0" * (-len(head) % 4)
    head += struct.pack("<I", len(poses))
    head += b"\0" * (-len(head) % 8)
    p = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
    body = np.zeros((len(p), 7), dtype="<f8")
    body[:, 0], body[:, 1] = p[:, 0], p[:, 1]
    body[:, 5], body[:, 6] = np.sin(p[:, 2] / 2.0), np.cos(p[:, 2] / 2.0)
    return b"\x00\x01\x00\x00" + head + body.tobytes()


class CdrWriter:
    """Little-endian CDR (the encapsulation ROS 2 uses) written field by field with
    ``struct``; :class:`FixedCdr` compiles the per-step messages' layouts with it once."""

    def __init__(self) -> None:
        self.buf = bytearray(_ENCAPSULATION)

    def align(self, n: int) -> None:
        self.buf += b"\0" * (-(len(self.buf) - 4) % n)

    def u32(self, v: int) -> None:
        self.align(4)
        self.buf += struct.pack("<I", v)

    def string(self, text: str) -> None:
        data = text.encode() + b"\0"
        self.u32(len(data))
        self.buf += data


#: m/s^2: what an accelerometer at rest on a level floor reads upwards (REP 145: an IMU
#: reports the specific force, gravity included).
STANDARD_GRAVITY = 9.80665
_ENCAPSULATION = b"\x00\x01\x00\x00"
_NO_COVARIANCE = (0.0,) * 36


def sec_nsec(t: float) -> tuple[int, int]:
    """A ``builtin_interfaces/Time`` of simulated seconds."""
    return divmod(nanoseconds(t), 1_000_000_000)


class FixedCdr:
    """A message layout whose strings are known in advance (frame ids): its bytes are
    compiled once into a template, and each message writes only its numbers into a copy
    (one ``struct`` call per run of numbers). The per-step messages (tf, odometry,
    estimate, scan header) cost ~1-2 us each this way instead of ~0.1 ms as message
    objects; every layout is checked byte for byte against rosbags' serialiser in the
    tests.

    ``fields``: ``("time",)`` (a stamp, filled by ``(sec, nsec)``), ``("f64", n)`` (n
    numbers), and the fixed ``("string", text)``, ``("count", n)`` (a sequence length)
    and ``("zeros", n)`` (n float64 zeros).
    """

    def __init__(self, fields: list[tuple[Any, ...]]) -> None:
        w = CdrWriter()
        self.slots: list[tuple[int, struct.Struct]] = []  # (offset, layout) of each number run
        for kind, *args in fields:
            if kind == "string":
                w.string(args[0])
                continue
            if kind == "count":
                w.u32(args[0])
                continue
            if kind == "time":
                w.align(4)
                fmt, size = "<iI", 8
            else:
                w.align(8)
                fmt, size = f"<{args[0]}d", 8 * args[0]
            if kind != "zeros":
                self.slots.append((len(w.buf), struct.Struct(fmt)))
            w.buf += bytes(size)
        self.template = bytes(w.buf)

    def pack(self, *slots: tuple[float, ...]) -> bytes:
        """The message with each numeric field's values, in layout order."""
        buf = bytearray(self.template)
        for (offset, layout), values in zip(self.slots, slots, strict=True):
            layout.pack_into(buf, offset, *values)
        return bytes(buf)


def _pose7(p: Pose2D, z: float = 0.0) -> tuple[float, ...]:
    return (p.x, p.y, z, 0.0, 0.0, math.sin(p.yaw / 2.0), math.cos(p.yaw / 2.0))


def _covariance36(cov3: np.ndarray | None) -> tuple[float, ...]:
    """:func:`~agv_mission.bags.ros_messages.covariance6` as a tuple, without numpy's per-element indexing."""
    if cov3 is None:
        return _NO_COVARIANCE
    (xx, xy, xa), (yx, yy, ya), (ax, ay, aa) = np.asarray(cov3, dtype=float).tolist()
    return (
        (xx, xy, 0.0, 0.0, 0.0, xa)
        + (yx, yy, 0.0, 0.0, 0.0, ya)
        + (0.0,) * 18  # z, roll, pitch
        + (ax, ay, 0.0, 0.0, 0.0, aa)
    )


_CLOCK = FixedCdr([("time",)])
_TWIST = FixedCdr([("f64", 6)])


@cache
def _tf_layout(links: tuple[tuple[str, str], ...]) -> FixedCdr:
    fields: list[tuple[Any, ...]] = [("count", len(links))]
    for parent, child in links:
        fields += [("time",), ("string", parent), ("string", child), ("f64", 7)]
    return FixedCdr(fields)


@cache
def _pose_with_covariance_layout(frame: str) -> FixedCdr:
    return FixedCdr([("time",), ("string", frame), ("f64", 7 + 36)])


@cache
def _odometry_layout(frame: str, child: str, covariance: bool) -> FixedCdr:
    pose = ("f64", 7 + 36 + 6) if covariance else ("f64", 7)
    rest = [] if covariance else [("zeros", 36), ("f64", 6)]
    return FixedCdr([("time",), ("string", frame), ("string", child), pose, *rest, ("zeros", 36)])


def clock_cdr(t: float) -> bytes:
    return _CLOCK.pack(sec_nsec(t))


def twist_cdr(v: float, w: float) -> bytes:
    return _TWIST.pack((float(v), 0.0, 0.0, 0.0, 0.0, float(w)))


def tf_cdr(t: float, links: list[tuple[str, str, Pose2D, float]]) -> bytes:
    """``tf2_msgs/TFMessage`` of planar links (parent, child, pose, z), all stamped ``t``."""
    layout = _tf_layout(tuple((parent, child) for parent, child, _, _ in links))
    stamp = sec_nsec(t)
    slots: list[tuple[float, ...]] = []
    for _, _, p, z in links:
        slots += [stamp, _pose7(p, z)]
    return layout.pack(*slots)


def pose_with_covariance_cdr(t: float, frame: str, p: Pose2D, cov3: np.ndarray | None) -> bytes:
    return _pose_with_covariance_layout(frame).pack(sec_nsec(t), _pose7(p) + _covariance36(cov3))


def odometry_cdr(
    t: float, frame: str, child: str, p: Pose2D, v: float, w: float, cov3: np.ndarray | None
) -> bytes:
    twist = (float(v), 0.0, 0.0, 0.0, 0.0, float(w))
    if cov3 is None:
        return _odometry_layout(frame, child, False).pack(sec_nsec(t), _pose7(p), twist)
    layout = _odometry_layout(frame, child, True)
    return layout.pack(sec_nsec(t), _pose7(p) + _covariance36(cov3) + twist)


@cache
def _imu_layout(frame: str) -> FixedCdr:
    # orientation, its covariance, angular velocity, its covariance, linear acceleration
    # and its covariance
    return FixedCdr([("time",), ("string", frame), ("f64", 4 + 9 + 3 + 9 + 3 + 9)])


def imu_cdr(
    t: float, frame: str, gz: float, ax: float, ay: float, gyro_var: float, accel_var: float
) -> bytes:
    """``sensor_msgs/Imu`` of a planar IMU: no orientation estimate (its covariance's first
    element -1, REP 145), the z rate, the x, y acceleration and gravity on z."""
    g, a = gyro_var, accel_var
    values = (
        (0.0, 0.0, 0.0, 1.0, -1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
        + (0.0, 0.0, gz, g, 0.0, 0.0, 0.0, g, 0.0, 0.0, 0.0, g)
        + (ax, ay, STANDARD_GRAVITY, a, 0.0, 0.0, 0.0, a, 0.0, 0.0, 0.0, a)
    )
    return _imu_layout(frame).pack(sec_nsec(t), values)


def imu_cdr_rows(
    times: np.ndarray,
    frame: str,
    gz: np.ndarray,
    accel: np.ndarray,
    gyro_var: float,
    accel_var: float,
) -> list[bytes]:
    """:func:`imu_cdr` of every sample at once: stamps (n,), z rates (n,), accelerations
    (n, 2); the same bytes. A 200 Hz IMU writes 20 a control step: each row is a copy of
    the message with its constants (:func:`_imu_row`), only the stamp and the three
    measured numbers written in."""
    row, t_off, g_off, a_off = _imu_row(frame, float(gyro_var), float(accel_var))
    n, size = len(times), len(row)
    rows = np.empty((n, size), dtype=np.uint8)
    rows[:] = row
    ns = np.rint(np.asarray(times, dtype=float) * 1e9).astype(np.int64)
    sec, nsec = np.divmod(ns, 1_000_000_000)
    rows[:, t_off : t_off + 4] = sec.astype("<i4").view(np.uint8).reshape(n, 4)
    rows[:, t_off + 4 : t_off + 8] = nsec.astype("<u4").view(np.uint8).reshape(n, 4)
    rows[:, g_off : g_off + 8] = np.ascontiguousarray(gz, dtype="<f8").view(np.uint8).reshape(n, 8)
    rates = np.ascontiguousarray(accel, dtype="<f8").view(np.uint8)
    rows[:, a_off : a_off + 16] = rates.reshape(n, 16)
    data = rows.tobytes()
    return [data[i * size : (i + 1) * size] for i in range(n)]


@cache
def _imu_row(frame: str, gyro_var: float, accel_var: float) -> tuple[np.ndarray, int, int, int]:
    """An IMU message's bytes with its constants (orientation, covariances, gravity) and
    zeros for the rest, and the offsets of its stamp, z rate and x, y acceleration."""
    row = np.frombuffer(imu_cdr(0.0, frame, 0.0, 0.0, 0.0, gyro_var, accel_var), np.uint8)
    (t_off, _), (v_off, _) = _imu_layout(frame).slots
    return row, t_off, v_off + 8 * 15, v_off + 8 * 25


@cache
def _laser_scan_header(frame: str) -> FixedCdr:
    return FixedCdr([("time",), ("string", frame)])


def laser_scan_cdr(scan: LaserScan, frame: str, scan_time: float) -> bytes:
    """CDR of :func:`laser_scan`'s message (``inf`` for no return), without building it:
    header, seven float32 (all 4-aligned after the header's string), the ranges as a
    float32 sequence, an empty intensities sequence."""
    ranges = np.ascontiguousarray(scan.ranges, dtype="<f4")
    n = len(ranges)
    head = _laser_scan_header(frame).pack(sec_nsec(scan.time))
    head += b"\0" * (-(len(head) - 4) % 4)
    fixed = struct.pack(
        "<7fI",
        scan.angle_min,
        scan.angle_min + scan.angle_increment * max(n - 1, 0),
        scan.angle_increment,
        0.0,
        scan_time,
        scan.range_min,
        scan.range_max,
        n,
    )
    return b"".join((head, fixed, ranges.tobytes(), b"\0\0\0\0"))


class PeopleMarkersCdr:
    """``/people`` (:func:`~agv_mission.bags.ros_messages.people_markers`) without message
    objects: the array of the people in the world is serialised once by rosbags with a
    marked stamp and position per marker, and each step writes its numbers where the
    marks were, all at once (a new template when someone enters). 50 markers as message
    objects cost milliseconds a step; this costs microseconds."""

    def __init__(self, frame: str = "map") -> None:
        self.frame = frame
        self._ids = np.zeros(0, dtype=np.int64)
        self._radii = np.zeros(0)
        # the arrays last passed: the same objects again are the same people (the caller's
        # arrays of who is in the world, never changed in place)
        self._ids_seen: object = None
        self._radii_seen: object = None
        self._template = np.zeros(0, dtype=np.uint8)
        self._length = 0  # of the message (the template may run on)
        self._stamps = np.zeros(0, dtype=np.int64)  # every stamp's bytes, in order
        self._positions = np.zeros(0, dtype=np.int64)  # every marker's x and y bytes
        # (first marker's start, marker size, its stamps' offsets, its x's offset)
        self._layout: tuple[int, int, tuple[int, int], int] | None = None

    def pack(self, t: float, ids: np.ndarray, xy: np.ndarray, radii: np.ndarray) -> bytes:
        """The markers at time ``t`` (``ids`` and ``radii`` passed again as the same array
        objects are taken to hold the same people: pass new arrays when someone enters)."""
        if ids is not self._ids_seen or radii is not self._radii_seen:  # else as last time
            self._ids_seen, self._radii_seen = ids, radii
            ids, radii = np.asarray(ids), np.asarray(radii, float)
            if not (np.array_equal(ids, self._ids) and np.array_equal(radii, self._radii)):
                self._compile(ids, radii)
        buf = self._template  # every stamp and position is written anew: no copy
        stamp = np.frombuffer(_STAMP.pack(*sec_nsec(t)), dtype=np.uint8)
        xy_bytes = np.ascontiguousarray(xy, dtype="<f8").view(np.uint8).reshape(-1, 16)
        if self._layout is not None:  # markers of one size: a table, a column per field
            start, size, stamps, at = self._layout
            table = buf[start : start + size * len(xy_bytes)].reshape(-1, size)
            for offset in stamps:
                table[:, offset : offset + 8] = stamp
            table[:, at : at + 16] = xy_bytes
        else:
            buf[self._stamps] = np.tile(stamp, len(self._stamps) // 8)
            buf[self._positions] = xy_bytes.ravel()
        return buf[: self._length].tobytes()

    def _compile(self, ids: np.ndarray, radii: np.ndarray) -> None:
        from agv_mission.bags import ros_messages as rm

        n = len(ids)
        marks = np.stack([1e9 + np.arange(n) + 0.5, 2e9 + np.arange(n) + 0.5], axis=1)
        msg = rm.people_markers(0.0, ids, marks, radii, self.frame)
        for i, m in enumerate(msg.markers):  # a distinct stamp per marker, to find each
            m.header.stamp.sec, m.header.stamp.nanosec = 1_000_000_000 + i, 777_000_000 + i
            m.texture.header.stamp.sec = 1_100_000_000 + i
            m.texture.header.stamp.nanosec = 777_000_000 + i
        data = rm.serialize(msg, rm.MARKER_ARRAY)
        stamps, positions = [], []
        for i in range(n):
            for sec in (1_000_000_000 + i, 1_100_000_000 + i):
                stamps.append(_find_once(data, _STAMP.pack(sec, 777_000_000 + i)))
            positions.append(_find_once(data, _XY.pack(*marks[i])))
        self._stamps = (np.array(stamps, dtype=np.int64)[:, None] + np.arange(8)).ravel()
        self._positions = (np.array(positions, dtype=np.int64)[:, None] + np.arange(16)).ravel()
        self._template = np.frombuffer(data, dtype=np.uint8).copy()
        self._length = len(data)
        self._ids, self._radii = ids.copy(), radii.copy()
        self._layout = None
        first = np.array(stamps[0::2], dtype=np.int64)
        size = np.diff(first)
        if n > 1 and (size == size[0]).all():  # the same layout every ``size`` bytes
            start, size = int(first[0]), int(size[0])
            others = [stamps[1] - start, positions[0] - start]
            if (np.array(stamps[1::2]) - first == others[0]).all() and (
                np.array(positions) - first == others[1]
            ).all():
                self._layout = (start, size, (0, others[0]), others[1])
                # the last marker has no padding after it: the table's last row needs room
                pad = start + n * size - len(self._template)
                self._template = np.concatenate([self._template, np.zeros(max(0, pad), np.uint8)])


_STAMP = struct.Struct("<iI")
_XY = struct.Struct("<2d")


def _find_once(data: bytes, mark: bytes) -> int:
    at = data.find(mark)
    if at < 0 or data.find(mark, at + 1) >= 0:
        raise AssertionError("a template mark is not unique")  # a message layout changed
    return at
