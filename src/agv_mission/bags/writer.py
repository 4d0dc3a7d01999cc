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
zero (play it back with ``use_sim_time``; ``/clock`` is in the bag).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from rosbags.interfaces import QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.rosbag2.metadata import Qos

from agv_mission.bags import cdr
from agv_mission.bags import ros_messages as rm
from agv_mission.geometry import Pose2D
from agv_mission.maps.grid import OccupancyGrid
from agv_mission.messages import json_default

if TYPE_CHECKING:
    from agv_mission.missions.observe import RunStart, StepSample

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
}

#: The people of the world (people-and-zones.md), a cylinder each, every control step.
PEOPLE_TOPIC = ("/people", rm.MARKER_ARRAY)

#: Nav2's filter masks (people-and-zones.md), latched, in a bag of a mission with zones.
ZONE_TOPICS: dict[str, tuple[str, bool]] = {
    "/keepout_filter_mask": (rm.OCCUPANCY_GRID, True),
    "/speed_filter_mask": (rm.OCCUPANCY_GRID, True),
}


def lidar_mount(robot: Any) -> tuple[Pose2D, float]:
    """The lidar's planar pose on ``base_footprint`` and its height (upside-down mounts
    and offsets come with the robot description when it has them)."""
    lidar = robot.lidar
    offset = Pose2D(
        float(getattr(lidar, "x", 0.0)),
        float(getattr(lidar, "y", 0.0)),
        float(getattr(lidar, "yaw", 0.0)),
    )
    return offset, float(lidar.height)


class BagWriter:
    """A :class:`~agv_mission.missions.observe.RunObserver` writing the run's ROS 2 bag.

    ``path``: the bag directory; default ``<run_dir>/bag`` (no bag for a run without a
    directory). ``/particlecloud`` is thinned to one cloud per ``particle_period``
    simulated seconds of at most ``max_particles`` poses (every k-th particle): a filter
    with thousands of particles updating at 10 Hz would otherwise be 95 % of the bag
    (30 MB per 40 s). A growing SLAM map goes to ``/map`` at most every ``map_period``
    simulated seconds (gmapping's ``map_update_interval``), its last state always.
    ``/battery_state`` goes out every ``battery_period`` simulated seconds and when
    charging starts or stops. The bag is closed by :meth:`on_end` (or :meth:`close`), so it is complete
    even when the run ends aborted or in error.
    """

    def __init__(
        self,
        path: Path | None = None,
        particle_period: float = 0.5,
        max_particles: int = 1000,
        map_period: float = 2.0,
        battery_period: float = 1.0,
    ) -> None:
        self.path = path
        self.particle_period = particle_period
        self.max_particles = max_particles
        self.map_period = map_period
        self.battery_period = battery_period
        self._battery: Any = None  # the robot's BatterySpec
        self._next_battery = 0.0
        self._charging = False
        self._next_particles = 0.0
        self._next_map = 0.0
        self._pending_map: tuple[float, Any] | None = None
        self.messages = 0
        self._writer: Writer | None = None
        self._conns: dict[str, Any] = {}
        self._prev: dict[str, tuple[float, Pose2D]] = {}
        self._scan_time = 0.0
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
        store = rm.typestore()
        for topic, (msgtype, latched) in TOPICS.items():
            self._conns[topic] = writer.add_connection(
                topic,
                msgtype,
                typestore=store,
                offered_qos_profiles=[LATCHED] if latched else [],
            )
        robot = start.robot
        self._battery = robot.battery
        self._scan_time = 1.0 / float(robot.lidar.rate)
        offset, height = lidar_mount(robot)
        t0 = 0.0
        self._write(
            "/tf_static",
            t0,
            rm.tf_message([rm.transform(t0, BASE_FRAME, SCAN_FRAME, offset, z=height)]),
        )
        self._write("/map", t0, rm.occupancy_grid(t0, start.world_map, MAP_FRAME))
        self._write("/rooms", t0, rm.room_markers(t0, start.rooms, MAP_FRAME))
        masks = {"/keepout_filter_mask": start.keepout_mask, "/speed_filter_mask": start.speed_mask}
        for topic, mask in masks.items():
            if mask is not None:
                msgtype, _ = ZONE_TOPICS[topic]
                self._conns[topic] = writer.add_connection(
                    topic, msgtype, typestore=store, offered_qos_profiles=[LATCHED]
                )
                grid = rm.occupancy_grid(t0, mask, MAP_FRAME)
                self._write_raw(topic, t0, rm.serialize(grid, msgtype))

    def on_step(self, sample: StepSample) -> None:
        if self._writer is None:
            return
        t = float(sample.t)
        est, odom = sample.estimate, sample.odom
        map_to_odom = est.compose(Pose2D(0.0, 0.0, 0.0).relative_to(odom))
        raw = self._write_raw
        for scan in sample.scans:  # (a lidar faster than the loop: several, each at its time)
            raw("/scan", float(scan.time), cdr.laser_scan_cdr(scan, SCAN_FRAME, self._scan_time))
        raw("/clock", t, cdr.clock_cdr(t))
        raw(
            "/tf",
            t,
            cdr.tf_cdr(
                t, [(MAP_FRAME, ODOM_FRAME, map_to_odom, 0.0), (ODOM_FRAME, BASE_FRAME, odom, 0.0)]
            ),
        )
        v, w = self._velocity("odom", t, odom)
        raw("/odom", t, cdr.odometry_cdr(t, ODOM_FRAME, BASE_FRAME, odom, v, w, None))
        v, w = self._velocity("truth", t, sample.truth)
        raw(
            "/ground_truth", t, cdr.odometry_cdr(t, MAP_FRAME, BASE_FRAME, sample.truth, v, w, None)
        )
        raw("/cmd_vel", t, cdr.twist_cdr(sample.v, sample.w))
        raw("/amcl_pose", t, cdr.pose_with_covariance_cdr(t, MAP_FRAME, est, sample.covariance))
        particles = sample.particles
        if particles is not None and len(particles) and t >= self._next_particles - 1e-9:
            self._next_particles = t + self.particle_period
            stride = -(-len(particles) // self.max_particles)
            self._write_raw(
                "/particlecloud", t, cdr.pose_array_cdr(t, MAP_FRAME, particles[::stride])
            )
        if sample.plan is not None and len(sample.plan):
            self._write("/plan", t, rm.path(t, sample.plan, MAP_FRAME))
        if sample.grid is not None:
            self._pending_map = (t, sample.grid)
        if self._pending_map is not None and t >= self._next_map - 1e-9:
            self._flush_map()
        for event in sample.events:
            self._write("/events", t, rm.string(json.dumps(event, default=_jsonable)))
        if sample.people is not None:
            topic, msgtype = PEOPLE_TOPIC
            if topic not in self._conns:
                self._conns[topic] = self._writer.add_connection(
                    topic, msgtype, typestore=rm.typestore()
                )
            raw(topic, t, self._people.pack(t, *sample.people))
        spec = self._battery
        due = t >= self._next_battery - 1e-9 or sample.charging != self._charging
        if spec is not None and sample.battery is not None and due:
            self._next_battery = t + self.battery_period
            self._charging = sample.charging
            state = rm.battery_state(
                t, sample.battery, sample.charging, spec.capacity, spec.voltage
            )
            self._write("/battery_state", t, state)

    def on_end(self, record: Any) -> None:
        self.close()

    def _flush_map(self) -> None:
        assert self._pending_map is not None
        t, grid = self._pending_map
        self._write("/map", t, rm.occupancy_grid(t, grid, MAP_FRAME))
        self._pending_map = None
        self._next_map = t + self.map_period

    def close(self) -> None:
        if self._writer is not None:
            if self._pending_map is not None:
                self._flush_map()
            self._writer.close()
            self._writer = None

    # ------------------------------------------------------------------ helpers

    def _write(self, topic: str, t: float, msg: Any) -> None:
        self._write_raw(topic, t, rm.serialize(msg, TOPICS[topic][0]))

    def _write_raw(self, topic: str, t: float, data: bytes) -> None:
        assert self._writer is not None
        self._writer.write(self._conns[topic], rm.nanoseconds(t), data)
        self.messages += 1

    def _velocity(self, key: str, t: float, p: Pose2D) -> tuple[float, float]:
        """Body-frame (v, w) from the previous pose of the same stream."""
        prev = self._prev.get(key)
        self._prev[key] = (t, p)
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
