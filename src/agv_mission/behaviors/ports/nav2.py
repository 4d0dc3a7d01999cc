"""The ports of Nav2's behaviour tree nodes (``nav2_behavior_tree/nav2_tree_nodes.xml``,
Humble, Jazzy and Rolling: the union of their ports), as node types of ours: the actions
(planning, following, smoothing, the selectors, the path handlers) and what all of Nav2's
ports share; the conditions in :mod:`~agv_mission.behaviors.ports.nav2_conditions`, the
decorators and navigators in :mod:`~agv_mission.behaviors.ports.nav2_flow`.

Ports that carry data between nodes (a goal, goals, a path, an error code) name the
blackboard entry the node reads every tick (``path="{path}"``), as Nav2's trees write
them; ports that name ROS plumbing (servers, services, topics, frames) are accepted and
ignored; ``planner_id`` / ``controller_id`` pick among the mission's configured planner
and controller (one each: any other name means the configured one, as Nav2's default
does). Spin, Wait, BackUp and ClearEntireCostmap are our ``spin``, ``wait``, ``back_up``
and ``clear_costmap`` (:mod:`agv_mission.behaviors.ports.actions`); RecoveryNode,
PipelineSequence, RoundRobin, RateController, IsBatteryLow and IsBatteryCharging are ours
too.
"""

from __future__ import annotations

from typing import Any, ClassVar, Literal

from pydantic import Field

from agv_mission.behaviors.ports.node import (
    ErrorOutputs,
    NodePorts,
    RosPlumbing,
    entry_port,
    output_port,
)
from agv_mission.behaviors.ports.values import StrictModel

_IGNORED = "ROS plumbing (Nav2): accepted and ignored"
NAV2 = "agv_mission.behaviors.nav2"


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
