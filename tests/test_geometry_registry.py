"""Geometry helpers and the plugin registry."""

from __future__ import annotations

import math

import pytest

from agv_mission.geometry import Pose2D, quaternion_from_yaw, wrap_angle, yaw_from_quaternion
from agv_mission.registry import UnknownPluginError, registry


@pytest.mark.parametrize("yaw", [-3.0, -1.0, 0.0, 0.5, 2.9])
def test_quaternion_round_trip(yaw: float) -> None:
    assert yaw_from_quaternion(*quaternion_from_yaw(yaw)) == pytest.approx(yaw)


def test_wrap_angle() -> None:
    assert wrap_angle(3 * math.pi / 2) == pytest.approx(-math.pi / 2)
    assert -math.pi <= wrap_angle(math.pi) < math.pi


def test_compose_and_relative_are_inverse() -> None:
    a, b = Pose2D(1.0, 2.0, 0.7), Pose2D(-0.3, 0.4, -2.0)
    c = a.compose(b)
    back = c.relative_to(a)
    assert (back.x, back.y, back.yaw) == pytest.approx((b.x, b.y, b.yaw))


def test_registry_serves_every_builtin_slot() -> None:
    assert {"ground_truth", "odometry"} <= set(registry.names("localization"))
    assert {"cost_grid", "ompl", "grid_astar"} <= set(registry.names("global_planner"))
    assert {"mpc", "pure_pursuit"} <= set(registry.names("local_planner"))
    with pytest.raises(UnknownPluginError, match="known: cost_grid, grid_astar, ompl"):
        registry.get("global_planner", "dijkstra")


def test_a_new_plugin_is_one_class_and_one_line() -> None:
    from typing import Literal

    from agv_mission.registry import PluginConfig, Registry

    reg = Registry()

    class NullConfig(PluginConfig):
        type: Literal["null"] = "null"

    @reg.register("local_planner", "null")
    class NullController:
        Config = NullConfig

        def __init__(self, config: NullConfig) -> None:
            self.config = config

    made = reg.create("local_planner", NullConfig())
    assert isinstance(made, NullController)


def test_driven_follows_the_arc_of_a_constant_command() -> None:
    start = Pose2D(1.0, -2.0, 0.3)
    straight = start.driven(0.5, 0.0, 2.0)
    assert straight.distance_to(start) == pytest.approx(1.0)
    assert straight.yaw == pytest.approx(start.yaw, abs=1e-12)
    pose = start  # a full turn on a circle of radius v / w comes back to the start
    for _ in range(100):
        pose = pose.driven(0.2, 2.0 * math.pi / 10.0, 0.1)
    assert pose.distance_to(start) < 1e-9 and abs(pose.heading_error_to(start)) < 1e-9
    half = Pose2D(0.0, 0.0, 0.0).driven(0.5, 0.5, 2.0 * math.pi)  # radius 1, half a circle
    assert (half.x, half.y) == pytest.approx((0.0, 2.0), abs=1e-12)
