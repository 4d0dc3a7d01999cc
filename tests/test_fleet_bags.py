"""A fleet run's bag (fleet.md): shared /clock, /tf, /tf_static, /map; every per-robot
topic under its namespace, frames ``agv1/odom`` -> ``agv1/base_footprint`` ->
``agv1/base_scan`` under the shared ``map``; read back with rosbags and mcap; mapped
offline one robot at a time (``agv-mission map --robot``)."""

from __future__ import annotations

import csv
import json
import math
from collections import Counter

import pytest
from rosbags.highlevel import AnyReader
from typer.testing import CliRunner

from agv_mission.bags.writer import SHARED_TOPICS, TOPICS, BagWriter
from agv_mission.cli import app
from agv_mission.geometry import Pose2D, yaw_from_quaternion
from agv_mission.missions.load.loader import load_mission
from agv_mission.missions.report.outputs import make_run_dir, write_run
from agv_mission.missions.run.runner import run_mission
from test_fleet_world import FLEET

NAMES = ("agv1", "agv2")
PER_ROBOT = [t for t in TOPICS if t not in SHARED_TOPICS]


def _t(stamp) -> float:
    return stamp.sec + stamp.nanosec * 1e-9


def _pose(tr) -> Pose2D:
    q = tr.rotation
    return Pose2D(tr.translation.x, tr.translation.y, yaw_from_quaternion(q.x, q.y, q.z, q.w))


class _Scans:
    """Counts the scans each robot's steps hand the observers."""

    def __init__(self) -> None:
        self.count: Counter[str] = Counter()

    def on_start(self, start) -> None:
        pass

    def on_step(self, sample) -> None:
        self.count[sample.robot] += len(sample.scans)

    def on_end(self, record) -> None:
        pass


def _read(bag):
    messages: dict[str, list] = {}
    types: dict[str, str] = {}
    with AnyReader([bag]) as reader:
        for conn in reader.connections:
            types[conn.topic] = conn.msgtype
        for conn, log_time, raw in reader.messages():
            messages.setdefault(conn.topic, []).append(
                (log_time, reader.deserialize(raw, conn.msgtype))
            )
    return types, messages


def _fleet_run(tmp_path_factory, text: str, name: str, time: float = 20.0):
    path = tmp_path_factory.mktemp(name) / f"{name}.yaml"
    path.write_text(text)
    loaded = load_mission(path, [f"limits.time={time}"])
    run_dir = make_run_dir(path.parent / "runs", loaded.name)
    scans = _Scans()
    record = run_mission(loaded, run_dir, observers=[BagWriter(), scans])
    write_run(run_dir, loaded, record)
    return loaded, run_dir, record, scans


@pytest.fixture(scope="module")
def pair(tmp_path_factory):
    """Two robots (a burger on pure pursuit, a waffle on MPC, amcl each) in the
    turtlebot3 world, a short go_to each."""
    loaded, run_dir, record, scans = _fleet_run(tmp_path_factory, FLEET.format(x1=-2.0), "pair")
    assert record.status == "succeeded", record.reason
    types, messages = _read(run_dir / "bag")
    return loaded, run_dir, record, scans, types, messages


def test_fleet_topics_shared_and_namespaced(pair):
    _, _, _, _, types, messages = pair
    expected = {t: TOPICS[t][0] for t in SHARED_TOPICS}
    expected |= {f"/{n}{t}": TOPICS[t][0] for n in NAMES for t in PER_ROBOT}
    assert types == expected
    assert "/scan" not in types and "/odom" not in types and "/agv1/map" not in types
    for topic in expected:
        assert messages.get(topic), f"{topic} is empty"
    assert len(messages["/map"]) == len(messages["/tf_static"]) == len(messages["/rooms"]) == 1


def test_fleet_frames_one_tree_per_robot_rooted_at_map(pair):
    _, _, _, _, _, messages = pair
    parents: dict[str, str] = {}
    (static,) = [m for _, m in messages["/tf_static"]]
    for tr in static.transforms:
        parents[tr.child_frame_id] = tr.header.frame_id
    assert parents == {f"{n}/base_scan": f"{n}/base_footprint" for n in NAMES}
    for _, msg in messages["/tf"]:
        ((a, b), (c, d)) = [(x.header.frame_id, x.child_frame_id) for x in msg.transforms]
        n = b.split("/")[0]
        assert n in NAMES and (a, b, c, d) == (
            "map",
            f"{n}/odom",
            f"{n}/odom",
            f"{n}/base_footprint",
        )
        for x in msg.transforms:
            assert parents.setdefault(x.child_frame_id, x.header.frame_id) == x.header.frame_id
    for n in NAMES:  # every robot's lidar reaches map through its own frames only
        chain, frame = [], f"{n}/base_scan"
        while frame in parents:
            frame = parents[frame]
            chain.append(frame)
        assert chain == [f"{n}/base_footprint", f"{n}/odom", "map"]
        for _, m in messages[f"/{n}/scan"]:
            assert m.header.frame_id == f"{n}/base_scan"
        for _, m in messages[f"/{n}/odom"]:
            assert (m.header.frame_id, m.child_frame_id) == (f"{n}/odom", f"{n}/base_footprint")
        for _, m in messages[f"/{n}/ground_truth"]:
            assert (m.header.frame_id, m.child_frame_id) == ("map", f"{n}/base_footprint")
        for topic in ("amcl_pose", "particlecloud", "plan"):
            assert {m.header.frame_id for _, m in messages[f"/{n}/{topic}"]} == {"map"}


def test_fleet_counts_and_poses_per_robot_match_trajectory_csv(pair):
    loaded, run_dir, record, scans, _, messages = pair
    with open(run_dir / "trajectory.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    steps = sorted({round(float(r["t"]), 6) for r in rows})
    clock = [round(_t(m.clock), 6) for _, m in messages["/clock"]]
    assert clock == steps  # one /clock per step, not one per robot
    assert len(messages["/tf"]) == len(rows)  # one /tf per robot per step
    for n in NAMES:
        mine = {round(float(r["t"]), 6): r for r in rows if r["robot"] == n}
        assert len(mine) == len(steps)
        for topic in ("odom", "ground_truth", "cmd_vel", "amcl_pose"):
            assert len(messages[f"/{n}/{topic}"]) == len(mine), topic
        assert len(messages[f"/{n}/scan"]) == scans.count[n] > 0
        assert len(messages[f"/{n}/plan"]) == len(record.robots[n].paths)
        assert len(messages[f"/{n}/battery_state"]) == math.floor(record.sim_time) + 1
        for _, m in messages[f"/{n}/amcl_pose"]:
            row = mine[round(_t(m.header.stamp), 6)]
            p = m.pose.pose.position
            assert (p.x, p.y) == pytest.approx((float(row["est_x"]), float(row["est_y"])), abs=2e-6)
        for _, m in messages[f"/{n}/ground_truth"]:
            row = mine[round(_t(m.header.stamp), 6)]
            p = m.pose.pose.position
            assert (p.x, p.y) == pytest.approx((float(row["x"]), float(row["y"])), abs=2e-6)
        for _, msg in messages["/tf"]:
            if msg.transforms[0].child_frame_id != f"{n}/odom":
                continue
            base = _pose(msg.transforms[0].transform).compose(_pose(msg.transforms[1].transform))
            row = mine[round(_t(msg.transforms[0].header.stamp), 6)]
            assert (base.x, base.y) == pytest.approx(
                (float(row["est_x"]), float(row["est_y"])), abs=1e-5
            )
    # the two robots are really two: a burger's and a waffle's lidar, apart
    first = {n: messages[f"/{n}/ground_truth"][0][1].pose.pose.position for n in NAMES}
    assert math.dist((first["agv1"].x, first["agv1"].y), (first["agv2"].x, first["agv2"].y)) > 1.0


def test_fleet_events_once_with_their_robot(pair):
    _, run_dir, _, _, _, messages = pair
    events = [json.loads(m.data) for _, m in messages["/events"]]
    result = json.loads((run_dir / "result.json").read_text())
    assert events and all(e["robot"] in NAMES for e in events)
    key = lambda e: (e.get("t", 0.0), e["robot"], json.dumps(e, sort_keys=True))  # noqa: E731
    assert sorted(events, key=key) == sorted(result["events"], key=key)
    assert {e["robot"] for e in events} == set(NAMES)


def test_fleet_bag_through_the_mcap_reader(pair):
    """An independent reader: mcap + mcap_ros2's decoder, on the bare .mcap file."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    _, run_dir, _, _, types, messages = pair
    (path,) = (run_dir / "bag").glob("*.mcap")
    counts: Counter[str] = Counter()
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for schema, channel, _message, decoded in reader.iter_decoded_messages():
            assert schema.name == types[channel.topic]
            counts[channel.topic] += 1
            if channel.topic.endswith("/scan"):
                assert decoded.header.frame_id == channel.topic[1:].replace("/scan", "/base_scan")
    assert counts == {k: len(v) for k, v in messages.items()}


def _map(args: list[str]) -> tuple[int, str]:
    r = CliRunner().invoke(app, ["map", *args])
    assert r.exception is None or isinstance(r.exception, SystemExit), r.exception
    return r.exit_code, r.output


def test_map_of_a_fleet_bag_picks_a_robot(pair, tmp_path):
    loaded, run_dir, _, _, _, _ = pair
    bag = str(run_dir / "bag")
    code, text = _map([bag, "--save-map", str(tmp_path / "x")])
    assert code == 2 and "agv1" in text and "agv2" in text and "--robot" in text, text
    assert "Traceback" not in text and not (tmp_path / "x.pgm").exists()
    code, text = _map([bag, "--robot", "agv9", "--save-map", str(tmp_path / "x")])
    assert code == 2 and "agv9" in text and "agv1, agv2" in text, text
    code, text = _map([bag, "--robot", "agv1", "--scan-topic", "/agv2/scan"])
    assert code == 2 and "/agv2/scan" in text, text
    for n in NAMES:
        code, text = _map([bag, "--robot", n, "--save-map", str(tmp_path / n)])
        assert code == 0, text
        report = json.loads((tmp_path / f"{n}_report.json").read_text())
        assert report["robot"] == n and report["scan_topic"] == f"/{n}/scan"
        assert report["odometry"] == f"/{n}/odom" and report["base_frame"] == f"{n}/base_footprint"
        assert report["ground_truth_topic"] == f"/{n}/ground_truth"
        assert report["scans"]["used"] == report["scans"]["total"] > 0
        assert report["rmse"]["position_rmse"] < 0.1  # the map frame is the shared map
    # a scan topic named is enough: its namespace is the robot
    code, text = _map([bag, "--scan-topic", "/agv2/scan", "--save-map", str(tmp_path / "s")])
    assert code == 0, text
    assert json.loads((tmp_path / "s_report.json").read_text())["odometry"] == "/agv2/odom"


@pytest.fixture(scope="module")
def solo(tmp_path_factory):
    """A fleet of one robot: its bag is namespaced too."""
    text = FLEET.format(x1=-2.0).split("  - name: agv2")[0] + "limits: {time: 20}\n"
    loaded, run_dir, record, _ = _fleet_run(tmp_path_factory, text, "solo")
    assert record.status == "succeeded", record.reason
    return run_dir / "bag"


def test_map_of_a_one_robot_fleet_bag_needs_no_robot(solo, tmp_path):
    code, text = _map([str(solo), "--save-map", str(tmp_path / "m")])
    assert code == 0, text
    report = json.loads((tmp_path / "m_report.json").read_text())
    assert report["robot"] == "agv1" and report["scan_topic"] == "/agv1/scan"
    assert report["ground_truth_topic"] == "/agv1/ground_truth"


SLAM_PAIR = """\
name: slampair
world: turtlebot3_world
seed: 3
stack: {slam: {type: grid}, local_planner: {type: pure_pursuit}}
robots:
  - name: agv1
    robot: burger
    start: {x: -2.0, y: -0.5, yaw: 0.0}
    tasks: [{type: map_area, coverage: 0.9, time_limit: 5.0}]
  - {name: agv2, robot: burger, start: {x: 2.0, y: 0.5, yaw: 3.14}}
limits: {time: 6}
"""


def test_a_fleet_robots_growing_slam_map_is_its_own(tmp_path_factory):
    """/map stays the known map, once; the robot mapping publishes its SLAM map under
    its namespace (as a per-robot slam_toolbox does), every 2 s and its last state."""
    loaded, run_dir, record, _ = _fleet_run(tmp_path_factory, SLAM_PAIR, "slampair", time=6.0)
    types, messages = _read(run_dir / "bag")
    assert types["/agv1/map"] == TOPICS["/map"][0] and "/agv2/map" not in types
    assert len(messages["/map"]) == 1
    grids = messages["/agv1/map"]
    stamps = [_t(m.header.stamp) for _, m in grids]
    paced = stamps[:-1]  # the last one is the map's last state, whenever the run ended
    assert len(paced) >= 2 and all(
        b - a >= 2.0 - 1e-6 for a, b in zip(paced, paced[1:], strict=False)
    )
    assert stamps[-1] == pytest.approx(record.sim_time, abs=0.11)
    known = [sum(1 for v in m.data if v >= 0) for _, m in grids]
    assert known[-1] > known[0]  # it grows


def test_fleet_zone_masks_per_robot(tmp_path_factory):
    """Each robot's filter masks under its namespace: the speed mask is in percent of
    that robot's top speed, so a burger's and a waffle's differ."""
    zones = (
        "zones:\n"
        "  - {type: speed_limit, polygon: [[-1.0, -2.0], [0.0, -2.0], [0.0, -1.5], [-1.0, -1.5]],"
        " max_speed: 0.1}\n"
        "  - {type: keepout, polygon: [[0.5, 1.5], [1.0, 1.5], [1.0, 2.0], [0.5, 2.0]]}\n"
    )
    text = FLEET.format(x1=-2.0).replace("limits: {time: 60}", zones)
    loaded, run_dir, record, _ = _fleet_run(tmp_path_factory, text, "zonepair", time=0.5)
    types, messages = _read(run_dir / "bag")
    masks = sorted(t for t in types if t.endswith("_filter_mask"))
    assert masks == [f"/{n}/{k}_filter_mask" for n in NAMES for k in ("keepout", "speed")]
    values = {t: set(messages[t][0][1].data.tolist()) for t in masks}
    assert values["/agv1/keepout_filter_mask"] == values["/agv2/keepout_filter_mask"] == {0, 100}
    limits = {n: (values[f"/{n}/speed_filter_mask"] - {0}) for n in NAMES}
    assert all(len(v) == 1 for v in limits.values()) and limits["agv1"] != limits["agv2"]
