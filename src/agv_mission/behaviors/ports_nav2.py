"""The ports of Nav2's behaviour tree nodes (``nav2_behavior_tree/nav2_tree_nodes.xml``,
Humble, Jazzy and Rolling: the union of their ports), as node types of ours.

Ports that carry data between nodes (a goal, goals, a path, an error code) name the
blackboard entry the node reads every tick (``path="{path}"``), as Nav2's trees write
them; ports that name ROS plumbing (servers, services, topics, frames) are accepted and
ignored; ``planner_id`` / ``controller_id`` pick among the mission's configured planner
and controller (one each: any other name means the configured one, as Nav2's default
does). Spin, Wait, BackUp and ClearEntireCostmap are our ``spin``, ``wait``, ``back_up``
and ``clear_costmap`` (:mod:`agv_mission.behaviors.ports`); RecoveryNode, PipelineSequence,
RoundRobin, RateController, IsBatteryLow and IsBatteryCharging are ours too.
"""

from __future__ import annotations

from typing import Any, ClassVar, Literal

from pydantic import Field

from agv_mission.behaviors.ports import (
    ConditionPorts,
    DecoratorPorts,
    ErrorOutputs,
    Goal,
    NodePorts,
    RosPlumbing,
    StrictModel,
    entry_port,
    output_port,
)

_IGNORED = "ROS plumbing (Nav2): accepted and ignored"
NAV2 = "agv_mission.behaviors.nav2"
NAV2_FLOW = "agv_mission.behaviors.nav2_flow"


def ignored() -> Any:
    return Field(None, description=_IGNORED)


def read(description: str, default: Any = ...) -> Any:
    """A port naming the blackboard entry the node reads each tick (``{key}`` or key)."""
    return entry_port(description, default)


class Frames(StrictModel):
    """Nav2's frame and transform ports: one map frame here, accepted and ignored."""

    global_frame: Any = ignored()
    robot_base_frame: Any = ignored()
    robot_frame: Any = ignored()
    transform_tolerance: Any = ignored()


class Nav2Action(NodePorts, RosPlumbing):
    """A Nav2 action node (its XML ID is given)."""


# --------------------------------------------------------------------- planning


class ComputePathToPosePorts(Nav2Action, ErrorOutputs):
    """Plan from the robot (or ``start``) to ``goal`` with the mission's global planner and
    write the path (Nav2's ComputePathToPose)."""

    plugin: ClassVar[str] = f"{NAV2}:ComputePathToPose"
    type: Literal["compute_path_to_pose"]
    xml_id: ClassVar[str | None] = "ComputePathToPose"
    example: ClassVar[dict[str, Any] | None] = None
    goal: str = read("the goal's entry (a pose or a room label)")
    path: str = output_port("entry written with the path")
    start: str | None = read("an entry with the start pose (with use_start)", None)
    use_start: bool = Field(False, description="plan from `start` rather than the robot")
    planner_id: str = Field("", description="a configured planner's type (else the default)")
    viapoints: Any = Field(None, description="Nav2's via-points: accepted and ignored")


class ComputePathThroughPosesPorts(Nav2Action, ErrorOutputs):
    """Plan through ``goals`` in order (Nav2's ComputePathThroughPoses)."""

    plugin: ClassVar[str] = f"{NAV2}:ComputePathThroughPoses"
    type: Literal["compute_path_through_poses"]
    xml_id: ClassVar[str | None] = "ComputePathThroughPoses"
    example: ClassVar[dict[str, Any] | None] = None
    goals: str = read("the goals' entry")
    path: str = output_port("entry written with the path")
    start: str | None = read("an entry with the start pose (with use_start)", None)
    use_start: bool = Field(False, description="plan from `start` rather than the robot")
    planner_id: str = Field("", description="a configured planner's type (else the default)")
    last_reached_index: str | None = output_port("entry written with -1 (none skipped)", None)


class FollowPathPorts(Nav2Action, ErrorOutputs):
    """Drive along the path with the mission's controller until its end pose is reached
    (Nav2's FollowPath); a new path in the entry replaces the one followed."""

    plugin: ClassVar[str] = f"{NAV2}:FollowPath"
    type: Literal["follow_path"]
    xml_id: ClassVar[str | None] = "FollowPath"
    example: ClassVar[dict[str, Any] | None] = None
    path: str = read("the path's entry")
    controller_id: str = Field("", description="a configured controller's type (else the default)")
    goal_checker_id: Any = Field(None, description="one goal checker here: accepted")
    progress_checker_id: Any = Field(None, description="one progress checker here: accepted")
    path_handler_id: Any = Field(None, description="accepted and ignored")
    tracking_feedback: str | None = output_port("entry written with the distance to go", None)


class SmoothPathPorts(Nav2Action, ErrorOutputs):
    """Pass the path on (our planners smooth their own paths) (Nav2's SmoothPath)."""

    plugin: ClassVar[str] = f"{NAV2}:SmoothPath"
    type: Literal["smooth_path"]
    xml_id: ClassVar[str | None] = "SmoothPath"
    example: ClassVar[dict[str, Any] | None] = None
    unsmoothed_path: str = read("the path's entry")
    smoothed_path: str = output_port("entry written with the path")
    smoother_id: Any = ignored()
    max_smoothing_duration: float = Field(3.0, description="accepted")
    check_for_collisions: bool = Field(False, description="accepted")
    smoothing_duration: str | None = output_port("entry written with 0.0", None)
    was_completed: str | None = output_port("entry written with true", None)


class DriveOnHeadingPorts(Nav2Action, ErrorOutputs):
    """Drive straight ahead ``dist_to_travel`` at ``speed`` if the costmap says the way is
    free (Nav2's DriveOnHeading)."""

    plugin: ClassVar[str] = f"{NAV2}:DriveOnHeading"
    type: Literal["drive_on_heading"]
    xml_id: ClassVar[str | None] = "DriveOnHeading"
    dist_to_travel: float = Field(0.15, gt=0.0, description="m")
    speed: float = Field(0.025, gt=0.0, description="m/s")
    time_allowance: float = Field(10.0, gt=0.0, description="simulated seconds before it fails")
    disable_collision_checks: bool = Field(False, description="drive without the costmap")


class CancelControlPorts(Nav2Action):
    """Stop following the path (Nav2's CancelControl)."""

    plugin: ClassVar[str] = f"{NAV2}:CancelControl"
    type: Literal["cancel_control"]
    xml_id: ClassVar[str | None] = "CancelControl"


class _SelectorPorts(NodePorts):
    topic_name: Any = ignored()


class PlannerSelectorPorts(_SelectorPorts):
    """Write the planner to use (Nav2's PlannerSelector: the default, no topic here)."""

    plugin: ClassVar[str] = f"{NAV2}:PlannerSelector"
    example: ClassVar[dict[str, Any] | None] = {"selected_planner": "selected"}
    type: Literal["planner_selector"]
    xml_id: ClassVar[str | None] = "PlannerSelector"
    default_planner: str = Field("", description="written when nothing else is selected")
    selected_planner: str = output_port("entry written with the planner's name")


class ControllerSelectorPorts(_SelectorPorts):
    """Write the controller to use (Nav2's ControllerSelector)."""

    plugin: ClassVar[str] = f"{NAV2}:ControllerSelector"
    example: ClassVar[dict[str, Any] | None] = {"selected_controller": "selected"}
    type: Literal["controller_selector"]
    xml_id: ClassVar[str | None] = "ControllerSelector"
    default_controller: str = Field("", description="written when nothing else is selected")
    selected_controller: str = output_port("entry written with the controller's name")


class SmootherSelectorPorts(_SelectorPorts):
    """Write the smoother to use (Nav2's SmootherSelector)."""

    plugin: ClassVar[str] = f"{NAV2}:SmootherSelector"
    example: ClassVar[dict[str, Any] | None] = {"selected_smoother": "selected"}
    type: Literal["smoother_selector"]
    xml_id: ClassVar[str | None] = "SmootherSelector"
    default_smoother: str = Field("", description="written when nothing else is selected")
    selected_smoother: str = output_port("entry written with the smoother's name")


class GoalCheckerSelectorPorts(_SelectorPorts):
    """Write the goal checker to use (Nav2's GoalCheckerSelector)."""

    plugin: ClassVar[str] = f"{NAV2}:GoalCheckerSelector"
    example: ClassVar[dict[str, Any] | None] = {"selected_goal_checker": "selected"}
    type: Literal["goal_checker_selector"]
    xml_id: ClassVar[str | None] = "GoalCheckerSelector"
    default_goal_checker: str = Field("", description="written when nothing else is selected")
    selected_goal_checker: str = output_port("entry written with the goal checker's name")


class ProgressCheckerSelectorPorts(_SelectorPorts):
    """Write the progress checker to use (Nav2's ProgressCheckerSelector)."""

    plugin: ClassVar[str] = f"{NAV2}:ProgressCheckerSelector"
    example: ClassVar[dict[str, Any] | None] = {"selected_progress_checker": "selected"}
    type: Literal["progress_checker_selector"]
    xml_id: ClassVar[str | None] = "ProgressCheckerSelector"
    default_progress_checker: str = Field("", description="written when nothing else is selected")
    selected_progress_checker: str = output_port("entry written with the checker's name")


class PathHandlerSelectorPorts(_SelectorPorts):
    """Write the path handler to use (Nav2's PathHandlerSelector)."""

    plugin: ClassVar[str] = f"{NAV2}:PathHandlerSelector"
    example: ClassVar[dict[str, Any] | None] = {"selected_path_handler": "selected"}
    type: Literal["path_handler_selector"]
    xml_id: ClassVar[str | None] = "PathHandlerSelector"
    default_path_handler: str = Field("", description="written when nothing else is selected")
    selected_path_handler: str = output_port("entry written with the handler's name")


class RemovePassedGoalsPorts(NodePorts, Frames):
    """Drop the leading goals within ``radius`` of the robot, keeping the last (Nav2's
    RemovePassedGoals)."""

    plugin: ClassVar[str] = f"{NAV2}:RemovePassedGoals"
    type: Literal["remove_passed_goals"]
    xml_id: ClassVar[str | None] = "RemovePassedGoals"
    example: ClassVar[dict[str, Any] | None] = None
    input_goals: str = read("the goals' entry")
    output_goals: str = output_port("entry written with the goals left")
    radius: float = Field(0.5, gt=0.0, description="m")
    input_waypoint_statuses: str | None = read("the statuses' entry (passed on)", None)
    output_waypoint_statuses: str | None = output_port("entry written with the statuses", None)


class TruncatePathPorts(NodePorts):
    """The path without its last ``distance`` metres (Nav2's TruncatePath)."""

    plugin: ClassVar[str] = f"{NAV2}:TruncatePath"
    type: Literal["truncate_path"]
    xml_id: ClassVar[str | None] = "TruncatePath"
    example: ClassVar[dict[str, Any] | None] = None
    input_path: str = read("the path's entry")
    output_path: str = output_port("entry written with the truncated path")
    distance: float = Field(1.0, ge=0.0, description="m cut off the end")


class TruncatePathLocalPorts(NodePorts, Frames):
    """The part of the path from ``distance_backward`` behind the robot to
    ``distance_forward`` ahead (negative: to the end) (Nav2's TruncatePathLocal)."""

    plugin: ClassVar[str] = f"{NAV2}:TruncatePathLocal"
    type: Literal["truncate_path_local"]
    xml_id: ClassVar[str | None] = "TruncatePathLocal"
    example: ClassVar[dict[str, Any] | None] = None
    input_path: str = read("the path's entry")
    output_path: str = output_port("entry written with the local path")
    distance_forward: float = Field(8.0, description="m ahead (negative: to the end)")
    distance_backward: float = Field(4.0, description="m behind")
    pose: Any = Field(None, description="Nav2's: accepted (the robot's estimate is used)")
    angular_distance_weight: float = Field(0.0, description="accepted")
    max_robot_pose_search_dist: Any = Field(None, description="accepted")


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

    plugin: ClassVar[str] = f"{NAV2}:ValidatePath"
    type: Literal["validate_path"]
    xml_id: ClassVar[str | None] = "ValidatePath"
    example: ClassVar[dict[str, Any] | None] = None


class IsPathValidPorts(_PathCheckPorts, ConditionPorts):
    """The path ahead of the robot is free on the costmap (Nav2's IsPathValid)."""

    plugin: ClassVar[str] = f"{NAV2}:IsPathValid"
    type: Literal["is_path_valid"]
    xml_id: ClassVar[str | None] = "IsPathValid"
    example: ClassVar[dict[str, Any] | None] = None


# --------------------------------------------------------------------- conditions


class _GoalWatchPorts(ConditionPorts):
    goal: str = read("the goal's entry", "goal")
    goals: str = read("the goals' entry", "goals")


class GoalUpdatedPorts(_GoalWatchPorts):
    """The goal (or goals) changed since it was first ticked (Nav2's GoalUpdated)."""

    plugin: ClassVar[str] = f"{NAV2}:GoalUpdatedCondition"
    type: Literal["goal_updated"]
    xml_id: ClassVar[str | None] = "GoalUpdated"


class GlobalUpdatedGoalPorts(_GoalWatchPorts):
    """The goal (or goals) changed since it was last ticked (Nav2's GlobalUpdatedGoal)."""

    plugin: ClassVar[str] = f"{NAV2}:GlobalUpdatedGoal"
    type: Literal["global_updated_goal"]
    xml_id: ClassVar[str | None] = "GlobalUpdatedGoal"


class GoalReachedPorts(ConditionPorts, Frames):
    """The robot's estimate is within the goal tolerance of the goal (Nav2's GoalReached)."""

    plugin: ClassVar[str] = f"{NAV2}:GoalReached"
    type: Literal["goal_reached"]
    xml_id: ClassVar[str | None] = "GoalReached"
    goal: str = read("the goal's entry", "goal")


class IsStuckPorts(ConditionPorts):
    """The robot is driving a goal but has made no progress for half the progress timeout
    (Nav2's IsStuck)."""

    plugin: ClassVar[str] = f"{NAV2}:IsStuck"
    type: Literal["is_stuck"]
    xml_id: ClassVar[str | None] = "IsStuck"


class IsGoalNearbyPorts(ConditionPorts, Frames):
    """What is left of the path is shorter than ``proximity_threshold`` (Nav2's
    IsGoalNearby)."""

    plugin: ClassVar[str] = f"{NAV2}:IsGoalNearby"
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

    plugin: ClassVar[str] = f"{NAV2}:WouldAControllerRecoveryHelp"
    type: Literal["would_a_controller_recovery_help"]
    xml_id: ClassVar[str | None] = "WouldAControllerRecoveryHelp"
    example: ClassVar[dict[str, Any] | None] = None


class WouldAPlannerRecoveryHelpPorts(_ErrorCodePorts):
    """The planner's error code is one a recovery may help (200, 207, 208, 300, 307, 308)."""

    plugin: ClassVar[str] = f"{NAV2}:WouldAPlannerRecoveryHelp"
    type: Literal["would_a_planner_recovery_help"]
    xml_id: ClassVar[str | None] = "WouldAPlannerRecoveryHelp"
    example: ClassVar[dict[str, Any] | None] = None


class WouldASmootherRecoveryHelpPorts(_ErrorCodePorts):
    """The smoother's error code is one a recovery may help (500, 502, 503, 504)."""

    plugin: ClassVar[str] = f"{NAV2}:WouldASmootherRecoveryHelp"
    type: Literal["would_a_smoother_recovery_help"]
    xml_id: ClassVar[str | None] = "WouldASmootherRecoveryHelp"
    example: ClassVar[dict[str, Any] | None] = None


class AreErrorCodesPresentPorts(_ErrorCodePorts):
    """The error code is one of ``error_codes_to_check`` (Nav2's AreErrorCodesPresent)."""

    plugin: ClassVar[str] = f"{NAV2}:AreErrorCodesPresent"
    type: Literal["are_error_codes_present"]
    xml_id: ClassVar[str | None] = "AreErrorCodesPresent"
    example: ClassVar[dict[str, Any] | None] = None


class TimeExpiredPorts(ConditionPorts):
    """Succeeds once every ``seconds`` of simulated time (Nav2's TimeExpired)."""

    plugin: ClassVar[str] = f"{NAV2}:TimeExpired"
    type: Literal["time_expired"]
    xml_id: ClassVar[str | None] = "TimeExpired"
    seconds: float = Field(1.0, gt=0.0, description="simulated seconds")


class PathExpiringTimerPorts(ConditionPorts):
    """Succeeds when ``seconds`` passed since the path last changed (Nav2's
    PathExpiringTimer)."""

    plugin: ClassVar[str] = f"{NAV2}:PathExpiringTimer"
    type: Literal["path_expiring_timer"]
    xml_id: ClassVar[str | None] = "PathExpiringTimer"
    example: ClassVar[dict[str, Any] | None] = None
    seconds: float = Field(1.0, gt=0.0, description="simulated seconds")
    path: str = read("the path's entry")


class DistanceTraveledPorts(ConditionPorts, Frames):
    """Succeeds once every ``distance`` metres driven (Nav2's DistanceTraveled)."""

    plugin: ClassVar[str] = f"{NAV2}:DistanceTraveled"
    type: Literal["distance_traveled"]
    xml_id: ClassVar[str | None] = "DistanceTraveled"
    distance: float = Field(1.0, gt=0.0, description="m")


class TransformAvailablePorts(ConditionPorts):
    """Succeeds: every frame of the simulated robot is always available."""

    plugin: ClassVar[str] = f"{NAV2}:TransformAvailable"
    type: Literal["transform_available"]
    xml_id: ClassVar[str | None] = "TransformAvailable"
    child: Any = ignored()
    parent: Any = ignored()


# --------------------------------------------------------------------- decorators


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


# --------------------------------------------------------------------- navigators


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
        from agv_mission.behaviors.ports import Pose

        return [(("goals", i), g) for i, g in enumerate(self.goals) if isinstance(g, Pose)]

    def rooms_visited(self) -> list[tuple[tuple[str | int, ...], str]]:
        return [(("goals", i), g) for i, g in enumerate(self.goals) if isinstance(g, str)]
