"""`agv-mission map` on bags as real robots record them (written by the tests)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from agv_mission.bags.offline import map_bag, slam_config
from agv_mission.bags.reader import read_bag
from agv_mission.geometry import Pose2D
from bagtools import Quirks, simulated_drive, wall_precision, write_quirk_bag


@pytest.fixture(scope="module")
def drive():
    return simulated_drive(30.0)


CASES = {
    "ros2_plain": Quirks(),
    "ros1_offcentre_rotated": Quirks(fmt="ros1", mount=Pose2D(0.12, -0.05, math.pi / 2)),
    "mcap_upside_down": Quirks(fmt="mcap", upside_down=True, mount=Pose2D(-0.08, 0.0, 0.3)),
    "ros1_clockwise_1440_nan": Quirks(fmt="ros1", beams=1440, clockwise=True, nan_fraction=0.2),
    "ros2_180_beams_12m": Quirks(beams=180, range_max=12.0, mount_via_base_link=True),
    "ros1_2000_beams_odom_tf_only": Quirks(
        fmt="ros1", beams=2000, odom_on_tf_only=True, scan_until=15.0
    ),
    "ros1_static_on_tf_odom_30hz": Quirks(
        fmt="ros1", static_on_tf=True, odom_rate=30.0, mount=Pose2D(0.1, 0.0, 0.0)
    ),
    "ros2_odom_3hz_scan_first_gap": Quirks(odom_rate=3.0, scans_before_odom=1.0, gap=(12.0, 13.5)),
}


@pytest.mark.parametrize("name", list(CASES))
def test_quirky_bag_maps_the_world(tmp_path, drive, name):
    q = CASES[name]
    bag = write_quirk_bag(tmp_path / name, drive, q)
    result = map_bag(bag, slam_config([]))
    report = result.report
    scans = report["scans"]
    assert scans["beams"] == [q.beams]
    assert scans["used"] >= 0.8 * scans["total"]
    mount = report["lidar_mount"]
    assert mount["upside_down"] is q.upside_down
    assert (mount["x"], mount["y"]) == pytest.approx((q.mount.x, q.mount.y), abs=1e-6)
    assert report["rmse"]["position_rmse"] < 0.05, report["rmse"]
    assert wall_precision(result.grid, drive.world) > 0.9
    if q.scans_before_odom:
        assert scans["before_odometry"] >= int(q.scans_before_odom * q.scan_rate) - 1
    if q.gap:
        assert scans["in_odometry_gaps"] >= 1
        assert scans["scan_gaps"] >= 1
    if q.odom_on_tf_only:
        assert report["odometry"] == "/tf odom->base_footprint"


def test_upside_down_lidar_ignored_mirrors_the_map(tmp_path, drive):
    """The mount matters: the same bag without its /tf_static maps mirrored walls."""
    q = Quirks(upside_down=True, static_on_tf=False)
    bag = write_quirk_bag(tmp_path / "flip", drive, q)
    good = map_bag(bag, slam_config([]))
    data = read_bag(bag)
    assert data.flipped
    from agv_mission.bags import offline

    original = offline.read_bag

    def no_mount(*args, **kwargs):
        d = original(*args, **kwargs)
        d.flipped, d.mount = False, Pose2D(0.0, 0.0, 0.0)
        return d

    offline.read_bag = no_mount
    try:
        bad = map_bag(bag, slam_config([]))
    finally:
        offline.read_bag = original
    assert wall_precision(good.grid, drive.world) > 0.9
    assert wall_precision(bad.grid, drive.world) < wall_precision(good.grid, drive.world) - 0.2


def test_map_command_writes_map_saver_files_and_report(tmp_path, drive, run_cli):
    bag = write_quirk_bag(tmp_path / "cli", drive, Quirks(fmt="ros1"))
    code, text = run_cli(["map", str(bag), "--save-map", str(tmp_path / "out" / "house")])
    assert code == 0, text
    assert (tmp_path / "out" / "house.pgm").read_bytes().startswith(b"P5")
    meta = (tmp_path / "out" / "house.yaml").read_text()
    assert "resolution: 0.05" in meta and "house.pgm" in meta
    report = json.loads((tmp_path / "out" / "house_report.json").read_text())
    assert report["scan_topic"] == "/scan" and report["odometry"] == "/odom"
    traj = np.loadtxt(tmp_path / "out" / "house_trajectory.csv", delimiter=",", skiprows=1)
    assert traj.shape[1] == 4 and len(traj) == report["trajectory_poses"]
    assert 0.3 * report["scans"]["used"] <= len(traj) <= report["scans"]["used"]  # motion filter


def test_map_command_invalid_input_exit_2(tmp_path, drive, run_cli):
    code, text = run_cli(["map", str(tmp_path / "missing.bag")])
    assert code == 2 and "no such file" in text and "Traceback" not in text
    (tmp_path / "junk.bag").write_bytes(b"not a bag")
    code, text = run_cli(["map", str(tmp_path / "junk.bag")])
    assert code == 2 and "junk.bag" in text and "Traceback" not in text
    bag = write_quirk_bag(tmp_path / "b", drive, Quirks())
    code, text = run_cli(["map", str(bag), "--scan-topic", "/nope"])
    assert code == 2 and "/nope" in text
    code, text = run_cli(["map", str(bag), "--odom-topic", "/scan"])
    assert code == 2 and "not nav_msgs/Odometry" in text
    code, text = run_cli(["map", str(bag), "--set", "resolution=-1"])
    assert code == 2 and "stack.slam.resolution" in text


def test_map_command_without_usable_odometry(tmp_path, drive, run_cli):
    """No odometry at all is invalid input (2); odometry that starts after the last scan
    is a readable bag that maps nothing (1)."""
    bag = write_quirk_bag(tmp_path / "none", drive, Quirks(scans_before_odom=40.0))
    code, text = run_cli(["map", str(bag), "--save-map", str(tmp_path / "m")])
    assert code == 2 and "no odometry" in text and "Traceback" not in text
    late = write_quirk_bag(
        tmp_path / "late", drive, Quirks(scans_before_odom=15.0, scan_until=10.0)
    )
    code, text = run_cli(["map", str(late), "--save-map", str(tmp_path / "m")])
    assert code == 1 and "no scan falls inside the odometry" in text, text
    assert not (tmp_path / "m.pgm").exists()


def test_scans_sharing_coarse_stamps_meet_their_own_odometry(tmp_path, drive):
    """A log converted with six-digit stamps (CSAIL's: 365 scans share one): scans and
    odometry stamped alike in 10 s steps still pair up, by the order they were written,
    and the ground truth with them: the map is the world's and the relative pose error
    small."""
    bag = write_quirk_bag(tmp_path / "coarse", drive, Quirks(coarse_stamps=10.0))
    data = read_bag(bag)
    assert data.notes["stamps_spread"] > 0.9 * len(data.scans)  # a few stamps as recorded
    times = np.array([s.time for s in data.scans])
    assert np.all(np.diff(times) > 0) and np.array_equal(times, data.odom[:, 0])
    result = map_bag(bag, slam_config([]))
    assert result.report["input"]["stamps_spread"] == data.notes["stamps_spread"]
    # the span of stamps spread apart is no duration: no speed "x its duration" either
    assert result.report["bag_duration"] is None is result.report["speed_vs_real_time"]
    assert result.report["relative_pose_error"]["translation_m"] < 0.03
    assert wall_precision(result.grid, drive.world) > 0.9


def test_map_frame_fitted_to_the_robots_estimate_not_its_first_guess(tmp_path, drive):
    """A localiser starts 12 cm and 2.3 degrees off (amcl's first cluster mean) and
    converges within 3 s: a map anchored at the first scan's map -> odom would carry that
    error into every wall; fitted to the estimate over the whole run (the finished
    poses moved, the map rendered from them) it lines up with the world."""
    error = Pose2D(0.1, -0.07, 0.04)
    bag = write_quirk_bag(tmp_path / "settling", drive, Quirks(localiser_start_error=error))
    fitted = map_bag(bag, slam_config([]))
    frame = fitted.report["map_frame"]
    assert frame["fitted"] is True
    # the correction undoes most of the start error (the fit weighs the whole run)
    undo = Pose2D(frame["x"], frame["y"], frame["yaw"]).compose(error)
    assert math.hypot(undo.x, undo.y) < 0.03 and abs(undo.yaw) < 0.01, frame
    assert fitted.report["rmse"]["position_rmse"] < 0.03, fitted.report["rmse"]
    assert wall_precision(fitted.grid, drive.world) > 0.95
    from agv_mission.bags import offline

    original = offline._map_frame_fit
    offline._map_frame_fit = lambda data, base: None  # anchored at the first scan
    try:
        anchored = map_bag(bag, slam_config([]))
    finally:
        offline._map_frame_fit = original
    assert anchored.report["map_frame"] == {"fitted": False}
    assert anchored.report["rmse"]["position_rmse"] > 0.08, anchored.report["rmse"]
    assert wall_precision(anchored.grid, drive.world) < wall_precision(fitted.grid, drive.world)


def test_map_frame_of_odometry_alone_is_not_fitted(tmp_path, drive):
    """A bag whose map -> odom never moves (no localiser corrected the odometry): the map
    frame stays the first scan's; fitting it to the odometry would bend it by the drift."""
    bag = write_quirk_bag(tmp_path / "odom", drive, Quirks())
    result = map_bag(bag, slam_config([]))
    assert result.report["map_frame"] == {"fitted": False}
    assert result.report["rmse"]["position_rmse"] < 0.05
