"""Local planners in closed loop with an exact unicycle integration (the test harness).

Real casadi/fatrop solves; no MuJoCo. No timing assertions (see benchmarks/bench_mpc.py).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from agv_mission.geometry import Pose2D
from agv_mission.planners.base import VelocityLimits
from agv_mission.planners.mpc import MpcConfig, MpcController
from agv_mission.planners.path_follower import ProgressTracker
from agv_mission.planners.path_tracking import (
    ReferenceProfile,
    closest_point,
    cumulative_length,
    interpolate,
)
from agv_mission.planners.pure_pursuit import PurePursuitConfig, PurePursuitController

PERIOD = 0.1
LIMITS = VelocityLimits(max_v=0.26, max_w=1.82, max_acc_v=1.0, max_acc_w=3.0)
RADIUS = 0.2
L_PATH = np.array([[0.0, 0.0], [1.5, 0.0], [1.5, 1.2]])
NO_POINTS = np.zeros((0, 2))


def closed_loop(controller, path, start, obstacles=NO_POINTS, max_steps=400):
    """Run until stopped at the goal; returns poses (n+1, 3) and commands (n, 2) and oks."""
    goal = Pose2D(float(path[-1][0]), float(path[-1][1]))
    pose, vel = start, (0.0, 0.0)
    poses, cmds, oks = [pose.as_array()], [], []
    controller.reset()
    for _ in range(max_steps):
        cmd = controller.compute(pose, vel, path, goal, obstacles)
        cmds.append((cmd.v, cmd.w))
        oks.append(cmd.ok)
        pose = pose.driven(cmd.v, cmd.w, PERIOD)
        vel = (cmd.v, cmd.w)
        poses.append(pose.as_array())
        if pose.distance_to(goal) < 0.05 and cmd.v == 0.0 and cmd.w == 0.0:
            break
    return np.array(poses), np.array(cmds), np.array(oks)


def assert_within_limits(cmds: np.ndarray) -> None:
    eps = 1e-9
    v, w = cmds[:, 0], cmds[:, 1]
    assert np.all(v >= -eps), "reversed"
    assert np.all(v <= LIMITS.max_v + eps)
    assert np.all(np.abs(w) <= LIMITS.max_w + eps)
    dv = np.abs(np.diff(np.concatenate(([0.0], v))))
    dw = np.abs(np.diff(np.concatenate(([0.0], w))))
    assert dv.max() <= LIMITS.max_acc_v * PERIOD + 1e-6
    assert dw.max() <= LIMITS.max_acc_w * PERIOD + 1e-6


def assert_stopped_at_goal(poses: np.ndarray, cmds: np.ndarray, path: np.ndarray) -> None:
    goal = path[-1]
    assert np.linalg.norm(poses[-1, :2] - goal) < 0.05
    assert cmds[-1, 0] == 0.0 and cmds[-1, 1] == 0.0
    # No overshoot beyond the goal along the last segment.
    last = (path[-1] - path[-2]) / np.linalg.norm(path[-1] - path[-2])
    final_leg = poses[np.linalg.norm(poses[:, :2] - goal, axis=1) < 0.5, :2]
    assert np.max((final_leg - goal) @ last) < 0.02


def circle_points(center, radius, n=24):
    a = np.linspace(0.0, 2.0 * np.pi, n, endpoint=False)
    return np.column_stack((center[0] + radius * np.cos(a), center[1] + radius * np.sin(a)))


@pytest.fixture(scope="module")
def mpc() -> MpcController:
    return MpcController(MpcConfig(), LIMITS, RADIUS, PERIOD)


# -- path_tracking helpers ------------------------------------------------------------------


def test_closest_point_and_interpolation():
    cum = cumulative_length(L_PATH)
    proj = closest_point(L_PATH, (1.7, 0.5), cum)
    assert proj.s == pytest.approx(2.0)
    assert proj.distance == pytest.approx(0.2)
    pts, headings = interpolate(L_PATH, cum, np.array([0.5, 2.0, 99.0]))
    np.testing.assert_allclose(pts, [[0.5, 0.0], [1.5, 0.5], [1.5, 1.2]])
    np.testing.assert_allclose(headings, [0.0, math.pi / 2, math.pi / 2])
    # A window keeps the projection on the part of the path near the previous progress.
    loop = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 0.3], [0.0, 0.3]])
    assert closest_point(loop, (0.5, 0.14), s_max=1.0).s == pytest.approx(0.5)


def test_reference_profile_accelerates_and_stops_at_the_end():
    cum = cumulative_length(L_PATH)
    profile = ReferenceProfile(L_PATH, cum, 0.26, 1.82, 1.0, 0.5)
    s, v = map(np.array, profile.sample(0.0, 0.0, 30, 0.1))
    assert v[0] == 0.0 and np.all(np.diff(v[:4]) > 0)
    assert np.all(np.diff(v) <= 1.0 * 0.1 + 1e-9) and v.max() <= 0.26 + 1e-9
    # Slower through the corner (1.5 m along) than on the straight before it.
    assert profile.speed_sq[round(1.5 / profile.step)] < 0.25**2
    assert profile.speed_sq[round(0.5 / profile.step)] == pytest.approx(0.26**2)
    s_end, v_end = map(np.array, profile.sample(cum[-1] - 0.05, 0.1, 20, 0.1))
    assert v_end[-1] < 0.02 and s_end[-1] <= cum[-1] + 1e-9 and np.all(np.diff(s_end) >= 0)
    points = [profile.point(s) for s in (0.5, 2.0, 99.0)]
    np.testing.assert_allclose(
        points, [[0.5, 0.0, 0.0], [1.5, 0.5, math.pi / 2], [1.5, 1.2, math.pi / 2]]
    )
    # In the robot's frame: (1, 0) facing +y sees the corner ahead-left, the path heading
    # as relative yaw.
    rows = profile.in_frame([0.5, 2.0], [0.1, 0.2], Pose2D(1.0, 0.0, math.pi / 2))
    np.testing.assert_allclose(rows, [0.0, 0.5, -math.pi / 2, 0.1, 0.5, -0.5, 0.0, 0.2], atol=1e-12)


def test_reference_headings_are_continuous_along_the_path():
    # A path that winds one and a half turns: headings keep growing, no 2 pi jumps.
    angles = np.linspace(0.0, 3.0 * math.pi, 60)
    spiral = np.column_stack((np.cos(angles), np.sin(angles))) * (1.0 + angles[:, None] / 10)
    profile = ReferenceProfile(spiral, cumulative_length(spiral), 0.26, 1.82, 1.0, 0.5)
    headings = np.array([profile.point(s)[2] for s in np.linspace(0.0, profile.total, 200)])
    assert np.all(np.diff(headings) >= 0.0) and headings[-1] - headings[0] > 2.5 * math.pi


def test_progress_window_agrees_with_closest_point_on_the_window():
    rng = np.random.default_rng(3)
    path = np.cumsum(rng.normal(0.0, 0.2, (40, 2)), axis=0)
    cum = cumulative_length(path)
    tracker = ProgressTracker(window_back=0.3, window_ahead=0.5)
    for _ in range(200):
        tracker.reset()
        progress = tracker.update(path, cum, path[0])
        assert progress == 0.0
        tracker.progress = progress = float(rng.uniform(0.0, cum[-1]))
        point = path[rng.integers(len(path))] + rng.normal(0.0, 0.3, 2)
        expected = closest_point(path, point, cum, s_min=progress - 0.3, s_max=progress + 0.5)
        assert tracker.update(path, cum, point) == pytest.approx(
            max(expected.s, progress - 0.05), abs=1e-9
        )


def test_mpc_obstacle_slots_hold_the_nearest_points_of_each_stage():
    ctrl = MpcController(MpcConfig(obstacles_per_stage=2), LIMITS, RADIUS, PERIOD)
    rng = np.random.default_rng(5)
    pose = Pose2D(1.0, -2.0, 0.7)
    points = np.column_stack((pose.x, pose.y)) + rng.uniform(-1.5, 1.5, (300, 2))
    stages = np.column_stack((np.linspace(0.0, 0.5, 19), np.zeros(19)))  # robot frame
    nearest = ctrl._stage_obstacles(points, stages, pose)
    c, s = math.cos(pose.yaw), math.sin(pose.yaw)
    rel = points - (pose.x, pose.y)
    local = np.column_stack((c * rel[:, 0] + s * rel[:, 1], c * rel[:, 1] - s * rel[:, 0]))
    slots = ctrl._obs
    for k, stage in enumerate(stages):
        d2 = ((local - stage) ** 2).sum(axis=1)
        order = np.argsort(d2)[:2]
        np.testing.assert_allclose(np.sort(slots[k], axis=0), np.sort(local[order], axis=0))
        assert nearest[k] == pytest.approx(d2[order[0]])
    # Points beyond obstacle_range of every stage are parked far away, not constraints.
    far = np.array([[pose.x + 5.0, pose.y + 5.0]])
    assert np.isinf(ctrl._stage_obstacles(far, stages, pose)).all()
    assert np.all(np.abs(ctrl._obs) >= 49.0)


# -- MPC ------------------------------------------------------------------------------------


def test_mpc_follows_l_path_and_stops_at_goal(mpc):
    poses, cmds, oks = closed_loop(mpc, L_PATH, Pose2D(0.0, 0.0, 0.0))
    assert oks.all()
    assert_within_limits(cmds)
    assert_stopped_at_goal(poses, cmds, L_PATH)


def test_mpc_turns_in_place_when_path_is_behind(mpc):
    poses, cmds, oks = closed_loop(mpc, L_PATH, Pose2D(0.0, 0.0, math.pi))
    assert oks.all()
    assert_within_limits(cmds)
    assert_stopped_at_goal(poses, cmds, L_PATH)


def test_mpc_keeps_clear_of_lidar_points_near_the_path(mpc):
    path = np.array([[0.0, 0.0], [2.0, 0.0]])
    points = circle_points((1.0, 0.22), 0.06)  # nearest point 0.16 m from the path
    poses, cmds, oks = closed_loop(mpc, path, Pose2D(0.0, 0.0, 0.0), points)
    clearance = np.linalg.norm(poses[:, None, :2] - points[None], axis=2).min()
    assert clearance > RADIUS
    assert oks.all()
    assert_within_limits(cmds)
    assert_stopped_at_goal(poses, cmds, path)


def test_mpc_removes_a_lateral_offset_at_the_goal(mpc):
    path = np.array([[0.0, 0.0], [1.0, 0.0]])
    poses, cmds, oks = closed_loop(mpc, path, Pose2D(1.0, 0.04, 0.0))
    assert oks.all()
    assert_within_limits(cmds)
    assert np.linalg.norm(poses[-1, :2] - path[-1]) < 0.03
    assert cmds[-1, 0] == 0.0 and cmds[-1, 1] == 0.0


def test_mpc_settles_when_a_wall_keeps_it_off_the_goal(mpc):
    """Goal 0.23 m from a wall, margin wants 0.25 m: stop close by, no turning back and forth."""
    path = np.array([[0.0, 0.0], [1.0, 0.0]])
    wall = np.column_stack((np.linspace(0.5, 2.5, 201), np.full(201, 0.23)))
    poses, cmds, oks = closed_loop(mpc, path, Pose2D(0.0, 0.0, 0.0), wall, max_steps=200)
    assert oks.all()
    assert np.linalg.norm(poses[-1, :2] - path[-1]) < 0.03
    assert np.abs(cmds[100:, 1]).sum() * PERIOD < 0.1  # settled, no limit cycle
    assert np.linalg.norm(poses[:, None, :2] - wall[None], axis=2).min() > RADIUS


def test_mpc_without_obstacle_constraints():
    ctrl = MpcController(MpcConfig(max_obstacles=0, horizon=10), LIMITS, RADIUS, PERIOD)
    poses, cmds, oks = closed_loop(ctrl, L_PATH, Pose2D(0.0, 0.0, 0.0))
    assert oks.all()
    assert_stopped_at_goal(poses, cmds, L_PATH)


def test_mpc_returns_ok_with_prediction(mpc):
    mpc.reset()
    cmd = mpc.compute(Pose2D(0.0, 0.0, 0.0), (0.0, 0.0), L_PATH, Pose2D(1.5, 1.2), NO_POINTS)
    assert cmd.ok
    assert 0.0 < cmd.v <= LIMITS.max_acc_v * PERIOD + 1e-9
    assert cmd.predicted is not None and cmd.predicted.shape == (mpc.config.horizon + 1, 2)
    assert np.allclose(cmd.predicted[0], [0.0, 0.0])
    assert np.all(cmd.predicted[1:, 0] > 0.0)  # heads along the path


def test_mpc_warm_start_needs_no_more_iterations(mpc):
    points = circle_points((1.0, 0.3), 0.06)
    mpc.reset()
    goal = Pose2D(1.5, 1.2)
    pose, vel = Pose2D(0.3, 0.02, 0.05), (0.2, 0.0)
    cmd = mpc.compute(pose, vel, L_PATH, goal, points)
    cold = mpc.last_stats["iter_count"]
    pose = pose.driven(cmd.v, cmd.w, PERIOD)
    cmd = mpc.compute(pose, (cmd.v, cmd.w), L_PATH, goal, points)
    warm = mpc.last_stats["iter_count"]
    assert cmd.ok
    assert warm <= cold


def test_mpc_solver_failure_brakes_with_ok_false():
    cfg = MpcConfig(solver="fatrop", solver_options={"max_iter": 1})
    ctrl = MpcController(cfg, LIMITS, RADIUS, PERIOD)
    cmd = ctrl.compute(Pose2D(0.0, 0.0, 0.0), (0.2, 0.5), L_PATH, Pose2D(1.5, 1.2), NO_POINTS)
    assert not cmd.ok
    assert cmd.v == pytest.approx(0.2 - LIMITS.max_acc_v * PERIOD)
    assert cmd.w == pytest.approx(0.5 - LIMITS.max_acc_w * PERIOD)


def test_mpc_with_ipopt_solves():
    ctrl = MpcController(MpcConfig(solver="ipopt"), LIMITS, RADIUS, PERIOD)
    cmd = ctrl.compute(Pose2D(0.0, 0.0, 0.0), (0.0, 0.0), L_PATH, Pose2D(1.5, 1.2), NO_POINTS)
    assert cmd.ok and cmd.v > 0.0


def test_mpc_fatrop_and_rti_agree_on_the_first_command():
    """The real-time iteration (3 SQP steps from a cold start) lands near the NLP optimum."""
    pose, vel, goal = Pose2D(0.3, 0.02, 0.05), (0.2, 0.0), Pose2D(1.5, 1.2)
    points = circle_points((1.0, 0.3), 0.06)
    cmds = []
    for solver in ("rti", "fatrop"):
        ctrl = MpcController(MpcConfig(solver=solver), LIMITS, RADIUS, PERIOD)
        cmd = ctrl.compute(pose, vel, L_PATH, goal, points)
        assert cmd.ok
        cmds.append((cmd.v, cmd.w))
    assert cmds[0] == pytest.approx(cmds[1], abs=0.02)


def test_mpc_config_rejects_unknown_keys():
    with pytest.raises(ValueError):
        MpcConfig(horizon=20, horizont=10)
    assert MpcConfig.model_validate({"type": "mpc"}).solver == "rti"


# -- pure pursuit ---------------------------------------------------------------------------


@pytest.mark.parametrize("yaw", [0.0, math.pi])
def test_pure_pursuit_follows_l_path_and_stops_at_goal(yaw):
    ctrl = PurePursuitController(PurePursuitConfig(), LIMITS, RADIUS, PERIOD)
    poses, cmds, oks = closed_loop(ctrl, L_PATH, Pose2D(0.0, 0.0, yaw))
    assert oks.all()
    assert_within_limits(cmds)
    assert_stopped_at_goal(poses, cmds, L_PATH)


def test_mpc_rti_functions_are_cached_on_disk(tmp_path, monkeypatch):
    from agv_mission.planners import mpc_problem

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    cfg = MpcConfig(horizon=8)
    built = mpc_problem.MpcProblem(cfg, LIMITS)
    files = list((tmp_path / "agv-mission" / "mpc").glob("*.casadi"))
    assert len(files) == 1
    loaded = mpc_problem.MpcProblem(cfg, LIMITS)
    assert loaded.rti_fn is not built.rti_fn
    controls = np.zeros((cfg.horizon, 3))
    p = np.zeros(built.n_params)
    p[built.p_ref] = np.linspace(0.0, 1.0, 4 * (cfg.horizon + 1))
    p[-4:] = (0.07, 1.0, 1.0, 1.0)
    steps = [mpc_problem.RtiStep(f).step(controls, p, 1) for f in (built.rti_fn, loaded.rti_fn)]
    for a, b in zip(*steps, strict=True):
        assert np.allclose(a, b)
    assert np.abs(steps[0][1]).max() > 0.0  # the step moved the controls
