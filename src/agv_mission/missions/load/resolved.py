"""A resolved mission: what a loaded mission file is once everything it names is loaded
and checked (:class:`LoadedMission`, each robot a :class:`RobotSetup`)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from agv_mission.atomic import input_path
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


@dataclass
class LoadedMission:
    """A validated mission with everything it names loaded and resolved."""

    mission: Mission  # a Setup (no tasks) when loaded with tasks_required=False
    source: Path | None
    name: str
    world: World  # what is simulated
    robot: RobotDescription
    rooms: dict[str, Room]
    start: Pose2D
    costmap: Costmap
    room_goals: dict[str, Pose2D] = field(default_factory=dict)  # where each visit goes
    recorder: Path | None = None  # an existing recorder file to append to
    tree: TreeSpec | None = None  # what the robot does (None for a setup)
    docks: dict[str, Dock] = field(default_factory=dict)  # the world's and rooms file's
    given_map: OccupancyGrid | None = None  # the mission's ``map:``, when it names one
    zones: ZoneFilters | None = None  # keepout and speed filters (None: no zones)
    people: list[PeopleGroup] = field(default_factory=list)  # resolved ``people:``
    fleet: list[RobotSetup] = field(default_factory=list)  # a fleet mission's robots
    fleet_tasks: list[FleetTask] = field(default_factory=list)  # its tasks: dispatched, assigned
    #: inputs taken as near as they could be (a person's route point moved off a wall)
    warnings: list[Problem] = field(default_factory=list)

    @property
    def is_fleet(self) -> bool:
        """A mission with a ``robots:`` list (fleet.md); else a one-robot mission."""
        return bool(self.fleet)

    @property
    def robots(self) -> list[RobotSetup]:
        """Every robot of the mission: the fleet's, or the one robot of a one-robot
        mission (named :data:`SOLE_ROBOT`)."""
        if self.fleet:
            return self.fleet
        stack = self.mission.stack
        return [
            RobotSetup(
                SOLE_ROBOT,
                self.robot,
                self.start,
                stack,
                self.costmap,
                self.tree,
                self.zones,
                self.room_goals,
            )
        ]

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
        if isinstance(doc.get("tree"), str) and self.source is not None:
            # the copy in a run directory still finds the XML file
            doc["tree"] = str(input_path(doc["tree"].strip(), self.source.parent).resolve())
        if self.source is not None:  # and its navigators' behavior_tree files
            _absolute_tree_files([doc.get("tree"), doc.get("trees")], self.source.parent)
        return {k: doc[k] for k in FIELD_ORDER if k in doc}


def _absolute_tree_files(value: Any, base: Path) -> None:
    """Every ``behavior_tree`` file named in ``value`` (a YAML tree) made absolute."""
    if isinstance(value, list):
        for item in value:
            _absolute_tree_files(item, base)
    elif isinstance(value, dict):
        tree_file = value.get("behavior_tree")
        if isinstance(tree_file, str):
            value["behavior_tree"] = str(input_path(tree_file.strip(), base).resolve())
        for item in value.values():
            _absolute_tree_files(item, base)
