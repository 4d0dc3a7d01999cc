"""The ports of Nav2's decorators and of NavigateThroughPoses's navigator
(:mod:`agv_mission.behaviors.nav2_flow`)."""

from __future__ import annotations

from typing import Any, ClassVar, Literal

from pydantic import Field

from agv_mission.behaviors.ports.nav2 import Frames, read
from agv_mission.behaviors.ports.node import (
    DecoratorPorts,
    ErrorOutputs,
    NodePorts,
    RosPlumbing,
    output_port,
)
from agv_mission.behaviors.ports.values import Goal

NAV2_FLOW = "agv_mission.behaviors.nav2_flow"


class DistanceControllerPorts(DecoratorPorts, Frames):
    """Ticks its child at the start and after every ``distance`` metres driven."""

    plugin: ClassVar[str] = f"{NAV2_FLOW}:DistanceController"
    type: Literal["distance_controller"]
    xml_id: ClassVar[str | None] = "DistanceController"
    distance: float = Field(1.0, gt=0.0, description="m")


class SpeedControllerPorts(DecoratorPorts):
    """Ticks its child at a rate between ``min_rate`` and ``max_rate`` that grows with the
    robot's speed (Nav2's SpeedController)."""

    plugin: ClassVar[str] = f"{NAV2_FLOW}:SpeedController"
    type: Literal["speed_controller"]
    xml_id: ClassVar[str | None] = "SpeedController"
    min_rate: float = Field(0.1, gt=0.0, description="Hz")
    max_rate: float = Field(1.0, gt=0.0, description="Hz")
    min_speed: float = Field(0.0, ge=0.0, description="m/s")
    max_speed: float = Field(0.5, gt=0.0, description="m/s")
    goal: Any = Field(None, description="accepted")
    goals: Any = Field(None, description="accepted")


class GoalUpdaterPorts(DecoratorPorts):
    """Copies the goal to ``output_goal`` (no goal topic here), then ticks its child
    (Nav2's GoalUpdater)."""

    plugin: ClassVar[str] = f"{NAV2_FLOW}:GoalUpdater"
    type: Literal["goal_updater"]
    xml_id: ClassVar[str | None] = "GoalUpdater"
    example: ClassVar[dict[str, Any] | None] = None
    input_goal: str | None = read("the goal's entry", None)
    output_goal: str | None = output_port("entry written with the goal", None)
    input_goals: str | None = read("the goals' entry", None)
    output_goals: str | None = output_port("entry written with the goals", None)


class GoalUpdatedControllerPorts(DecoratorPorts):
    """Ticks its child at the start and whenever the goal changes (Nav2's
    GoalUpdatedController)."""

    plugin: ClassVar[str] = f"{NAV2_FLOW}:GoalUpdatedController"
    type: Literal["goal_updated_controller"]
    xml_id: ClassVar[str | None] = "GoalUpdatedController"
    goal: str = read("the goal's entry", "goal")
    goals: str = read("the goals' entry", "goals")


class PathLongerOnApproachPorts(DecoratorPorts):
    """Ticks its child when, within ``prox_len`` of the goal, a new path is more than
    ``length_factor`` times the old one; succeeds otherwise (Nav2's PathLongerOnApproach)."""

    plugin: ClassVar[str] = f"{NAV2_FLOW}:PathLongerOnApproach"
    type: Literal["path_longer_on_approach"]
    xml_id: ClassVar[str | None] = "PathLongerOnApproach"
    example: ClassVar[dict[str, Any] | None] = None
    path: str = read("the path's entry")
    prox_len: float = Field(3.0, gt=0.0, description="m")
    length_factor: float = Field(2.0, gt=0.0, description="new / old length")


class SingleTriggerPorts(DecoratorPorts):
    """Ticks its child until it ends once; fails afterwards (Nav2's SingleTrigger)."""

    plugin: ClassVar[str] = f"{NAV2_FLOW}:SingleTrigger"
    type: Literal["single_trigger"]
    xml_id: ClassVar[str | None] = "SingleTrigger"


class NavigateThroughPosesPorts(NodePorts, RosPlumbing, ErrorOutputs):
    """Drive through ``goals`` in order (Nav2's NavigateThroughPoses); with
    ``behavior_tree``, the goals are ``{goals}`` of that tree, which is run instead."""

    plugin: ClassVar[str] = f"{NAV2_FLOW}:NavigateThroughGoals"
    type: Literal["navigate_through_poses"]
    example: ClassVar[dict[str, Any] | None] = {"goals": [{"x": 2.0, "y": 2.0}]}
    goals: list[Goal] = Field(min_length=1, description="poses or room labels, in order")
    behavior_tree: str | None = Field(
        None,
        description="a BT.CPP XML file (e.g. one of Nav2's navigator trees), relative to "
        "the mission file, run with the goals as {goals}",
    )

    def goal_poses(self) -> list[tuple[tuple[str | int, ...], Any]]:
        from agv_mission.behaviors.ports.values import Pose

        return [(("goals", i), g) for i, g in enumerate(self.goals) if isinstance(g, Pose)]

    def rooms_visited(self) -> list[tuple[tuple[str | int, ...], str]]:
        return [(("goals", i), g) for i, g in enumerate(self.goals) if isinstance(g, str)]
