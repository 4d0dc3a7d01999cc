"""A whole mission file: :class:`Setup` (world, robot, start, stack, simulation) and
:class:`Mission` (a setup and its tasks), and the order a resolved mission is written in."""

from __future__ import annotations

from typing import Any

from pydantic import Field, field_validator, model_validator

from agv_mission.behaviors.ports import Task
from agv_mission.missions.load.schema.base import (
    MAX_FAULTS,
    MAX_NAME_LENGTH,
    MAX_OBSTACLES,
    MAX_SIM_SECONDS,
    MAX_TASKS,
    StartSpec,
    StrictModel,
)
from agv_mission.missions.load.schema.disturbances import Fault, Obstacle
from agv_mission.missions.load.schema.expect import Expectations
from agv_mission.missions.load.schema.fleet import Fleet
from agv_mission.missions.load.schema.people import People
from agv_mission.missions.load.schema.stack import Stack
from agv_mission.missions.load.schema.zones import MAX_ZONES, Zone
from agv_mission.robots.sim_config import SimConfig


class Limits(StrictModel):
    time: float = Field(
        600.0, gt=0.0, le=MAX_SIM_SECONDS, description="simulated seconds for the whole mission"
    )
    collisions: int = Field(0, ge=0, description="collisions allowed before the mission fails")


class WorldImport(StrictModel):
    """How a Gazebo world (``.world``/``.sdf``) is read (robots-and-worlds.md)."""

    skip_unsupported: bool = Field(
        False,
        description="skip what cannot be read (a mesh, a tilted cylinder, a non-static model) "
        "and list it in result.json's world_import, instead of refusing the world",
    )


#: ``map: none``: the robot is given no map (robots-and-worlds.md).
NO_MAP = "none"
#: Largest seed: SQLite's (the service's run registry) and most JSON readers' integers.
MAX_SEED = 2**63 - 1


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
    world_import: WorldImport = Field(
        default_factory=WorldImport, description="how a Gazebo world is read"
    )
    map: str | None = Field(
        None,
        description="a ROS map_server YAML the robot is given (localisation, planning, rooms), "
        "in the world's frame, e.g. from an earlier map_area run; the world stays what is "
        "simulated; `none`: no map (odometry, plans on what the lidar shows); default: the "
        "world's own map",
    )
    rooms: str | None = Field(None, description="rooms file; built-in worlds carry their own")
    robot: str = Field("burger", description="burger, waffle, rosbots, or a robot file")
    start: StartSpec | None = Field(
        None, description="a pose or a room label; default: the world's spawn pose"
    )
    seed: int = Field(
        0,
        ge=0,
        le=MAX_SEED,
        description="every random draw of the run derives from it (a 63-bit integer, as "
        "the run registry and result.json keep it)",
    )
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
    zones: list[Zone] = Field(
        default_factory=list,
        max_length=MAX_ZONES,
        description="keepout and speed-limit zones: polygons, rooms or Nav2 filter masks",
    )
    people: People = Field(
        default_factory=list,
        description="simulated people who wander in an area or walk a route (ORCA)",
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


#: A fleet robot's name: its ROS namespace (fleet.md).
ROBOT_NAME_PATTERN = r"^[a-z][a-z0-9_]{0,31}$"
MAX_ROBOTS = 64


class FleetRobot(StrictModel):
    """One robot of a fleet mission: a body in the shared world with its own stack and
    behaviour (fleet.md)."""

    name: str = Field(
        pattern=ROBOT_NAME_PATTERN,
        description="[a-z][a-z0-9_]{0,31}, unique: the robot's ROS namespace",
    )
    robot: str = Field("burger", description="burger, waffle, rosbots, or a robot file")
    start: StartSpec = Field(description="a pose, a room label or a dock name")
    stack: Stack = Field(
        default_factory=Stack,
        description="merged over the mission's stack (the mission's stack where it says nothing)",
    )
    tasks: list[Task] | None = Field(  # type: ignore[assignment]
        None,
        max_length=MAX_TASKS,
        description="this robot's own tasks (they run before any dispatched to it)",
    )
    tree: dict[str, Any] | str | None = Field(
        None, description="this robot's own tree (a node or a BT.CPP XML file), instead of tasks"
    )

    @model_validator(mode="after")
    def _one_behaviour(self) -> FleetRobot:
        if self.tasks is not None and self.tree is not None:
            raise ValueError("a robot has `tasks` or `tree`, not both")
        return self


class Mission(Setup):
    """A mission file: a setup and what to do in it, as ``tasks`` or as a ``tree``; with a
    ``robots:`` list, a fleet mission (fleet.md)."""

    tasks: list[Task] = Field(  # type: ignore[assignment]  (absent: None, given: a list)
        None,
        min_length=1,
        max_length=MAX_TASKS,
        description="shorthand for a tree: a sequence of these task nodes",
    )
    tree: dict[str, Any] | str = Field(  # type: ignore[assignment]
        None,
        description="the behaviour tree (behaviour-trees.md): a node {type, name, ports..., "
        "children | child}, or a BT.CPP v4 XML file (a path ending in .xml); "
        "`agv-mission tree nodes` lists the node types",
    )
    trees: dict[str, dict[str, Any]] = Field(
        default_factory=dict,
        description="named subtrees (BT.CPP <BehaviorTree ID>), used as {type: subtree, id}",
    )
    blackboard: dict[str, Any] = Field(
        default_factory=dict, description="initial blackboard entries, read by ports as {key}"
    )
    robots: list[FleetRobot] = Field(
        default_factory=list,
        max_length=MAX_ROBOTS,
        description="a fleet: every robot a body in the same world with its own stack and "
        "behaviour; `tasks` are then the fleet's (`robot:` assigns one, the others are "
        "dispatched)",
    )
    fleet: Fleet = Field(
        default_factory=Fleet,
        description="the fleet layer's plugins: `dispatcher` (default quickest_finish) and "
        "`traffic` (default reservations)",
    )
    expect: Expectations | None = Field(
        None,
        description="what `agv-mission regress` checks of the run (ignored by `run`): final "
        "and per-task status, time, collisions, clearance, localisation, map IoU, rooms, "
        "waypoints",
    )

    @model_validator(mode="after")
    def _tree_or_tasks(self) -> Mission:
        if self.robots:
            if self.tree is not None:
                raise ValueError("a fleet mission's robots carry their trees (robots[].tree)")
            return self
        if (self.tasks is None) == (self.tree is None):
            raise ValueError("a mission has `tasks` or `tree`, not both" if self.tasks else
                             "a mission needs `tasks` or a `tree`")  # fmt: skip
        if isinstance(self.tree, str) and not self.tree.strip().endswith(".xml"):
            raise ValueError("tree: a string names a BT.CPP XML file (ending in .xml)")
        return self


# The order a resolved mission is written in (mission.yaml): what to do after the stack.
FIELD_ORDER = (
    "name",
    "world",
    "world_import",
    "map",
    "rooms",
    "robot",
    "start",
    "seed",
    "fleet",
    "stack",
    "simulation",
    "blackboard",
    "trees",
    "tree",
    "robots",
    "tasks",
    "limits",
    "obstacles",
    "faults",
    "zones",
    "people",
    "recorder",
    "output",
    "expect",
)
