"""The mission file, as pydantic models: the contract of ``mission-format.md`` in types.

Plugin blocks (``stack.localization``, ``stack.global_planner``, ...) are unions of the
``Config`` models of every plugin registered for that slot, told apart by ``type``; a
new plugin extends the schema by registering itself.
"""

from __future__ import annotations

import math
from typing import Annotated, Any, Literal, Union

from pydantic import (
    BaseModel,
    ConfigDict,
    Discriminator,
    Field,
    GetJsonSchemaHandler,
    Tag,
    field_validator,
    model_validator,
)
from pydantic.json_schema import JsonSchemaValue
from pydantic_core import CoreSchema

from agv_mission.geometry import Bounds, Pose2D, yaw_from_quaternion
from agv_mission.maps.costmap import CostmapConfig
from agv_mission.missions.expectations import Expectations
from agv_mission.navigation.config import NavigationConfig
from agv_mission.registry import registry
from agv_mission.robots.sim_config import SimConfig

QUATERNION_TOLERANCE = 1e-3

# Bounds on what scales memory or time (a mission over them is refused, not run).
MAX_TASKS = 1000
MAX_WAYPOINTS = 10_000
MAX_LOOPS = 1_000_000
MAX_ROOMS = 1000
MAX_OBSTACLES = 1000
MAX_FAULTS = 100
MAX_SIM_SECONDS = 86_400.0  # one simulated day
MAX_NAME_LENGTH = 100  # a path component of the run directory, with a timestamp after it


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
        position = Position.model_validate(data.get("position", {"x": 0.0, "y": 0.0}), strict=True)
        if "orientation" not in data:
            return {"x": position.x, "y": position.y, "yaw": 0.0}
        q = Orientation.model_validate(data["orientation"], strict=True)
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
    "minProperties": 1,
    "additionalProperties": False,
}


def _plugin_union(slot: str) -> Any:
    """A discriminated union of the config models of every plugin of ``slot``."""
    configs = tuple(registry.configs(slot))
    if len(configs) == 1:
        return configs[0]
    return Annotated[Union[configs], Field(discriminator="type")]  # noqa: UP007


LocalizationConfig = _plugin_union("localization")
GlobalPlannerConfig = _plugin_union("global_planner")
LocalPlannerConfig = _plugin_union("local_planner")
SlamConfig = _plugin_union("slam")


# The plugin a stack block without ``type`` (or no block at all) selects.
DEFAULT_PLUGINS = {
    "localization": "amcl",
    "global_planner": "cost_grid",
    "local_planner": "mpc",
    "slam": "grid",
}


def with_default_plugin_types(data: Any) -> Any:
    """``data`` with ``type`` filled in for every stack block that leaves it out (in place),
    so ``--set stack.global_planner.planner=RRTstar`` works without a block in the file.

    A block is the slot's default plugin, unless its keys are not all the default's and
    exactly one plugin of the slot has them all (``planner`` is OMPL's alone)."""
    stack = data.get("stack") if isinstance(data, dict) else None
    if isinstance(stack, dict):
        for slot, name in DEFAULT_PLUGINS.items():
            block = stack.get(slot)
            if isinstance(block, dict) and "type" not in block:
                block["type"] = _plugin_with_keys(slot, set(block)) or name
    return data


def _plugin_with_keys(slot: str, keys: set[Any]) -> str | None:
    """The one plugin of ``slot`` whose config has every key of ``keys`` when the default
    plugin's does not; None otherwise."""
    configs = {
        config.model_fields["type"].default: set(config.model_fields)
        for config in registry.configs(slot)
    }
    if keys <= configs.get(DEFAULT_PLUGINS[slot], set()):
        return None
    fits = [name for name, fields in configs.items() if keys <= fields]
    return fits[0] if len(fits) == 1 else None


def _default(slot: str, name: str) -> Any:
    return registry.config(slot, name)()


class Stack(StrictModel):
    """The navigation stack: one plugin per slot, chosen by ``type``."""

    localization: LocalizationConfig = Field(  # type: ignore[valid-type]
        default_factory=lambda: _default("localization", DEFAULT_PLUGINS["localization"])
    )
    global_planner: GlobalPlannerConfig = Field(  # type: ignore[valid-type]
        default_factory=lambda: _default("global_planner", DEFAULT_PLUGINS["global_planner"])
    )
    local_planner: LocalPlannerConfig = Field(  # type: ignore[valid-type]
        default_factory=lambda: _default("local_planner", DEFAULT_PLUGINS["local_planner"])
    )
    slam: SlamConfig = Field(  # type: ignore[valid-type]
        default_factory=lambda: _default("slam", DEFAULT_PLUGINS["slam"]),
        description="used while a map_area task maps",
    )
    costmap: CostmapConfig = Field(default_factory=CostmapConfig)
    navigation: NavigationConfig = Field(default_factory=NavigationConfig)


class FailurePolicy(StrictModel):
    """What a failed goal does to its task (patrol: to each waypoint; visit_rooms: each room)."""

    on_failure: Literal["abort", "skip", "retry"] = Field(
        "abort",
        description="abort: the mission fails; skip: record the failure and go on; "
        "retry: try again `retries` times, then abort",
    )
    retries: int = Field(1, ge=1, description="extra attempts with on_failure: retry")


class GoToTask(FailurePolicy):
    """Navigate to one pose."""

    type: Literal["go_to"]
    pose: Pose


class PatrolTask(FailurePolicy):
    """Visit the waypoints in order, ``loops`` times, waiting ``dwell`` seconds at each."""

    type: Literal["patrol"]
    waypoints: list[Pose] = Field(min_length=1, max_length=MAX_WAYPOINTS)
    loops: int = Field(1, ge=1, le=MAX_LOOPS, description="rounds; each is built when it starts")
    dwell: float = Field(
        0.0, ge=0.0, le=MAX_SIM_SECONDS, description="simulated seconds at each waypoint"
    )


class WanderTask(StrictModel):
    """Drive ahead while the range ahead exceeds ``min_range``, turn otherwise (seed ex. 7.3)."""

    type: Literal["wander"]
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


class VisitRoomsTask(FailurePolicy, SettleBeforeRecording):
    """Go into each room in order (its anchor, or a free point well inside it)."""

    type: Literal["visit_rooms"]
    rooms: list[str] = Field(
        min_length=1, max_length=MAX_ROOMS, description="room labels, visited in this order"
    )
    record: bool = Field(False, description="record the estimated pose in each room")


class RecordRoomTask(SettleBeforeRecording):
    """Record the current estimated pose under a label (the seed's room_service call)."""

    type: Literal["record_room"]
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


class MapAreaTask(StrictModel):
    """Explore ``bounds`` by frontiers while SLAM builds the map; save it map_saver-style.

    Later tasks of the mission navigate (and localise) on the saved map.
    """

    type: Literal["map_area"]
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


class TeleopTask(StrictModel):
    """Hold the robot under remote command (the service's live stream sends cmd_vel).

    The robot stops when no command arrived for 0.5 s of wall time; under the service,
    simulated time runs at wall-clock speed during this task.
    """

    type: Literal["teleop"]
    duration: float | None = Field(
        None, gt=0.0, description="simulated seconds; None: until the run is cancelled"
    )


Task = Annotated[
    Union[  # noqa: UP007
        GoToTask, PatrolTask, WanderTask, VisitRoomsTask, RecordRoomTask, MapAreaTask, TeleopTask
    ],
    Field(discriminator="type"),
]


StartSpec = Annotated[
    Union[Annotated[Pose, Tag("Pose")], Annotated[str, Tag("str")]],  # noqa: UP007
    Discriminator(lambda v: "str" if isinstance(v, str) else "Pose"),
]


class Limits(StrictModel):
    time: float = Field(
        600.0, gt=0.0, le=MAX_SIM_SECONDS, description="simulated seconds for the whole mission"
    )
    collisions: int = Field(0, ge=0, description="collisions allowed before the mission fails")


class BoxObstacle(StrictModel):
    """An unmapped box: present in the simulation, absent from the robot's map."""

    type: Literal["box"]
    x: float
    y: float
    size_x: float = Field(gt=0, description="full length along its own x, m")
    size_y: float = Field(gt=0, description="full width along its own y, m")
    yaw: float = 0.0


class CylinderObstacle(StrictModel):
    """An unmapped cylinder (a person, a bin): in the simulation, not on the map."""

    type: Literal["cylinder"]
    x: float
    y: float
    radius: float = Field(gt=0)


Obstacle = Annotated[Union[BoxObstacle, CylinderObstacle], Field(discriminator="type")]  # noqa: UP007


class Window(StrictModel):
    start: float = Field(0.0, ge=0.0, description="simulated seconds")
    end: float | None = Field(None, gt=0.0, description="simulated seconds; None: to the end")

    @model_validator(mode="after")
    def _ordered(self) -> Window:
        if self.end is not None and self.end <= self.start:
            raise ValueError(f"end ({self.end:g}) must come after start ({self.start:g})")
        return self


class LidarDropoutFault(Window):
    """Scans are lost with probability ``rate`` inside the window."""

    type: Literal["lidar_dropout"]
    rate: float = Field(1.0, gt=0.0, le=1.0)


class WheelSlipFault(Window):
    """The wheels slip: each encoder read is off by up to ``factor`` of the travel."""

    type: Literal["wheel_slip"]
    factor: float = Field(gt=0.0, le=1.0)


class OdometryNoiseFault(Window):
    """Encoder noise multiplied by ``scale`` (added as ``0.01 * scale`` when it is off)."""

    type: Literal["odometry_noise"]
    scale: float = Field(gt=0.0)


class KidnapFault(StrictModel):
    """The robot is carried to ``pose`` at ``time`` (the localiser is not told)."""

    type: Literal["kidnap"]
    time: float = Field(gt=0.0, description="simulated seconds")
    pose: Pose


Fault = Annotated[
    Union[LidarDropoutFault, WheelSlipFault, OdometryNoiseFault, KidnapFault],  # noqa: UP007
    Field(discriminator="type"),
]


class OutputConfig(StrictModel):
    """Where a run directory goes and what it holds beyond the contract's minimum.

    ``output: runs`` (the contract's spelling) is short for ``output: {dir: runs}``. The
    model is path-like (``Path(mission.output)`` is the directory), so code that took
    ``output`` as a string keeps working.
    """

    dir: str = Field("runs", description="root of run directories")
    bag: bool = Field(True, description="write bag/ (a ROS 2 bag of the run) in the run directory")

    @model_validator(mode="before")
    @classmethod
    def _from_string(cls, v: Any) -> Any:
        return {"dir": v} if isinstance(v, str) else v

    def __fspath__(self) -> str:
        return self.dir

    def __str__(self) -> str:
        return self.dir


class Setup(StrictModel):
    """Where and with what a robot drives: world, robot, start, stack and simulation.

    The part of a mission that does not say what to do; ``teleop`` drives in one of these.
    """

    name: str | None = Field(
        None,
        max_length=MAX_NAME_LENGTH,
        description="default: the file's stem",
        json_schema_extra={"pattern": r"^[^/\\]*[^/\\\s][^/\\]*$"},
    )
    world: str = Field(
        "turtlebot3_world",
        description="a built-in world, a world file, or a ROS map_server YAML",
    )
    rooms: str | None = Field(None, description="rooms file; built-in worlds carry their own")
    robot: str = Field("burger", description="burger, waffle, rosbots, or a robot file")
    start: StartSpec | None = Field(
        None, description="a pose or a room label; default: the world's spawn pose"
    )
    seed: int = Field(0, ge=0, description="every random draw of the run derives from it")
    stack: Stack = Field(default_factory=Stack)
    simulation: SimConfig = Field(default_factory=SimConfig)
    limits: Limits = Field(default_factory=Limits)
    obstacles: list[Obstacle] = Field(
        default_factory=list,
        max_length=MAX_OBSTACLES,
        description="unmapped obstacles, in the simulation only",
    )
    faults: list[Fault] = Field(
        default_factory=list, max_length=MAX_FAULTS, description="faults to inject"
    )
    recorder: str | None = Field(
        None,
        description="an existing location_recorder.yaml to append to (updated in place; "
        "the run directory gets a copy)",
    )
    output: OutputConfig = Field(
        default_factory=OutputConfig,
        description="root of run directories (a string), or {dir, bag}: bag: false skips bag/",
    )

    @field_validator("name")
    @classmethod
    def _name_is_a_path_component(cls, v: str | None) -> str | None:
        if v is not None and (not v.strip() or "/" in v or "\\" in v):
            raise ValueError("name must be a non-empty string without path separators")
        return v


class Mission(Setup):
    """A mission file: a setup and the tasks to carry out in it."""

    tasks: list[Task] = Field(min_length=1, max_length=MAX_TASKS)
    expect: Expectations | None = Field(
        None,
        description="what `agv-mission regress` checks of the run (ignored by `run`): final "
        "and per-task status, time, collisions, clearance, localisation, map IoU, rooms, "
        "waypoints",
    )


# The order a resolved mission is written in (mission.yaml): what to do after the stack.
FIELD_ORDER = (
    "name",
    "world",
    "rooms",
    "robot",
    "start",
    "seed",
    "stack",
    "simulation",
    "tasks",
    "limits",
    "obstacles",
    "faults",
    "recorder",
    "output",
    "expect",
)


JSON_SCHEMA_DIALECT = "https://json-schema.org/draft/2020-12/schema"


def mission_json_schema() -> dict[str, Any]:
    """The JSON Schema of a mission file (what ``agv-mission schema`` prints).

    A stack block without ``type`` is the slot's default plugin, as the loader reads it.
    """
    schema = Mission.model_json_schema()
    slots = schema["$defs"]["Stack"]["properties"]
    for slot, name in DEFAULT_PLUGINS.items():
        union = slots[slot]
        mapping = union.get("discriminator", {}).get("mapping", {})
        if name not in mapping:
            continue
        slots[slot] = {
            "title": union.get("title", slot),
            "description": f"a plugin chosen by `type`; without one: {name}, or the one "
            "plugin whose options the block uses",
            "if": {"type": "object", "not": {"required": ["type"]}},
            "then": {"anyOf": [{"$ref": ref} for ref in mapping.values()]},
            "else": {k: v for k, v in union.items() if k != "title"},
        }
    # ``output: runs`` is the contract's spelling of ``output: {dir: runs}``
    output = schema["properties"]["output"]
    schema["properties"]["output"] = {
        "description": output["description"],
        "anyOf": [{"type": "string"}, {"$ref": output["$ref"]}],
    }
    return {"$schema": JSON_SCHEMA_DIALECT, **schema}
