"""Mission loading: YAML with line numbers, ``--set`` overrides, validation, resolution.

Everything that can be wrong with the input is found here, before anything runs, and
reported as :class:`MissionError` naming file, line and field.
"""

from __future__ import annotations

import copy
import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from importlib.resources import as_file, files
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from pydantic import ValidationError

from agv_mission.atomic import InputFileError, read_input_bytes
from agv_mission.geometry import Pose2D
from agv_mission.maps.costmap import Costmap
from agv_mission.maps.grid import UNKNOWN
from agv_mission.maps.recorder import RecorderFileError, load_entries
from agv_mission.maps.rooms import Room, reachable_cells, visit_point
from agv_mission.maps.rooms_file import RoomsFileError, load_rooms
from agv_mission.maps.world_loader import WorldError, builtin_names, load_world
from agv_mission.maps.worlds import Box, Cylinder, World
from agv_mission.missions.errors import MissionError, Problem
from agv_mission.missions.overrides import apply, parse_override
from agv_mission.missions.problems import (
    kind_of,
    non_string_keys,
    one_line,
    os_message,
    problem_at,
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
from agv_mission.missions.yaml_lines import FieldPath, load_with_lines
from agv_mission.planners.configs import goal_margin
from agv_mission.robots.description import (
    BUILTIN_ROBOTS,
    RobotDescription,
    RobotFileError,
    load_robot,
)

MAX_GRID_CELLS = 16_000_000  # a costmap or SLAM grid: 16 M cells (e.g. 200 m x 200 m at 5 cm)

# A front door's rule on which files a mission may name: (field, resolved path) -> a
# problem message, or None when the file may be read.
PathGuard = Callable[[str, Path], "str | None"]


@dataclass
class LoadedMission:
    """A validated mission with everything it names loaded and resolved."""

    mission: Mission  # a Setup (no tasks) when loaded with tasks_required=False
    source: Path | None
    name: str
    world: World
    robot: RobotDescription
    rooms: dict[str, Room]
    start: Pose2D
    costmap: Costmap
    room_goals: dict[str, Pose2D] = field(default_factory=dict)  # where each visit goes
    recorder: Path | None = None  # an existing recorder file to append to

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
    bad_keys = non_string_keys(data)
    if bad_keys:
        raise MissionError(
            [
                problem_at(
                    file,
                    p,
                    f"keys must be strings, got {p[-1]!r} (quote it)",
                    lines,
                    override_paths,
                )
                for p in bad_keys
            ]
        )

    with_default_plugin_types(data)
    non_finite = _non_finite_numbers(data)
    if non_finite:
        raise MissionError(
            [
                problem_at(
                    file,
                    p,
                    f"expected a finite number, got {yaml.safe_dump(value).splitlines()[0]}",
                    lines,
                    override_paths,
                )
                for p, value in non_finite
            ]
        )

    model: type[Setup] = Mission if tasks_required or "tasks" in data else Setup
    try:
        mission = model.model_validate(data, strict=True)
    except ValidationError as exc:
        raise MissionError(
            validation_problems(file, exc, data, lines, override_paths, model)
        ) from None
    except RecursionError:  # e.g. an alias that contains itself: a: &x [*x]
        raise MissionError(
            [Problem(file, None, "", "the document nests too deeply (or contains itself)")]
        ) from None

    base_dir = path.parent if path.name else Path.cwd()
    loaded = _resolve(
        mission, file, base_dir, path.stem or "mission", lines, override_paths, path_guard
    )
    loaded.source = path
    return loaded


def _resolve(
    mission: Setup,
    file: str,
    base_dir: Path,
    stem: str,
    lines: dict[FieldPath, int],
    override_paths: dict[FieldPath, str],
    path_guard: PathGuard | None = None,
) -> LoadedMission:
    problems: list[Problem] = []

    def problem(field_path: FieldPath, message: str) -> None:
        problems.append(problem_at(file, field_path, message, lines, override_paths))

    if path_guard is not None:
        named = {
            "world": None if mission.world.strip() in builtin_names() else mission.world,
            "robot": None if mission.robot in BUILTIN_ROBOTS else mission.robot,
            "rooms": mission.rooms,
            "recorder": mission.recorder,
        }
        for key, spec in named.items():
            refused = spec is not None and path_guard(key, _resolve_path(spec.strip(), base_dir))
            if refused:
                problem((key,), refused)
        if problems:
            raise MissionError(problems)

    try:
        world = load_world(mission.world, base_dir)
    except WorldError as exc:
        problem(("world",), one_line(str(exc)))
        raise MissionError(problems) from None
    except (OSError, ValueError, RuntimeError) as exc:  # a path the OS refuses
        problem(("world",), f"cannot read world {mission.world!r}: {os_message(exc)}")
        raise MissionError(problems) from None
    except MemoryError:
        problem(
            ("world",),
            f"world {mission.world!r} needs a map too large for memory "
            "(is its resolution too fine for its bounds?)",
        )
        raise MissionError(problems) from None
    try:
        robot = load_robot(mission.robot, base_dir)
    except FileNotFoundError:
        problem(
            ("robot",),
            f"no built-in robot or robot file {mission.robot!r} "
            "(built-in: burger, waffle, rosbots)",
        )
    except RobotFileError as exc:
        problem(("robot",), f"invalid robot file {mission.robot!r}: {exc}")
    except (OSError, ValueError, RuntimeError) as exc:
        problem(("robot",), f"cannot read robot file {mission.robot!r}: {os_message(exc)}")
    rooms = dict(world.rooms)
    if mission.rooms is not None:
        try:
            rooms.update(load_rooms(_resolve_path(mission.rooms, base_dir)))
        except RoomsFileError as exc:  # names the file, the line and the room
            problem(("rooms",), one_line(str(exc)))
        except Exception as exc:
            problem(("rooms",), f"cannot read rooms file {mission.rooms!r}: {os_message(exc)}")
    if problems:
        raise MissionError(problems)

    resolution = mission.stack.costmap.resolution
    if resolution is not None:
        cells = grid_cells(world.map.extent, resolution)
        if cells > MAX_GRID_CELLS:
            problem(
                ("stack", "costmap", "resolution"),
                f"{resolution:g} m cells make a costmap of {cells:.3g} cells for this world; "
                f"at most {MAX_GRID_CELLS:.3g} (use a coarser resolution)",
            )
            raise MissionError(problems)
    costmap = Costmap.from_grid(world.map, robot.footprint_radius, mission.stack.costmap)

    if mission.start is None:
        start = world.spawn
    elif isinstance(mission.start, str):
        room = rooms.get(mission.start)
        if room is None:
            problem(
                ("start",),
                f"unknown room {mission.start!r}; known rooms: "
                f"{', '.join(sorted(rooms)) or '(none)'}",
            )
            start = world.spawn
        elif room.anchor is None:
            x, y = room.centroid()
            start = Pose2D(x, y, 0.0)
        else:
            start = room.anchor
    else:
        start = mission.start.to_pose2d()
    _check_pose(start, costmap, ("start",), problem)
    margin = goal_margin(mission.stack.global_planner)  # goals: as the navigator plans
    for i, task in enumerate(_tasks(mission)):
        if task.type == "go_to":
            _check_pose(task.pose.to_pose2d(), costmap, ("tasks", i, "pose"), problem, margin)
        elif task.type == "patrol":
            for j, wp in enumerate(task.waypoints):
                _check_pose(wp.to_pose2d(), costmap, ("tasks", i, "waypoints", j), problem, margin)
    for i, fault in enumerate(mission.faults):
        if fault.type == "kidnap":
            _check_pose(fault.pose.to_pose2d(), costmap, ("faults", i, "pose"), problem)
    if mission.obstacles:
        world = _with_obstacles(world, mission.obstacles)
        for i, obstacle in enumerate(mission.obstacles):
            gap = _distance_to_obstacle(obstacle, start.x, start.y)
            if gap < robot.footprint_radius:
                problem(
                    ("obstacles", i),
                    f"the robot's start ({start.x:g}, {start.y:g}) "
                    f"lies within {robot.footprint_radius:g} m of this obstacle",
                )
    _check_map_areas(mission, world.map.extent, problem)
    room_goals = _room_goals(mission, rooms, costmap, start, problem)
    recorder = None
    if mission.recorder is not None:
        try:
            recorder = _resolve_path(mission.recorder, base_dir)
            load_entries(recorder)
        except RecorderFileError as exc:
            problem(("recorder",), str(exc))
        except (OSError, ValueError, RuntimeError) as exc:
            problem(
                ("recorder",),
                f"cannot read recorder file {mission.recorder!r}: {os_message(exc)}",
            )
    if problems:
        raise MissionError(problems)
    return LoadedMission(
        mission=mission,  # type: ignore[arg-type]
        source=None,
        name=mission.name or stem[:MAX_NAME_LENGTH],
        world=world,
        robot=robot,
        rooms=rooms,
        start=start,
        costmap=costmap,
        room_goals=room_goals,
        recorder=recorder,
    )


def _tasks(mission: Setup) -> list[Any]:
    return mission.tasks if isinstance(mission, Mission) else []


def _with_obstacles(world: World, obstacles: list[Any]) -> World:
    """The world with unmapped obstacles added to its geometry (its map stays as it was)."""
    boxes = list(world.boxes)
    cylinders = list(world.cylinders)
    for o in obstacles:
        if o.type == "box":
            boxes.append(Box(o.x, o.y, o.size_x / 2.0, o.size_y / 2.0, o.yaw))
        else:
            cylinders.append(Cylinder(o.x, o.y, o.radius))
    return dataclasses.replace(world, boxes=boxes, cylinders=cylinders)


def _distance_to_obstacle(o: Any, x: float, y: float) -> float:
    if o.type == "cylinder":
        return math.hypot(x - o.x, y - o.y) - o.radius
    c, s = math.cos(o.yaw), math.sin(o.yaw)
    lx, ly = c * (x - o.x) + s * (y - o.y), -s * (x - o.x) + c * (y - o.y)
    dx, dy = max(abs(lx) - o.size_x / 2.0, 0.0), max(abs(ly) - o.size_y / 2.0, 0.0)
    return math.hypot(dx, dy)


def _room_goals(
    mission: Setup, rooms: dict[str, Room], costmap: Costmap, start: Pose2D, problem: Any
) -> dict[str, Pose2D]:
    """Where each visited room is entered: its anchor, or a reachable point well inside."""
    goals: dict[str, Pose2D] = {}
    allowed: np.ndarray | None = None
    for i, task in enumerate(_tasks(mission)):
        if task.type != "visit_rooms":
            continue
        for j, label in enumerate(task.rooms):
            if label in goals:
                continue
            room = rooms.get(label)
            if room is None:
                problem(
                    ("tasks", i, "rooms", j),
                    f"unknown room {label!r}; known rooms: "
                    f"{', '.join(sorted(rooms)) or '(none: give a rooms file)'}",
                )
                continue
            if room.anchor is not None:
                margin = goal_margin(mission.stack.global_planner)
                _check_pose(room.anchor, costmap, ("tasks", i, "rooms", j), problem, margin)
                goals[label] = room.anchor
                continue
            if allowed is None:
                allowed = reachable_cells(costmap, start, margin=0.1)
            point = visit_point(room, costmap, allowed)
            if point is None:
                problem(
                    ("tasks", i, "rooms", j),
                    f"room {label!r} has no free point the robot can reach",
                )
            else:
                goals[label] = point
    return goals


def grid_cells(extent: tuple[float, float, float, float], resolution: float) -> float:
    """Cells of a grid covering ``extent`` at ``resolution`` (a float: it may be huge)."""
    xmin, xmax, ymin, ymax = extent
    return math.ceil((xmax - xmin) / resolution) * math.ceil((ymax - ymin) / resolution)


def _non_finite_numbers(data: Any, limit: int = 10) -> list[tuple[FieldPath, float]]:
    """Paths of ``.inf``/``.nan`` values anywhere in the document (every block, plugin
    configs included: no number of a mission may be infinite)."""
    found: list[tuple[FieldPath, float]] = []
    seen: set[int] = set()
    stack: list[tuple[Any, FieldPath]] = [(data, ())]
    while stack and len(found) < limit:
        node, path = stack.pop()
        if isinstance(node, float):
            if not math.isfinite(node):
                found.append((path, node))
            continue
        if id(node) in seen:
            continue
        seen.add(id(node))
        if isinstance(node, dict):
            stack.extend((value, (*path, key)) for key, value in node.items())
        elif isinstance(node, list):
            stack.extend((item, (*path, i)) for i, item in enumerate(node))
    return sorted(found, key=lambda item: tuple(map(str, item[0])))


def _check_map_areas(
    mission: Mission, extent: tuple[float, float, float, float], problem: Any
) -> None:
    """``map_area`` bounds overlap the world's map, and SLAM's grid over them fits."""
    xmin, xmax, ymin, ymax = extent
    resolution = float(getattr(mission.stack.slam, "resolution", 0.05))
    for i, task in enumerate(_tasks(mission)):
        if task.type != "map_area":
            continue
        bounds = task.bounds.as_tuple() if task.bounds is not None else extent
        bx0, bx1, by0, by1 = bounds
        if bx1 <= xmin or bx0 >= xmax or by1 <= ymin or by0 >= ymax:
            problem(
                ("tasks", i, "bounds"),
                f"(x {bx0:g}..{bx1:g}, y {by0:g}..{by1:g}) do not overlap the map "
                f"(x {xmin:g}..{xmax:g}, y {ymin:g}..{ymax:g})",
            )
            continue
        cells = grid_cells(bounds, resolution)
        if cells > MAX_GRID_CELLS:
            problem(
                ("tasks", i, "bounds"),
                f"a SLAM map of these bounds at {resolution:g} m has {cells:.3g} cells; at "
                f"most {MAX_GRID_CELLS:.3g} (smaller bounds or a coarser stack.slam.resolution)",
            )


def _check_pose(
    pose: Pose2D, costmap: Costmap, field_path: FieldPath, problem: Any, margin: float = 0.0
) -> None:
    """A pose on the map, in known free space, with the robot's radius (and, for a goal,
    the planner's ``margin``) clear of obstacles."""
    xmin, xmax, ymin, ymax = costmap.grid.extent
    xy = np.array([pose.x, pose.y])
    if not all(math.isfinite(v) for v in (pose.x, pose.y, pose.yaw)):
        problem(
            field_path,
            f"(x {pose.x:g}, y {pose.y:g}, yaw {pose.yaw:g}) is not a finite pose",
        )
    elif not (xmin <= pose.x < xmax and ymin <= pose.y < ymax):
        problem(
            field_path,
            f"({pose.x:g}, {pose.y:g}) is outside the map "
            f"(x {xmin:g}..{xmax:g}, y {ymin:g}..{ymax:g})",
        )
    elif costmap.grid.value_at(xy) == UNKNOWN:
        problem(field_path, f"({pose.x:g}, {pose.y:g}) lies in unknown space of the map")
    elif not costmap.is_free(xy, margin):
        clearance = float(costmap.clearance(xy))
        needs = f"robot radius {costmap.robot_radius:.3f} m"
        if margin > 0:
            needs += f" + the planner's clearance {margin:.3f} m"
        problem(
            field_path,
            f"({pose.x:g}, {pose.y:g}) is inside or too close to an obstacle "
            f"(clearance {clearance:.3f} m; needs more than {needs})",
        )


def _resolve_path(spec: str, base_dir: Path) -> Path:
    p = Path(spec).expanduser()
    return p if p.is_absolute() else base_dir / p


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
