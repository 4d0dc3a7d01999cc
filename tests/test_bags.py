"""Every run's bag/, read back by two independent readers: rosbags and mcap."""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import numpy as np
import pytest
from rosbags.highlevel import AnyReader

from agv_mission.bags import cdr
from agv_mission.bags import ros_messages as rm
from agv_mission.bags.writer import TOPICS, BagWriter
from agv_mission.geometry import Pose2D, yaw_from_quaternion
from agv_mission.missions.load.loader import load_mission
from agv_mission.missions.report.outputs import make_run_dir, write_run
from agv_mission.missions.run.runner import run_mission
from agv_mission.sensor_msgs import LaserScan

REPO = Path(__file__).resolve().parents[1]

CONTRACT = {
    "/clock": "rosgraph_msgs/msg/Clock",
    "/tf": "tf2_msgs/msg/TFMessage",
    "/tf_static": "tf2_msgs/msg/TFMessage",
    "/odom": "nav_msgs/msg/Odometry",
    "/scan": "sensor_msgs/msg/LaserScan",
    "/cmd_vel": "geometry_msgs/msg/Twist",
    "/map": "nav_msgs/msg/OccupancyGrid",
    "/amcl_pose": "geometry_msgs/msg/PoseWithCovarianceStamped",
    "/particlecloud": "geometry_msgs/msg/PoseArray",
    "/plan": "nav_msgs/msg/Path",
    "/ground_truth": "nav_msgs/msg/Odometry",
    "/rooms": "visualization_msgs/msg/MarkerArray",
    "/events": "std_msgs/msg/String",
    "/battery_state": "sensor_msgs/msg/BatteryState",  # behaviour-trees.md
    "/imu": "sensor_msgs/msg/Imu",  # robots-and-worlds.md (a robot with an IMU)
}


def _t(stamp) -> float:
    return stamp.sec + stamp.nanosec * 1e-9


@pytest.fixture(scope="module")
def patrol_run(tmp_path_factory):
    """A real amcl patrol (25 simulated seconds) with the bag writer attached."""
    loaded = load_mission(
        REPO / "missions" / "patrol.yaml",
        ["limits.time=25", "stack.local_planner.type=pure_pursuit"],
    )
    run_dir = make_run_dir(tmp_path_factory.mktemp("runs"), loaded.name)
    record = run_mission(loaded, run_dir, observers=[BagWriter()])
    write_run(run_dir, loaded, record)
    messages: dict[str, list] = {}
    types: dict[str, str] = {}
    with AnyReader([run_dir / "bag"]) as reader:
        for conn in reader.connections:
            types[conn.topic] = conn.msgtype
        for conn, log_time, raw in reader.messages():
            messages.setdefault(conn.topic, []).append(
                (log_time, reader.deserialize(raw, conn.msgtype))
            )
    return loaded, run_dir, record, types, messages


def test_contract_topics_and_types(patrol_run):
    _, run_dir, _, types, messages = patrol_run
    assert types == CONTRACT == {k: v[0] for k, v in TOPICS.items()}
    assert (run_dir / "bag" / "metadata.yaml").exists()
    assert len(list((run_dir / "bag").glob("*.mcap"))) == 1
    for topic in CONTRACT:
        assert messages.get(topic), f"{topic} is empty"


def test_battery_state_matches_trajectory_csv(patrol_run):
    """/battery_state once per simulated second, its percentage the trajectory's battery
    column at that stamp, discharging, with the burger's 11.1 V 1.8 Ah pack."""
    loaded, run_dir, record, _, messages = patrol_run
    with open(run_dir / "trajectory.csv", newline="") as f:
        rows = {round(float(r["t"]), 6): float(r["battery"]) for r in csv.DictReader(f)}
    states = [m for _, m in messages["/battery_state"]]
    assert len(states) == math.floor(record.sim_time) + 1
    for m in states:
        assert m.percentage == pytest.approx(rows[round(_t(m.header.stamp), 6)], abs=1e-6)
        assert m.power_supply_status == rm.POWER_SUPPLY_STATUS_DISCHARGING
        assert (m.voltage, m.capacity) == pytest.approx((11.1, 1.8))
        assert m.charge == pytest.approx(m.percentage * 1.8, rel=1e-5)
    levels = [m.percentage for m in states]
    assert levels[0] == 1.0 and all(b < a for a, b in zip(levels, levels[1:], strict=False))
    assert record.battery is not None and record.battery[-1] == pytest.approx(
        json.loads((run_dir / "result.json").read_text())["metrics"]["battery"]["end"]
    )


def test_stamps_are_monotonic_simulated_time(patrol_run):
    _, _, record, _, messages = patrol_run
    steps = record.trajectory[:, 0]
    clock = [_t(m.clock) for _, m in messages["/clock"]]
    assert clock == pytest.approx(list(steps), abs=1e-9)
    for topic, items in messages.items():
        logs = [lt for lt, _ in items]
        assert logs == sorted(logs), topic
        assert logs[-1] <= int(round(record.sim_time * 1e9)), topic
        for log_time, msg in items:
            header = getattr(msg, "header", None)
            if header is not None:
                assert int(round(_t(header.stamp) * 1e9)) == log_time, topic


def test_scans_at_the_lidar_rate_with_ros_ranges(patrol_run):
    loaded, _, record, _, messages = patrol_run
    lidar = loaded.robot.lidar
    scans = [m for _, m in messages["/scan"]]
    expected = math.floor(record.sim_time * lidar.rate + 1e-9) + 1
    assert abs(len(scans) - expected) <= 1
    stamps = np.array([_t(s.header.stamp) for s in scans])
    assert np.diff(stamps) == pytest.approx(1.0 / lidar.rate, abs=0.051)
    for s in scans:
        assert s.header.frame_id == "base_scan"
        assert (s.range_min, s.range_max) == pytest.approx((lidar.range_min, lidar.range_max))
        assert len(s.ranges) == lidar.beams
        assert s.angle_increment == pytest.approx(2 * math.pi / lidar.beams)
        assert s.angle_max == pytest.approx(s.angle_min + s.angle_increment * (lidar.beams - 1))
        r = np.asarray(s.ranges)
        finite = r[np.isfinite(r)]
        assert np.all((finite >= lidar.range_min) & (finite <= lidar.range_max))
        assert np.isnan(r).mean() < 0.05  # a dropped beam (invalid reading) is nan
    assert any(np.isposinf(np.asarray(s.ranges)).any() for s in scans)  # "no return": +inf
    dropped = np.mean([np.isnan(np.asarray(s.ranges)).mean() for s in scans])
    assert dropped == pytest.approx(lidar.dropout, abs=0.005)  # REP 117, at the LDS-01's rate


def test_map_matches_the_world(patrol_run):
    loaded, _, _, _, messages = patrol_run
    world = loaded.world.map
    grid = messages["/map"][0][1]
    assert grid.header.frame_id == "map"
    assert grid.info.resolution == pytest.approx(world.resolution)
    assert (grid.info.width, grid.info.height) == (world.width, world.height)
    assert (grid.info.origin.position.x, grid.info.origin.position.y) == pytest.approx(
        (world.origin.x, world.origin.y)
    )
    assert np.array_equal(np.asarray(grid.data).reshape(world.height, world.width), world.data)


def test_estimate_and_tf_tree_match_trajectory_csv(patrol_run):
    """/amcl_pose at each stamp equals trajectory.csv; map->odom->base_footprint composes
    to it (REP-105: map->odom is the localiser's belief); /ground_truth is the true pose."""
    _, run_dir, _, _, messages = patrol_run
    with open(run_dir / "trajectory.csv", newline="") as f:
        rows = [{k: float(v) for k, v in row.items()} for row in csv.DictReader(f)]
    by_t = {round(r["t"], 6): r for r in rows}
    amcl = messages["/amcl_pose"]
    assert len(amcl) == len(rows)
    for _, msg in amcl:
        row = by_t[round(_t(msg.header.stamp), 6)]
        p = msg.pose.pose
        yaw = yaw_from_quaternion(
            p.orientation.x, p.orientation.y, p.orientation.z, p.orientation.w
        )
        assert (p.position.x, p.position.y) == pytest.approx((row["est_x"], row["est_y"]), abs=2e-6)
        assert math.remainder(yaw - row["est_yaw"], 2 * math.pi) == pytest.approx(0.0, abs=2e-6)
        assert msg.header.frame_id == "map"
    assert any(np.any(np.asarray(m.pose.covariance) != 0.0) for _, m in amcl)  # amcl has one
    for _, msg in messages["/ground_truth"]:
        row = by_t[round(_t(msg.header.stamp), 6)]
        p = msg.pose.pose.position
        assert (p.x, p.y) == pytest.approx((row["x"], row["y"]), abs=2e-6)
    static = messages["/tf_static"][0][1].transforms
    assert [(x.header.frame_id, x.child_frame_id) for x in static] == [
        ("base_footprint", "base_scan")
    ]
    for _, msg in messages["/tf"]:
        links = {(x.header.frame_id, x.child_frame_id): x.transform for x in msg.transforms}
        assert set(links) == {("map", "odom"), ("odom", "base_footprint")}
        poses = {}
        for key, tr in links.items():
            q = tr.rotation
            poses[key] = Pose2D(
                tr.translation.x, tr.translation.y, yaw_from_quaternion(q.x, q.y, q.z, q.w)
            )
        base = poses[("map", "odom")].compose(poses[("odom", "base_footprint")])
        row = by_t[round(_t(msg.transforms[0].header.stamp), 6)]
        assert (base.x, base.y) == pytest.approx((row["est_x"], row["est_y"]), abs=1e-5)


def test_plans_particles_rooms_events(patrol_run):
    loaded, _, record, _, messages = patrol_run
    plans = [m for _, m in messages["/plan"]]
    assert len(plans) == len(record.paths)
    last = record.paths[-1]
    assert (
        plans[-1].poses[-1].pose.position.x,
        plans[-1].poses[-1].pose.position.y,
    ) == pytest.approx((last[-1, 0], last[-1, 1]))
    clouds = [m for _, m in messages["/particlecloud"]]
    assert all(m.header.frame_id == "map" and 0 < len(m.poses) <= 1000 for m in clouds)
    markers = messages["/rooms"][0][1].markers
    assert len(markers) == 2 * len(loaded.rooms)
    assert {m.text for m in markers if m.type == 9} == set(loaded.rooms)
    events = [json.loads(m.data) for _, m in messages["/events"]]
    assert events == json.loads(json.dumps(record.events))


def test_struct_cdr_equals_rosbags_serialiser():
    """The per-step messages packed with struct are the very bytes rosbags' serialiser
    writes for the same messages."""
    p, q = Pose2D(1.2, -3.4, 2.5), Pose2D(0.0, 1.0, -0.1)
    cov = np.arange(9.0).reshape(3, 3)
    pairs = [
        (cdr.clock_cdr(12.345), rm.clock(12.345), rm.CLOCK),
        (cdr.twist_cdr(0.2, -0.7), rm.twist(0.2, -0.7), rm.TWIST),
        (
            cdr.tf_cdr(3.3, [("map", "odom", p, 0.0), ("odom", "base_footprint", q, 0.17)]),
            rm.tf_message(
                [
                    rm.transform(3.3, "map", "odom", p),
                    rm.transform(3.3, "odom", "base_footprint", q, z=0.17),
                ]
            ),
            rm.TF_MESSAGE,
        ),
        (
            cdr.pose_with_covariance_cdr(5.5, "map", p, cov),
            rm.pose_with_covariance(5.5, "map", p, cov),
            rm.POSE_WITH_COVARIANCE_STAMPED,
        ),
        (
            cdr.odometry_cdr(5.5, "odom", "base_footprint", p, 0.1, 0.2, cov),
            rm.odometry(5.5, "odom", "base_footprint", p, 0.1, 0.2, cov),
            rm.ODOMETRY,
        ),
        (
            cdr.odometry_cdr(7.25, "map", "base_link", q, -0.3, 1.5, None),
            rm.odometry(7.25, "map", "base_link", q, -0.3, 1.5, None),
            rm.ODOMETRY,
        ),
        (
            cdr.pose_with_covariance_cdr(0.1, "odom", q, None),
            rm.pose_with_covariance(0.1, "odom", q, None),
            rm.POSE_WITH_COVARIANCE_STAMPED,
        ),
    ]
    ranges = np.random.default_rng(2).uniform(0.1, 4.0, 360).astype(np.float32)
    ranges[::7] = np.inf
    for frame, beams in (("base_scan", 360), ("laser", 5), ("ab", 1)):
        scan = LaserScan(ranges[:beams], 0.1, 2 * np.pi / 360, 0.12, 3.5, 123.456789)
        pairs.append(
            (
                cdr.laser_scan_cdr(scan, frame, 0.2),
                rm.laser_scan(scan, frame, 0.2),
                rm.LASER_SCAN,
            )
        )
    for raw, msg, msgtype in pairs:
        assert raw == rm.serialize(msg, msgtype), msgtype


def test_pose_array_cdr_equals_rosbags_serialiser():
    """The numpy PoseArray serialiser writes the very bytes rosbags' would."""
    particles = np.random.default_rng(1).normal(size=(7, 3))
    types = rm.typestore().types
    msg = types[rm.POSE_ARRAY](
        header=rm.header(12.3456789, "map"),
        poses=[rm.pose(Pose2D(*p)) for p in particles],
    )
    assert cdr.pose_array_cdr(12.3456789, "map", particles) == rm.serialize(msg, rm.POSE_ARRAY)


def test_mcap_reader_decodes_every_message(patrol_run):
    """An independent reader: mcap + mcap_ros2's decoder, on the bare .mcap file."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    _, run_dir, _, _, messages = patrol_run
    (path,) = (run_dir / "bag").glob("*.mcap")
    counts: dict[str, int] = {}
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for schema, channel, _message, decoded in reader.iter_decoded_messages():
            assert schema.name == CONTRACT[channel.topic]
            assert channel.message_encoding == "cdr"
            counts[channel.topic] = counts.get(channel.topic, 0) + 1
            if channel.topic == "/scan":
                assert decoded.header.frame_id == "base_scan"
                assert len(decoded.ranges) == 360
    assert counts == {k: len(v) for k, v in messages.items()}


def _mission(tmp_path: Path, output: str) -> Path:
    path = tmp_path / "m.yaml"
    path.write_text(
        "world: turtlebot3_world\nstart: {x: -2.0, y: -0.5, yaw: 0.0}\n"
        "stack: {localization: {type: ground_truth}, local_planner: {type: pure_pursuit}}\n"
        "tasks: [{type: go_to, pose: {x: -1.6, y: -0.5, yaw: 0.0}}]\n"
        f"limits: {{time: 10.0}}\noutput: {output}\n"
    )
    return path


@pytest.mark.parametrize(
    ("output", "args", "bag"),
    [
        ("runs", [], True),
        ("runs", ["--no-bag"], False),
        ("{dir: runs, bag: false}", [], False),
        ("{dir: runs}", ["--set", "output.bag=false"], False),
    ],
)
def test_run_command_writes_bag_unless_told_not_to(tmp_path, monkeypatch, output, args, bag):
    from typer.testing import CliRunner

    from agv_mission.cli import app

    monkeypatch.chdir(tmp_path)
    result = CliRunner().invoke(app, ["run", str(_mission(tmp_path, output)), *args])
    assert result.exit_code == 0, result.output
    (run_dir,) = (tmp_path / "runs").iterdir()
    assert (run_dir / "result.json").exists()
    assert (run_dir / "bag" / "metadata.yaml").exists() is bag


class _Collector:
    """A RunObserver that keeps the events each step hands it (as the live stream does)."""

    def __init__(self) -> None:
        self.events: list[dict] = []

    def on_start(self, start) -> None:
        pass

    def on_step(self, sample) -> None:
        self.events += sample.events

    def on_end(self, record) -> None:
        pass


def test_fault_events_reach_every_observer(tmp_path):
    """Faults are logged before the behaviour tree ticks (and a dropout while sensing):
    they reach the bag's /events and every other observer as they reach result.json."""
    text = (
        "name: faulty\nworld: turtlebot3_world\nstart: {x: -2.0, y: -0.5, yaw: 0}\nseed: 3\n"
        "stack: {localization: {type: ground_truth}}\n"
        "faults:\n  - {type: lidar_dropout, rate: 0.5}\n  - {type: wheel_slip, factor: 0.1}\n"
        "  - {type: kidnap, time: 1.0, pose: {x: -2.0, y: -0.3, yaw: 0.0}}\n"
        "tasks: [{type: go_to, pose: {x: -1.6, y: -0.5, yaw: 0}}]\nlimits: {time: 3}\n"
    )
    (tmp_path / "faulty.yaml").write_text(text)
    loaded = load_mission(tmp_path / "faulty.yaml")
    run_dir = make_run_dir(tmp_path / "runs", loaded.name)
    collector = _Collector()
    record = run_mission(loaded, run_dir, observers=[BagWriter(), collector])
    write_run(run_dir, loaded, record)
    result = json.loads((run_dir / "result.json").read_text())
    faults = [e for e in result["events"] if e["event"] == "fault"]
    assert {e["kind"] for e in faults} == {"lidar_dropout", "wheel_slip", "kidnap"}
    with AnyReader([run_dir / "bag"]) as reader:
        [conn] = [c for c in reader.connections if c.topic == "/events"]
        bagged = [
            (log_time * 1e-9, json.loads(reader.deserialize(raw, conn.msgtype).data))
            for _, log_time, raw in reader.messages(connections=[conn])
        ]
    assert [e for _, e in bagged] == result["events"]
    assert collector.events == json.loads(json.dumps(record.events))
    for stamp, event in bagged:  # each in the step it was logged in
        assert stamp == pytest.approx(event["t"], abs=0.051)
