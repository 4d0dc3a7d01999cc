"""Loop closure: the pose graph optimiser, and the graph SLAM on a 100 m loop (slow)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from agv_mission.geometry import Pose2D
from agv_mission.mapping.graph_slam import GraphSlamConfig
from agv_mission.mapping.pose_graph import optimize_pose_graph
from agv_mission.missions.load.schema import Stack
from agv_mission.sensor_msgs import LaserScan

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
    from agv_mission.mapping.pose_graph import smooth_trajectory
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


def test_a_verified_loop_edge_pulls_metres_of_drift_out():
    """A right loop closure nearly 10 m off the drifted graph enters at full weight and
    the solved graph follows it (Gauss-Newton re-linearised to convergence)."""
    from agv_mission.mapping.pose_graph import solve_pose_graph

    truth, txy, nodes, ii, jj, z, sigma = _square_loop(yaw_bias=0.003)
    n = len(nodes)
    ii.append(0), jj.append(n - 1), sigma.append([0.05, 0.05, 0.05])
    z.append(truth[-1].relative_to(truth[0]).as_array())
    loop = np.zeros(len(ii), dtype=bool)
    loop[-1] = True
    solved, keep = solve_pose_graph(
        nodes, np.array(ii), np.array(jj), np.array(z), np.array(sigma), loop, gate=5.0
    )
    assert _rmse(nodes, txy) > 9.0
    assert keep.all()
    assert _rmse(solved, txy) < 0.1 * _rmse(nodes, txy)


def test_a_loop_edge_the_solved_graph_cannot_satisfy_is_dropped():
    """Two right closures and a false one (two places 50 m apart taken for one): the
    solution with all three leaves the false one far off; it is dropped, the graph solved
    again, and the right ones kept."""
    from agv_mission.mapping.pose_graph import solve_pose_graph

    truth, txy, nodes, ii, jj, z, sigma = _square_loop(yaw_bias=0.003)
    n = len(nodes)
    for a, b in ((0, n - 1), (20, n - 21), (50, 250)):
        ii.append(a), jj.append(b), sigma.append([0.05, 0.05, 0.05])
        right = truth[b].relative_to(truth[a]).as_array()
        z.append(right if (a, b) != (50, 250) else np.zeros(3))
    edges = np.array(ii), np.array(jj), np.array(z), np.array(sigma)
    loop = np.arange(len(ii)) >= n - 1
    solved, keep = solve_pose_graph(nodes, *edges, loop, gate=5.0)
    assert keep[:-1].all() and not keep[-1]
    right = optimize_pose_graph(nodes, *(e[:-1] for e in edges), huber=math.inf)
    assert np.allclose(solved, right)
    assert _rmse(solved, txy) < 0.1 * _rmse(nodes, txy)


def test_two_closures_confirm_each_other_only_when_they_agree():
    """The pairwise check a closure that moves the graph must pass: two right closures
    of one revisit agree within centimetres on a graph drifted by metres; a right one and
    one shifted 1 m along a corridor do not."""
    from agv_mission.mapping.pose_graph import loop_pair_error

    truth, txy, nodes, *_ = _square_loop(yaw_bias=0.003)
    n = len(nodes)

    def closure(a: int, b: int, shift: float = 0.0) -> tuple[int, int, np.ndarray]:
        z = truth[b].relative_to(truth[a]).compose(Pose2D(shift, 0.0, 0.0))
        return a, b, z.as_array()

    drifted = Pose2D(*nodes[n - 1]).relative_to(Pose2D(*nodes[2]))
    assert math.hypot(drifted.x, drifted.y) > 5.0  # the graph is far off at the revisit
    # what is left: the drift of the two 4-edge stretches between the closures' ends
    shift, turn = loop_pair_error(nodes, closure(2, n - 1), closure(6, n - 5))
    assert shift < 0.05 and turn < 0.03
    shift, _ = loop_pair_error(nodes, closure(2, n - 1), closure(6, n - 5, shift=1.0))
    assert shift > 0.9


def _room_scan(pose: Pose2D, t: float) -> LaserScan:
    """A 360-beam scan of a 12 x 8 m room with two pillars, cast exactly."""
    walls = [((0, 0), (12, 0)), ((12, 0), (12, 8)), ((12, 8), (0, 8)), ((0, 8), (0, 0))]
    for cx, cy in ((4.0, 5.5), (8.0, 2.5)):  # 1 m square pillars
        c = [(cx - 0.5, cy - 0.5), (cx + 0.5, cy - 0.5), (cx + 0.5, cy + 0.5), (cx - 0.5, cy + 0.5)]
        walls += [(c[k], c[(k + 1) % 4]) for k in range(4)]
    a = pose.yaw - math.pi + np.arange(360) * (2 * math.pi / 360)
    d = np.stack([np.cos(a), np.sin(a)], axis=1)
    best = np.full(360, np.inf)
    for p, q in walls:
        p, e = np.array(p, float), np.array(q, float) - np.array(p, float)
        w = p - (pose.x, pose.y)
        den = d[:, 0] * e[1] - d[:, 1] * e[0]
        with np.errstate(divide="ignore", invalid="ignore"):
            r = (w[0] * e[1] - w[1] * e[0]) / den
            s = (w[0] * d[:, 1] - w[1] * d[:, 0]) / den
        hit = (np.abs(den) > 1e-9) & (r > 0) & (s >= 0) & (s <= 1)
        best = np.where(hit & (r < best), r, best)
    return LaserScan(best.astype(np.float32), -math.pi, 2 * math.pi / 360, 0.1, 20.0, t)


@pytest.mark.parametrize("std", [None, 0.02])
def test_the_front_end_learns_the_odometrys_scale_where_the_scan_sees_the_motion(std):
    """Odometry 5 % long (a wheel radius off), a room whose walls and pillars pin every
    direction: with ``odom_scale_std`` the front end learns the scale (toward 1 / 1.05:
    more than half way in 8 m, no match counted better than 2 cm against a 2 % prior)
    and the odometry's distances are corrected by it; without, it is taken as exact."""
    from agv_mission.mapping.configs import GridSlamConfig
    from agv_mission.mapping.slam import GridSlam

    slam = GridSlam(GridSlamConfig(odom_scale_std=std))
    truth = Pose2D(2.0, 4.0, 0.0)
    slam.reset(truth, Pose2D(0.0, 0.0, 0.0))
    for k in range(1, 60):
        truth = Pose2D(2.0 + 0.13 * k, 4.0 + 0.6 * math.sin(0.1 * k), 0.06 * math.sin(0.1 * k))
        odom = Pose2D(1.05 * (truth.x - 2.0), 1.05 * (truth.y - 4.0), truth.yaw)
        pose = slam.update(odom, _room_scan(truth, 0.1 * k), truth, 0.1 * k)
    assert math.hypot(pose.x - truth.x, pose.y - truth.y) < 0.05
    if std is None:
        assert slam.odom_scale == 1.0
    else:
        assert 1.0 / 1.05 - 0.003 < slam.odom_scale < 1.0 - 0.5 * (1.0 - 1.0 / 1.05)


def _drifting_odometry(truth: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Wheel odometry along ``truth``: 2 % short, curving 0.003 rad per metre (unequal
    wheels), with a little random error on top."""
    odom, o = [], Pose2D(0.0, 0.0, 0.0)
    for a, b in zip(truth[:-1], truth[1:], strict=True):
        odom.append(o.as_array())
        d = Pose2D(*b).relative_to(Pose2D(*a))
        dist = math.hypot(d.x, d.y)
        yaw = d.yaw * (1 + rng.normal(0.0, 0.02)) + 0.003 * dist + rng.normal(0.0, 0.001)
        o = o.compose(Pose2D(0.98 * d.x, 0.98 * d.y, yaw))
    odom.append(o.as_array())
    return np.array(odom)


def _sparse_square(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """A 20 x 20 m square driven twice in 1 m steps (a sparse log), and the front end's
    chain along it: every step's heading 0.5 deg off at random."""
    truth, pose = [], Pose2D(0.0, 0.0, 0.0)
    for k in range(160):
        truth.append(pose.as_array())
        pose = pose.compose(Pose2D(1.0, 0.0, math.pi / 2 if (k + 1) % 20 == 0 else 0.0))
    truth = np.array(truth)
    chain, p = [truth[0]], Pose2D(*truth[0])
    for a, b in zip(truth[:-1], truth[1:], strict=True):
        d = Pose2D(*b).relative_to(Pose2D(*a))
        p = p.compose(Pose2D(d.x, d.y, d.yaw + rng.normal(0.0, 0.009)))
        chain.append(p.as_array())
    return truth, np.array(chain)


def test_odometry_calibration_finds_the_scale_and_the_curvature_per_metre():
    """Against SLAM poses with a random heading error per step several times the
    odometry's drift per metre, the fit over the whole trajectory still finds it."""
    from agv_mission.mapping.pose_graph import calibrate_odometry, odometry_steps

    rng = np.random.default_rng(7)
    truth, chain = _sparse_square(rng)
    odom = _drifting_odometry(truth, rng)
    scale, per_metre, per_radian = calibrate_odometry(chain, odometry_steps(odom))
    assert scale == pytest.approx(1 / 0.98, abs=0.005)
    assert per_metre == pytest.approx(-0.003, abs=0.0015)
    assert abs(per_radian) < 0.03


def test_fusing_calibrated_odometry_straightens_a_drifting_chain():
    """A front-end chain whose headings wander (0.5 deg a step) and odometry with a
    systematic drift: the graph of both, the drift learnt and taken out, lies closer to
    the truth than the chain, and closer than the raw odometry."""
    from agv_mission.mapping.pose_graph import fuse_odometry

    rng = np.random.default_rng(3)
    truth, chain = _sparse_square(rng)
    odom = _drifting_odometry(truth, rng)
    n = len(chain)
    ii, jj = np.arange(n - 1), np.arange(1, n)
    z = np.array(
        [
            Pose2D(*b).relative_to(Pose2D(*a)).as_array()
            for a, b in zip(chain[:-1], chain[1:], strict=True)
        ]
    )
    sigma = np.tile([0.02, 0.02, 0.009], (n - 1, 1))
    edges = (ii, jj, z, sigma, np.zeros(n - 1, dtype=bool))
    fusion = fuse_odometry(chain, edges, odom, (0.02, 0.05, 0.005))
    fused = fusion.nodes

    def error(poses: np.ndarray) -> float:
        return float(np.hypot(*(poses[:, :2] - truth[:, :2]).T).mean())

    assert error(fused) < 0.6 * error(chain)
    learnt = fusion.report()  # what ``map`` reports of the wheels: 2 % short, 0.003 rad/m
    assert learnt["odometry_scale"] == pytest.approx(1 / 0.98, abs=0.005)
    assert learnt["odometry_drift_deg_per_m"] == pytest.approx(math.degrees(-0.003), abs=0.09)
    assert error(fused) < error(odom)


def test_odometry_heading_spread_weakens_slipping_wheels_and_keeps_steady_ones():
    """A solved graph tied to its map (each node's heading 0.3 deg off at random, no
    drift) and two recordings' odometry along it: steady wheels keep the model's heading
    noise; wheels whose every step slips (up to 6 deg a metre, as the simulator's
    encoders slip a share of every read) are weakened several times."""
    from agv_mission.mapping.pose_graph import (
        calibrate_odometry,
        odometry_edges,
        odometry_heading_spread,
        odometry_steps,
    )

    for seed in (5, 6, 7):
        rng = np.random.default_rng(seed)
        truth, _ = _sparse_square(rng)
        nodes = truth + rng.normal(0.0, [0.01, 0.01, 0.005], truth.shape)
        steady = _drifting_odometry(truth, rng)
        slipping, o = [truth[0]], Pose2D(*truth[0])
        for a, b in zip(truth[:-1], truth[1:], strict=True):
            d = Pose2D(*b).relative_to(Pose2D(*a))
            o = o.compose(Pose2D(d.x, d.y, d.yaw + rng.uniform(-0.1, 0.1)))
            slipping.append(o.as_array())

        spreads = []
        for odom in (steady, np.array(slipping)):
            steps = odometry_steps(odom)
            z, sigma = odometry_edges(steps, (0.02, 0.05, 0.005), calibrate_odometry(nodes, steps))
            spreads.append(odometry_heading_spread(nodes, z, sigma))
        assert spreads[0] == pytest.approx(1.0)
        assert spreads[1] > 3.0
