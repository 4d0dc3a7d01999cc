"""Bags the way real robots record them, written by the tests (``rosbags`` writers).

A trajectory driven in the real simulation is replayed through a ray-marched lidar on
the world's map with the quirks of real recordings: ROS 1 or ROS 2 or bare MCAP,
lidars off-centre, rotated or upside down, clockwise scanners, 180-2000 beams, ``nan``
ranges, odometry at another rate or only on ``/tf``, a first scan before the first
odometry, gaps.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np
from rosbags.typesys import Stores, get_typestore

from agv_mission.geometry import Pose2D
from agv_mission.maps.grid import OCCUPIED, OccupancyGrid

REPO = Path(__file__).resolve().parents[1]


@dataclass(frozen=True)
class Drive:
    """A driven trajectory: true poses and drifting wheel odometry at 10 Hz."""

    t: np.ndarray  # (n,)
    truth: np.ndarray  # (n, 3) map frame
    odom: np.ndarray  # (n, 3) odom frame
    world: OccupancyGrid


@cache
def simulated_drive(seconds: float = 30.0) -> Drive:
    """The true trajectory of a real simulated patrol; odometry with 2 % scale error and
    0.02 rad/m of yaw drift integrated from it."""
    from agv_mission.missions.load.loader import load_mission
    from agv_mission.missions.run.runner import run_mission

    loaded = load_mission(
        REPO / "missions" / "patrol.yaml",
        [f"limits.time={seconds}", "stack.localization.type=ground_truth"],
    )
    record = run_mission(loaded)
    traj = record.trajectory
    t, truth = traj[:, 0], traj[:, 1:4]
    odom = np.zeros_like(truth)
    pose = Pose2D(0.3, -0.2, 0.4)  # the odometry frame is not the map frame
    odom[0] = pose.as_array()
    for k in range(1, len(t)):
        d = Pose2D(*truth[k]).relative_to(Pose2D(*truth[k - 1]))
        dist = math.hypot(d.x, d.y)
        pose = pose.compose(Pose2D(1.02 * d.x, 1.02 * d.y, d.yaw + 0.02 * dist))
        odom[k] = pose.as_array()
    return Drive(t=t, truth=truth, odom=odom, world=loaded.world.map)


def ray_march(
    world: OccupancyGrid, origin: Pose2D, angles: np.ndarray, range_max: float
) -> np.ndarray:
    """Ranges (float32, inf for no return) from ``origin`` along map-frame ``angles``."""
    step = world.resolution / 4.0
    t = np.arange(1, int(range_max / step) + 1) * step
    xs = origin.x + np.cos(angles)[:, None] * t[None, :]
    ys = origin.y + np.sin(angles)[:, None] * t[None, :]
    hit = world.value_at(np.stack([xs, ys], axis=-1)) == OCCUPIED
    first = np.argmax(hit, axis=1)
    return np.where(hit.any(axis=1), t[first], np.inf).astype(np.float32)


@dataclass
class Quirks:
    """How the recording differs from ours."""

    fmt: str = "ros2"  # ros1 | ros2 | mcap (a bare .mcap file)
    beams: int = 360
    range_max: float = 3.5
    range_min: float = 0.12
    scan_rate: float = 5.0
    odom_rate: float = 10.0  # resampled from the 10 Hz drive
    mount: Pose2D = Pose2D(0.0, 0.0, 0.0)
    mount_via_base_link: bool = False  # base_footprint -> base_link -> laser
    upside_down: bool = False
    clockwise: bool = False
    nan_fraction: float = 0.0
    odom_on_tf_only: bool = False
    static_on_tf: bool = False  # ROS 1 style: the mount repeated on /tf
    scans_before_odom: float = 0.0  # seconds of scans before the first odometry
    gap: tuple[float, float] | None = None  # no scans and no odometry in this window
    scan_until: float | None = None  # no scans after this time
    map_to_odom: bool = True
    #: map -> odom of a localiser that starts this far off the truth (map frame) and
    #: converges to it within ``SETTLE`` seconds (amcl's first cluster mean); None: the
    #: start's map -> odom throughout, as an odometry-only run publishes.
    localiser_start_error: Pose2D | None = None
    truth_topic: bool = True
    scan_frame: str = "laser"
    base_frame: str = "base_footprint"
    #: Every stamp floored to this many seconds, odometry one message per scan at the
    #: scan's time (a log printed with six-digit stamps); 0: exact stamps.
    coarse_stamps: float = 0.0


def write_quirk_bag(path: Path, drive: Drive, q: Quirks) -> Path:
    """Write the drive as a bag with quirks ``q``; returns what to hand ``map`` (the
    ``.bag``, the bag directory, or the ``.mcap`` inside it)."""
    ros1 = q.fmt == "ros1"
    store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    if "tf2_msgs/msg/TFMessage" not in store.types:  # not in rosbags' Noetic store
        from rosbags.typesys import get_types_from_msg

        store.register(
            get_types_from_msg(
                "geometry_msgs/TransformStamped[] transforms", "tf2_msgs/msg/TFMessage"
            )
        )
    types = store.types
    rng = np.random.default_rng(3)

    def coarse(t: float) -> float:
        return math.floor(t / q.coarse_stamps) * q.coarse_stamps if q.coarse_stamps else t

    def header(t: float, frame: str):
        t = coarse(t)
        sec, nsec = divmod(int(round(t * 1e9)), 1_000_000_000)
        stamp = types["builtin_interfaces/msg/Time"](sec=int(sec), nanosec=int(nsec))
        if ros1:
            return types["std_msgs/msg/Header"](seq=0, stamp=stamp, frame_id=frame)
        return types["std_msgs/msg/Header"](stamp=stamp, frame_id=frame)

    def vec(x, y, z=0.0):
        return types["geometry_msgs/msg/Vector3"](x=float(x), y=float(y), z=float(z))

    def quat(roll: float, yaw: float):
        cr, sr, cy, sy = (
            math.cos(roll / 2),
            math.sin(roll / 2),
            math.cos(yaw / 2),
            math.sin(yaw / 2),
        )
        return types["geometry_msgs/msg/Quaternion"](x=sr * cy, y=sr * sy, z=cr * sy, w=cr * cy)

    def tfs(t: float, parent: str, child: str, p: Pose2D, z: float = 0.0, roll: float = 0.0):
        return types["geometry_msgs/msg/TransformStamped"](
            header=header(t, parent),
            child_frame_id=child,
            transform=types["geometry_msgs/msg/Transform"](
                translation=vec(p.x, p.y, z), rotation=quat(roll, p.yaw)
            ),
        )

    def odometry(t: float, frame: str, p: Pose2D):
        cov = np.zeros(36)
        return types["nav_msgs/msg/Odometry"](
            header=header(t, frame),
            child_frame_id=q.base_frame,
            pose=types["geometry_msgs/msg/PoseWithCovariance"](
                pose=types["geometry_msgs/msg/Pose"](
                    position=types["geometry_msgs/msg/Point"](x=p.x, y=p.y, z=0.0),
                    orientation=quat(0.0, p.yaw),
                ),
                covariance=cov,
            ),
            twist=types["geometry_msgs/msg/TwistWithCovariance"](
                twist=types["geometry_msgs/msg/Twist"](linear=vec(0, 0), angular=vec(0, 0)),
                covariance=cov,
            ),
        )

    messages: list[tuple[float, str, str, object]] = []  # (t, topic, type, msg)
    t = drive.t
    t_end = float(t[-1])
    in_gap = (lambda s: q.gap[0] <= s <= q.gap[1]) if q.gap else (lambda s: False)

    # The lidar mount, as a static chain.
    roll = math.pi if q.upside_down else 0.0
    statics = []
    if q.mount_via_base_link:
        statics.append(tfs(0.0, q.base_frame, "base_link", Pose2D(0.0, 0.0, 0.0), z=0.01))
        statics.append(tfs(0.0, "base_link", q.scan_frame, q.mount, z=0.16, roll=roll))
    else:
        statics.append(tfs(0.0, q.base_frame, q.scan_frame, q.mount, z=0.17, roll=roll))
    tf_type = "tf2_msgs/msg/TFMessage"
    if not q.static_on_tf:
        messages.append((0.0, "/tf_static", tf_type, types[tf_type](transforms=statics)))

    # Odometry (and the dynamic /tf) at the odometry rate, starting late if asked.
    odom_start = float(t[0]) + q.scans_before_odom
    odom_times = np.arange(odom_start, t_end + 1e-9, 1.0 / q.odom_rate)
    if q.coarse_stamps:
        odom_times = np.arange(float(t[0]) + 0.05, t_end + 1e-9, 1.0 / q.scan_rate)
    for s in odom_times:
        if in_gap(s):
            continue
        p = _interp(t, drive.odom, s)
        links = [tfs(s, "odom", q.base_frame, p)]
        if q.map_to_odom:
            links.append(tfs(s, "map", "odom", _map_to_odom(drive, q, s)))
        if q.static_on_tf:
            links += [_restamp(x, header(s, x.header.frame_id)) for x in statics]
        messages.append((s, "/tf", tf_type, types[tf_type](transforms=links)))
        if not q.odom_on_tf_only:
            messages.append((s, "/odom", "nav_msgs/msg/Odometry", odometry(s, "odom", p)))
        if q.truth_topic:
            messages.append(
                (
                    s,
                    "/ground_truth",
                    "nav_msgs/msg/Odometry",
                    odometry(s, "map", _interp(t, drive.truth, s)),
                )
            )

    # Scans through the ray-marched lidar.
    n = q.beams
    inc = 2.0 * math.pi / n
    amin = -math.pi
    if q.clockwise:
        amin, inc = math.pi - inc, -inc
    beam = amin + inc * np.arange(n)
    scan_end = t_end if q.scan_until is None else q.scan_until
    for s in np.arange(float(t[0]) + 0.05, scan_end + 1e-9, 1.0 / q.scan_rate):
        if in_gap(s):
            continue
        sensor = _interp(t, drive.truth, s).compose(q.mount)
        world_angles = sensor.yaw + (-beam if q.upside_down else beam)
        r = ray_march(drive.world, sensor, world_angles, q.range_max)
        r[r < q.range_min] = np.inf
        if q.nan_fraction:
            r[rng.random(n) < q.nan_fraction] = np.nan
        scan = types["sensor_msgs/msg/LaserScan"](
            header=header(s, q.scan_frame),
            angle_min=float(amin),
            angle_max=float(amin + inc * (n - 1)),
            angle_increment=float(inc),
            time_increment=0.0,
            scan_time=1.0 / q.scan_rate,
            range_min=q.range_min,
            range_max=q.range_max,
            ranges=r,
            intensities=np.zeros(0, np.float32),
        )
        messages.append((s, "/scan", "sensor_msgs/msg/LaserScan", scan))

    messages = [(coarse(m[0]), *m[1:]) for m in messages]
    messages.sort(key=lambda m: m[0])
    written = _write_messages(path, messages, store, ros1)
    if q.fmt == "mcap":
        return next(path.glob("*.mcap"))
    return written


#: Seconds a localiser's start error takes to vanish (``Quirks.localiser_start_error``).
SETTLE = 3.0


def _map_to_odom(drive: Drive, q: Quirks, s: float) -> Pose2D:
    """The bag's map -> odom at ``s``: fixed at the start's, or a localiser's estimate
    (truth, off by the start error fading out) composed with the odometry's inverse."""
    origin = Pose2D(0.0, 0.0, 0.0)
    e = q.localiser_start_error
    if e is None:
        truth0, odom0 = Pose2D(*drive.truth[0]), Pose2D(*drive.odom[0])
        return truth0.compose(origin.relative_to(odom0))
    k = max(0.0, 1.0 - (s - float(drive.t[0])) / SETTLE)
    estimate = Pose2D(k * e.x, k * e.y, k * e.yaw).compose(_interp(drive.t, drive.truth, s))
    return estimate.compose(origin.relative_to(_interp(drive.t, drive.odom, s)))


def _restamp(tf, header):
    return type(tf)(header=header, child_frame_id=tf.child_frame_id, transform=tf.transform)


def _interp(t: np.ndarray, poses: np.ndarray, s: float) -> Pose2D:
    yaw = np.unwrap(poses[:, 2])
    return Pose2D(
        float(np.interp(s, t, poses[:, 0])),
        float(np.interp(s, t, poses[:, 1])),
        float(np.interp(s, t, yaw)),
    )


def wall_precision(built: OccupancyGrid, world: OccupancyGrid, tolerance: float = 0.1) -> float:
    """Share of the built map's occupied cells within ``tolerance`` of a world wall: a
    mirrored, shifted or doubled wall drags it down."""
    from scipy.ndimage import distance_transform_edt

    rows, cols = np.nonzero(built.data == OCCUPIED)
    if not len(rows):
        return 0.0
    centres = built.cell_to_world(rows, cols)
    dist = distance_transform_edt(world.data != OCCUPIED) * world.resolution
    wr, wc = world.world_to_cell(centres)
    inside = world.in_bounds(wr, wc)
    d = np.full(len(rows), np.inf)
    d[inside] = dist[wr[inside], wc[inside]]
    return float(np.mean(d <= tolerance))


def write_small_bag(
    path: Path,
    fmt: str = "ros2",
    scans: int = 20,
    scan: dict | None = None,
    odom: dict | None = None,
    truth: dict | None = None,
    mount: tuple[float, ...] = (0.1, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0),
    scan_nanosec: int | None = None,
) -> Path:
    """A two-second bag of a robot creeping ahead in a round room (360 beams of 2 m):
    ``scans`` LaserScans on /scan, /odom at 20 Hz, the lidar's ``mount`` (x y z qx qy qz
    qw) on /tf_static; ``scan`` fields replace every scan's, ``odom`` / ``truth``
    (``x``, ``y``, ``q``: a quaternion tuple) replace the sixth odometry message's (and a
    /ground_truth topic is written when ``truth`` is given); ``scan_nanosec``: every
    scan's ``header.stamp.nanosec``. Returns what to hand ``map``."""
    ros1 = fmt == "ros1"
    store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    if "tf2_msgs/msg/TFMessage" not in store.types:
        from rosbags.typesys import get_types_from_msg

        store.register(
            get_types_from_msg(
                "geometry_msgs/TransformStamped[] transforms", "tf2_msgs/msg/TFMessage"
            )
        )
    types = store.types

    def header(t: float, frame: str, nanosec: int | None = None):
        nanosec = int(round(t % 1 * 1e9)) if nanosec is None else nanosec
        stamp = types["builtin_interfaces/msg/Time"](sec=int(t), nanosec=nanosec)
        if ros1:
            return types["std_msgs/msg/Header"](seq=0, stamp=stamp, frame_id=frame)
        return types["std_msgs/msg/Header"](stamp=stamp, frame_id=frame)

    def vec(x, y, z=0.0):
        return types["geometry_msgs/msg/Vector3"](x=float(x), y=float(y), z=float(z))

    def quat(x, y, z, w):
        return types["geometry_msgs/msg/Quaternion"](x=x, y=y, z=z, w=w)

    def odometry(t: float, frame: str, x: float, y: float, q: tuple):
        cov = np.zeros(36)
        return types["nav_msgs/msg/Odometry"](
            header=header(t, frame),
            child_frame_id="base_footprint",
            pose=types["geometry_msgs/msg/PoseWithCovariance"](
                pose=types["geometry_msgs/msg/Pose"](
                    position=types["geometry_msgs/msg/Point"](x=float(x), y=float(y), z=0.0),
                    orientation=quat(*(float(v) for v in q)),
                ),
                covariance=cov,
            ),
            twist=types["geometry_msgs/msg/TwistWithCovariance"](
                twist=types["geometry_msgs/msg/Twist"](linear=vec(0, 0), angular=vec(0, 0)),
                covariance=cov,
            ),
        )

    tx, ty, tz, *q = (float(v) for v in mount)
    static = types["geometry_msgs/msg/TransformStamped"](
        header=header(0.0, "base_footprint"),
        child_frame_id="laser",
        transform=types["geometry_msgs/msg/Transform"](
            translation=vec(tx, ty, tz), rotation=quat(*q)
        ),
    )
    tf_type = "tf2_msgs/msg/TFMessage"
    messages = [(0.0, "/tf_static", tf_type, types[tf_type](transforms=[static]))]
    for k in range(2 * scans + 2):
        t, pose = 0.05 * k, {"x": 0.02 * k, "y": 0.0, "q": (0.0, 0.0, 0.0, 1.0)}
        here = {**pose, **(odom or {})} if k == 5 else pose
        messages.append((t, "/odom", "nav_msgs/msg/Odometry", odometry(t, "odom", **here)))
        if truth is not None:
            here = {**pose, **truth} if k == 5 else pose
            messages.append(
                (t, "/ground_truth", "nav_msgs/msg/Odometry", odometry(t, "map", **here))
            )
    n = 360
    for k in range(scans):
        t = 0.1 * k + 0.05
        fields = {
            "angle_min": -math.pi,
            "angle_max": math.pi - 2 * math.pi / n,
            "angle_increment": 2 * math.pi / n,
            "time_increment": 0.0,
            "scan_time": 0.1,
            "range_min": 0.1,
            "range_max": 5.0,
            "ranges": np.full(n, 2.0, np.float32),
            "intensities": np.zeros(0, np.float32),
            **(scan or {}),
        }
        msg = types["sensor_msgs/msg/LaserScan"](header=header(t, "laser", scan_nanosec), **fields)
        messages.append((t, "/scan", "sensor_msgs/msg/LaserScan", msg))
    messages.sort(key=lambda m: m[0])
    written = _write_messages(path, messages, store, ros1)
    return next(path.glob("*.mcap")) if fmt == "mcap" else written


def _write_messages(path: Path, messages: list, store: Any, ros1: bool) -> Path:
    """``messages`` (seconds, topic, type, message; in order) as a ROS 1 bag beside
    ``path`` or a ROS 2 MCAP bag at ``path``: the bag written."""
    if ros1:
        from rosbags.rosbag1 import Writer as Writer1

        target = path.with_suffix(".bag")
        with Writer1(target) as writer:
            conns = {}
            for s, topic, msgtype, msg in messages:
                if topic not in conns:
                    conns[topic] = writer.add_connection(topic, msgtype, typestore=store)
                writer.write(conns[topic], int(s * 1e9) + 1, store.serialize_ros1(msg, msgtype))
        return target
    from rosbags.rosbag2 import StoragePlugin, Writer

    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        conns = {}
        for s, topic, msgtype, msg in messages:
            if topic not in conns:
                conns[topic] = writer.add_connection(topic, msgtype, typestore=store)
            writer.write(conns[topic], int(s * 1e9) + 1, store.serialize_cdr(msg, msgtype))
    return path
