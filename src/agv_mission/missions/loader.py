"""Mission loading: YAML with line numbers, ``--set`` overrides, validation, resolution.

Everything that can be wrong with the input is found here, before anything runs, and
reported as :class:`MissionError` naming file, line and field.
"""

from __future__ import annotations

import copy
from collections.abc import Callable
from dataclasses import dataclass, field
from importlib.resources import as_file, files
from pathlib import Path
from typing import Any

import yaml
from pydantic import ValidationError

from agv_mission.atomic import InputFileError, input_path, read_input_bytes
from agv_mission.geometry import Pose2D
from agv_mission.maps.costmap import Costmap
from agv_mission.maps.grid import OccupancyGrid
from agv_mission.maps.recorder import RecorderFileError, load_entries
from agv_mission.maps.rooms import Room
from agv_mission.maps.rooms_file import RoomsFileError, load_rooms
from agv_mission.maps.ros_map import MapLoadError, load_ros_map
from agv_mission.maps.world_loader import WorldError, builtin_names, load_world
from agv_mission.maps.worlds import World
from agv_mission.missions.errors import MissionError, Problem
from agv_mission.missions.overrides import apply, parse_override
from agv_mission.missions.problems import (
    ProblemLog,
    kind_of,
    non_finite_numbers,
    non_string_keys,
    one_line,
    os_message,
    validation_problems,
    yaml_problem,
)
from agv_mission.missions.schema import (
    FIELD_ORDER,
    MAX_NAME_LENGTH,
    Mission,
    Setup,
    with_default_plugin_types,
)
from agv_mission.missions.world_checks import costmap_fits, place_mission
from agv_mission.missions.yaml_lines import FieldPath, load_with_lines
from agv_mission.robots.description import (
    BUILTIN_ROBOTS,
    RobotDescription,
    RobotFileError,
    load_robot,
)

# A front door's rule on which files a mission may name: (field, resolved path) -> a
# problem message, or None when the file may be read.
PathGuard = Callable[[str, Path], "str | None"]


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
    given_map: OccupancyGrid | None = None  # the mission's ``map:``, when it names one

    @property
    def map(self) -> OccupancyGrid:
        """The map the robot is given (localisation, planning, rooms): the mission's
        ``map:``, else the world's own map."""
        return self.given_map if self.given_map is not None else self.world.map

    def resolved(self) -> dict[str, Any]:
        """The mission as it runs: defaults filled in and overrides applied."""
        doc = self.mission.model_dump(mode="json")
        doc["name"] = self.name
        return {k: doc[k] for k in FIELD_ORDER if k in doc}


DEMO_MISSION = "visit_rooms.yaml"  # what ``agv-mission run`` runs without a file


def load_demo_mission(overrides: list[str] | None = None, seed: int | None = None) -> LoadedMission:
    """The demo mission shipped in the package, loaded like a file."""
    with as_file(files("agv_mission") / "data" / "missions" / DEMO_MISSION) as demo:
        return load_mission(demo, overrides, seed)


def load_mission(
    path: str | Path,
    overrides: list[str] | None = None,
    seed: int | None = None,
    text: str | None = None,
    *,
    tasks_required: bool = True,
    path_guard: PathGuard | None = None,
) -> LoadedMission:
    """Read, override, validate and resolve a mission file.

    With ``tasks_required=False`` a file without ``tasks`` is a :class:`Setup` (world,
    robot, start, stack) and resolves the same way; one with tasks is still checked whole.
    ``path_guard`` is asked before any file the mission names is read (the service lets
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
    override_paths: dict[FieldPath, str] = {}
    for item in overrides or []:
        field_path, value = parse_override(file, item)
        apply(data, field_path, value, file, item)
        override_paths[field_path] = f"--set {item}"
    if seed is not None:
        data["seed"] = seed
        override_paths[("seed",)] = f"--seed {seed}"
    log = ProblemLog(file, lines, override_paths)
    bad_keys = non_string_keys(data)
    if bad_keys:
        raise MissionError(
            [log.at(p, f"keys must be strings, got {p[-1]!r} (quote it)") for p in bad_keys]
        )

    with_default_plugin_types(data)
    non_finite = non_finite_numbers(data)
    if non_finite:
        raise MissionError(
            [
                log.at(p, f"expected a finite number, got {yaml.safe_dump(value).splitlines()[0]}")
                for p, value in non_finite
            ]
        )

    model: type[Setup] = Mission if tasks_required or "tasks" in data else Setup
    try:
        mission = model.model_validate(data, strict=True)
    except ValidationError as exc:
        raise MissionError(validation_problems(log, exc, data, model)) from None
    except RecursionError:  # e.g. an alias that contains itself: a: &x [*x]
        raise MissionError(
            [Problem(file, None, "", "the document nests too deeply (or contains itself)")]
        ) from None

    base_dir = path.parent if path.name else Path.cwd()
    loaded = _resolve(mission, base_dir, path.stem or "mission", log, path_guard)
    loaded.source = path
    return loaded


def _resolve(
    mission: Setup,
    base_dir: Path,
    stem: str,
    log: ProblemLog,
    path_guard: PathGuard | None = None,
) -> LoadedMission:
    """Load what the mission names (world, robot, rooms, recorder) and check the mission
    against them; every problem found is raised together."""
    if path_guard is not None:
        named = {
            "world": None if mission.world.strip() in builtin_names() else mission.world,
            "robot": None if mission.robot in BUILTIN_ROBOTS else mission.robot,
            "map": mission.map,
            "rooms": mission.rooms,
            "recorder": mission.recorder,
        }
        for key, spec in named.items():
            refused = spec is not None and path_guard(key, input_path(spec.strip(), base_dir))
            if refused:
                log.add((key,), refused)
        log.raise_if_any()

    try:
        world = load_world(mission.world, base_dir)
    except WorldError as exc:
        log.add(("world",), one_line(str(exc)))
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
        log.add(("robot",), f"invalid robot file {mission.robot!r}: {exc}")
    except (OSError, ValueError, RuntimeError) as exc:
        log.add(("robot",), f"cannot read robot file {mission.robot!r}: {os_message(exc)}")
    given_map = None
    if mission.map is not None:
        try:
            given_map = load_ros_map(input_path(mission.map.strip(), base_dir))
        except MapLoadError as exc:  # names the file and what is wrong with it
            log.add(("map",), one_line(str(exc)))
        except (OSError, ValueError, RuntimeError) as exc:
            log.add(("map",), f"cannot read map {mission.map!r}: {os_message(exc)}")
        except MemoryError:
            log.add(("map",), f"map {mission.map!r} is too large for memory")
    rooms = dict(world.rooms)
    if mission.rooms is not None:
        try:
            rooms.update(load_rooms(input_path(mission.rooms, base_dir)))
        except RoomsFileError as exc:  # names the file, the line and the room
            log.add(("rooms",), one_line(str(exc)))
        except Exception as exc:
            log.add(("rooms",), f"cannot read rooms file {mission.rooms!r}: {os_message(exc)}")
    log.raise_if_any()

    known = given_map if given_map is not None else world.map
    if not costmap_fits(mission, known, log.add):
        raise MissionError(log.problems)
    costmap = Costmap.from_grid(known, robot.footprint_radius, mission.stack.costmap)
    placed = place_mission(mission, world, robot, rooms, costmap, log.add)
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
        given_map=given_map,
    )


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
