"""Loop closure: the pose graph optimiser, and the graph SLAM on a 100 m loop (slow)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from agv_mission.geometry import Pose2D
from agv_mission.mapping.graph_slam import GraphSlamConfig, optimize_pose_graph
from agv_mission.missions.load.schema import Stack

REPO = Path(__file__).resolve().parents[1]


def _square_loop(n: int = 400, scale: float = 1.0, yaw_bias: float = 0.003):
    """A 100 m square driven with drifting odometry: truth, dead reckoning, edges."""
    truth = [Pose2D(0.0, 0.0, 0.0)]
    for k in range(1, n):
        truth.append(truth[-1].compose(Pose2D(0.25, 0.0, np.pi / 2 if k % 100 == 0 else 0.0)))
    odo, ii, jj, z, sigma = [truth[0]], [], [], [], []
    for k in range(1, n):
        d = truth[k].relative_to(truth[k - 1])
        m = Pose2D(d.x * scale, d.y, d.yaw + yaw_bias)
        ii.append(k - 1), jj.append(k), z.append(m.as_array()), sigma.append([0.02, 0.02, 0.01])
        odo.append(odo[-1].compose(m))
    truth_xy = np.array([p.as_array() for p in truth])
    nodes = np.array([p.as_array() for p in odo])
    return truth, truth_xy, nodes, ii, jj, z, sigma


def _rmse(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum((a[:, :2] - b[:, :2]) ** 2, axis=1))))


def test_one_loop_edge_closes_a_100m_loop():
    truth, txy, nodes, ii, jj, z, sigma = _square_loop()
    n = len(nodes)
    ii.append(0), jj.append(n - 1), sigma.append([0.05, 0.05, 0.02])
    z.append(truth[-1].relative_to(truth[0]).as_array())
    before = _rmse(nodes, txy)
    after = optimize_pose_graph(nodes, np.array(ii), np.array(jj), np.array(z), np.array(sigma))
    assert before > 5.0
    assert _rmse(after, txy) < 0.05 * before
    assert np.allclose(after[0], nodes[0])  # the gauge stays
    # the last pose now agrees with the loop edge
    end = Pose2D(*after[-1]).relative_to(Pose2D(*after[0]))
    assert np.allclose(end.as_array(), z[-1], atol=0.05)


def test_a_wrong_loop_edge_is_held_down_by_huber():
    truth, txy, nodes, ii, jj, z, sigma = _square_loop(yaw_bias=0.0)
    n = len(nodes)
    ii.append(0), jj.append(n - 1), sigma.append([0.05, 0.05, 0.02])
    z.append(truth[-1].relative_to(truth[0]).as_array())
    ii.append(50), jj.append(250), sigma.append([0.05, 0.05, 0.02])
    z.append(np.array([0.0, 0.0, 0.0]))  # a false loop: two far-apart places "the same"
    robust = optimize_pose_graph(nodes, np.array(ii), np.array(jj), np.array(z), np.array(sigma))
    plain = optimize_pose_graph(
        nodes, np.array(ii), np.array(jj), np.array(z), np.array(sigma), huber=1e9
    )
    assert _rmse(robust, txy) < 0.5 * _rmse(plain, txy)


def test_graph_is_a_slam_plugin_with_the_grid_keys():
    slam = Stack.model_validate({"slam": {"type": "graph", "update_min_d": 0.2}}).slam
    assert isinstance(slam, GraphSlamConfig) and slam.update_min_d == 0.2


@pytest.mark.slow
def test_graph_slam_closes_a_100m_loop_with_slipping_wheels(tmp_path):
    from agv_mission.bags.offline import map_bag, slam_config
    from agv_mission.bags.writer import BagWriter
    from agv_mission.missions.load.loader import load_mission
    from agv_mission.missions.run.runner import run_mission

    # wheels alone: their heading drifts as they slip (a gyro would hold it straight)
    loaded = load_mission(
        REPO / "benchmarks" / "data" / "loop_patrol.yaml", ["stack.odometry.imu=false"]
    )
    record = run_mission(loaded, tmp_path, observers=[BagWriter()])
    assert record.status == "succeeded"
    assert record.metrics["distance_driven"] > 95.0
    grid = map_bag(tmp_path / "bag", slam_config(["type=grid"])).report
    graph = map_bag(tmp_path / "bag", slam_config(["type=graph"])).report
    assert graph["slam_diagnostics"]["loop_closures"] >= 1
    # The trajectory's shape after alignment (ATE): what closing the loop straightens; the
    # unaligned RMSE also carries the heading error picked up before the first closure.
    assert graph["rmse"]["ate_aligned"] < 0.5 * grid["rmse"]["ate_aligned"]
    assert graph["rmse"]["position_rmse"] < 0.75 * grid["rmse"]["position_rmse"]


def test_final_smoothing_keeps_the_slam_poses_and_the_odometry_motion():
    """Poses jittering 2 cm about a 100 m loop (a scan matcher's) and odometry 1 % long
    with a heading drift (a wheel's): the smoothed trajectory moves as the odometry does
    over a metre and stays where the poses are over the loop, better than either."""
    from agv_mission.mapping.graph_slam import smooth_trajectory
    from agv_mission.mapping.quality import relative_pose_error

    rng = np.random.default_rng(4)
    truth, pose = [], Pose2D(0.0, 0.0, 0.0)
    for k in range(1000):  # a 25 x 25 m square, 0.1 m steps
        truth.append(pose.as_array())
        pose = pose.compose(Pose2D(0.1, 0.0, math.pi / 2 if (k + 1) % 250 == 0 else 0.0))
    truth = np.array(truth)
    slam = truth + rng.normal(0.0, [0.02, 0.02, 0.005], truth.shape)
    odom, o = [], Pose2D(0.0, 0.0, 0.0)
    for a, b in zip(truth[:-1], truth[1:], strict=True):
        odom.append(o.as_array())
        d = Pose2D(*b).relative_to(Pose2D(*a))
        o = o.compose(Pose2D(1.01 * d.x, 1.01 * d.y, d.yaw + 0.0005))
    odom.append(o.as_array())
    smoothed = smooth_trajectory(slam, np.array(odom), (0.02, 0.05, 0.03), (0.04, 0.02))
    stamps = np.arange(len(truth), dtype=float)[:, None]

    def rpe(poses: np.ndarray) -> float:
        rows = np.hstack([stamps, poses])
        return relative_pose_error(rows, np.hstack([stamps, truth]))["translation_mean"]

    assert rpe(smoothed) < 0.5 * rpe(slam)
    assert rpe(smoothed) < rpe(np.array(odom))
    worst = np.hypot(*(smoothed[:, :2] - truth[:, :2]).T).max()
    assert worst < 0.1  # the odometry alone ends metres off
    assert np.hypot(*(np.array(odom)[-1, :2] - truth[-1, :2])) > 1.0
