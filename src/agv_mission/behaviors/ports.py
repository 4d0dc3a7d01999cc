"""The typed ports of every built-in node type, and the poses they carry.

Each node type's ports are a :class:`NodePorts` model (a plugin config of the registry's
``behavior`` slot): its fields are the ports (type, default, description), its ``type``
is the node's snake_case name, its ``plugin`` names the behaviour class, loaded only when
a tree is built, and its ``kind`` says how the assembly builds it (``action`` and
``condition``: ``cls(name, handle, **ports)``; ``decorator``: ``cls(name, child,
**ports)``; ``control``: ``cls(name, children, **ports)``). This module imports only
pydantic: validating a mission or printing the schema never loads the behaviours.

The task types of ``mission-format.md`` are action nodes like any other: their port
models are the task models (``GoToTask`` ...), and what is checked of them against the map
and reported of them in ``result.json`` is written here, beside their ports.
"""

from __future__ import annotations

import math
import re
from typing import Annotated, Any, ClassVar, Literal, Union

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    GetJsonSchemaHandler,
    field_validator,
    model_validator,
)
from pydantic.json_schema import JsonSchemaValue
from pydantic_core import CoreSchema, InitErrorDetails, PydanticCustomError, ValidationError

from agv_mission.geometry import Bounds, Pose2D, yaw_from_quaternion
from agv_mission.registry import PluginConfig

QUATERNION_TOLERANCE = 1e-3
MAX_WAYPOINTS = 10_000
MAX_LOOPS = 1_000_000
MAX_ROOMS = 1000
MAX_SIM_SECONDS = 86_400.0  # one simulated day

FieldPath = tuple[str | int, ...]

#: A port value that names a blackboard entry (BT.CPP's convention).
BLACKBOARD_REF = re.compile(r"^\{([A-Za-z_][\w.#/-]*)\}$")


def blackboard_key(value: Any) -> str | None:
    """The entry ``"{key}"`` names, or None for a literal."""
    if isinstance(value, str):
        m = BLACKBOARD_REF.match(value)
        if m:
            return m.group(1)
    return None


NodeKind = Literal["action", "condition", "control", "decorator"]


class StrictModel(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)


class Position(StrictModel):
    x: float
    y: float
    z: float = 0.0


class Orientation(StrictModel):
    x: float = 0.0
    y: float = 0.0
    z: float
    w: float


class Pose(StrictModel):
    """A planar pose: ``{x, y, yaw}`` or ROS style ``{position: {...}, orientation: {...}}``."""

    x: float = Field(description="metres, map frame")
    y: float = Field(description="metres, map frame")
    yaw: float = Field(0.0, description="radians, counter-clockwise from +x")

    @model_validator(mode="before")
    @classmethod
    def _from_ros(cls, data: Any) -> Any:
        if not isinstance(data, dict) or ("position" not in data and "orientation" not in data):
            return data
        extra = set(data) - {"position", "orientation"}
        if extra:
            raise ValueError(
                f"a ROS-style pose has only 'position' and 'orientation', not {sorted(extra, key=str)}"
            )
        for key in ("position", "orientation"):
            if key not in data:  # geometry_msgs/Pose has both: no silent (0, 0) or yaw 0
                raise _nested_error(
                    key,
                    PydanticCustomError(
                        "ros_pose_incomplete",
                        "a ROS-style pose needs both 'position' and 'orientation'",
                    ),
                    data,
                )
        details: list[InitErrorDetails] = []
        position = _validate_part(Position, "position", data["position"], details)
        q = _validate_part(Orientation, "orientation", data["orientation"], details)
        if details:
            raise ValidationError.from_exception_data("Pose", details)
        norm = math.sqrt(q.x**2 + q.y**2 + q.z**2 + q.w**2)
        if abs(norm - 1.0) > QUATERNION_TOLERANCE:
            raise ValueError(
                f"orientation quaternion has length {norm:.6f}; expected unit length (within 1e-3)"
            )
        if abs(q.x) > QUATERNION_TOLERANCE or abs(q.y) > QUATERNION_TOLERANCE:
            raise ValueError(
                "orientation tilts out of the plane (x and y must be 0 for a planar robot)"
            )
        return {"x": position.x, "y": position.y, "yaw": yaw_from_quaternion(q.x, q.y, q.z, q.w)}

    def to_pose2d(self) -> Pose2D:
        return Pose2D(self.x, self.y, self.yaw)

    @classmethod
    def __get_pydantic_json_schema__(
        cls, core_schema: CoreSchema, handler: GetJsonSchemaHandler
    ) -> JsonSchemaValue:
        """Either spelling, as the validator takes them (the quaternion's unit length and
        planarity are checks the schema cannot express)."""
        schema = handler.resolve_ref_schema(handler(core_schema))
        planar = {
            k: schema.pop(k)
            for k in ("type", "properties", "required", "additionalProperties")
            if k in schema
        }
        schema["anyOf"] = [planar, ROS_POSE_SCHEMA]
        return schema


def _nested_error(key: str, error: PydanticCustomError | str, data: Any) -> ValidationError:
    return ValidationError.from_exception_data(
        "Pose", [InitErrorDetails(type=error, loc=(key,), input=data)]
    )


def _validate_part(
    model: type[StrictModel], key: str, value: Any, details: list[InitErrorDetails]
) -> Any:
    """``position``/``orientation`` validated with their errors (added to ``details``) at
    their own key, so a quaternion without ``w`` is reported at ``...orientation.w``."""
    try:
        return model.model_validate(value, strict=True)
    except ValidationError as exc:
        for err in exc.errors(include_url=False):
            detail = InitErrorDetails(type=err["type"], loc=(key, *err["loc"]), input=err["input"])
            if "ctx" in err:
                detail["ctx"] = err["ctx"]
            details.append(detail)
        return None


def _number_object(required: list[str], optional: list[str]) -> dict[str, Any]:
    return {
        "type": "object",
        "properties": {k: {"type": "number"} for k in required + optional},
        "required": required,
        "additionalProperties": False,
    }


ROS_POSE_SCHEMA: dict[str, Any] = {
    "type": "object",
    "title": "ROS-style pose",
    "description": "geometry_msgs/Pose: position (z ignored) and a unit quaternion about +z",
    "properties": {
        "position": _number_object(["x", "y"], ["z"]),
        "orientation": _number_object(["z", "w"], ["x", "y"]),
    },
    "required": ["position", "orientation"],
    "additionalProperties": False,
}

#: A goal: a pose, or the label of a room (entered at its anchor or a free point inside).
Goal = Union[Pose, str]  # noqa: UP007

_OUTCOMES = {"goal_reached": "reached", "goal_failed": "failed", "goal_skipped": "skipped"}


def output_port(description: str, default: Any = ...) -> Any:
    """A port the node writes (BT.CPP's output port): its value names a blackboard key."""
    return Field(default, description=description, json_schema_extra={"direction": "output"})


def entry_port(description: str, default: Any = ...) -> Any:
    """An input port whose value names the blackboard entry the node reads (``name`` or
    ``{name}``), rather than carrying the value."""
    return Field(default, min_length=1, description=description, json_schema_extra={"entry": True})


class NodePorts(PluginConfig):
    """The ports of one node type (a plugin config of the ``behavior`` slot)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    plugin: ClassVar[str]
    kind: ClassVar[NodeKind] = "action"
    #: A task of ``mission-format.md``: reported per task in ``result.json``.
    task: ClassVar[bool] = False
    #: Ports the conformance check builds the node with (None: it needs a run's mapper,
    #: checked statically only).
    example: ClassVar[dict[str, Any] | None] = {}
    # ---- its BT.CPP XML spelling (missions/load/tree_xml.py): the element's ID (default: the
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


# ------------------------------------------------------------------------ task types


class FailurePolicy(StrictModel):
    """What a failed goal does to its task (patrol: to each waypoint; visit_rooms: each room)."""

    on_failure: Literal["abort", "skip", "retry"] = Field(
        "abort",
        description="abort: the mission fails; skip: record the failure and go on; "
        "retry: try again `retries` times, then abort",
    )
    retries: int = Field(1, ge=1, description="extra attempts with on_failure: retry")


class TaskPorts(NodePorts):
    task: ClassVar[bool] = True


class GoToTask(TaskPorts, FailurePolicy):
    """Navigate to one pose."""

    plugin: ClassVar[str] = "agv_mission.behaviors.tasks:GoTo"
    type: Literal["go_to"]
    example: ClassVar[dict[str, Any] | None] = {"pose": {"x": 2.0, "y": 2.0}}
    pose: Pose

    def goal_poses(self) -> list[tuple[FieldPath, Pose]]:
        return [(("pose",), self.pose)]

    def report(self, status: str, events: list[dict[str, Any]]) -> dict[str, Any]:
        out = super().report(status, events)
        if out["status"] == "partial":
            out["status"] = "skipped"
        return out


class PatrolTask(TaskPorts, FailurePolicy):
    """Visit the waypoints in order, ``loops`` times, waiting ``dwell`` seconds at each."""

    plugin: ClassVar[str] = "agv_mission.behaviors.tasks:Patrol"
    type: Literal["patrol"]
    example: ClassVar[dict[str, Any] | None] = {"waypoints": [{"x": 2.0, "y": 1.0}]}
    waypoints: list[Pose] = Field(min_length=1, max_length=MAX_WAYPOINTS)
    loops: int = Field(1, ge=1, le=MAX_LOOPS, description="rounds; each is built when it starts")
    dwell: float = Field(
        0.0, ge=0.0, le=MAX_SIM_SECONDS, description="simulated seconds at each waypoint"
    )

    def goal_poses(self) -> list[tuple[FieldPath, Pose]]:
        return [(("waypoints", j), wp) for j, wp in enumerate(self.waypoints)]

    def report(self, status: str, events: list[dict[str, Any]]) -> dict[str, Any]:
        out = super().report(status, events)
        out["waypoints_planned"] = self.loops * len(self.waypoints)
        out["waypoints"] = [
            {k: e[k] for k in ("loop", "waypoint", "t", "x", "y", "yaw", "reason") if k in e}
            | {"status": _OUTCOMES[e["event"]]}
            for e in events
            if e["event"] in _OUTCOMES
        ]
        return out


class WanderTask(TaskPorts):
    """Drive ahead while the range ahead exceeds ``min_range``, turn otherwise (seed ex. 7.3)."""

    plugin: ClassVar[str] = "agv_mission.behaviors.tasks:WanderTaskNode"
    type: Literal["wander"]
    example: ClassVar[dict[str, Any] | None] = {"duration": 1.0}
    duration: float = Field(gt=0.0, le=MAX_SIM_SECONDS, description="simulated seconds")
    min_range: float = Field(0.8, gt=0.0, description="metres")
    speed: float | None = Field(None, gt=0.0, description="m/s; default: the robot's maximum")
    turn_rate: float = Field(0.4, gt=0.0, description="rad/s while turning")
    sector: float = Field(
        20.0, gt=0.0, le=180.0, description="half-width of the 'ahead' sector, degrees"
    )


class SettleBeforeRecording(StrictModel):
    """Tasks that record a pose let the localiser settle first."""

    settle: float = Field(
        1.0,
        ge=0.0,
        description="seconds standing still before recording, localisation updating on "
        "every scan (amcl's request_nomotion_update)",
    )


class VisitRoomsTask(TaskPorts, FailurePolicy, SettleBeforeRecording):
    """Go into each room in order (its anchor, or a free point well inside it)."""

    plugin: ClassVar[str] = "agv_mission.behaviors.tasks:VisitRooms"
    type: Literal["visit_rooms"]
    example: ClassVar[dict[str, Any] | None] = {"rooms": ["room"]}
    rooms: list[str] = Field(
        min_length=1, max_length=MAX_ROOMS, description="room labels, visited in this order"
    )
    record: bool = Field(False, description="record the estimated pose in each room")

    def rooms_visited(self) -> list[tuple[FieldPath, str]]:
        return [(("rooms", j), room) for j, room in enumerate(self.rooms)]

    def report(self, status: str, events: list[dict[str, Any]]) -> dict[str, Any]:
        out = super().report(status, events)
        out["rooms"] = [_room_report(room, events) for room in self.rooms]
        return out


def _room_report(room: str, events: list[dict[str, Any]]) -> dict[str, Any]:
    outcome = next(
        (
            e
            for e in events
            if e.get("room") == room and e["event"] in ("goal_failed", "goal_skipped")
        ),
        None,
    )
    reached = any(e["event"] == "goal_reached" and e.get("room") == room for e in events)
    report: dict[str, Any] = {
        "room": room,
        "status": _OUTCOMES[outcome["event"]] if outcome else ("reached" if reached else "not_run"),
        "recorded": any(e["event"] == "room_recorded" and e.get("room") == room for e in events),
    }
    if outcome:
        report["reason"] = outcome["reason"]
    return report


class RecordRoomTask(TaskPorts, SettleBeforeRecording):
    """Record the current estimated pose under a label (the seed's room_service call)."""

    plugin: ClassVar[str] = "agv_mission.behaviors.tasks:RecordRoomTaskNode"
    type: Literal["record_room"]
    example: ClassVar[dict[str, Any] | None] = {"room": "room"}
    room: str = Field(min_length=1, description="the label to record under")


class AreaBounds(StrictModel):
    """An axis-aligned rectangle of the map frame, metres."""

    xmin: float
    xmax: float
    ymin: float
    ymax: float

    @model_validator(mode="after")
    def _ordered(self) -> AreaBounds:
        if self.xmax <= self.xmin or self.ymax <= self.ymin:
            raise ValueError("bounds need xmin < xmax and ymin < ymax")
        return self

    def as_tuple(self) -> Bounds:
        return (self.xmin, self.xmax, self.ymin, self.ymax)


class MapAreaTask(TaskPorts):
    """Explore ``bounds`` by frontiers while SLAM builds the map; save it map_saver-style.

    Later tasks of the mission navigate (and localise) on the saved map.
    """

    plugin: ClassVar[str] = "agv_mission.behaviors.tasks:MapAreaTaskNode"
    type: Literal["map_area"]
    example: ClassVar[dict[str, Any] | None] = None
    bounds: AreaBounds | None = Field(None, description="default: the whole world map")
    save_map: str = Field("map", description="writes <save_map>.pgm + .yaml in the run directory")
    coverage: float | None = Field(
        None, gt=0.0, le=1.0, description="stop once this share of the bounds is known"
    )
    time_limit: float | None = Field(
        None, gt=0.0, le=MAX_SIM_SECONDS, description="stop after this many seconds"
    )
    min_frontier_size: int = Field(8, ge=1, description="smallest frontier worth a visit, cells")

    @field_validator("save_map")
    @classmethod
    def _stem(cls, v: str) -> str:
        if not v.strip() or "/" in v or "\\" in v or v in (".", ".."):
            raise ValueError("save_map is a file name stem without path separators")
        return v

    def map_bounds(self) -> list[tuple[FieldPath, AreaBounds | None]]:
        return [(("bounds",), self.bounds)]


class TeleopTask(TaskPorts):
    """Hold the robot under remote command (the service's live stream sends cmd_vel).

    The robot stops when no command arrived for 0.5 s of wall time; under the service,
    simulated time runs at wall-clock speed during this task.
    """

    plugin: ClassVar[str] = "agv_mission.behaviors.tasks:Teleop"
    type: Literal["teleop"]
    example: ClassVar[dict[str, Any] | None] = {"duration": 0.5}
    duration: float | None = Field(
        None, gt=0.0, description="simulated seconds; None: until the run is cancelled"
    )


class DockTask(TaskPorts):
    """Drive to the dock's staging pose, then straight and slowly onto the dock."""

    plugin: ClassVar[str] = "agv_mission.behaviors.battery:Dock"
    type: Literal["dock"]
    example: ClassVar[dict[str, Any] | None] = None
    dock: str = Field("charger", min_length=1, description="a dock of the world or rooms file")


class UndockTask(TaskPorts):
    """Back out of the dock to its staging pose."""

    plugin: ClassVar[str] = "agv_mission.behaviors.battery:Undock"
    type: Literal["undock"]
    example: ClassVar[dict[str, Any] | None] = None


class ChargeTask(TaskPorts):
    """Charge on the dock (the robot must be docked) until the level reaches ``until``."""

    plugin: ClassVar[str] = "agv_mission.behaviors.battery:Charge"
    type: Literal["charge"]
    example: ClassVar[dict[str, Any] | None] = None
    until: float = Field(1.0, gt=0.0, le=1.0, description="battery level to charge to, 0..1")


Task = Annotated[
    Union[  # noqa: UP007
        GoToTask,
        PatrolTask,
        WanderTask,
        VisitRoomsTask,
        RecordRoomTask,
        MapAreaTask,
        TeleopTask,
        DockTask,
        UndockTask,
        ChargeTask,
    ],
    Field(discriminator="type"),
]

# ------------------------------------------------------------------------ controls


class SequencePorts(ControlPorts):
    """Ticks its children in order; fails on the first failure, resumes at the running one."""

    btcpp_builtin: ClassVar[bool] = True

    plugin: ClassVar[str] = "agv_mission.behaviors.controls:Sequence"
    type: Literal["sequence"]


class ReactiveSequencePorts(ControlPorts):
    """Re-ticks every earlier child each tick: conditions guard a running action."""

    btcpp_builtin: ClassVar[bool] = True

    plugin: ClassVar[str] = "agv_mission.behaviors.controls:ReactiveSequence"
    type: Literal["reactive_sequence"]


class FallbackPorts(ControlPorts):
    """Succeeds on the first child that succeeds; resumes at the running one."""

    btcpp_builtin: ClassVar[bool] = True

    plugin: ClassVar[str] = "agv_mission.behaviors.controls:Fallback"
    type: Literal["fallback"]


class ReactiveFallbackPorts(ControlPorts):
    """Re-ticks earlier children every tick; one that starts running halts the later one."""

    btcpp_builtin: ClassVar[bool] = True

    plugin: ClassVar[str] = "agv_mission.behaviors.controls:ReactiveFallback"
    type: Literal["reactive_fallback"]


class ParallelPorts(ControlPorts):
    """Ticks every child each tick; succeeds or fails on counts of children (BT.CPP v4)."""

    btcpp_builtin: ClassVar[bool] = True

    plugin: ClassVar[str] = "agv_mission.behaviors.controls:Parallel"
    type: Literal["parallel"]
    success_count: int = Field(-1, ge=-1, description="successes that succeed it (-1: all)")
    failure_count: int = Field(1, ge=-1, description="failures that fail it (-1: all)")


class PipelineSequencePorts(ControlPorts):
    """Nav2's PipelineSequence: re-ticks every child up to the running one."""

    plugin: ClassVar[str] = "agv_mission.behaviors.controls:PipelineSequence"
    type: Literal["pipeline_sequence"]


class RoundRobinPorts(ControlPorts):
    """Nav2's RoundRobin: one child per tick in turn; succeeds on the first success."""

    plugin: ClassVar[str] = "agv_mission.behaviors.controls:RoundRobin"
    type: Literal["round_robin"]
    wrap_around: bool = Field(False, description="Nav2's: accepted (children are tried in turn)")


class RecoveryPorts(ControlPorts):
    """Nav2's RecoveryNode: two children, the action and its recovery, retried."""

    xml_id: ClassVar[str | None] = "RecoveryNode"
    children_range: ClassVar[tuple[int, int] | None] = (2, 2)

    plugin: ClassVar[str] = "agv_mission.behaviors.controls:Recovery"
    type: Literal["recovery"]
    number_of_retries: int = Field(1, ge=0, description="recoveries before it fails")


# ------------------------------------------------------------------------ decorators


class InverterPorts(DecoratorPorts):
    """Success becomes failure and failure success."""

    btcpp_builtin: ClassVar[bool] = True

    plugin: ClassVar[str] = "agv_mission.behaviors.decorators:Inverter"
    type: Literal["inverter"]


class ForceSuccessPorts(DecoratorPorts):
    """Succeeds whenever its child ends."""

    btcpp_builtin: ClassVar[bool] = True

    plugin: ClassVar[str] = "agv_mission.behaviors.decorators:ForceSuccess"
    type: Literal["force_success"]


class ForceFailurePorts(DecoratorPorts):
    """Fails whenever its child ends."""

    btcpp_builtin: ClassVar[bool] = True

    plugin: ClassVar[str] = "agv_mission.behaviors.decorators:ForceFailure"
    type: Literal["force_failure"]


class RetryPorts(DecoratorPorts):
    """Runs its child again after a failure, up to ``num_attempts`` tries in all."""

    btcpp_builtin: ClassVar[bool] = True
    xml_id: ClassVar[str | None] = "RetryUntilSuccessful"

    plugin: ClassVar[str] = "agv_mission.behaviors.decorators:Retry"
    type: Literal["retry"]
    example: ClassVar[dict[str, Any] | None] = {"num_attempts": 2}
    num_attempts: int = Field(ge=-1, description="tries in all (-1: until it succeeds)")


class RepeatPorts(DecoratorPorts):
    """Runs its child again after a success, ``num_cycles`` times; fails on a failure."""

    btcpp_builtin: ClassVar[bool] = True

    plugin: ClassVar[str] = "agv_mission.behaviors.decorators:Repeat"
    type: Literal["repeat"]
    example: ClassVar[dict[str, Any] | None] = {"num_cycles": 2}
    num_cycles: int = Field(ge=-1, description="successes to run (-1: until the time limit)")


class TimeoutPorts(DecoratorPorts):
    """Halts its child and fails after ``seconds`` of simulated time."""

    btcpp_builtin: ClassVar[bool] = True
    xml_ports: ClassVar[dict[str, str]] = {"seconds": "msec"}
    xml_scale: ClassVar[dict[str, float]] = {"seconds": 1000.0}

    plugin: ClassVar[str] = "agv_mission.behaviors.decorators:Timeout"
    type: Literal["timeout"]
    example: ClassVar[dict[str, Any] | None] = {"seconds": 1.0}
    seconds: float = Field(gt=0.0, le=MAX_SIM_SECONDS, description="simulated seconds")


class DelayPorts(DecoratorPorts):
    """Waits ``seconds`` of simulated time (robot stopped), then runs its child."""

    btcpp_builtin: ClassVar[bool] = True
    xml_ports: ClassVar[dict[str, str]] = {"seconds": "delay_msec"}
    xml_scale: ClassVar[dict[str, float]] = {"seconds": 1000.0}

    plugin: ClassVar[str] = "agv_mission.behaviors.decorators:Delay"
    type: Literal["delay"]
    example: ClassVar[dict[str, Any] | None] = {"seconds": 0.2}
    seconds: float = Field(ge=0.0, le=MAX_SIM_SECONDS, description="simulated seconds")


class RateControllerPorts(DecoratorPorts):
    """Ticks its child at most ``hz`` times per simulated second (returns the last status
    between)."""

    plugin: ClassVar[str] = "agv_mission.behaviors.decorators:RateController"
    type: Literal["rate_controller"]
    example: ClassVar[dict[str, Any] | None] = {"hz": 5.0}
    hz: float = Field(gt=0.0, description="ticks per simulated second")


class KeepRunningUntilFailurePorts(DecoratorPorts):
    """Runs its child again after every success; fails when it fails."""

    btcpp_builtin: ClassVar[bool] = True

    plugin: ClassVar[str] = "agv_mission.behaviors.decorators:KeepRunningUntilFailure"
    type: Literal["keep_running_until_failure"]


class RunOncePorts(DecoratorPorts):
    """Runs its child once; afterwards returns its result (or succeeds: ``then_skip``)."""

    btcpp_builtin: ClassVar[bool] = True

    plugin: ClassVar[str] = "agv_mission.behaviors.decorators:RunOnce"
    type: Literal["run_once"]
    then_skip: bool = Field(True, description="after the first run: succeed (else its status)")


# ------------------------------------------------------------------------ conditions


class InRoomPorts(ConditionPorts):
    """The estimated position lies inside the room's polygon."""

    plugin: ClassVar[str] = "agv_mission.behaviors.conditions:InRoomCondition"
    type: Literal["in_room"]
    example: ClassVar[dict[str, Any] | None] = {"room": "room"}
    room: str = Field(min_length=1, description="a room label")

    def rooms_named(self) -> list[tuple[FieldPath, str]]:
        return [(("room",), self.room)]


class AtPosePorts(ConditionPorts):
    """The estimated position is within ``tolerance`` of ``pose``."""

    plugin: ClassVar[str] = "agv_mission.behaviors.conditions:AtPose"
    type: Literal["at_pose"]
    example: ClassVar[dict[str, Any] | None] = {"pose": {"x": 1.0, "y": 1.0}}
    pose: Goal = Field(description="a pose or a room label")
    tolerance: float = Field(0.25, gt=0.0, description="m")


class RangeAheadBelowPorts(ConditionPorts):
    """The nearest lidar return within ``fov`` of straight ahead is closer than ``distance``
    (the seed's ``range_ahead``)."""

    plugin: ClassVar[str] = "agv_mission.behaviors.conditions:RangeAheadBelow"
    type: Literal["range_ahead_below"]
    example: ClassVar[dict[str, Any] | None] = {"distance": 0.5}
    distance: float = Field(gt=0.0, description="m")
    fov: float = Field(0.35, gt=0.0, le=math.pi, description="the cone's half-width, rad")


class PersonNearPorts(ConditionPorts):
    """A person's edge is within ``distance`` of the robot's footprint (the people the run
    tracks, as ``metrics.people`` measures them)."""

    plugin: ClassVar[str] = "agv_mission.behaviors.conditions:PersonNear"
    type: Literal["person_near"]
    example: ClassVar[dict[str, Any] | None] = {"distance": 1.0}
    distance: float = Field(gt=0.0, description="m")


class IsBatteryLowPorts(ConditionPorts):
    """The battery's level is at or below ``min_battery`` (Nav2's IsBatteryLow); fails
    without a battery."""

    plugin: ClassVar[str] = "agv_mission.behaviors.battery:IsBatteryLow"
    type: Literal["is_battery_low"]
    example: ClassVar[dict[str, Any] | None] = {"min_battery": 0.3}
    min_battery: float = Field(ge=0.0, le=1.0, description="battery level, 0..1")
    battery_topic: Any = Field(None, description="ROS plumbing (Nav2): accepted and ignored")
    is_voltage: bool = Field(False, description="Nav2's: min_battery is a voltage (refused)")

    @field_validator("is_voltage")
    @classmethod
    def _level(cls, v: bool) -> bool:
        if v:
            raise ValueError("the battery model gives a level, not a voltage")
        return v


class IsBatteryChargingPorts(ConditionPorts):
    """The robot is docked and charging."""

    plugin: ClassVar[str] = "agv_mission.behaviors.battery:IsBatteryCharging"
    type: Literal["is_battery_charging"]
    example: ClassVar[dict[str, Any] | None] = {}
    battery_topic: Any = Field(None, description="ROS plumbing (Nav2): accepted and ignored")


class TimeElapsedPorts(ConditionPorts):
    """At least ``seconds`` of simulated time have passed since the mission started."""

    plugin: ClassVar[str] = "agv_mission.behaviors.conditions:TimeElapsed"
    type: Literal["time_elapsed"]
    example: ClassVar[dict[str, Any] | None] = {"seconds": 0.0}
    seconds: float = Field(ge=0.0, description="simulated seconds")


class CheckBlackboardPorts(ConditionPorts):
    """Blackboard entry ``key`` equals, is less than or greater than a value."""

    plugin: ClassVar[str] = "agv_mission.behaviors.conditions:CheckBlackboard"
    type: Literal["check_blackboard"]
    example: ClassVar[dict[str, Any] | None] = {"key": "k", "equals": 1}
    key: str = entry_port("the entry read (a name, or {name})")
    equals: Any = Field(None, description="succeed when the entry equals this")
    less: float | None = Field(None, description="succeed when the entry is below this")
    greater: float | None = Field(None, description="succeed when the entry is above this")

    @model_validator(mode="after")
    def _one_test(self) -> CheckBlackboardPorts:
        given = [k for k in ("equals", "less", "greater") if getattr(self, k) is not None]
        if len(given) != 1:
            raise ValueError("give exactly one of equals, less, greater")
        return self


class IsPathClearPorts(ConditionPorts):
    """A plan to ``goal`` exists on the current costmap (lidar obstacles included)."""

    plugin: ClassVar[str] = "agv_mission.behaviors.conditions:IsPathClear"
    type: Literal["is_path_clear"]
    example: ClassVar[dict[str, Any] | None] = {"goal": {"x": 3.0, "y": 3.0}}
    goal: Goal = Field(description="a pose or a room label")


# ------------------------------------------------------------------------ actions


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
