"""One robot's mission resolved against what it names: the world, the robot, the map,
rooms, recorder; then checked against them (starts, goals, docks, zones, people)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from agv_mission.atomic import input_path
from agv_mission.maps.costmap import Costmap
from agv_mission.maps.docks import Dock
from agv_mission.maps.grid import OccupancyGrid
from agv_mission.maps.rooms import Room
from agv_mission.maps.rooms_file import RoomsFileError, load_rooms_file
from agv_mission.maps.ros_map import MapLoadError, load_ros_map
from agv_mission.maps.world_loader import WorldError, builtin_names, load_world
from agv_mission.maps.worlds import World
from agv_mission.missions.load.errors import MissionError
from agv_mission.missions.load.layout import names_no_map
from agv_mission.missions.load.no_map import check_localization, no_map_grid, scan_height
from agv_mission.missions.load.people_resolution import resolve_people
from agv_mission.missions.load.problems import (
    ProblemLog,
    one_line,
    os_message,
)
from agv_mission.missions.load.resolved import SOLE_ROBOT, LoadedMission, PathGuard, RobotSetup
from agv_mission.missions.load.schema import (
    MAX_NAME_LENGTH,
    Setup,
)
from agv_mission.missions.load.schema.base import Pose
from agv_mission.missions.load.schema.zones import KeepoutMask, SpeedMask
from agv_mission.missions.load.tree_sources import node_checks
from agv_mission.missions.load.tree_spec import TreeSpec
from agv_mission.missions.load.world_checks import check_docks, costmap_fits, place_mission
from agv_mission.missions.load.zone_filters import zone_filters
from agv_mission.robots.builtin_robots import BUILTIN_ROBOTS
from agv_mission.robots.description import RobotDescription
from agv_mission.robots.robot_files import RobotFileError, load_robot

if TYPE_CHECKING:
    from agv_mission.maps.recorder import RecorderFile


def resolve_setup(
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
        _guard_paths(mission, base_dir, log, path_guard)
    world = _load_world(mission, base_dir, log)
    robot = _load_robot(mission, base_dir, log)
    given_map = _load_map(mission, base_dir, log)
    rooms = dict(world.rooms)
    docks = dict(world.docks)
    rooms_docks = _load_rooms(mission, base_dir, log, rooms, docks)
    log.raise_if_any()
    assert robot is not None  # else its problems were raised

    checks = [*node_checks(tree, log), *more_checks]
    if names_no_map(mission.map):
        try:
            given_map = no_map_grid(mission, world, rooms, checks)
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
    placed = place_mission(mission, world, robot, rooms, costmap, log.add, checks)
    check_docks(mission, robot, docks, rooms_docks, costmap, log.add, checks)
    zones = zone_filters(mission, robot, rooms, costmap, base_dir, log)
    if zones is not None:
        costmap = zones.costmap  # keepout zones are obstacles of every plan
    people = resolve_people(mission.people, rooms, world.map, log.add, log.warn)  # the world's
    recorder = _recorder(mission, base_dir, log)
    log.raise_if_any()
    return LoadedMission(
        mission=mission,  # type: ignore[arg-type]
        source=None,
        name=mission.name or stem[:MAX_NAME_LENGTH],
        world=placed.world,
        rooms=rooms,
        robots=[
            RobotSetup(
                SOLE_ROBOT,
                robot,
                placed.start,
                mission.stack,
                costmap,
                tree,
                zones,
                placed.room_goals,
            )
        ],
        recorder=recorder,
        docks=docks,
        given_map=given_map,
        people=people,
    )


def _guard_paths(mission: Setup, base_dir: Path, log: ProblemLog, path_guard: PathGuard) -> None:
    """Every file the mission names, asked of the front door's guard before it is read."""
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


def _load_world(mission: Setup, base_dir: Path, log: ProblemLog) -> World:
    """The world the mission names; without one nothing else can be checked."""
    try:
        return load_world(
            mission.world,
            base_dir,
            scan_height(mission.robot, base_dir),
            mission.world_import.skip_unsupported,
        )
    except WorldError as exc:  # each of a world file's problems at its own line
        for message in exc.problems or [one_line(str(exc))]:
            log.add(("world",), message)
    except (OSError, ValueError, RuntimeError) as exc:  # a path the OS refuses
        log.add(("world",), f"cannot read world {mission.world!r}: {os_message(exc)}")
    except MemoryError:
        log.add(
            ("world",),
            f"world {mission.world!r} needs a map too large for memory "
            "(is its resolution too fine for its bounds?)",
        )
    raise MissionError(log.problems) from None


def _load_robot(mission: Setup, base_dir: Path, log: ProblemLog) -> RobotDescription | None:
    """The robot's description; None with its problems noted (the caller raises them)."""
    try:
        return load_robot(mission.robot, base_dir)
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
    return None


def _load_map(mission: Setup, base_dir: Path, log: ProblemLog) -> OccupancyGrid | None:
    """The mission's ``map:`` (None: the world's own map; ``none``: built later)."""
    if names_no_map(mission.map):
        check_localization(mission, log.add)
        return None
    if mission.map is None:
        return None
    try:
        return load_ros_map(input_path(mission.map.strip(), base_dir))
    except MapLoadError as exc:  # names the file and what is wrong with it
        log.add(("map",), one_line(str(exc)))
    except (OSError, ValueError, RuntimeError) as exc:
        log.add(("map",), f"cannot read map {mission.map!r}: {os_message(exc)}")
    except MemoryError:
        log.add(("map",), f"map {mission.map!r} is too large for memory")
    return None


def _load_rooms(
    mission: Setup,
    base_dir: Path,
    log: ProblemLog,
    rooms: dict[str, Room],
    docks: dict[str, Dock],
) -> dict[str, Dock]:
    """The rooms file's rooms and docks added to the world's (in place); its docks."""
    if mission.rooms is None:
        return {}
    try:
        file_rooms, rooms_docks = load_rooms_file(input_path(mission.rooms, base_dir))
    except RoomsFileError as exc:  # each problem names the file, its line and the room
        for line in exc.lines():
            log.add(("rooms",), line)
        return {}
    except Exception as exc:
        log.add(("rooms",), f"cannot read rooms file {mission.rooms!r}: {os_message(exc)}")
        return {}
    rooms.update(file_rooms)
    docks.update(rooms_docks)
    return rooms_docks


def _recorder(mission: Setup, base_dir: Path, log: ProblemLog) -> RecorderFile | None:
    """The existing recorder file the run appends to, read and checked (the run starts
    from what it held now)."""
    if mission.recorder is None:
        return None
    from agv_mission.maps.recorder import RecorderFile, RecorderFileError  # filelock: ~0.05 s

    recorder = None
    try:
        recorder = RecorderFile.read(input_path(mission.recorder, base_dir))
    except RecorderFileError as exc:
        log.add(("recorder",), str(exc))
    except (OSError, ValueError, RuntimeError) as exc:
        log.add(
            ("recorder",),
            f"cannot read recorder file {mission.recorder!r}: {os_message(exc)}",
        )
    return recorder
