"""Mission loading: YAML with line numbers, ``--set`` overrides, validation, resolution.

Everything that can be wrong with the input is found here, before anything runs, and
reported as :class:`MissionError` naming file, line and field.
"""

from __future__ import annotations

import contextlib
import copy
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from importlib.resources import as_file, files
from pathlib import Path
from typing import Any

import yaml
from pydantic import ValidationError

from agv_mission.atomic import InputFileError, input_path, read_input_bytes
from agv_mission.geometry import Pose2D
from agv_mission.maps.costmap import Costmap
from agv_mission.maps.docks import Dock
from agv_mission.maps.grid import OccupancyGrid
from agv_mission.maps.recorder import RecorderFileError, load_entries
from agv_mission.maps.rooms import Room
from agv_mission.maps.rooms_file import RoomsFileError, load_rooms_file
from agv_mission.maps.ros_map import MapLoadError, load_ros_map
from agv_mission.maps.world_loader import WorldError, builtin_names, load_world
from agv_mission.maps.worlds import World
from agv_mission.maps.zones import FilterMask, ZoneFilters
from agv_mission.missions.spec.errors import MissionError, Problem
from agv_mission.missions.spec.no_map import (
    check_localization,
    default_to_odometry,
    names_no_map,
    no_map_grid,
    scan_height,
)
from agv_mission.missions.spec.overrides import Override, apply_overrides
from agv_mission.missions.spec.people_resolution import resolve_people
from agv_mission.missions.spec.problems import (
    ProblemLog,
    kind_of,
    non_finite_numbers,
    non_string_keys,
    one_line,
    os_message,
    validation_problems,
    yaml_problem,
)
from agv_mission.missions.spec.schema import (
    FIELD_ORDER,
    MAX_NAME_LENGTH,
    MAX_SIM_SECONDS,
    Mission,
    Setup,
    Stack,
    with_default_plugin_types,
)
from agv_mission.missions.spec.schema.base import Pose
from agv_mission.missions.spec.schema.zones import KeepoutMask, KeepoutZone, SpeedMask
from agv_mission.missions.spec.tree_assembly import assemble, tasks_tree
from agv_mission.missions.spec.tree_spec import TreeSource, TreeSpec, Where, tasks_spec, yaml_spec
from agv_mission.missions.spec.tree_xml import parse_xml
from agv_mission.missions.spec.world_checks import check_docks, costmap_fits, place_mission
from agv_mission.missions.spec.yaml_lines import FieldPath, load_with_lines
from agv_mission.robots.description import (
    BUILTIN_ROBOTS,
    RobotDescription,
    RobotFileError,
    load_robot,
)
from agv_mission.world.crowd import PeopleGroup

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


DEMO_MISSION = "visit_rooms.yaml"  # what ``agv-mission run`` runs without a file


def load_demo_mission(
    overrides: Sequence[str | Override] | None = None, seed: int | None = None
) -> LoadedMission:
    """The demo mission shipped in the package, loaded like a file."""
    with as_file(files("agv_mission") / "data" / "missions" / DEMO_MISSION) as demo:
        return load_mission(demo, overrides, seed)


def load_mission(
    path: str | Path,
    overrides: Sequence[str | Override] | None = None,
    seed: int | None = None,
    text: str | None = None,
    *,
    tasks_required: bool = True,
    path_guard: PathGuard | None = None,
) -> LoadedMission:
    """Read, override, validate and resolve a mission file.

    With ``tasks_required=False`` a file without ``tasks`` is a :class:`Setup` (world,
    robot, start, stack) and resolves the same way; one with tasks is still checked whole.
    ``overrides`` apply in order (a plain string is a ``--set`` item; an
    :class:`Override` names its option, e.g. ``--sweep``). ``path_guard`` is asked before any file the mission names is read (the service lets
    missions read only files under its data directory).
    """
    path = Path(path)
    file = str(path)
    if text is None:
        text = _read_text(path, file)
    try:
        data, lines = load_with_lines(text)
    except yaml.YAMLError as exc:
        raise MissionError([yaml_problem(file, exc, text)]) from None
    except RecursionError:
        raise MissionError([Problem(file, None, "", "the document nests too deeply")]) from None
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise MissionError(
            [
                Problem(
                    file,
                    lines.get((), 1),
                    "",
                    f"expected a mapping of mission keys, got {kind_of(data)}",
                )
            ]
        )
    data = copy.deepcopy(data)
    applied = apply_overrides(data, overrides or [])
    override_paths: dict[FieldPath, str] = dict(applied.paths)
    if seed is not None:
        data["seed"] = seed
        override_paths[("seed",)] = f"--seed {seed}"
    log = ProblemLog(file, lines, override_paths, type_swaps=applied.type_swaps)
    log.warnings += applied.hints  # tasks[0].loops: taken as tasks.0.loops, saying so
    bad_keys = non_string_keys(data)
    if bad_keys:
        raise MissionError(
            [log.at(p, f"keys must be strings, got {p[-1]!r} (quote it)") for p in bad_keys]
        )

    default_to_odometry(data)  # map: none
    assigned = _fleet_layout(data, log)
    with_default_plugin_types(data)
    for robot in data.get("robots") or []:
        if isinstance(robot, dict) and isinstance(robot.get("stack"), dict):
            with_default_plugin_types(robot)
    non_finite = non_finite_numbers(data)
    if non_finite:
        raise MissionError(
            [
                log.at(p, f"expected a finite number, got {yaml.safe_dump(value).splitlines()[0]}")
                for p, value in non_finite
            ]
        )

    wants = tasks_required or "tasks" in data or "tree" in data or "robots" in data
    model: type[Setup] = Mission if wants else Setup
    tree_file = data.get("tree")
    if isinstance(tree_file, str) and not tree_file.strip().endswith(".xml"):
        message = f"a string names a BT.CPP XML file (ending in .xml), not {tree_file!r}"
        raise MissionError([log.at(("tree",), message)])
    fleet = data.get("robots") not in (None, [])
    if model is Mission and not fleet and ("tasks" in data) == ("tree" in data):
        both = "tasks" in data
        message = (
            "a mission has `tasks` or `tree`, not both" if both else "required field is missing"
        )
        raise MissionError([log.at(("tree",) if both else ("tasks",), message)])
    try:
        mission = model.model_validate(data, strict=True)
    except ValidationError as exc:
        raise MissionError([*log.problems, *validation_problems(log, exc, data, model)]) from None
    except RecursionError:  # e.g. an alias that contains itself: a: &x [*x]
        raise MissionError(
            [Problem(file, None, "", "the document nests too deeply (or contains itself)")]
        ) from None
    log.raise_if_any()  # what the fleet's layout found

    base_dir = path.parent if path.name else Path.cwd()
    if isinstance(mission, Mission) and mission.robots:
        loaded = _resolve_fleet(
            mission, data, assigned, base_dir, path.stem or "mission", log, path_guard
        )
        loaded.source, loaded.warnings = path, list(log.warnings)
        return loaded
    tree = None
    if isinstance(mission, Mission):
        for i, fault in enumerate(mission.faults):
            if fault.robot is not None:
                log.add(("faults", i, "robot"), "robot: names a fleet robot; this mission has one")
        log.raise_if_any()
        tree = assemble(tree_source(mission, data, log, base_dir, path_guard))
    loaded = _resolve(mission, base_dir, path.stem or "mission", log, path_guard, tree)
    loaded.source, loaded.warnings = path, list(log.warnings)
    return loaded


def _fleet_layout(data: dict[str, Any], log: ProblemLog) -> dict[int, str]:
    """A fleet mission's data made ready to validate (in place): each robot's ``stack``
    merged over the mission's, and the fleet tasks' ``robot:`` taken out (returned by
    task index). Top-level ``robot:``/``start:`` beside ``robots:`` are refused."""
    robots = data.get("robots")
    if not isinstance(robots, list) or not robots:
        return {}
    for key in ("robot", "start"):
        if key in data:
            log.add(
                (key,),
                f"a fleet mission (with `robots:`) names each robot's {key} in its entry "
                f"under robots:, not a top-level `{key}:`",
            )
            del data[key]  # reported; the rest is still checked
    shared = data.get("stack")
    for robot in robots:
        if isinstance(robot, dict) and isinstance(shared, dict):
            own = robot.get("stack")
            if own is None or isinstance(own, dict):
                robot["stack"] = _merged(shared, own or {})
    assigned: dict[int, str] = {}
    for i, task in enumerate(data.get("tasks") or []):
        if isinstance(task, dict) and "robot" in task:
            name = task.pop("robot")
            if not isinstance(name, str):
                log.add(("tasks", i, "robot"), f"expected a robot's name, got {kind_of(name)}")
            else:
                assigned[i] = name
    return assigned


def _merged(base: dict[str, Any], over: dict[str, Any]) -> dict[str, Any]:
    """``over`` merged into a copy of ``base``, mapping by mapping; a plugin block whose
    ``type`` differs replaces the base's block whole."""
    out = copy.deepcopy(base)
    for key, value in over.items():
        old = out.get(key)
        swap = (
            isinstance(old, dict)
            and isinstance(value, dict)
            and ("type" in value and old.get("type", value["type"]) != value["type"])
        )
        if isinstance(old, dict) and isinstance(value, dict) and not swap:
            out[key] = _merged(old, value)
        else:
            out[key] = copy.deepcopy(value)
    return out


def tree_source(
    mission: Mission,
    data: dict[str, Any],
    log: ProblemLog,
    base_dir: Path,
    path_guard: PathGuard | None = None,
) -> TreeSource:
    """What the mission says to do, as written: tasks, a YAML tree, or a BT.CPP file."""
    file, lines = log.file, log.lines
    trees = {
        tree_id: yaml_spec(body, ("trees", tree_id), file, lines)
        for tree_id, body in (data.get("trees") or {}).items()
    }
    load = tree_loader(base_dir, path_guard)
    if mission.tasks is not None:
        main = tasks_spec(data["tasks"], file, lines)
        return TreeSource(main, trees, dict(mission.blackboard), load=load)
    if isinstance(mission.tree, dict):
        main = yaml_spec(data["tree"], ("tree",), file, lines)
        return TreeSource(main, trees, dict(mission.blackboard), load=load)
    assert isinstance(mission.tree, str)
    source = _xml_source(mission.tree, ("tree",), log, base_dir, path_guard)
    source.trees = {**trees, **source.trees}
    source.blackboard = dict(mission.blackboard)
    source.load = load
    return source


def tree_loader(base_dir: Path, path_guard: PathGuard | None) -> Callable[[str, Where], TreeSource]:
    """How a navigator node's ``behavior_tree`` file is read (relative to the mission
    file), its problems reported at the node's port."""

    def load(name: str, where: Where) -> TreeSource:
        xml_path = input_path(name.strip(), base_dir)
        refused = path_guard("tree", xml_path) if path_guard is not None else None
        if refused:
            raise MissionError([where.problem(refused, "behavior_tree")])
        try:
            text = read_input_bytes(xml_path).decode("utf-8")
        except InputFileError as exc:
            raise MissionError(
                [where.problem(f"cannot read {name!r}: {exc}", "behavior_tree")]
            ) from None
        except (OSError, UnicodeDecodeError) as exc:
            message = f"cannot read {name!r}: {os_message(exc)}"
            raise MissionError([where.problem(message, "behavior_tree")]) from None
        return parse_xml(text, str(xml_path))

    return load


def _xml_source(
    name: str,
    field_path: FieldPath,
    log: ProblemLog,
    base_dir: Path,
    path_guard: PathGuard | None,
) -> TreeSource:
    """The BT.CPP XML file ``name`` (the mission's field at ``field_path``) as a tree."""
    xml_path = input_path(name.strip(), base_dir)
    refused = path_guard("tree", xml_path) if path_guard is not None else None
    if refused:
        log.add(field_path, refused)
        log.raise_if_any()
    try:
        text = read_input_bytes(xml_path).decode("utf-8")
    except InputFileError as exc:
        log.add(field_path, f"cannot read {name!r}: {exc}")
        raise MissionError(log.problems) from None
    except (OSError, UnicodeDecodeError) as exc:
        log.add(field_path, f"cannot read {name!r}: {os_message(exc)}")
        raise MissionError(log.problems) from None
    return parse_xml(text, str(xml_path))


def _resolve(
    mission: Setup,
    base_dir: Path,
    stem: str,
    log: ProblemLog,
    path_guard: PathGuard | None = None,
    tree: TreeSpec | None = None,
    more_checks: Sequence[Any] = (),
) -> LoadedMission:
    """Load what the mission names (world, robot, rooms, recorder) and check the mission
    against them (with ``more_checks``: nodes beside the tree, e.g. a fleet's tasks); every
    problem found is raised together."""
    if path_guard is not None:
        named = {
            "world": None if mission.world.strip() in builtin_names() else mission.world,
            "robot": None if mission.robot in BUILTIN_ROBOTS else mission.robot,
            "map": None if names_no_map(mission.map) else mission.map,
            "rooms": mission.rooms,
            "recorder": mission.recorder,
        }
        for key, spec in named.items():
            refused = spec is not None and path_guard(key, input_path(spec.strip(), base_dir))
            if refused:
                log.add((key,), refused)
        for i, zone in enumerate(mission.zones):  # a mask is a map_server YAML and its image
            if isinstance(zone, KeepoutMask | SpeedMask):
                refused = path_guard("world", input_path(zone.map.strip(), base_dir))
                if refused:
                    log.add(("zones", i, "map"), refused)
        log.raise_if_any()

    try:
        world = load_world(
            mission.world,
            base_dir,
            scan_height(mission.robot, base_dir),
            mission.world_import.skip_unsupported,
        )
    except WorldError as exc:  # each of a world file's problems at its own line
        for message in exc.problems or [one_line(str(exc))]:
            log.add(("world",), message)
        raise MissionError(log.problems) from None
    except (OSError, ValueError, RuntimeError) as exc:  # a path the OS refuses
        log.add(("world",), f"cannot read world {mission.world!r}: {os_message(exc)}")
        raise MissionError(log.problems) from None
    except MemoryError:
        log.add(
            ("world",),
            f"world {mission.world!r} needs a map too large for memory "
            "(is its resolution too fine for its bounds?)",
        )
        raise MissionError(log.problems) from None
    try:
        robot = load_robot(mission.robot, base_dir)
    except FileNotFoundError:
        log.add(
            ("robot",),
            f"no built-in robot or robot file {mission.robot!r} "
            "(built-in: burger, waffle, rosbots)",
        )
    except RobotFileError as exc:
        for line, name, message in exc.problems:
            where = (f"line {line}: " if line is not None else "") + (f"{name}: " if name else "")
            log.add(("robot",), f"invalid robot file {mission.robot!r}: {where}{message}")
    except (OSError, ValueError, RuntimeError) as exc:
        log.add(("robot",), f"cannot read robot file {mission.robot!r}: {os_message(exc)}")
    given_map = None
    if names_no_map(mission.map):
        check_localization(mission, log.add)
    elif mission.map is not None:
        try:
            given_map = load_ros_map(input_path(mission.map.strip(), base_dir))
        except MapLoadError as exc:  # names the file and what is wrong with it
            log.add(("map",), one_line(str(exc)))
        except (OSError, ValueError, RuntimeError) as exc:
            log.add(("map",), f"cannot read map {mission.map!r}: {os_message(exc)}")
        except MemoryError:
            log.add(("map",), f"map {mission.map!r} is too large for memory")
    rooms = dict(world.rooms)
    docks = dict(world.docks)
    rooms_docks: dict[str, Dock] = {}
    if mission.rooms is not None:
        try:
            file_rooms, rooms_docks = load_rooms_file(input_path(mission.rooms, base_dir))
            rooms.update(file_rooms)
            docks.update(rooms_docks)
        except RoomsFileError as exc:  # each problem names the file, its line and the room
            for line in exc.lines():
                log.add(("rooms",), line)
        except Exception as exc:
            log.add(("rooms",), f"cannot read rooms file {mission.rooms!r}: {os_message(exc)}")
    log.raise_if_any()

    node_checks = [*_node_checks(tree, log), *more_checks]
    if names_no_map(mission.map):
        try:
            given_map = no_map_grid(mission, world, rooms, node_checks)
        except ValueError as exc:
            log.add(("map",), f"map: none: {exc}")
            raise MissionError(log.problems) from None
    known = given_map if given_map is not None else world.map
    if not costmap_fits(mission, known, log.add):
        raise MissionError(log.problems)
    costmap = Costmap.from_grid(known, robot.inscribed_radius, mission.stack.costmap)
    if isinstance(mission.start, str) and mission.start not in rooms and mission.start in docks:
        dock = docks[mission.start].pose  # a robot may start on its dock
        mission = mission.model_copy(
            update={"start": Pose.model_validate({"x": dock.x, "y": dock.y, "yaw": dock.yaw})}
        )
    placed = place_mission(mission, world, robot, rooms, costmap, log.add, node_checks)
    check_docks(mission, robot, docks, rooms_docks, costmap, log.add, node_checks)
    zones = _zone_filters(mission, robot, rooms, costmap, base_dir, log)
    if zones is not None:
        costmap = zones.costmap  # keepout zones are obstacles of every plan
    people = resolve_people(mission.people, rooms, world.map, log.add, log.warn)  # the world's
    recorder = None
    if mission.recorder is not None:
        try:
            recorder = input_path(mission.recorder, base_dir)
            load_entries(recorder)
        except RecorderFileError as exc:
            log.add(("recorder",), str(exc))
        except (OSError, ValueError, RuntimeError) as exc:
            log.add(
                ("recorder",),
                f"cannot read recorder file {mission.recorder!r}: {os_message(exc)}",
            )
    log.raise_if_any()
    return LoadedMission(
        mission=mission,  # type: ignore[arg-type]
        source=None,
        name=mission.name or stem[:MAX_NAME_LENGTH],
        world=placed.world,
        robot=robot,
        rooms=rooms,
        start=placed.start,
        costmap=costmap,
        room_goals=placed.room_goals,
        recorder=recorder,
        tree=tree,
        docks=docks,
        given_map=given_map,
        zones=zones,
        people=people,
    )


class _RobotLog:
    """A fleet robot's view of the mission's problems: what it calls ``start``, ``robot``
    and ``stack`` is its entry's under ``robots:``. It collects its own problems (one
    robot's do not stop the next robot's checks); :meth:`merge` hands them on, each
    problem once."""

    OWN = ("start", "robot", "stack")

    def __init__(self, log: ProblemLog, index: int) -> None:
        self.log, self.index = log, index
        self.file, self.lines = log.file, log.lines
        self.problems: list[Problem] = []

    def _path(self, field_path: FieldPath) -> FieldPath:
        if field_path and field_path[0] in self.OWN:
            return ("robots", self.index, *field_path)
        return field_path

    def at(self, field_path: FieldPath, message: str) -> Problem:
        return self.log.at(self._path(field_path), message)

    def add(self, field_path: FieldPath, message: str) -> None:
        problem = self.at(field_path, message)
        if problem not in self.problems:
            self.problems.append(problem)

    def warn(self, field_path: FieldPath, message: str) -> None:
        self.log.warn(self._path(field_path), message)

    def raise_if_any(self) -> None:
        if self.problems:
            raise MissionError(self.problems)

    def merge(self) -> None:
        for problem in self.problems:
            if problem not in self.log.problems:
                self.log.problems.append(problem)


def _robot_tree(
    mission: Mission,
    index: int,
    data: dict[str, Any],
    log: ProblemLog,
    base_dir: Path,
    path_guard: PathGuard | None,
) -> TreeSpec | None:
    """A fleet robot's own behaviour (its tasks or tree) as a tree; None when it has none.
    The fleet's tasks join it when the run releases them
    (:func:`agv_mission.missions.run.fleet_orders.queue_fleet_tasks`)."""
    file, lines = log.file, log.lines
    robot, entry = mission.robots[index], data["robots"][index]
    base: FieldPath = ("robots", index)
    trees = {
        tree_id: yaml_spec(body, ("trees", tree_id), file, lines)
        for tree_id, body in (data.get("trees") or {}).items()
    }
    if isinstance(robot.tree, str):
        source = _xml_source(robot.tree, (*base, "tree"), log, base_dir, path_guard)
        source.trees = {**trees, **source.trees}
    elif isinstance(robot.tree, dict):
        source = TreeSource(yaml_spec(entry["tree"], (*base, "tree"), file, lines), trees)
    elif entry.get("tasks"):
        source = TreeSource(tasks_spec(entry["tasks"], file, lines, (*base, "tasks")), trees)
    else:
        return None
    source.blackboard = dict(mission.blackboard)
    source.load = tree_loader(base_dir, path_guard)
    return assemble(source)


def _resolve_fleet(
    mission: Mission,
    data: dict[str, Any],
    assigned: dict[int, str],
    base_dir: Path,
    stem: str,
    log: ProblemLog,
    path_guard: PathGuard | None,
) -> LoadedMission:
    """A fleet mission: every robot resolved against the one world, as a one-robot
    mission of its own; names unique, starts apart, assigned tasks to known robots."""
    names = [r.name for r in mission.robots]
    for j, name in enumerate(names):
        if name in names[:j]:
            log.add(("robots", j, "name"), f"robot name {name!r} is used twice")
    for i, name in sorted(assigned.items()):
        if name not in names:
            log.add(("tasks", i, "robot"), f"no robot {name!r} in robots: ({', '.join(names)})")
    for i, fault in enumerate(mission.faults):
        if fault.robot is not None and fault.robot not in names:
            log.add(
                ("faults", i, "robot"), f"no robot {fault.robot!r} in robots: ({', '.join(names)})"
            )
        elif fault.robot is None and fault.type == "kidnap":
            log.add(
                ("faults", i, "robot"),
                "a kidnap in a fleet carries one robot off: name it (robot: NAME)",
            )
    log.raise_if_any()
    file, lines = log.file, log.lines
    fleet_tasks = []
    for i, task in enumerate(data.get("tasks") or []):
        spec = tasks_spec([task], file, lines, ("tasks",), [i])
        fleet_tasks.append(FleetTask(i, task["type"], assemble(TreeSource(spec)), assigned.get(i)))
    trees = [_robot_tree(mission, i, data, log, base_dir, path_guard) for i in range(len(names))]
    log.raise_if_any()
    # Each fleet task is checked on the map of the robot that will do it (the assigned
    # one; for a dispatched task the robot with the widest footprint); every robot learns
    # where the rooms it may be sent to are entered.
    widest = max(range(len(names)), key=lambda i: _footprint(mission.robots[i].robot, base_dir))
    resolved = []
    for i, robot in enumerate(mission.robots):
        view = mission.model_copy(
            update={"robot": robot.robot, "start": robot.start, "stack": robot.stack}
        )
        robot_log = _RobotLog(log, i)
        checks = []
        for task in fleet_tasks:
            reporter = task.robot == robot.name or (task.robot is None and i == widest)
            for where, ports, report in _node_checks(task.tree, log):
                checks.append((where, ports, report if reporter else _silent))
        with contextlib.suppress(MissionError):  # its problems are in robot_log
            resolved.append(
                _resolve(view, base_dir, stem, robot_log, path_guard, trees[i], checks)  # type: ignore[arg-type]
            )
        robot_log.merge()
    log.raise_if_any()
    for k, b in enumerate(resolved):
        for j, a in enumerate(resolved[:k]):
            gap = a.start.distance_to(b.start)
            need = a.robot.footprint_radius + b.robot.footprint_radius
            if gap < need:
                log.add(
                    ("robots", k, "start"),
                    f"{names[k]} starts {gap:.2f} m from {names[j]}'s start; their "
                    f"footprints need {need:.2f} m",
                )
    log.raise_if_any()
    first = resolved[0]
    first.mission = mission
    first.name = mission.name or stem[:MAX_NAME_LENGTH]
    first.fleet = [
        RobotSetup(
            names[i],
            r.robot,
            r.start,
            mission.robots[i].stack,
            r.costmap,
            trees[i],
            r.zones,
            r.room_goals,
        )
        for i, r in enumerate(resolved)
    ]
    first.tree = trees[0]
    first.fleet_tasks = fleet_tasks
    return first


def _silent(field_path: FieldPath, message: str) -> None:
    """A reporter for checks another robot reports."""


def _footprint(robot: str, base_dir: Path) -> float:
    """A robot's footprint radius, 0 when its description does not load (reported later)."""
    try:
        return load_robot(robot, base_dir).footprint_radius
    except Exception:
        return 0.0


def _zone_filters(
    mission: Setup,
    robot: RobotDescription,
    rooms: dict[str, Room],
    costmap: Costmap,
    base_dir: Path,
    log: ProblemLog,
) -> ZoneFilters | None:
    """The mission's ``zones:`` on the costmap's grid; each problem at its zone's field."""
    if not mission.zones:
        return None
    keepouts: list[Any] = []
    speeds: list[tuple[Any, float]] = []
    keepout_masks: list[FilterMask] = []
    speed_masks: list[tuple[FilterMask, bool]] = []
    for i, zone in enumerate(mission.zones):
        if isinstance(zone, KeepoutMask | SpeedMask):
            path = input_path(zone.map.strip(), base_dir)  # the path guard saw it first
            try:
                mask = FilterMask(load_ros_map(path), zone.base, zone.multiplier)
            except MapLoadError as exc:
                log.add(("zones", i, "map"), one_line(str(exc)))
                continue
            except (OSError, ValueError, RuntimeError) as exc:
                log.add(("zones", i, "map"), f"cannot read mask {zone.map!r}: {os_message(exc)}")
                continue
            except MemoryError:
                log.add(("zones", i, "map"), f"mask {zone.map!r} is too large for memory")
                continue
            if isinstance(zone, KeepoutMask):
                keepout_masks.append(mask)
            else:
                speed_masks.append((mask, zone.unit == "percent"))
            continue
        if zone.room is not None:
            room = rooms.get(zone.room)
            if room is None:
                known = ", ".join(sorted(rooms)) or "none"
                log.add(("zones", i, "room"), f"no room {zone.room!r} (rooms: {known})")
                continue
            polygon = room.polygon
        else:
            polygon = tuple((p[0], p[1]) for p in zone.polygon or ())
        if isinstance(zone, KeepoutZone):
            keepouts.append(polygon)
        else:
            limit = zone.max_speed
            if limit is None:
                limit = (zone.percent or 100.0) / 100.0 * robot.max_linear_velocity
            speeds.append((polygon, limit))
    log.raise_if_any()
    return ZoneFilters.build(
        costmap, robot.max_linear_velocity, keepouts, speeds, keepout_masks, speed_masks
    )


def _node_checks(tree: TreeSpec | None, log: ProblemLog) -> list[Any]:
    """Each node with literal ports, once, with where to report what the world checks
    find (the mission file's line, or an XML file's element)."""
    if tree is None:
        return []
    out = []
    seen: set[tuple[str, FieldPath]] = set()
    for _, node in tree.nodes():
        where = node.where
        if node.ports is None or (where.file, where.path) in seen:
            continue
        seen.add((where.file, where.path))
        if where.file == log.file:
            out.append((where.path, node.ports, log.add))
        else:
            out.append((where.path, node.ports, _xml_report(where, log)))
    return out


def _xml_report(where: Any, log: ProblemLog) -> Any:
    def report(field_path: FieldPath, message: str) -> None:
        sub = field_path[len(where.path) :]
        port = ".".join(map(str, sub)) or None
        log.problems.append(where.problem(message, port))

    return report


def _read_text(path: Path, file: str) -> str:
    try:
        raw = read_input_bytes(path)
    except InputFileError as exc:
        raise MissionError([Problem(file, None, "", str(exc))]) from None
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = raw[: exc.start].count(b"\n") + 1
        column = exc.start - (raw.rfind(b"\n", 0, exc.start) + 1) + 1
        message = f"not a UTF-8 text file (byte 0x{raw[exc.start]:02x} at column {column})"
        raise MissionError([Problem(file, line, "", message)]) from None


def remote_controlled(loaded: LoadedMission, time_limit: float = MAX_SIM_SECONDS) -> LoadedMission:
    """``loaded``'s setup (world, robots, starts, stacks) with one open-ended ``teleop`` task
    per robot instead of its behaviour: every robot under remote command, as the service's
    teleop task, the terminal and VDA 5050 vehicles drive them. A fleet keeps its robots
    and loses its fleet tasks (nothing is dispatched)."""
    teleop = [{"type": "teleop"}]
    doc = loaded.mission.model_dump(exclude={"tasks", "tree", "trees", "blackboard", "expect"})
    doc["limits"] = {**doc.get("limits", {}), "time": time_limit}
    if not loaded.is_fleet:
        doc["tasks"] = teleop
        return replace(loaded, mission=Mission.model_validate(doc), tree=tasks_tree(teleop))
    for robot in doc["robots"]:
        robot["tasks"] = robot["tree"] = None
    fleet = [replace(r, tree=tasks_tree(teleop)) for r in loaded.fleet]
    return replace(
        loaded,
        mission=Mission.model_validate(doc),
        tree=fleet[0].tree,
        fleet=fleet,
        fleet_tasks=[],
    )
