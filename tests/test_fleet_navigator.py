"""The navigator obeys the traffic layer's orders (the narrow interface the run hands it):
``wait`` holds it without a 'no progress' recovery, ``go`` with a limit slows it to stop
in time, ``yield`` takes it to the detour and back to its goal, ``replan`` plans round
the avoided cells. The navigator is the real one of a mission's robot stack."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from agv_mission.fleet.base import TrafficDecision
from agv_mission.geometry import Pose2D
from agv_mission.missions.load.loader import load_mission
from agv_mission.missions.run.stack import build_world
from agv_mission.navigation.navigator import NavStatus
from agv_mission.navigation.state import RobotState

WORLDS = Path(__file__).parent / "worlds"
START, GOAL = Pose2D(-4.5, 0.0, 0.0), Pose2D(4.5, 0.0, 0.0)


def _navigator(tmp_path):
    path = tmp_path / "one.yaml"
    path.write_text(
        f"name: one\nworld: {WORLDS / 'fleet_aisle.yaml'}\nrobot: burger\n"
        f"start: {{x: {START.x}, y: {START.y}, yaw: 0.0}}\n"
        "stack: {localization: {type: ground_truth}, local_planner: {type: pure_pursuit}}\n"
        "tasks: [{type: go_to, pose: {x: 4.5, y: 0.0}}]\n"
    )
    _, stacks, _ = build_world(load_mission(path))
    nav = stacks[0].build_navigator()
    state = RobotState(time=0.0, estimate=START, velocity=(0.2, 0.0))
    nav.start(GOAL, state)
    return nav, state


def test_wait_holds_the_robot_with_no_recovery_however_long(tmp_path):
    nav, state = _navigator(tmp_path)
    timeout = nav.config.progress_timeout
    plans = nav.stats.plans
    for k in range(int(3 * timeout / 0.1)):
        state.time = 0.1 * k
        nav.obey(TrafficDecision("wait", limit=0.0, blocker="other"), state)
        cmd = nav.update(state)
        assert (cmd.v, cmd.w) == (0.0, 0.0)
    assert nav.status is NavStatus.RUNNING and nav.stats.plans == plans
    assert nav.traffic_path() is not None  # the plan is kept and still reserved


def test_go_with_a_limit_slows_to_stop_within_it(tmp_path):
    nav, state = _navigator(tmp_path)
    free = nav.update(state)
    assert free.v > 0.1
    nav.obey(TrafficDecision("go", limit=0.05, blocker="other"), state)
    limited = nav.update(state)
    a, dt, v = nav.limits.max_acc_v, nav.control_period, limited.v
    assert 0.0 < v < free.v
    assert v * dt + v * v / (2 * a) <= 0.05 + 1e-9  # a period at v, then braking: in time


def test_yield_drives_to_the_detour_holds_there_and_resumes_the_goal(tmp_path):
    nav, state = _navigator(tmp_path)
    detour = Pose2D(-4.5, 1.0, math.pi / 2)  # in the west room, off the aisle's line
    nav.obey(TrafficDecision("yield", detour=detour, blocker="other"), state)
    assert nav.yielding and nav.traffic_path() is not None
    assert np.hypot(*(nav.traffic_path()[-1] - (detour.x, detour.y))) < 0.05
    cmd = nav.update(state)
    assert cmd.v != 0.0 or cmd.w != 0.0  # on its way
    state.estimate = detour
    assert (nav.update(state).v, nav.update(state).w) == (0.0, 0.0)  # there: holds
    nav.obey(None, state)  # released
    assert not nav.yielding and nav.status is NavStatus.RUNNING
    assert np.hypot(*(nav.traffic_path()[-1] - (GOAL.x, GOAL.y))) < 0.05


def test_replan_keeps_out_of_the_avoided_cells_or_keeps_its_plan(tmp_path):
    nav, state = _navigator(tmp_path)
    before = nav.traffic_path().copy()
    # a body in the middle of the west room, on the straight way to the aisle
    xs, ys = np.meshgrid(np.arange(-3.9, -3.4, 0.05), np.arange(-0.25, 0.25, 0.05))
    avoid = np.column_stack([xs.ravel(), ys.ravel()])
    nav.obey(TrafficDecision("replan", avoid=avoid, blocker="other"), state)
    after = nav.traffic_path()
    assert not np.array_equal(before, after)
    near = np.min(
        np.hypot(after[:, None, 0] - avoid[None, :, 0], after[:, None, 1] - avoid[None, :, 1])
    )
    assert near > nav.costmap.robot_radius
    # the aisle itself avoided: no way round; the plan stays as it was
    aisle = np.column_stack([np.arange(-2.0, 2.0, 0.05), np.zeros(80)])
    nav.obey(TrafficDecision("replan", avoid=aisle, blocker="other"), state)
    assert np.array_equal(nav.traffic_path(), after) and nav.status is NavStatus.RUNNING
