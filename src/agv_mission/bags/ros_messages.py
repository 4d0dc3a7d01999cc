"""Standard ROS 2 messages built from this project's types (``rosbags`` typestore, CDR).

The message classes and their CDR serialisers come from ``rosbags``' built-in Humble
typestore, so the bag carries the exact ``.msg`` definitions ROS tools expect. The
messages a run writes every step are packed by :mod:`agv_mission.bags.cdr` instead.
"""

from __future__ import annotations

import math
from functools import cache
from typing import Any

import numpy as np
from rosbags.typesys import Stores, get_typestore

from agv_mission.geometry import Pose2D
from agv_mission.maps.grid import OccupancyGrid
from agv_mission.sensor_msgs import LaserScan

LASER_SCAN = "sensor_msgs/msg/LaserScan"
ODOMETRY = "nav_msgs/msg/Odometry"
TF_MESSAGE = "tf2_msgs/msg/TFMessage"
CLOCK = "rosgraph_msgs/msg/Clock"
TWIST = "geometry_msgs/msg/Twist"
OCCUPANCY_GRID = "nav_msgs/msg/OccupancyGrid"
POSE_WITH_COVARIANCE_STAMPED = "geometry_msgs/msg/PoseWithCovarianceStamped"
POSE_ARRAY = "geometry_msgs/msg/PoseArray"
PATH = "nav_msgs/msg/Path"
MARKER_ARRAY = "visualization_msgs/msg/MarkerArray"
STRING = "std_msgs/msg/String"
BATTERY_STATE = "sensor_msgs/msg/BatteryState"
IMU = "sensor_msgs/msg/Imu"

# sensor_msgs/BatteryState constants
POWER_SUPPLY_STATUS_CHARGING, POWER_SUPPLY_STATUS_DISCHARGING = 1, 2
POWER_SUPPLY_STATUS_FULL = 4
POWER_SUPPLY_HEALTH_GOOD = 1
POWER_SUPPLY_TECHNOLOGY_LIPO = 3


@cache
def typestore() -> Any:
    """The ROS 2 Humble typestore (message classes + CDR), built once."""
    return get_typestore(Stores.ROS2_HUMBLE)


def nanoseconds(t: float) -> int:
    """Simulated seconds as integer nanoseconds (a bag's log time)."""
    return int(round(t * 1e9))


def stamp(t: float) -> Any:
    sec, nsec = divmod(nanoseconds(t), 1_000_000_000)
    return typestore().types["builtin_interfaces/msg/Time"](sec=int(sec), nanosec=int(nsec))


def header(t: float, frame: str) -> Any:
    return typestore().types["std_msgs/msg/Header"](stamp=stamp(t), frame_id=frame)


def _point(x: float, y: float, z: float = 0.0) -> Any:
    return typestore().types["geometry_msgs/msg/Point"](x=float(x), y=float(y), z=float(z))


def _vector(x: float, y: float, z: float = 0.0) -> Any:
    return typestore().types["geometry_msgs/msg/Vector3"](x=float(x), y=float(y), z=float(z))


def _quaternion(yaw: float) -> Any:
    return typestore().types["geometry_msgs/msg/Quaternion"](
        x=0.0, y=0.0, z=math.sin(yaw / 2.0), w=math.cos(yaw / 2.0)
    )


def pose(p: Pose2D, z: float = 0.0) -> Any:
    return typestore().types["geometry_msgs/msg/Pose"](
        position=_point(p.x, p.y, z), orientation=_quaternion(p.yaw)
    )


def transform(t: float, parent: str, child: str, p: Pose2D, z: float = 0.0) -> Any:
    """``geometry_msgs/TransformStamped`` of ``child`` in ``parent`` (a planar pose)."""
    types = typestore().types
    return types["geometry_msgs/msg/TransformStamped"](
        header=header(t, parent),
        child_frame_id=child,
        transform=types["geometry_msgs/msg/Transform"](
            translation=_vector(p.x, p.y, z), rotation=_quaternion(p.yaw)
        ),
    )


def tf_message(transforms: list[Any]) -> Any:
    return typestore().types[TF_MESSAGE](transforms=transforms)


def clock(t: float) -> Any:
    return typestore().types[CLOCK](clock=stamp(t))


def twist(v: float, w: float) -> Any:
    return typestore().types[TWIST](linear=_vector(v, 0.0), angular=_vector(0.0, 0.0, w))


def covariance6(cov3: np.ndarray | None) -> np.ndarray:
    """The 6x6 (x, y, z, roll, pitch, yaw) row-major covariance of a planar 3x3 one."""
    out = np.zeros(36, dtype=np.float64)
    if cov3 is not None:
        idx = (0, 1, 5)
        c = np.asarray(cov3, dtype=float)
        for i, a in enumerate(idx):
            for j, b in enumerate(idx):
                out[a * 6 + b] = c[i, j]
    return out


def odometry(
    t: float, frame: str, child: str, p: Pose2D, v: float, w: float, cov3: np.ndarray | None
) -> Any:
    types = typestore().types
    return types[ODOMETRY](
        header=header(t, frame),
        child_frame_id=child,
        pose=types["geometry_msgs/msg/PoseWithCovariance"](
            pose=pose(p), covariance=covariance6(cov3)
        ),
        twist=types["geometry_msgs/msg/TwistWithCovariance"](
            twist=twist(v, w), covariance=np.zeros(36, dtype=np.float64)
        ),
    )


def imu(
    t: float, frame: str, gz: float, ax: float, ay: float, gyro_var: float, accel_var: float
) -> Any:
    """``sensor_msgs/Imu`` of a planar IMU (see :func:`agv_mission.bags.cdr.imu_cdr`)."""
    types = typestore().types
    no_orientation = np.zeros(9)
    no_orientation[0] = -1.0
    return types[IMU](
        header=header(t, frame),
        orientation=types["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
        orientation_covariance=no_orientation,
        angular_velocity=_vector(0.0, 0.0, gz),
        angular_velocity_covariance=np.diag([gyro_var] * 3).ravel(),
        linear_acceleration=_vector(ax, ay, 9.80665),
        linear_acceleration_covariance=np.diag([accel_var] * 3).ravel(),
    )


def pose_with_covariance(t: float, frame: str, p: Pose2D, cov3: np.ndarray | None) -> Any:
    types = typestore().types
    return types[POSE_WITH_COVARIANCE_STAMPED](
        header=header(t, frame),
        pose=types["geometry_msgs/msg/PoseWithCovariance"](
            pose=pose(p), covariance=covariance6(cov3)
        ),
    )


def laser_scan(scan: LaserScan, frame: str, scan_time: float) -> Any:
    """``sensor_msgs/LaserScan``: ``inf`` for no return, as ROS drivers publish it."""
    n = len(scan.ranges)
    return typestore().types[LASER_SCAN](
        header=header(scan.time, frame),
        angle_min=float(scan.angle_min),
        angle_max=float(scan.angle_min + scan.angle_increment * max(n - 1, 0)),
        angle_increment=float(scan.angle_increment),
        time_increment=0.0,
        scan_time=float(scan_time),
        range_min=float(scan.range_min),
        range_max=float(scan.range_max),
        ranges=np.asarray(scan.ranges, dtype=np.float32),
        intensities=np.zeros(0, dtype=np.float32),
    )


def occupancy_grid(t: float, grid: OccupancyGrid, frame: str = "map") -> Any:
    types = typestore().types
    info = types["nav_msgs/msg/MapMetaData"](
        map_load_time=stamp(t),
        resolution=float(grid.resolution),
        width=grid.width,
        height=grid.height,
        origin=pose(grid.origin),
    )
    data = np.ascontiguousarray(grid.data, dtype=np.int8).reshape(-1)
    return types[OCCUPANCY_GRID](header=header(t, frame), info=info, data=data)


def path(t: float, points: np.ndarray, frame: str = "map") -> Any:
    """``nav_msgs/Path`` of (k, 2+) way points; yaw along the path when not given."""
    types = typestore().types
    pts = np.asarray(points, dtype=float)
    if pts.shape[1] >= 3:
        yaws = pts[:, 2]
    else:
        d = np.diff(pts[:, :2], axis=0)
        yaws = np.append(np.arctan2(d[:, 1], d[:, 0]), 0.0) if len(pts) > 1 else np.zeros(1)
        if len(pts) > 1:
            yaws[-1] = yaws[-2]
    poses = [
        types["geometry_msgs/msg/PoseStamped"](
            header=header(t, frame), pose=pose(Pose2D(float(x), float(y), float(a)))
        )
        for (x, y), a in zip(pts[:, :2], yaws, strict=True)
    ]
    return types[PATH](header=header(t, frame), poses=poses)


def battery_state(
    t: float, level: float, charging: bool, capacity_wh: float, voltage: float | None
) -> Any:
    """The battery's state: ``percentage`` 0..1, charge and capacity in Ah when the
    nominal ``voltage`` is known (NaN otherwise, as the message says for unmeasured)."""
    nan = math.nan
    capacity = capacity_wh / voltage if voltage else nan
    if charging:
        status = POWER_SUPPLY_STATUS_FULL if level >= 1.0 else POWER_SUPPLY_STATUS_CHARGING
    else:
        status = POWER_SUPPLY_STATUS_DISCHARGING
    return typestore().types[BATTERY_STATE](
        header=header(t, ""),
        voltage=float(voltage) if voltage else nan,
        temperature=nan,
        current=nan,
        charge=float(level * capacity),
        capacity=float(capacity),
        design_capacity=float(capacity),
        percentage=float(level),
        power_supply_status=status,
        power_supply_health=POWER_SUPPLY_HEALTH_GOOD,
        power_supply_technology=POWER_SUPPLY_TECHNOLOGY_LIPO,
        present=True,
        cell_voltage=np.zeros(0, np.float32),
        cell_temperature=np.zeros(0, np.float32),
        location="",
        serial_number="",
    )


def string(text: str) -> Any:
    return typestore().types[STRING](data=text)


def room_markers(t: float, rooms: dict[str, Any], frame: str = "map") -> Any:
    """Room outlines (closed line strips) and their labels (text), one namespace each."""
    types = typestore().types
    marker = types["visualization_msgs/msg/Marker"]
    colour = types["std_msgs/msg/ColorRGBA"]
    zero = types["builtin_interfaces/msg/Duration"](sec=0, nanosec=0)
    markers = []
    for i, (label, room) in enumerate(sorted(rooms.items())):
        poly = list(room.polygon) + [room.polygon[0]]
        common = {
            "header": header(t, frame),
            "id": i,
            "action": 0,
            "lifetime": zero,
            "frame_locked": False,
            "colors": [],
            "texture_resource": "",
            "texture": types["sensor_msgs/msg/CompressedImage"](
                header=header(t, frame), format="", data=np.zeros(0, np.uint8)
            ),
            "uv_coordinates": [],
            "mesh_resource": "",
            "mesh_file": types["visualization_msgs/msg/MeshFile"](
                filename="", data=np.zeros(0, np.uint8)
            ),
            "mesh_use_embedded_materials": False,
        }
        markers.append(
            marker(
                ns="room_outlines",
                type=4,  # LINE_STRIP
                pose=pose(Pose2D(0.0, 0.0, 0.0)),
                scale=_vector(0.03, 0.0, 0.0),
                color=colour(r=0.2, g=0.4, b=1.0, a=1.0),
                points=[_point(x, y) for x, y in poly],
                text="",
                **common,
            )
        )
        cx, cy = room.inside_point()
        markers.append(
            marker(
                ns="room_labels",
                type=9,  # TEXT_VIEW_FACING
                pose=pose(Pose2D(cx, cy, 0.0), z=0.3),
                scale=_vector(0.0, 0.0, 0.3),
                color=colour(r=1.0, g=1.0, b=1.0, a=1.0),
                points=[],
                text=label,
                **common,
            )
        )
    return types[MARKER_ARRAY](markers=markers)


PERSON_HEIGHT = 1.7  # m: the cylinder a person is drawn as (and is, in the world)


def people_markers(
    t: float, ids: np.ndarray, xy: np.ndarray, radii: np.ndarray, frame: str = "map"
) -> Any:
    """One cylinder per person (namespace ``people``, id the person's), standing on the
    floor, as pedsim_ros and HuNavSim draw their agents."""
    types = typestore().types
    marker = types["visualization_msgs/msg/Marker"]
    colour = types["std_msgs/msg/ColorRGBA"]
    zero = types["builtin_interfaces/msg/Duration"](sec=0, nanosec=0)
    markers = []
    for pid, (x, y), r in zip(
        np.asarray(ids).tolist(), np.asarray(xy).tolist(), radii, strict=True
    ):
        markers.append(
            marker(
                header=header(t, frame),
                ns="people",
                id=int(pid),
                type=3,  # CYLINDER
                action=0,
                pose=pose(Pose2D(float(x), float(y), 0.0), z=PERSON_HEIGHT / 2),
                scale=_vector(2 * float(r), 2 * float(r), PERSON_HEIGHT),
                color=colour(r=1.0, g=0.55, b=0.1, a=0.9),
                lifetime=zero,
                frame_locked=False,
                points=[],
                colors=[],
                texture_resource="",
                texture=types["sensor_msgs/msg/CompressedImage"](
                    header=header(t, frame), format="", data=np.zeros(0, np.uint8)
                ),
                uv_coordinates=[],
                text="",
                mesh_resource="",
                mesh_file=types["visualization_msgs/msg/MeshFile"](
                    filename="", data=np.zeros(0, np.uint8)
                ),
                mesh_use_embedded_materials=False,
            )
        )
    return types[MARKER_ARRAY](markers=markers)


def serialize(msg: Any, msgtype: str) -> bytes:
    return bytes(typestore().serialize_cdr(msg, msgtype))
