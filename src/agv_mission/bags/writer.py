"""Every run as a ROS 2 bag: a run observer that writes ``bag/`` (MCAP storage, CDR).

Written with ``rosbags`` (``rosbag2.Writer``, storage MCAP, metadata version 9) rather
than ``mcap`` + ``mcap-ros2-support``: rosbags writes the ``metadata.yaml`` that
``ros2 bag play`` needs beside the ``.mcap`` and carries the standard message
definitions in its Humble typestore, where ``mcap_ros2``'s writer wants every ``.msg``
text written out by hand and no bag directory around it. The ``mcap`` reader stays the
tests' independent check.

Frames follow REP-105: ``map -> odom`` is what the localiser believes (its estimate
composed with the inverse odometry, so RViz shows drift the way a real robot does),
``odom -> base_footprint`` the dead-reckoned pose, ``base_footprint -> base_scan`` the
lidar mount on ``/tf_static``. Everything is stamped in simulated time, which starts at
zero (play it back with ``use_sim_time``; ``/clock`` is in the bag). A fleet's robots
have these frames and their topics under their namespaces (fleet.md, Nav2's multi-robot
naming: ``agv1/odom``, ``/agv1/scan``); see :class:`BagWriter`.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from rosbags.interfaces import QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.rosbag2.metadata import Qos

from agv_mission.bags import cdr
from agv_mission.bags import ros_messages as rm
from agv_mission.geometry import Pose2D
from agv_mission.json_values import json_default
from agv_mission.maps.grid import OccupancyGrid

if TYPE_CHECKING:
    from agv_mission.missions.run.observe import RobotStart, RunStart
    from agv_mission.missions.run.samples import StepSample

BAG_DIRNAME = "bag"
MAP_FRAME, ODOM_FRAME, BASE_FRAME, SCAN_FRAME = "map", "odom", "base_footprint", "base_scan"

_ZERO = QosTime(sec=0, nsec=0)
#: Latched topics (``/tf_static``, ``/map``, ``/rooms``): a late subscriber still gets them.
LATCHED = Qos(
    QosHistory.KEEP_LAST,
    1,
    QosReliability.RELIABLE,
    QosDurability.TRANSIENT_LOCAL,
    _ZERO,
    _ZERO,
    QosLiveliness.AUTOMATIC,
    _ZERO,
    False,
)

#: topic -> (type, latched): the contract's topics (mission-format.md, "Topics of bag/").
TOPICS: dict[str, tuple[str, bool]] = {
    "/clock": (rm.CLOCK, False),
    "/tf": (rm.TF_MESSAGE, False),
    "/tf_static": (rm.TF_MESSAGE, True),
    "/odom": (rm.ODOMETRY, False),
    "/scan": (rm.LASER_SCAN, False),
    "/cmd_vel": (rm.TWIST, False),
    "/map": (rm.OCCUPANCY_GRID, True),
    "/amcl_pose": (rm.POSE_WITH_COVARIANCE_STAMPED, False),
    "/particlecloud": (rm.POSE_ARRAY, False),
    "/plan": (rm.PATH, False),
    "/ground_truth": (rm.ODOMETRY, False),
    "/rooms": (rm.MARKER_ARRAY, True),
    "/events": (rm.STRING, False),
    "/battery_state": (rm.BATTERY_STATE, False),
    "/imu": (rm.IMU, False),  # robots-and-worlds.md: a robot with an IMU only
}

#: The people of the world (people-and-zones.md), a cylinder each, every PEOPLE_PERIOD.
PEOPLE_TOPIC = ("/people", rm.MARKER_ARRAY)
#: s: the people's decision period (``world.crowd.DECISION_PERIOD``, not imported: the crowd
#: brings ORCA and scipy's graphs with it).
PEOPLE_PERIOD = 0.2

#: Nav2's filter masks (people-and-zones.md), latched, in a bag of a mission with zones.
ZONE_TOPICS: dict[str, tuple[str, bool]] = {
    "/keepout_filter_mask": (rm.OCCUPANCY_GRID, True),
    "/speed_filter_mask": (rm.OCCUPANCY_GRID, True),
}

#: A fleet's topics written once for all robots (fleet.md); every other one is per robot.
SHARED_TOPICS = frozenset({"/clock", "/tf", "/tf_static", "/map", "/rooms", "/events"})
#: A robot's growing SLAM map: ``/map`` alone, ``/NAME/map`` in a fleet (``/map`` known).
GROWING_MAP = "slam_map"


def lidar_mount(robot: Any) -> tuple[Pose2D, float]:
    """The lidar's planar pose on ``base_footprint`` and its height (upside-down mounts
    and offsets come with the robot description when it has them)."""
    lidar = robot.lidar
    mount = lidar.mount
    return Pose2D(float(mount.x), float(mount.y), float(mount.yaw)), float(lidar.height)


@dataclass
class _RobotBag:
    """One robot's part of the bag: its topic names, frames and what its streams
    remember between steps (Nav2's multi-robot naming in a fleet: ``/agv1/odom``,
    ``agv1/base_footprint``; a one-robot mission's plain names)."""

    name: str
    topics: dict[str, str]  # contract topic (``/odom``) -> this robot's (``/agv1/odom``)
    odom_frame: str
    base_frame: str
    scan_frame: str
    scan_time: float
    battery: Any  # the robot's BatterySpec, None: not modelled
    imu: Any  # the robot's ImuSpec, None: no IMU
    next_battery: float = 0.0
    charging: bool = False
    next_particles: float = 0.0
    next_map: float = 0.0
    pending_map: tuple[float, Any] | None = None
    prev: dict[str, tuple[float, Pose2D]] = field(default_factory=dict)

    @classmethod
    def of(cls, start: RobotStart, fleet: bool) -> _RobotBag:
        ns = start.name if fleet else ""
        topics = {t: robot_topic(t, ns) for t in (*TOPICS, *ZONE_TOPICS)}
        topics[GROWING_MAP] = f"/{ns}/map" if ns else "/map"
        return cls(
            name=start.name,
            topics=topics,
            odom_frame=robot_frame(ODOM_FRAME, ns),
            base_frame=robot_frame(BASE_FRAME, ns),
            scan_frame=robot_frame(SCAN_FRAME, ns),
            scan_time=1.0 / float(start.robot.lidar.rate),
            battery=start.robot.battery,
            imu=start.robot.imu,
        )


def robot_topic(topic: str, namespace: str) -> str:
    """A per-robot topic in the robot's namespace (``/agv1/scan``); shared ones as they are."""
    if not namespace or topic in SHARED_TOPICS:
        return topic
    return f"/{namespace}{topic}"


def robot_frame(frame: str, namespace: str) -> str:
    """A robot's frame with its namespace as prefix (``agv1/odom``); ``map`` is shared."""
    if not namespace or frame == MAP_FRAME:
        return frame
    return f"{namespace}/{frame}"


class BagWriter:
    """A :class:`~agv_mission.missions.run.observe.RunObserver` writing the run's ROS 2 bag.

    ``path``: the bag directory; default ``<run_dir>/bag`` (no bag for a run without a
    directory). ``/particlecloud`` is thinned to one cloud per ``particle_period``
    simulated seconds of at most ``max_particles`` poses (every k-th particle): a filter
    with thousands of particles updating at 10 Hz would otherwise be 95 % of the bag
    (30 MB per 40 s). A growing SLAM map goes to ``/map`` at most every ``map_period``
    simulated seconds (gmapping's ``map_update_interval``), its last state always.
    ``/battery_state`` goes out every ``battery_period`` simulated seconds and when
    charging starts or stops. ``/people`` goes out every ``people_period`` simulated
    seconds, the people's decision period: they walk straight in between, so its markers
    hold every corner of their walks. The bag is closed by :meth:`on_end` (or
    :meth:`close`), so it is complete even when the run ends aborted or in error.

    A fleet run (fleet.md) shares ``/clock``, ``/tf``, ``/tf_static``, ``/map``, ``/rooms``
    and ``/events`` (each event once, with its ``robot``, as ``result.json`` lists them);
    every other topic is per robot under its namespace (``/agv1/scan``), in frames
    ``agv1/odom``, ``agv1/base_footprint``, ``agv1/base_scan`` under the shared ``map``.
    Zone masks are per robot (``/agv1/speed_filter_mask``: each robot's filter server, its
    speed mask in percent of its own top speed). A robot's own growing SLAM map goes to its
    ``/agv1/map``: ``/map`` stays the known one.
    """

    def __init__(
        self,
        path: Path | None = None,
        particle_period: float = 0.5,
        max_particles: int = 1000,
        map_period: float = 2.0,
        battery_period: float = 1.0,
        people_period: float = PEOPLE_PERIOD,
    ) -> None:
        self.path = path
        self.particle_period = particle_period
        self.max_particles = max_particles
        self.map_period = map_period
        self.battery_period = battery_period
        self.people_period = people_period
        self._next_people = 0.0
        self.messages = 0
        self._writer: Writer | None = None
        self._conns: dict[str, Any] = {}
        self._robots: dict[str, _RobotBag] = {}
        self._fleet = False
        self._clock: float | None = None
        self._people = cdr.PeopleMarkersCdr(MAP_FRAME)

    def prepare(self) -> BagWriter:
        """Build the typestore and its serialisers now, not when the run starts (~0.3 s
        the first time in a process): a run should start driving as soon as it begins."""
        for msgtype, _ in TOPICS.values():
            rm.typestore().get_msgdef(msgtype)
        t = 0.0
        samples = {
            rm.OCCUPANCY_GRID: rm.occupancy_grid(
                t, OccupancyGrid(np.zeros((1, 1), np.int8), 0.05, Pose2D(0.0, 0.0, 0.0))
            ),
            rm.PATH: rm.path(t, np.zeros((2, 2))),
            rm.MARKER_ARRAY: rm.room_markers(t, {}),
            rm.STRING: rm.string(""),
            rm.TF_MESSAGE: rm.tf_message([]),
        }
        for msgtype, msg in samples.items():
            rm.serialize(msg, msgtype)
        return self

    # ------------------------------------------------------------------ observer

    def on_start(self, start: RunStart) -> None:
        path = self.path
        if path is None:
            if start.run_dir is None:
                return
            path = Path(start.run_dir) / BAG_DIRNAME
        self.path = path
        writer = Writer(path, version=9, storage_plugin=StoragePlugin.MCAP)
        writer.open()
        self._writer = writer
        self._fleet = start.fleet
        self._robots = {r.name: _RobotBag.of(r, start.fleet) for r in start.robots}
        for topic in TOPICS:
            names = (
                [topic]
                if topic in SHARED_TOPICS
                else [
                    bag.topics[topic]
                    for bag in self._robots.values()
                    if topic != "/imu" or bag.imu is not None
                ]
            )
            for name in names:
                self._connect(name, *TOPICS[topic])
        t0 = 0.0
        mounts = []
        for r in start.robots:
            bag = self._robots[r.name]
            offset, height = lidar_mount(r.robot)
            mounts.append(rm.transform(t0, bag.base_frame, bag.scan_frame, offset, z=height))
        self._write("/tf_static", t0, rm.tf_message(mounts))
        self._write("/map", t0, rm.occupancy_grid(t0, start.world_map, MAP_FRAME))
        self._write("/rooms", t0, rm.room_markers(t0, start.rooms, MAP_FRAME))
        for r in start.robots:
            bag = self._robots[r.name]
            for topic, mask in (
                ("/keepout_filter_mask", r.keepout_mask),
                ("/speed_filter_mask", r.speed_mask),
            ):
                if mask is not None:
                    msgtype, latched = ZONE_TOPICS[topic]
                    name = self._connect(bag.topics[topic], msgtype, latched)
                    grid = rm.occupancy_grid(t0, mask, MAP_FRAME)
                    self._write_raw(name, t0, rm.serialize(grid, msgtype))

    def on_step(self, sample: StepSample) -> None:
        if self._writer is None:
            return
        # a one-robot run's steps are its robot's whatever they call it
        bag = self._robots[sample.robot] if self._fleet else next(iter(self._robots.values()))
        topic = bag.topics
        t = float(sample.t)
        est, odom = sample.estimate, sample.odom
        map_to_odom = est.compose(Pose2D(0.0, 0.0, 0.0).relative_to(odom))
        raw = self._write_raw
        for scan in sample.scans:  # (a lidar faster than the loop: several, each at its time)
            raw(
                topic["/scan"],
                float(scan.time),
                cdr.laser_scan_cdr(scan, bag.scan_frame, bag.scan_time),
            )
        if bag.imu is not None:
            for batch in sample.imu:
                self._write_imu(topic["/imu"], bag, batch)
        if self._clock is None or t > self._clock:  # once per step, however many robots
            self._clock = t
            raw("/clock", t, cdr.clock_cdr(t))
        links = [
            (MAP_FRAME, bag.odom_frame, map_to_odom, 0.0),
            (bag.odom_frame, bag.base_frame, odom, 0.0),
        ]
        raw("/tf", t, cdr.tf_cdr(t, links))
        v, w = self._velocity(bag, "odom", t, odom)
        raw(
            topic["/odom"],
            t,
            cdr.odometry_cdr(t, bag.odom_frame, bag.base_frame, odom, v, w, None),
        )
        v, w = self._velocity(bag, "truth", t, sample.truth)
        raw(
            topic["/ground_truth"],
            t,
            cdr.odometry_cdr(t, MAP_FRAME, bag.base_frame, sample.truth, v, w, None),
        )
        raw(topic["/cmd_vel"], t, cdr.twist_cdr(sample.v, sample.w))
        raw(
            topic["/amcl_pose"],
            t,
            cdr.pose_with_covariance_cdr(t, MAP_FRAME, est, sample.covariance),
        )
        particles = sample.particles
        if particles is not None and len(particles) and t >= bag.next_particles - 1e-9:
            bag.next_particles = t + self.particle_period
            stride = -(-len(particles) // self.max_particles)
            raw(
                topic["/particlecloud"],
                t,
                cdr.pose_array_cdr(t, MAP_FRAME, particles[::stride]),
            )
        if sample.plan is not None and len(sample.plan):
            self._write("/plan", t, rm.path(t, sample.plan, MAP_FRAME), topic["/plan"])
        if sample.grid is not None:
            bag.pending_map = (t, sample.grid)
        if bag.pending_map is not None and t >= bag.next_map - 1e-9:
            self._flush_map(bag)
        for event in sample.events:
            if self._fleet:
                event = {**event, "robot": bag.name}
            self._write("/events", t, rm.string(json.dumps(event, default=_jsonable)))
        if sample.people is not None and t >= self._next_people - 1e-9:  # the world's people
            self._write_people(t, sample.people)
        self._write_battery(bag, sample, t)

    def _write_people(self, t: float, people: Any) -> None:
        """The world's people at ``t`` (every ``people_period``)."""
        assert self._writer is not None
        self._next_people = t + self.people_period
        name, msgtype = PEOPLE_TOPIC
        if name not in self._conns:
            self._conns[name] = self._writer.add_connection(name, msgtype, typestore=rm.typestore())
        self._write_raw(name, t, self._people.pack(t, *people))

    def _write_battery(self, bag: _RobotBag, sample: StepSample, t: float) -> None:
        """The robot's battery state, every ``battery_period`` and when charging starts or
        stops."""
        spec = bag.battery
        due = t >= bag.next_battery - 1e-9 or sample.charging != bag.charging
        if spec is not None and sample.battery is not None and due:
            bag.next_battery = t + self.battery_period
            bag.charging = sample.charging
            state = rm.battery_state(
                t, sample.battery, sample.charging, spec.capacity, spec.voltage
            )
            self._write("/battery_state", t, state, bag.topics["/battery_state"])

    def on_end(self, record: Any) -> None:
        self.close()

    def _write_imu(self, name: str, bag: _RobotBag, batch: Any) -> None:
        """``sensor_msgs/Imu`` per sample, in the base frame: no orientation (covariance
        -1, as a raw IMU publishes), the gyro's z rate, the accelerometer's x, y and
        gravity, each with its per-sample noise variance."""
        spec = bag.imu
        rate = 1.0 / batch.period
        gyro_var = spec.gyro_noise_density**2 * rate
        accel_var = spec.accel_noise_density**2 * rate
        write = self._writer.write  # type: ignore[union-attr]
        conn = self._conns[name]
        datas = cdr.imu_cdr_rows(
            batch.times, bag.base_frame, batch.gyro, batch.accel, gyro_var, accel_var
        )
        for t, data in zip(batch.times.tolist(), datas, strict=True):
            write(conn, rm.nanoseconds(t), data)
        self.messages += len(batch.times)

    def _flush_map(self, bag: _RobotBag) -> None:
        assert bag.pending_map is not None
        t, grid = bag.pending_map
        name = bag.topics[GROWING_MAP]
        if name not in self._conns:  # a fleet robot's own SLAM map, once it has one
            self._connect(name, *TOPICS["/map"])
        self._write("/map", t, rm.occupancy_grid(t, grid, MAP_FRAME), name)
        bag.pending_map = None
        bag.next_map = t + self.map_period

    def close(self) -> None:
        if self._writer is not None:
            for bag in self._robots.values():
                if bag.pending_map is not None:
                    self._flush_map(bag)
            self._writer.close()
            self._writer = None

    # ------------------------------------------------------------------ helpers

    def _connect(self, name: str, msgtype: str, latched: bool) -> str:
        assert self._writer is not None
        self._conns[name] = self._writer.add_connection(
            name,
            msgtype,
            typestore=rm.typestore(),
            offered_qos_profiles=[LATCHED] if latched else [],
        )
        return name

    def _write(self, topic: str, t: float, msg: Any, name: str | None = None) -> None:
        """``msg`` of the contract's ``topic`` type, on ``name`` (default: ``topic``)."""
        self._write_raw(name or topic, t, rm.serialize(msg, TOPICS[topic][0]))

    def _write_raw(self, topic: str, t: float, data: bytes) -> None:
        assert self._writer is not None
        self._writer.write(self._conns[topic], rm.nanoseconds(t), data)
        self.messages += 1

    @staticmethod
    def _velocity(bag: _RobotBag, key: str, t: float, p: Pose2D) -> tuple[float, float]:
        """Body-frame (v, w) from the previous pose of the same stream."""
        prev = bag.prev.get(key)
        bag.prev[key] = (t, p)
        if prev is None or t <= prev[0]:
            return 0.0, 0.0
        dt = t - prev[0]
        d = p.relative_to(prev[1])
        return d.x / dt, d.yaw / dt


def _jsonable(value: Any) -> Any:
    """numpy as JSON; anything else an event may carry (a path) as its text."""
    try:
        return json_default(value)
    except TypeError:
        return str(value)
