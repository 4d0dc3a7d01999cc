"""The ports of Nav2's condition nodes (:mod:`agv_mission.behaviors.nav2_conditions`): the
path's validity, the goal's updates and arrival, progress, error codes, timers."""

from __future__ import annotations

from typing import Any, ClassVar, Literal

from pydantic import Field

from agv_mission.behaviors.ports.nav2 import Frames, ignored, read
from agv_mission.behaviors.ports.node import (
    ConditionPorts,
    NodePorts,
    output_port,
)

NAV2_CONDITIONS = "agv_mission.behaviors.nav2_conditions"


class _PathCheckPorts(NodePorts):
    path: str = read("the path's entry")
    max_cost: Any = Field(None, description="accepted: lethal or inscribed cells block")
    consider_unknown_as_obstacle: bool = Field(False, description="accepted")
    layer_name: Any = ignored()
    footprint: Any = ignored()
    check_full_path: Any = Field(None, description="accepted: the path ahead is checked")
    stop_at_first_collision: Any = Field(None, description="accepted")
    max_lookahead_distance: Any = Field(None, description="accepted")
    service_name: Any = ignored()
    server_timeout: Any = ignored()
    collision_poses: str | None = output_port("entry written with the blocked points", None)


class ValidatePathPorts(_PathCheckPorts):
    """Succeeds when the path ahead of the robot is free on the costmap (Nav2's
    ValidatePath)."""

    plugin: ClassVar[str] = f"{NAV2_CONDITIONS}:ValidatePath"
    type: Literal["validate_path"]
    xml_id: ClassVar[str | None] = "ValidatePath"
    example: ClassVar[dict[str, Any] | None] = None


class IsPathValidPorts(_PathCheckPorts, ConditionPorts):
    """The path ahead of the robot is free on the costmap (Nav2's IsPathValid)."""

    plugin: ClassVar[str] = f"{NAV2_CONDITIONS}:IsPathValid"
    type: Literal["is_path_valid"]
    xml_id: ClassVar[str | None] = "IsPathValid"
    example: ClassVar[dict[str, Any] | None] = None


class _GoalWatchPorts(ConditionPorts):
    goal: str = read("the goal's entry", "goal")
    goals: str = read("the goals' entry", "goals")


class GoalUpdatedPorts(_GoalWatchPorts):
    """The goal (or goals) changed since it was first ticked (Nav2's GoalUpdated)."""

    plugin: ClassVar[str] = f"{NAV2_CONDITIONS}:GoalUpdatedCondition"
    type: Literal["goal_updated"]
    xml_id: ClassVar[str | None] = "GoalUpdated"


class GlobalUpdatedGoalPorts(_GoalWatchPorts):
    """The goal (or goals) changed since it was last ticked (Nav2's GlobalUpdatedGoal)."""

    plugin: ClassVar[str] = f"{NAV2_CONDITIONS}:GlobalUpdatedGoal"
    type: Literal["global_updated_goal"]
    xml_id: ClassVar[str | None] = "GlobalUpdatedGoal"


class GoalReachedPorts(ConditionPorts, Frames):
    """The robot's estimate is within the goal tolerance of the goal (Nav2's GoalReached)."""

    plugin: ClassVar[str] = f"{NAV2_CONDITIONS}:GoalReached"
    type: Literal["goal_reached"]
    xml_id: ClassVar[str | None] = "GoalReached"
    goal: str = read("the goal's entry", "goal")


class IsStuckPorts(ConditionPorts):
    """The robot is driving a goal but has made no progress for half the progress timeout
    (Nav2's IsStuck)."""

    plugin: ClassVar[str] = f"{NAV2_CONDITIONS}:IsStuck"
    type: Literal["is_stuck"]
    xml_id: ClassVar[str | None] = "IsStuck"


class IsGoalNearbyPorts(ConditionPorts, Frames):
    """What is left of the path is shorter than ``proximity_threshold`` (Nav2's
    IsGoalNearby)."""

    plugin: ClassVar[str] = f"{NAV2_CONDITIONS}:IsGoalNearby"
    type: Literal["is_goal_nearby"]
    xml_id: ClassVar[str | None] = "IsGoalNearby"
    example: ClassVar[dict[str, Any] | None] = None
    path: str = read("the path's entry")
    proximity_threshold: float = Field(1.0, description="m")
    max_robot_pose_search_dist: Any = Field(None, description="accepted")


class _ErrorCodePorts(ConditionPorts):
    error_code: str = read("the entry with the error code (missing: 0, none)")
    error_codes_to_check: Any = Field(None, description="codes that count (a list or '1,2')")


class WouldAControllerRecoveryHelpPorts(_ErrorCodePorts):
    """The controller's error code is one a recovery may help (100, 104, 105, 106)."""

    plugin: ClassVar[str] = f"{NAV2_CONDITIONS}:WouldAControllerRecoveryHelp"
    type: Literal["would_a_controller_recovery_help"]
    xml_id: ClassVar[str | None] = "WouldAControllerRecoveryHelp"
    example: ClassVar[dict[str, Any] | None] = None


class WouldAPlannerRecoveryHelpPorts(_ErrorCodePorts):
    """The planner's error code is one a recovery may help (200, 207, 208, 300, 307, 308)."""

    plugin: ClassVar[str] = f"{NAV2_CONDITIONS}:WouldAPlannerRecoveryHelp"
    type: Literal["would_a_planner_recovery_help"]
    xml_id: ClassVar[str | None] = "WouldAPlannerRecoveryHelp"
    example: ClassVar[dict[str, Any] | None] = None


class WouldASmootherRecoveryHelpPorts(_ErrorCodePorts):
    """The smoother's error code is one a recovery may help (500, 502, 503, 504)."""

    plugin: ClassVar[str] = f"{NAV2_CONDITIONS}:WouldASmootherRecoveryHelp"
    type: Literal["would_a_smoother_recovery_help"]
    xml_id: ClassVar[str | None] = "WouldASmootherRecoveryHelp"
    example: ClassVar[dict[str, Any] | None] = None


class AreErrorCodesPresentPorts(_ErrorCodePorts):
    """The error code is one of ``error_codes_to_check`` (Nav2's AreErrorCodesPresent)."""

    plugin: ClassVar[str] = f"{NAV2_CONDITIONS}:AreErrorCodesPresent"
    type: Literal["are_error_codes_present"]
    xml_id: ClassVar[str | None] = "AreErrorCodesPresent"
    example: ClassVar[dict[str, Any] | None] = None


class TimeExpiredPorts(ConditionPorts):
    """Succeeds once every ``seconds`` of simulated time (Nav2's TimeExpired)."""

    plugin: ClassVar[str] = f"{NAV2_CONDITIONS}:TimeExpired"
    type: Literal["time_expired"]
    xml_id: ClassVar[str | None] = "TimeExpired"
    seconds: float = Field(1.0, gt=0.0, description="simulated seconds")


class PathExpiringTimerPorts(ConditionPorts):
    """Succeeds when ``seconds`` passed since the path last changed (Nav2's
    PathExpiringTimer)."""

    plugin: ClassVar[str] = f"{NAV2_CONDITIONS}:PathExpiringTimer"
    type: Literal["path_expiring_timer"]
    xml_id: ClassVar[str | None] = "PathExpiringTimer"
    example: ClassVar[dict[str, Any] | None] = None
    seconds: float = Field(1.0, gt=0.0, description="simulated seconds")
    path: str = read("the path's entry")


class DistanceTraveledPorts(ConditionPorts, Frames):
    """Succeeds once every ``distance`` metres driven (Nav2's DistanceTraveled)."""

    plugin: ClassVar[str] = f"{NAV2_CONDITIONS}:DistanceTraveled"
    type: Literal["distance_traveled"]
    xml_id: ClassVar[str | None] = "DistanceTraveled"
    distance: float = Field(1.0, gt=0.0, description="m")


class TransformAvailablePorts(ConditionPorts):
    """Succeeds: every frame of the simulated robot is always available."""

    plugin: ClassVar[str] = f"{NAV2_CONDITIONS}:TransformAvailable"
    type: Literal["transform_available"]
    xml_id: ClassVar[str | None] = "TransformAvailable"
    child: Any = ignored()
    parent: Any = ignored()
