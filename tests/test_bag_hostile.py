"""``agv-mission map`` on bags whose messages cannot be a recording's: exit 2 naming the
file, the topic, the message and the field; never a traceback, a silent map of
nonsense, or a huge allocation."""

from __future__ import annotations

import math
import struct

import numpy as np
import pytest

from bagtools import write_small_bag

NAN, INF = float("nan"), float("inf")

#: name -> (bag format, write_small_bag's arguments, what the message must say)
CASES = {
    "increment_zero": (
        "ros2",
        {"scan": {"angle_increment": 0.0}},
        "/scan message 1: angle_increment: 0 with 360 beams",
    ),
    "increment_nan": (
        "mcap",
        {"scan": {"angle_increment": NAN}},
        "/scan message 1: angle_increment: is not finite",
    ),
    "increment_huge": (
        "ros1",
        {"scan": {"angle_increment": 1e30}},
        "angle_increment: 1e+30 rad x 359 beams",
    ),
    "angle_min_nan": (
        "ros2",
        {"scan": {"angle_min": NAN}},
        "/scan message 1: angle_min: is not finite",
    ),
    "angle_min_huge": (
        "ros1",
        {"scan": {"angle_min": 1e30}},
        "angle_min: 1e+30 rad is more than a turn",
    ),
    "range_max_nan": (
        "ros2",
        {"scan": {"range_max": NAN}},
        "range_max: must be more than range_min",
    ),
    "range_max_zero": (
        "mcap",
        {"scan": {"range_max": 0.0}},
        "range_max: must be more than range_min",
    ),
    "range_min_nan": ("ros1", {"scan": {"range_min": NAN}}, "range_min: must be a finite distance"),
    "beams_200k": (
        "ros2",
        {"scans": 2, "scan": {"ranges": np.full(200_000, 2.0, np.float32)}},
        "ranges: 200000 beams, more than 100000",
    ),
    "odom_nan": (
        "ros1",
        {"odom": {"x": NAN}},
        "/odom message 6: pose.pose.position.x: is not finite",
    ),
    "odom_inf": (
        "ros2",
        {"odom": {"y": INF}},
        "/odom message 6: pose.pose.position.y: is not finite",
    ),
    "odom_1e300": (
        "mcap",
        {"odom": {"x": 1e300}},
        "/odom message 6: pose.pose.position.x: 1e+300 m is farther",
    ),
    "odom_quaternion_zero": (
        "ros2",
        {"odom": {"q": (0, 0, 0, 0)}},
        "/odom message 6: pose.pose.orientation: a quaternion of zero length",
    ),
    "odom_quaternion_1e300": (
        "mcap",
        {"odom": {"q": (0, 0, 1e300, 1e300)}},
        "pose.pose.orientation: not a unit quaternion (length 1.414e+300",
    ),
    "mount_quaternion_long": (
        "ros1",
        {"mount": (0.1, 0, 0, 0, 0, 3, 4)},
        "transforms[0].transform.rotation: not a unit quaternion (length 5",
    ),
    "odom_quaternion_nan": (
        "ros1",
        {"odom": {"q": (0, 0, NAN, 1)}},
        "pose.pose.orientation.z: is not finite",
    ),
    "mount_nan": (
        "ros2",
        {"mount": (NAN, 0, 0, 0, 0, 0, 1)},
        "/tf_static message 1: transforms[0].transform.translation.x: is not finite",
    ),
    "mount_1e9": (
        "ros1",
        {"mount": (1e9, 0, 0, 0, 0, 0, 1)},
        "transforms[0].transform.translation.x: 1e+09 m is farther",
    ),
    "mount_quaternion_zero": (
        "mcap",
        {"mount": (0.1, 0, 0, 0, 0, 0, 0)},
        "transforms[0].transform.rotation: a quaternion of zero length",
    ),
    "stamp_nanosec_4e9": (
        "ros2",
        {"scan_nanosec": 4_000_000_000},
        "/scan message 1: header.stamp.nanosec: 4000000000 is not below 10^9",
    ),
    "stamp_nsecs_4e9_ros1": (
        "ros1",
        {"scan_nanosec": 4_000_000_000},
        "/scan message 1: header.stamp.nanosec: 4000000000 is not below 10^9",
    ),
    "truth_nan": (
        "ros2",
        {"truth": {"x": NAN}},
        "/ground_truth message 6: pose.pose.position.x: is not finite",
    ),
    "truth_1e300": (
        "ros1",
        {"truth": {"y": 1e300}},
        "/ground_truth message 6: pose.pose.position.y: 1e+300 m",
    ),
}


@pytest.mark.parametrize("name", list(CASES))
def test_hostile_message_is_exit_2_naming_topic_message_and_field(tmp_path, run_cli, name):
    fmt, args, expected = CASES[name]
    bag = write_small_bag(tmp_path / name, fmt, **args)
    code, text = run_cli(["map", str(bag), "--save-map", str(tmp_path / "m")])
    flat = " ".join(text.split())  # the console wraps long lines
    assert code == 2, text
    assert str(bag.name) in flat and expected in flat, text
    assert "Traceback" not in text
    assert not (tmp_path / "m.pgm").exists()


def test_sound_odd_scans_still_map(tmp_path, run_cli):
    """What a real scanner may send is not refused: a clockwise scan (negative increment)
    whose angle_max disagrees, an infinite range limit, no beams at all."""
    for name, scan in {
        "clockwise": {"angle_min": math.pi, "angle_max": 0.0, "angle_increment": -0.0175},
        "no_limit": {"range_max": INF},
        "no_beams": {"ranges": np.zeros(0, np.float32)},
    }.items():
        bag = write_small_bag(tmp_path / name, "ros2", scan=scan)
        code, text = run_cli(["map", str(bag), "--save-map", str(tmp_path / name)])
        assert code == 0, (name, text)


def test_garbled_message_is_exit_2_naming_it(tmp_path, run_cli):
    """A scan claiming 10^8 ranges it does not hold (a truncated or garbled message) is
    refused naming the message, not a decoder's traceback."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    types = store.types
    stamp = types["builtin_interfaces/msg/Time"](sec=0, nanosec=5)
    scan = types["sensor_msgs/msg/LaserScan"](
        header=types["std_msgs/msg/Header"](stamp=stamp, frame_id="laser"),
        angle_min=-1.0,
        angle_max=1.0,
        angle_increment=0.5,
        time_increment=0.0,
        scan_time=0.1,
        range_min=0.1,
        range_max=5.0,
        ranges=np.arange(1, 6, dtype=np.float32),
        intensities=np.zeros(0, np.float32),
    )
    raw = bytearray(store.serialize_cdr(scan, "sensor_msgs/msg/LaserScan"))
    at = raw.find(struct.pack("<If", 5, 1.0))
    raw[at : at + 4] = struct.pack("<I", 10**8)
    bag = tmp_path / "garbled"
    with Writer(bag, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        conn = writer.add_connection("/scan", "sensor_msgs/msg/LaserScan", typestore=store)
        writer.write(conn, 5, bytes(raw))
    code, text = run_cli(["map", str(bag), "--save-map", str(tmp_path / "m")])
    flat = " ".join(text.split())
    assert code == 2 and "/scan message 1: not a sensor_msgs/msg/LaserScan" in flat, text
    assert "Traceback" not in text


def test_a_recording_without_one_valid_range_maps_nothing_quietly(tmp_path):
    """range_min 1e30: every return invalid, no scan integrated: an empty map, not a
    "Mean of empty slice" RuntimeWarning from the final smoothing."""
    import warnings

    from agv_mission.bags.offline import map_bag, slam_config

    bag = write_small_bag(tmp_path / "blind", "ros2", scan={"range_min": 1e30, "range_max": INF})
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        result = map_bag(bag, slam_config([]))
    assert result.report["scans"]["used"] == 20


def test_a_resolution_whose_first_map_is_too_large_is_exit_2(tmp_path, run_cli):
    """--set resolution=0.001 initial_size=1000: the first map would be 10^12 cells (a
    MapTooLarge traceback from SLAM's reset before)."""
    bag = write_small_bag(tmp_path / "fine", "ros2")
    sets = ["--set", "resolution=0.001", "--set", "initial_size=1000"]
    code, text = run_cli(["map", str(bag), *sets])
    flat = " ".join(text.split())
    assert code == 2 and "stack.slam (--set): a first map of" in flat, text
    assert "Traceback" not in text


@pytest.mark.parametrize(
    ("item", "message"),
    [
        ("resolution=1e300", "less than or equal to 1"),  # IndexError deep in matching
        ("point_sigma=1e300", "less than or equal to 1"),  # OverflowError
        ("odom_translation_noise=1e300", "less than or equal to 1"),  # singular matrix
        ("odom_scale_std=1e-300", "greater than or equal to 0.0001"),  # OverflowError
        ("free_threshold=0.9", "free_threshold must be below occupied_threshold"),
    ],
)
def test_a_slam_setting_no_map_could_use_is_exit_2_naming_it(tmp_path, run_cli, item, message):
    """SLAM settings that validated and then failed deep in the run (tracebacks, exit 1):
    bounds a recording's map can use, checked with the settings."""
    bag = write_small_bag(tmp_path / "fine", "ros2")
    code, text = run_cli(["map", str(bag), "--set", item])
    flat = " ".join(text.split())
    assert code == 2 and message in flat and "Traceback" not in flat, text
