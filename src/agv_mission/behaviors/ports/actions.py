"""The ports of the action nodes that are not tasks: navigation, motion, recoveries and the
blackboard's (:mod:`agv_mission.behaviors.actions`, :mod:`agv_mission.behaviors.recoveries`)."""

from __future__ import annotations

from typing import Any, ClassVar, Literal

from pydantic import (
    Field,
)

from agv_mission.behaviors.ports.node import ErrorOutputs, NodePorts, RosPlumbing, output_port
from agv_mission.behaviors.ports.values import MAX_SIM_SECONDS, FieldPath, Goal, Pose


class NavigateToPosePorts(NodePorts, RosPlumbing, ErrorOutputs):
    """Plan and drive to ``goal``, with recoveries between attempts (Nav2's navigator);
    with ``behavior_tree``, the goal is ``{goal}`` of that tree, which is run instead
    (Nav2's NavigateToPose action)."""

    plugin: ClassVar[str] = "agv_mission.behaviors.tasks:NavigateToGoal"
    type: Literal["navigate_to_pose"]
    example: ClassVar[dict[str, Any] | None] = {"goal": {"x": 2.0, "y": 2.0}}
    goal: Goal = Field(description="a pose, a room label, or {key}")
    recoveries: list[Literal["clear_costmap", "spin", "wait", "back_up"]] | None = Field(
        None, description="between attempts; default: stack.navigation.recoveries"
    )
    behavior_tree: str | None = Field(
        None,
        description="a BT.CPP XML file (e.g. one of Nav2's navigator trees), relative to "
        "the mission file, run with the goal as {goal}",
    )

    def goal_poses(self) -> list[tuple[FieldPath, Pose]]:
        return [(("goal",), self.goal)] if isinstance(self.goal, Pose) else []

    def rooms_visited(self) -> list[tuple[FieldPath, str]]:
        return [(("goal",), self.goal)] if isinstance(self.goal, str) else []


class DrivePorts(NodePorts):
    """Send a raw velocity for ``seconds`` (the seed's cmd_vel scripts)."""

    plugin: ClassVar[str] = "agv_mission.behaviors.actions:Drive"
    type: Literal["drive"]
    example: ClassVar[dict[str, Any] | None] = {"seconds": 0.5, "v": 0.1}
    v: float = Field(0.0, description="m/s, clipped to the robot's limits")
    w: float = Field(0.0, description="rad/s, clipped to the robot's limits")
    seconds: float = Field(gt=0.0, le=MAX_SIM_SECONDS, description="simulated seconds")


class StopPorts(NodePorts):
    """Stop the robot (one tick)."""

    plugin: ClassVar[str] = "agv_mission.behaviors.actions:Stop"
    type: Literal["stop"]


class WaitPorts(NodePorts, RosPlumbing, ErrorOutputs):
    """Stand still for ``seconds`` of simulated time (Nav2's Wait)."""

    xml_ports: ClassVar[dict[str, str]] = {"seconds": "wait_duration"}

    plugin: ClassVar[str] = "agv_mission.behaviors.actions:WaitFor"
    type: Literal["wait"]
    example: ClassVar[dict[str, Any] | None] = {"seconds": 0.2}
    seconds: float = Field(ge=0.0, le=MAX_SIM_SECONDS, description="simulated seconds")


class SpinPorts(NodePorts, RosPlumbing, ErrorOutputs):
    """Turn in place by ``angle`` (Nav2's Spin)."""

    xml_ports: ClassVar[dict[str, str]] = {"angle": "spin_dist"}

    plugin: ClassVar[str] = "agv_mission.behaviors.actions:SpinBy"
    type: Literal["spin"]
    example: ClassVar[dict[str, Any] | None] = {"angle": 1.0}
    angle: float = Field(1.57, description="rad, counter-clockwise positive")
    rate: float = Field(1.0, gt=0.0, description="rad/s, clipped to the robot's limit")
    time_allowance: float = Field(10.0, gt=0.0, description="simulated seconds before it fails")
    is_recovery: bool = Field(True, description="logged as a recovery event")
    disable_collision_checks: bool = Field(False, description="accepted; turning in place")


class BackUpPorts(NodePorts, RosPlumbing, ErrorOutputs):
    """Reverse ``distance`` at ``speed`` if the costmap says the space behind is free
    (Nav2's BackUp)."""

    xml_ports: ClassVar[dict[str, str]] = {"distance": "backup_dist", "speed": "backup_speed"}

    plugin: ClassVar[str] = "agv_mission.behaviors.recoveries:BackUp"
    type: Literal["back_up"]
    distance: float = Field(0.15, gt=0.0, description="m")
    speed: float = Field(0.05, gt=0.0, description="m/s")
    time_allowance: float | None = Field(
        None, gt=0.0, description="simulated seconds before it fails (default: 3 x d / v)"
    )
    disable_collision_checks: bool = Field(False, description="back up without the costmap")


class ClearCostmapPorts(NodePorts, RosPlumbing):
    """Forget the obstacles the lidar marked (Nav2's ClearEntireCostmap: one costmap here,
    local and global alike)."""

    xml_id: ClassVar[str | None] = "ClearEntireCostmap"

    plugin: ClassVar[str] = "agv_mission.behaviors.recoveries:ClearCostmap"
    type: Literal["clear_costmap"]
    service_name: Any = Field(None, description="ROS plumbing (Nav2): accepted and ignored")
    plugins: Any = Field(None, description="the costmap layers (one here): accepted, ignored")


class SetBlackboardPorts(NodePorts):
    """Write ``value`` to blackboard entry ``key``."""

    btcpp_builtin: ClassVar[bool] = True
    xml_ports: ClassVar[dict[str, str]] = {"key": "output_key"}

    plugin: ClassVar[str] = "agv_mission.behaviors.actions:SetBlackboard"
    type: Literal["set_blackboard"]
    example: ClassVar[dict[str, Any] | None] = {"key": "k", "value": 1}
    key: str = output_port("the entry written (a name, or {name})")
    value: Any = Field(description="any YAML value")


class LogPorts(NodePorts):
    """Log ``message`` as an event of result.json."""

    plugin: ClassVar[str] = "agv_mission.behaviors.actions:Log"
    type: Literal["log"]
    example: ClassVar[dict[str, Any] | None] = {"message": "hello"}
    message: str = Field(description="the event's message")
