"""diff_tf-style odometry, exact arc integration."""

from __future__ import annotations

import math

import pytest

from agv_mission.geometry import Pose2D
from agv_mission.robots.odometry import DiffDriveOdometry

TPM = 1000.0
WIDTH = 0.2


def test_first_update_sets_baseline():
    odo = DiffDriveOdometry(TPM, WIDTH, Pose2D(1.0, 2.0, 0.5))
    assert odo.update(12345, -678) == Pose2D(1.0, 2.0, 0.5)
    odo.update(12345 + 1000, -678 + 1000)
    assert odo.pose.x == pytest.approx(1.0 + math.cos(0.5))
    assert odo.pose.y == pytest.approx(2.0 + math.sin(0.5))
    assert odo.pose.yaw == pytest.approx(0.5)


def test_turn_in_place():
    odo = DiffDriveOdometry(TPM, WIDTH, initial_ticks=(0, 0))
    # dth = (dr - dl) / width = (0.1 + 0.1) / 0.2 = 1 rad
    odo.update(-100, 100)
    assert odo.pose.yaw == pytest.approx(1.0)
    assert odo.pose.x == pytest.approx(0.0) and odo.pose.y == pytest.approx(0.0)


@pytest.mark.parametrize("steps", [1, 3, 50])
def test_arc_is_exact_at_any_update_rate(steps):
    # Quarter circle of radius 1: left wheel on radius 0.9, right on 1.1.
    odo = DiffDriveOdometry(TPM, WIDTH, initial_ticks=(0, 0))
    quarter = math.pi / 2
    for k in range(1, steps + 1):
        f = k / steps
        odo.update(round(0.9 * quarter * f * TPM), round(1.1 * quarter * f * TPM))
    p = odo.pose
    assert p.x == pytest.approx(1.0, abs=2e-3)
    assert p.y == pytest.approx(1.0, abs=2e-3)
    assert p.yaw == pytest.approx(quarter, abs=2e-3)


def test_reset_keeps_tick_baseline():
    odo = DiffDriveOdometry(TPM, WIDTH, initial_ticks=(0, 0))
    odo.update(500, 500)
    odo.reset(Pose2D(-1.0, 0.0, math.pi))
    odo.update(1500, 1500)
    assert odo.pose.x == pytest.approx(-2.0)
    assert odo.pose.y == pytest.approx(0.0, abs=1e-12)
    assert odo.distance == pytest.approx(1.5)


def test_rejects_bad_parameters():
    with pytest.raises(ValueError):
        DiffDriveOdometry(0.0, WIDTH)
