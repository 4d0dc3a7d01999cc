"""A resolved mission: what a loaded mission file is once everything it names is loaded
and checked (:class:`LoadedMission`, each robot a :class:`RobotSetup`)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from enum import Enum
from pathlib import Path
from typing import TYPE_CHECKING, Any

from agv_mission.geometry import Pose2D
from agv_mission.maps.costmap import Costmap
from agv_mission.maps.docks import Dock
from agv_mission.maps.grid import OccupancyGrid
from agv_mission.maps.rooms import Room
from agv_mission.maps.worlds import World
from agv_mission.maps.zones import ZoneFilters
from agv_mission.missions.load.errors import Problem
from agv_mission.missions.load.schema import (
    FIELD_ORDER,
    Mission,
    Stack,
)
from agv_mission.missions.load.tree_spec import TreeSpec
from agv_mission.robots.description import (
    RobotDescription,
)
from agv_mission.world.people_groups import PeopleGroup

if TYPE_CHECKING:  # its module brings filelock (~0.05 s): a mission with a recorder only
    from agv_mission.maps.recorder import RecorderFile

# A front door's rule on which files a mission may name: (field, resolved path) -> a
# problem message, or None when the file may be read.
PathGuard = Callable[[str, Path], "str | None"]


@dataclass
class RobotSetup:
    """One robot of a mission as it runs: its name (ROS namespace), description, start,
    stack, the costmap its footprint inflates, its zone filters and what it does."""

    name: str
    robot: RobotDescription
    start: Pose2D
    stack: Stack
    costmap: Costmap
    tree: TreeSpec | None = None
    zones: ZoneFilters | None = None
    room_goals: dict[str, Pose2D] = field(default_factory=dict)


@dataclass
class FleetTask:
    """One task of a fleet mission's ``tasks:``: assigned (``robot``) or dispatched."""

    index: int  # its place in ``tasks:`` (0-based)
    type: str
    tree: TreeSpec  # the task as a tree of its own
    robot: str | None = None  # the robot it is assigned to; None: the dispatcher decides


#: The name of a one-robot mission's robot (its bodies and logs; no ROS namespace).
SOLE_ROBOT = "robot"


class Layout(Enum):
    """How a run of the mission is laid out, fixed by the file's shape when it loads.

    Every loaded mission is a list of robots; the layout says what its run writes and who
    decides beside the robots (the run directory, result.json, the bag)."""

    #: a top-level ``robot:`` (mission-format.md): the robot's run is the mission's run
    ROBOT = "robot"
    #: a ``robots:`` list (fleet.md): the fleet layer dispatches and directs the traffic;
    #: result.json names the robot that failed and holds each robot's result
    FLEET = "fleet"


@dataclass
class LoadedMission:
    """A validated mission with everything it names loaded and resolved: one world and
    its robots (a one-robot mission: one robot named :data:`SOLE_ROBOT`)."""

    mission: Mission  # a Setup (no tasks) when loaded with tasks_required=False
    source: Path | None
    name: str
    world: World  # what is simulated
    rooms: dict[str, Room]
    robots: list[RobotSetup]  # every robot of the mission, in the file's order
    layout: Layout = Layout.ROBOT
    recorder: RecorderFile | None = None  # an existing recorder file to append to, as read
    docks: dict[str, Dock] = field(default_factory=dict)  # the world's and rooms file's
    given_map: OccupancyGrid | None = None  # the mission's ``map:``, when it names one
    people: list[PeopleGroup] = field(default_factory=list)  # resolved ``people:``
    fleet_tasks: list[FleetTask] = field(default_factory=list)  # ``tasks:`` of a fleet
    #: inputs taken as near as they could be (a person's route point moved off a wall)
    warnings: list[Problem] = field(default_factory=list)

    # The first robot's parts: a one-robot mission's robot (teleop, the terminal's
    # messages and a VDA 5050 vehicle drive one robot).
    @property
    def lead(self) -> RobotSetup:
        return self.robots[0]

    @property
    def robot(self) -> RobotDescription:
        return self.lead.robot

    @property
    def start(self) -> Pose2D:
        return self.lead.start

    @property
    def costmap(self) -> Costmap:
        return self.lead.costmap

    @property
    def tree(self) -> TreeSpec | None:
        """What the robot does (None for a setup)."""
        return self.lead.tree

    @property
    def zones(self) -> ZoneFilters | None:
        """Keepout and speed filters (None: no zones)."""
        return self.lead.zones

    @property
    def room_goals(self) -> dict[str, Pose2D]:
        """Where each visit goes."""
        return self.lead.room_goals

    @property
    def map(self) -> OccupancyGrid:
        """The map the robot is given (localisation, planning, rooms): the mission's
        ``map:``, else the world's own map."""
        return self.given_map if self.given_map is not None else self.world.map

    def resolved(self) -> dict[str, Any]:
        """The mission as it runs: defaults filled in and overrides applied."""
        doc = self.mission.model_dump(mode="json")
        doc["name"] = self.name
        for key in ("tasks", "tree", "trees", "blackboard"):  # what the user did not write
            if key in doc and doc[key] in (None, {}):
                del doc[key]
        return {k: doc[k] for k in FIELD_ORDER if k in doc}
