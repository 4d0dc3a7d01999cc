"""A node type's ports: :class:`NodePorts` (a plugin config of the registry's ``behavior``
slot) by kind, and the port spellings Nav2 and BT.CPP share (outputs, error outputs, ROS
plumbing)."""

from __future__ import annotations

from typing import Any, ClassVar, Literal

from pydantic import (
    ConfigDict,
    Field,
)

from agv_mission.behaviors.ports.values import AreaBounds, FieldPath, Pose, StrictModel
from agv_mission.registry import PluginConfig

NodeKind = Literal["action", "condition", "control", "decorator"]


def output_port(description: str, default: Any = ...) -> Any:
    """A port the node writes (BT.CPP's output port): its value names a blackboard key."""
    return Field(default, description=description, json_schema_extra={"direction": "output"})


def entry_port(description: str, default: Any = ...) -> Any:
    """An input port whose value names the blackboard entry the node reads (``name`` or
    ``{name}``), rather than carrying the value."""
    return Field(default, min_length=1, description=description, json_schema_extra={"entry": True})


class NodePorts(PluginConfig):
    """The ports of one node type (a plugin config of the ``behavior`` slot)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, defer_build=True)

    plugin: ClassVar[str]
    kind: ClassVar[NodeKind] = "action"
    #: A task of ``mission-format.md``: reported per task in ``result.json``.
    task: ClassVar[bool] = False
    #: Ports the conformance check builds the node with (None: it needs a run's mapper,
    #: checked statically only).
    example: ClassVar[dict[str, Any] | None] = {}
    # ---- its BT.CPP XML spelling (missions/tree_xml.py): the element's ID (default: the
    # type in CamelCase), attribute names of ports named otherwise in YAML, the factor from
    # a YAML value to its XML one (seconds -> msec), and whether BT.CPP itself has the node
    # (an exported <TreeNodesModel> never declares those)
    xml_id: ClassVar[str | None] = None
    xml_ports: ClassVar[dict[str, str]] = {}
    xml_scale: ClassVar[dict[str, float]] = {}
    btcpp_builtin: ClassVar[bool] = False
    #: (least, most) children of a control node, where it is particular
    children_range: ClassVar[tuple[int, int] | None] = None

    # ---- what the world checks ask of a node before it runs (paths relative to it)

    def goal_poses(self) -> list[tuple[FieldPath, Pose]]:
        """Poses the robot will drive to: on the map, in free space."""
        return []

    def rooms_visited(self) -> list[tuple[FieldPath, str]]:
        """Rooms the robot will enter: known, with a reachable goal."""
        return []

    def rooms_named(self) -> list[tuple[FieldPath, str]]:
        """Rooms the node refers to: they must exist."""
        return self.rooms_visited()

    def map_bounds(self) -> list[tuple[FieldPath, AreaBounds | None]]:
        """Areas SLAM will map (None: the whole map)."""
        return []

    # ---- what result.json says of a task node beyond its status

    def report(self, status: str, events: list[dict[str, Any]]) -> dict[str, Any]:
        """The task report's status (maybe refined) and extra keys, from the task's events."""
        skips = [e for e in events if e["event"] == "goal_skipped"]
        if status == "succeeded" and skips:
            status = "partial"
        out: dict[str, Any] = {"status": status}
        if skips:
            out["reason"] = "; ".join(sorted({e["reason"] for e in skips}))
        return out


class ControlPorts(NodePorts):
    kind: ClassVar[NodeKind] = "control"


class DecoratorPorts(NodePorts):
    kind: ClassVar[NodeKind] = "decorator"


class ConditionPorts(NodePorts):
    kind: ClassVar[NodeKind] = "condition"


class RosPlumbing(StrictModel):
    """Nav2's ports that name ROS plumbing (servers, services, topics): accepted, ignored."""

    server_name: Any = Field(None, description="ROS plumbing (Nav2): accepted and ignored")
    server_timeout: Any = Field(None, description="ROS plumbing (Nav2): accepted and ignored")


class ErrorOutputs(StrictModel):
    """Nav2's error outputs: the action's error code (Nav2's numbering) and message."""

    error_code_id: str | None = output_port("entry written with Nav2's error code", None)
    error_msg: str | None = output_port("entry written with the error's message", None)
