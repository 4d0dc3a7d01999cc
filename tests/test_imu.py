"""The robots' IMU: its samples, the odometry that fuses its gyro, /imu in the bag, and
the localisation figures in result.json."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from rosbags.highlevel import AnyReader

from agv_mission.bags import cdr
from agv_mission.bags import ros_messages as rm
from agv_mission.bags.writer import BagWriter
from agv_mission.geometry import Pose2D, wrap_angle
from agv_mission.maps.grid import OccupancyGrid
from agv_mission.maps.worlds import World
from agv_mission.missions.load.loader import load_mission
from agv_mission.missions.report.outputs import make_run_dir, write_run
from agv_mission.missions.run.runner import MissionRun, run_mission
from agv_mission.robots.builtin_robots import BUILTIN_ROBOTS
from agv_mission.robots.diff_drive import DiffDriveBody, SimConfig
from agv_mission.robots.drive_base import new_odometry
from agv_mission.robots.odometry import DiffDriveOdometry, GyroFusedOdometry
from agv_mission.robots.robot_files import RobotFileError, load_robot

BURGER = BUILTIN_ROBOTS["burger"]


def _open_world() -> World:
    grid = OccupancyGrid(np.zeros((40, 40), dtype=np.int8), 0.25, Pose2D(-5.0, -5.0))
    return World("open", [], [], grid, Pose2D(0.0, 0.0))


def _drive(sim: DiffDriveBody, seconds: float, v: float, w: float, reads: list) -> None:
    """Drive (v, w) for ``seconds`` in 0.1 s steps, reading the IMU after each."""
    for _ in range(int(round(seconds / 0.1))):
        sim.set_command(v, w)
        sim.advance(0.1)
        reads.append(sim.imu_samples())


def test_every_builtin_robot_has_its_imu_from_its_source():
    for name in ("burger", "waffle"):
        imu = BUILTIN_ROBOTS[name].imu
        assert imu is not None and imu.rate == 200.0  # OpenCR firmware
        # MPU-9250: 0.01 deg/s/sqrt(Hz), 300 ug/sqrt(Hz)
        assert imu.gyro_noise_density == pytest.approx(math.radians(0.01))
        assert imu.accel_noise_density == pytest.approx(300e-6 * 9.80665)
    rosbots = BUILTIN_ROBOTS["rosbots"].imu
    assert rosbots is not None and rosbots.gyro_noise_density == pytest.approx(math.radians(0.005))
    # BARN's Gazebo Jackal: hector's IMU at 50 Hz, 0.005 rad/s per sample
    jackal = BUILTIN_ROBOTS["jackal"].imu
    assert jackal is not None and jackal.rate == 50.0
    assert jackal.gyro_noise_density * math.sqrt(jackal.rate) == pytest.approx(0.005)


def test_robot_file_imu_block_is_validated(tmp_path: Path):
    good = tmp_path / "bot.yaml"
    base = (
        "wheel_radius: 0.03\nwheel_separation: 0.2\nfootprint_radius: 0.15\n"
        "max_linear_velocity: 0.5\nmax_angular_velocity: 2.0\n"
        "encoder: {ticks_per_meter: 5000}\n"
    )
    good.write_text(
        base + "imu:\n  rate: 100.0\n  gyro_noise_density: 0.00017\n"
        "  gyro_bias_instability: 0.00005\n  accel_noise_density: 0.0029\n"
    )
    assert load_robot(str(good)).imu.rate == 100.0
    bad = tmp_path / "bad.yaml"
    bad.write_text(
        base + "imu:\n  rate: 100.0\n  gyro_noise_density: -1\n"
        "  gyro_bias_instability: 0.00005\n  accel_noise_density: 0.0029\n"
    )
    with pytest.raises(RobotFileError) as err:
        load_robot(str(bad))
    assert err.value.field == "imu.gyro_noise_density" and err.value.line == 9
    without = tmp_path / "plain.yaml"
    without.write_text(base)
    assert load_robot(str(without)).imu is None


def test_ideal_gyro_adds_up_to_the_true_turn_at_its_rate():
    sim = DiffDriveBody.alone(BURGER, _open_world(), Pose2D(0.0, 0.0, 3.0), SimConfig(ideal=True))
    yaw0 = sim.true_pose().yaw
    reads: list = []
    _drive(sim, 2.0, 0.2, 1.5, reads)
    _drive(sim, 1.0, 0.1, -2.0, reads)
    times = np.concatenate([r.times for r in reads])
    assert np.diff(times) == pytest.approx(1.0 / BURGER.imu.rate)  # every sample, in order
    assert times[-1] == pytest.approx(sim.time)
    turned = sum(r.turn for r in reads)
    assert turned == pytest.approx(wrap_angle(sim.true_pose().yaw - yaw0) + 0.0, abs=1e-9)
    gyro = np.concatenate([r.gyro for r in reads])
    assert gyro[150:190].mean() == pytest.approx(1.5, abs=0.05)  # turning at 1.5 rad/s
    accel = np.concatenate([r.accel for r in reads])
    assert accel[150:190, 1].mean() == pytest.approx(0.2 * 1.5, abs=0.03)  # v w


def test_noisy_gyro_has_its_datasheet_noise_and_a_constant_bias():
    sim = DiffDriveBody.alone(
        BURGER, _open_world(), Pose2D(0.0, 0.0, 0.0), SimConfig(), np.random.default_rng(5)
    )
    reads: list = []
    _drive(sim, 20.0, 0.0, 0.0, reads)  # standing still
    gyro = np.concatenate([r.gyro for r in reads])
    spec = BURGER.imu
    sd = spec.gyro_noise_density * math.sqrt(spec.rate)
    assert gyro.std() == pytest.approx(sd, rel=0.1)
    assert gyro.mean() == pytest.approx(sim.imu.bias, abs=4 * sd / math.sqrt(len(gyro)))
    assert sim.imu.bias != 0.0 and abs(sim.imu.bias) < 5 * spec.gyro_bias_instability


def test_fused_odometry_keeps_the_heading_the_wheels_lose():
    """A wheel scale error of 2 % (a worn tyre): on a 40 s circle the wheels alone are off
    by a large angle, the fused odometry by the gyro's drift; standing still, the gyro's
    bias does not turn it."""
    sim = DiffDriveBody.alone(
        BURGER,
        _open_world(),
        Pose2D(0.0, 0.0, 0.0),
        SimConfig(wheel_scale_error=0.02),
        np.random.default_rng(1),
    )
    wheels = new_odometry(BURGER, use_imu=False)
    fused = new_odometry(BURGER)
    assert type(wheels) is DiffDriveOdometry and isinstance(fused, GyroFusedOdometry)
    ticks = sim.encoder_ticks()
    wheels.update(*ticks)
    fused.update(*ticks)
    sim.imu_samples()
    for k in range(500):
        if k < 400:
            sim.set_command(0.2, 0.5)
        else:
            sim.set_command(0.0, 0.0)
        sim.advance(0.1)
        ticks = sim.encoder_ticks()
        imu = sim.imu_samples()
        wheels.update(*ticks)
        fused.update_fused(*ticks, imu.turn, len(imu) * imu.period)
        if k == 420:
            at_rest = fused.pose.yaw
    truth = sim.true_pose()
    wheel_err = abs(wrap_angle(wheels.pose.yaw - truth.yaw))
    fused_err = abs(wrap_angle(fused.pose.yaw - truth.yaw))
    assert wheel_err > 0.05 and fused_err < 0.01 and fused_err < wheel_err / 10
    assert math.hypot(fused.pose.x - truth.x, fused.pose.y - truth.y) < 0.1
    assert fused.pose.yaw == pytest.approx(at_rest, abs=1e-5)  # at rest it does not turn


def test_imu_cdr_equals_rosbags_serialiser():
    raw = cdr.imu_cdr(12.345, "base_footprint", 0.25, -0.1, 0.3, 1e-6, 2e-3)
    msg = rm.imu(12.345, "base_footprint", 0.25, -0.1, 0.3, 1e-6, 2e-3)
    assert raw == rm.serialize(msg, rm.IMU)


def test_imu_cdr_rows_are_imu_cdr_of_each_sample():
    rng = np.random.default_rng(3)
    times = 7.0 + np.arange(1, 41) * 0.005  # 200 Hz, nanosecond stamps that round
    gz, accel = rng.normal(size=40), rng.normal(size=(40, 2))
    rows = cdr.imu_cdr_rows(times, "imu_link", gz, accel, 1e-6, 2e-3)
    for row, t, g, (ax, ay) in zip(rows, times.tolist(), gz, accel, strict=True):
        assert row == cdr.imu_cdr(t, "imu_link", g, ax, ay, 1e-6, 2e-3)


MISSION = """
name: imu-bag
world: turtlebot3_world
robot: {robot}
start: {{x: -2.0, y: -0.5, yaw: 0.0}}
seed: 4
stack:
  odometry: {{imu: {imu}}}
tasks:
  - {{type: go_to, pose: {{x: -1.6, y: -0.5, yaw: 1.57}}}}
limits: {{time: 6.0}}
"""


def _bag_run(tmp_path: Path, robot: str, imu: str = "true"):
    loaded = load_mission(tmp_path / "m.yaml", text=MISSION.format(robot=robot, imu=imu))
    run_dir = make_run_dir(tmp_path / "runs", loaded.name)
    record = run_mission(loaded, run_dir, observers=[BagWriter()])
    write_run(run_dir, loaded, record)
    messages: dict[str, list] = {}
    with AnyReader([run_dir / "bag"]) as reader:
        for conn, log_time, raw in reader.messages():
            messages.setdefault(conn.topic, []).append(
                (log_time, reader.deserialize(raw, conn.msgtype), conn.msgtype)
            )
    return loaded, record, messages


def test_imu_in_the_bag_at_its_rate_with_the_gyro_rates(tmp_path: Path):
    loaded, record, messages = _bag_run(tmp_path, "burger")
    imu = messages["/imu"]
    assert {m for _, _, m in imu} == {"sensor_msgs/msg/Imu"}
    stamps = np.array([t for t, _, _ in imu]) * 1e-9
    rate = loaded.robot.imu.rate
    assert len(imu) == pytest.approx(record.sim_time * rate, abs=2)
    assert np.diff(stamps) == pytest.approx(1.0 / rate, abs=1e-6)
    first = imu[0][1]
    assert first.header.frame_id == "base_footprint"
    assert first.orientation_covariance[0] == -1.0  # no orientation estimate
    assert first.linear_acceleration.z == pytest.approx(9.80665)
    # the gyro's rates integrate to the robot's true turn (within its noise)
    gz = np.array([m.angular_velocity.z for _, m, _ in imu])
    turned = gz.sum() / rate
    traj = record.trajectory
    assert turned == pytest.approx(wrap_angle(traj[-1, 3] - traj[0, 3]), abs=0.02)


def test_robot_without_imu_has_no_imu_topic_and_wheel_odometry(tmp_path: Path):
    robot = tmp_path / "bot.yaml"
    robot.write_text(
        "wheel_radius: 0.033\nwheel_separation: 0.16\nfootprint_radius: 0.105\n"
        "max_linear_velocity: 0.22\nmax_angular_velocity: 2.84\n"
        "encoder: {ticks_per_meter: 19754}\n"
    )
    _, _, messages = _bag_run(tmp_path, str(robot))
    assert "/imu" not in messages and messages["/odom"]


def test_stack_odometry_imu_false_uses_the_wheels_alone():
    text = MISSION.format(robot="burger", imu="false")
    run = MissionRun(load_mission(Path("m.yaml"), text=text), None)
    assert type(run.stack.odometry) is DiffDriveOdometry
    run = MissionRun(
        load_mission(Path("m.yaml"), text=MISSION.format(robot="burger", imu="true")), None
    )
    assert isinstance(run.stack.odometry, GyroFusedOdometry)


def test_result_has_a_consistency_figure(tmp_path: Path):
    _, record, _ = _bag_run(tmp_path, "burger")
    c = record.metrics["localization"]["consistency"]
    assert 0.0 <= c["inside_2sigma"] <= 1.0
    assert c["radius_over_error"] == pytest.approx(
        c["mean_2sigma_radius"] / c["mean_error"], rel=1e-2
    )
