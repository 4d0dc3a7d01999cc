"""Reading a robot's recording: scans, odometry, the lidar mount and ground truth.

Any bag ``rosbags``' ``AnyReader`` opens: ROS 1 ``.bag``, ROS 2 bag directories (SQLite
or MCAP) and bare ``.mcap`` files; CARMEN logs (``.log``, ``.log.gz``) through
:mod:`agv_mission.bags.carmen`. Real recordings differ from ours, and each difference
is handled here, once:

* topics are found by type (``sensor_msgs/LaserScan``; ``nav_msgs/Odometry`` or, without
  one, the ``odom -> base`` transform of ``/tf``) unless named; in a bag of several robots
  (a fleet's, Nav2's multi-robot namespaces ``/agv1/scan``, ``/agv1/odom``) only the
  chosen robot's, and a lone namespaced robot is chosen by itself;
* the scan's frame is placed on the robot through ``/tf_static`` (or constant ``/tf``
  links, as ROS 1's ``static_transform_publisher`` sends them): off-centre and rotated
  mounts, and upside-down ones (the scan is mirrored so that it reads counter-clockwise
  seen from above);
* ``nan`` / ``-inf`` ranges and returns closer than ``range_min`` are invalid (they clear
  nothing), ``+inf`` is "no return" (clears up to the range limit), as REP-117 says;
* odometry at any rate is interpolated at each scan's stamp; scans before the first or
  after the last odometry, or inside a gap of odometry longer than ``max_odom_gap``, are
  counted and skipped.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from agv_mission.bags.carmen import is_carmen_log, read_carmen
from agv_mission.bags.message_checks import (
    Where,
    check_pose,
    check_scan,
    check_stamp,
    check_transform,
)
from agv_mission.bags.recording import BagData, BagError
from agv_mission.bags.tf_frames import Transform, scan_mount, static_chain, tf_links
from agv_mission.sensor_msgs import LaserScan

SCAN_TYPE = "sensor_msgs/msg/LaserScan"
ODOM_TYPE = "nav_msgs/msg/Odometry"
TF_TYPE = "tf2_msgs/msg/TFMessage"
POSE_TYPES = (
    "geometry_msgs/msg/PoseStamped",
    "geometry_msgs/msg/PoseWithCovarianceStamped",
)


def _yaw(q: Any) -> float:
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))


def _time(stamp: Any) -> float:
    sec = getattr(stamp, "sec", None)
    if sec is None:  # ROS 1 genpy-style names
        sec = stamp.secs
        return float(sec) + float(stamp.nsecs) * 1e-9
    return float(sec) + float(stamp.nanosec) * 1e-9


def _strip(frame: str) -> str:
    return frame.lstrip("/")


def open_reader(path: Path) -> Any:
    """An opened ``AnyReader``, or :class:`BagError` naming the problem."""
    from rosbags.highlevel import AnyReader

    if not path.exists():
        raise BagError(f"{path}: no such file or directory")
    try:
        reader = AnyReader([path])
        reader.open()
    except Exception as exc:  # rosbags raises several reader errors
        raise BagError(f"{path}: not a readable ROS 1 / ROS 2 bag ({exc})") from None
    return reader


def _pick(candidates: list[str], preferred: tuple[str, ...], counts: dict[str, int]) -> str:
    for name in preferred:
        if name in candidates:
            return name
    return max(candidates, key=lambda t: counts.get(t, 0))


def namespace(topic: str) -> str:
    """The first namespace of a topic (``/agv1/scan`` -> ``agv1``; ``/scan`` -> ``""``)."""
    parts = topic.strip("/").split("/")
    return parts[0] if len(parts) > 1 else ""


def robot_namespaces(topics: dict[str, str]) -> list[str]:
    """Namespaces that hold a robot: a LaserScan and odometry (``nav_msgs/Odometry``
    not named like ground truth) under ``/NAME/``, as a fleet's bag and Nav2's
    multi-robot launch name them; a lone ``/front/scan`` is a sensor's namespace."""
    scans = {namespace(t) for t, ty in topics.items() if ty == SCAN_TYPE}
    odoms = {
        namespace(t) for t, ty in topics.items() if ty == ODOM_TYPE and not _looks_like_truth(t)
    }
    return sorted((scans & odoms) - {""})


def _under(ns: str | None, topics: list[str]) -> list[str]:
    return topics if ns is None else [t for t in topics if namespace(t) == ns]


def read_bag(
    path: Path,
    scan_topic: str | None = None,
    odom_topic: str | None = None,
    truth_topic: str | None = None,
    robot: str | None = None,
) -> BagData:
    """Scans, odometry, mount and ground truth of the bag (or CARMEN log) at ``path``;
    ``robot``: whose, in a bag of several robots (their namespace)."""
    if is_carmen_log(path):
        if robot is not None:
            raise BagError(f"{path}: a CARMEN log holds one robot, no namespace {robot!r}")
        return read_carmen(path, scan_topic, odom_topic, truth_topic)
    reader = open_reader(path)
    try:
        return _read(reader, path, scan_topic, odom_topic, truth_topic, robot)
    finally:
        reader.close()


def _pick_robot(
    path: Path, topics: dict[str, str], scan_topic: str | None, robot: str | None
) -> str | None:
    """The namespace whose topics are read: the one named; else the scan topic's when it
    is a robot's; else the only robot's when no topic outside a namespace is a scan.
    Several robots and nothing named is invalid input naming them."""
    robots = robot_namespaces(topics)
    if robot is not None:
        if robot not in robots:
            found = ", ".join(robots) if robots else "none: no namespaced scan and odometry"
            raise BagError(f"{path}: no robot {robot!r} (robots: {found})")
        if scan_topic is not None and namespace(scan_topic) != robot:
            raise BagError(f"{path}: --scan-topic {scan_topic} is not robot {robot!r}'s")
        return robot
    if scan_topic is not None:
        ns = namespace(scan_topic)
        return ns if ns in robots else None
    if any(ty == SCAN_TYPE and not namespace(t) for t, ty in topics.items()):
        return None
    if len(robots) > 1:
        raise BagError(
            f"{path}: the bag holds several robots ({', '.join(robots)}): "
            "pick one with --robot NAME"
        )
    return robots[0] if robots else None


def _read(
    reader: Any,
    path: Path,
    scan_topic: str | None,
    odom_topic: str | None,
    truth_topic: str | None,
    robot: str | None = None,
) -> BagData:
    topics: dict[str, str] = {}
    counts: dict[str, int] = {}
    for conn in reader.connections:
        topics[conn.topic] = conn.msgtype
        counts[conn.topic] = counts.get(conn.topic, 0) + conn.msgcount

    robot, scan_topic, odom_topic, truth_topic = _choose_topics(
        path, topics, counts, scan_topic, odom_topic, truth_topic, robot
    )
    got = _collect(reader, path, scan_topic, odom_topic, truth_topic)
    scans, scan_frame, odom_child = got.scans, got.scan_frame, got.odom_child
    odom_rows, truth_rows, static = got.odom_rows, got.truth_rows, got.static
    if not scans:
        raise BagError(f"{path}: {scan_topic} holds no messages")

    links, moving = tf_links(got.dynamic, static)

    # The base frame: the odometry's child, or the first moving frame above the scan frame.
    chain = static_chain(scan_frame, static)
    odom_source = odom_topic or ""
    notes: dict[str, Any] = {}
    if odom_rows:
        base_frame = odom_child or chain[-1][0]
        # Sorted by stamp only: messages of one stamp keep the order they were written in.
        odom_rows.sort(key=lambda r: r[0])
        truth_rows.sort(key=lambda r: r[0])
        spread = _spread_shared_stamps(scans, odom_rows, truth_rows)
        if spread:
            notes["stamps_spread"] = spread
        odom = np.array(odom_rows)
    else:
        moving_children = {c: (p, c) for (p, c) in moving if p != "map"}
        base_frame = next((f for f, _ in chain if f in moving_children), "")
        if not base_frame:
            raise BagError(
                f"{path}: no odometry: no nav_msgs/Odometry topic and no /tf transform "
                f"moving a frame above the scan frame {scan_frame!r}"
            )
        link = moving_children[base_frame]
        odom = moving[link]
        odom_source = f"/tf {link[0]}->{link[1]}"
    mount_pose, flipped, found = scan_mount(chain, base_frame, scan_frame)

    odom_parent = next((p for (p, c) in moving if c == base_frame), "odom")
    map_to_odom = links.get(("map", odom_parent))
    truth = np.array(sorted(truth_rows, key=lambda r: r[0])) if truth_rows else None
    times = [s.time for s in scans]
    return BagData(
        scans=scans,
        scan_topic=scan_topic,
        scan_frame=scan_frame,
        odom=odom,
        odom_source=odom_source,
        base_frame=base_frame,
        mount=mount_pose,
        flipped=flipped,
        mount_found=found,
        map_to_odom=map_to_odom,
        truth=truth,
        truth_topic=truth_topic if truth is not None else None,
        topics=topics,
        robot=robot,
        duration=float(max(times) - min(times)) if times else 0.0,
        notes=notes,
    )


def _choose_topics(
    path: Path,
    topics: dict[str, str],
    counts: dict[str, int],
    scan_topic: str | None,
    odom_topic: str | None,
    truth_topic: str | None,
    robot: str | None,
) -> tuple[str | None, str, str | None, str | None]:
    """The robot (a namespace), and its scan, odometry and ground-truth topics: the ones
    asked for, checked, else the likeliest of the bag's."""
    robot = _pick_robot(path, topics, scan_topic, robot)
    prefix = f"/{robot}" if robot else ""
    scans_found = _under(robot, [t for t, ty in topics.items() if ty == SCAN_TYPE])
    if scan_topic is not None:
        if scan_topic not in topics:
            raise BagError(f"{path}: no topic {scan_topic} (topics: {', '.join(sorted(topics))})")
        if topics[scan_topic] != SCAN_TYPE:
            raise BagError(f"{path}: {scan_topic} is a {topics[scan_topic]}, not a LaserScan")
    elif not scans_found:
        raise BagError(
            f"{path}: no sensor_msgs/LaserScan topic (topics: {', '.join(sorted(topics))})"
        )
    else:
        scan_topic = _pick(scans_found, (f"{prefix}/scan", "scan", f"{prefix}/base_scan"), counts)

    odoms = _under(robot, [t for t, ty in topics.items() if ty == ODOM_TYPE])
    poses = odoms + _under(robot, [t for t, ty in topics.items() if ty in POSE_TYPES])
    truths = [t for t in poses if _looks_like_truth(t)]
    if truth_topic is not None and topics.get(truth_topic) not in (ODOM_TYPE, *POSE_TYPES):
        raise BagError(f"{path}: no odometry or pose topic {truth_topic} for ground truth")
    if truth_topic is None and truths:
        truth_topic = truths[0]
    if odom_topic is not None:
        if odom_topic not in topics:
            raise BagError(f"{path}: no topic {odom_topic} (topics: {', '.join(sorted(topics))})")
        if topics[odom_topic] not in (ODOM_TYPE, TF_TYPE):
            raise BagError(
                f"{path}: {odom_topic} is a {topics[odom_topic]}, not nav_msgs/Odometry or /tf"
            )
    else:
        plain = [t for t in odoms if t != truth_topic]
        if plain:
            odom_topic = _pick(
                plain, (f"{prefix}/odom", "odom", f"{prefix}/odometry/filtered"), counts
            )
    return robot, scan_topic, odom_topic, truth_topic


@dataclass
class _Messages:
    """What a bag's chosen topics hold: scans, odometry and truth rows (t, x, y, yaw), the
    frames they name, and /tf's static and moving links."""

    scans: list[LaserScan]
    scan_frame: str
    odom_rows: list[tuple[float, float, float, float]]
    odom_child: str
    truth_rows: list[tuple[float, float, float, float]]
    static: dict[str, tuple[str, Transform]]
    dynamic: dict[tuple[str, str], list[tuple[float, np.ndarray]]]


def _collect(
    reader: Any, path: Path, scan_topic: str, odom_topic: str | None, truth_topic: str | None
) -> _Messages:
    """Read the chosen topics' messages (and /tf's) in one pass, each checked
    (:mod:`~agv_mission.bags.message_checks`): bad values are a BagError naming it."""
    wanted = {scan_topic, "/tf", "/tf_static", "tf", "tf_static"}
    if odom_topic:
        wanted.add(odom_topic)
    if truth_topic:
        wanted.add(truth_topic)
    conns = [c for c in reader.connections if c.topic in wanted]

    scans: list[LaserScan] = []
    scan_frame = ""
    odom_rows: list[tuple[float, float, float, float]] = []
    odom_child = ""
    truth_rows: list[tuple[float, float, float, float]] = []
    static: dict[str, tuple[str, Transform]] = {}  # child -> (parent, transform)
    dynamic: dict[tuple[str, str], list[tuple[float, np.ndarray]]] = {}
    seen: dict[str, int] = {}
    for conn, msg in _messages(reader, path, conns, seen):
        topic = conn.topic
        where = Where(path, topic, seen[topic])
        if hasattr(msg, "header"):
            check_stamp(where, "header.stamp", msg.header.stamp)
        if topic == scan_topic:
            check_scan(where, msg)
            scan_frame = scan_frame or _strip(msg.header.frame_id)
            scans.append(_scan(msg))
        elif topic == odom_topic and conn.msgtype == ODOM_TYPE:
            odom_child = odom_child or _strip(msg.child_frame_id)
            p = msg.pose.pose
            check_pose(where, "pose.pose", p)
            odom_rows.append(
                (_time(msg.header.stamp), p.position.x, p.position.y, _yaw(p.orientation))
            )
        elif topic == truth_topic:
            nested = hasattr(msg.pose, "pose")
            p = msg.pose.pose if nested else msg.pose
            check_pose(where, "pose.pose" if nested else "pose", p)
            truth_rows.append(
                (_time(msg.header.stamp), p.position.x, p.position.y, _yaw(p.orientation))
            )
        elif conn.msgtype == TF_TYPE:
            is_static = topic.strip("/") == "tf_static"
            for k, tr in enumerate(msg.transforms):
                check_stamp(where, f"transforms[{k}].header.stamp", tr.header.stamp)
                check_transform(where, f"transforms[{k}].transform", tr.transform)
                parent, child = _strip(tr.header.frame_id), _strip(tr.child_frame_id)
                if is_static:
                    static[child] = (parent, Transform.from_msg(tr.transform))
                else:
                    t, q = tr.transform.translation, tr.transform.rotation
                    dynamic.setdefault((parent, child), []).append(
                        (_time(tr.header.stamp), np.array([t.x, t.y, t.z, q.x, q.y, q.z, q.w]))
                    )
    return _Messages(scans, scan_frame, odom_rows, odom_child, truth_rows, static, dynamic)


def _messages(reader: Any, path: Path, conns: list[Any], seen: dict[str, int]) -> Any:
    """The messages of ``conns``, deserialised, counting each topic's in ``seen``
    (1-based); a message or chunk that does not decode is a BagError naming it."""
    it = reader.messages(connections=conns)
    while True:
        try:
            conn, _log_time, raw = next(it)
        except StopIteration:
            return
        except Exception as exc:  # rosbags raises several reader errors
            raise BagError(f"{path}: cannot read the bag's messages ({exc})") from None
        seen[conn.topic] = seen.get(conn.topic, 0) + 1
        try:
            msg = reader.deserialize(raw, conn.msgtype)
        except Exception as exc:  # a truncated or garbled message: any decoder error
            raise BagError(
                f"{path}: {conn.topic} message {seen[conn.topic]}: "
                f"not a {conn.msgtype} ({type(exc).__name__}: {exc})"
            ) from None
        yield conn, msg


def _spread_shared_stamps(
    scans: list[LaserScan],
    odom: list[tuple[float, float, float, float]],
    truth: list[tuple[float, float, float, float]],
) -> int:
    """Scans stamped in coarse steps, each with an odometry message of its very stamp (a
    CARMEN log converted with its six-digit stamps: CSAIL's 365 scans share one), carry
    their pairing in their order, not their time: stamps that do not increase are spread
    1 ms apart (as :mod:`~agv_mission.bags.carmen` does), in the scans, the odometry and a
    ground truth stamped alike, so that each scan meets its own odometry. How many moved;
    0 (nothing changed) unless scans and odometry share every stamp."""
    times = [s.time for s in scans]
    if len(odom) != len(times) or all(b > a for a, b in zip(times, times[1:], strict=False)):
        return 0
    if any(abs(o[0] - t) > 1e-9 for o, t in zip(odom, times, strict=True)):
        return 0
    new = list(times)
    moved = 0
    for k in range(1, len(new)):
        if new[k] <= new[k - 1]:
            new[k] = new[k - 1] + 1e-3
            moved += 1
    for k, t in enumerate(new):
        scans[k] = replace(scans[k], time=t)
        odom[k] = (t, *odom[k][1:])
    if len(truth) == len(times) and all(
        abs(g[0] - t) <= 1e-9 for g, t in zip(truth, times, strict=True)
    ):
        for k, t in enumerate(new):
            truth[k] = (t, *truth[k][1:])
    return moved


def _looks_like_truth(topic: str) -> bool:
    """``/ground_truth``, ``/base_pose_ground_truth``, ``/gt/odom``, ``/mocap/pose``, ..."""
    words = set(re.split(r"[^a-z0-9]+", topic.lower()))
    return bool(words & {"truth", "groundtruth", "gt", "mocap", "vicon"})


def _scan(msg: Any) -> LaserScan:
    """A LaserScan with ROS's invalid readings as ``nan`` (no clearing) and ``+inf`` kept."""
    r = np.asarray(msg.ranges, dtype=np.float32).copy()
    with np.errstate(invalid="ignore"):
        r[np.isneginf(r) | (r < msg.range_min)] = np.nan
    return LaserScan(
        ranges=r,
        angle_min=float(msg.angle_min),
        angle_increment=float(msg.angle_increment),
        range_min=float(msg.range_min),
        range_max=float(msg.range_max),
        time=_time(msg.header.stamp),
    )


def upright(scan: LaserScan, flipped: bool) -> LaserScan:
    """The scan as a counter-clockwise scanner with positive increments would see it."""
    ranges, amin, inc = scan.ranges, scan.angle_min, scan.angle_increment
    if inc < 0:  # clockwise scanner: reverse the beams
        amin = amin + inc * (len(ranges) - 1)
        ranges, inc = ranges[::-1], -inc
    if flipped:  # upside down: beam angle a reads -a from above
        amax = amin + inc * (len(ranges) - 1)
        ranges, amin = ranges[::-1], -amax
    return LaserScan(
        ranges=np.ascontiguousarray(ranges),
        angle_min=float(amin),
        angle_increment=float(inc),
        range_min=scan.range_min,
        range_max=scan.range_max,
        time=scan.time,
    )


def interpolate_poses(
    rows: np.ndarray, times: np.ndarray, max_gap: float
) -> tuple[np.ndarray, np.ndarray]:
    """Poses (n, 3) of ``rows`` (m, 4: t, x, y, yaw) at ``times``, and which are valid:
    inside the recorded span and not inside a gap longer than ``max_gap``."""
    t = rows[:, 0]
    yaw = np.unwrap(rows[:, 3])
    out = np.stack(
        [
            np.interp(times, t, rows[:, 1]),
            np.interp(times, t, rows[:, 2]),
            np.interp(times, t, yaw),
        ],
        axis=1,
    )
    eps = 1e-6
    inside = (times >= t[0] - eps) & (times <= t[-1] + eps)
    hi = (
        np.clip(np.searchsorted(t, times), 1, len(t) - 1)
        if len(t) > 1
        else np.zeros(len(times), int)
    )
    gap = (t[hi] - t[hi - 1]) if len(t) > 1 else np.zeros(len(times))
    exact = np.isclose(times, t[np.clip(np.searchsorted(t, times), 0, len(t) - 1)], atol=eps)
    ok = inside & ((gap <= max_gap) | exact)
    return out, ok
