"""Mission loading: YAML with line numbers, ``--set`` overrides, validation, resolution.

Everything that can be wrong with the input is found here, before anything runs, and
reported as :class:`MissionError` naming file, line and field. Resolution (the world, its
maps and costmaps) is imported only once the file has passed its schema and its trees are
assembled, so bad input is reported without it; and what it reads is imported as it reads
it (Pillow for a map image, lxml for a Gazebo world).
"""

from __future__ import annotations

import copy
from collections.abc import Sequence
from dataclasses import replace
from importlib.resources import as_file, files
from pathlib import Path
from typing import TYPE_CHECKING, Any

import yaml
from pydantic import ValidationError

from agv_mission.atomic import InputFileError, read_input_bytes
from agv_mission.missions.load.errors import MissionError, Problem, utf8_text
from agv_mission.missions.load.layout import default_to_odometry, fleet_layout
from agv_mission.missions.load.overrides import Override, apply_overrides
from agv_mission.missions.load.problems import (
    ProblemLog,
    kind_of,
    non_finite_numbers,
    non_string_keys,
    validation_problems,
    yaml_problem,
)
from agv_mission.missions.load.schema import (
    MAX_SIM_SECONDS,
    Mission,
    Setup,
    with_default_plugin_types,
)
from agv_mission.missions.load.tree_assembly import assemble, tasks_tree
from agv_mission.missions.load.tree_sources import tree_source, with_absolute_tree_files
from agv_mission.missions.load.yaml_lines import FieldPath, load_with_lines

if TYPE_CHECKING:
    from agv_mission.missions.load.resolved import LoadedMission, PathGuard

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
    data, lines = _document(text, file)
    return load_mission_document(
        path, data, lines, overrides, seed, tasks_required=tasks_required, path_guard=path_guard
    )


def load_mission_document(
    path: Path,
    data: dict[str, Any],
    lines: dict[FieldPath, int],
    overrides: Sequence[str | Override] | None = None,
    seed: int | None = None,
    *,
    tasks_required: bool = True,
    path_guard: PathGuard | None = None,
) -> LoadedMission:
    """:func:`load_mission` of a document already read from ``path``: ``data``, the
    mapping (changed here), and ``lines``, each field's line in the file. A front door
    that takes fields of its own out of the file (the VDA 5050 master's ``actions:``)
    hands the rest over as it is: every problem still names the file's own lines."""
    file = str(path)
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
    assigned = fleet_layout(data, log)
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

    mission = _validated(data, log, tasks_required)
    log.raise_if_any()  # what the fleet's layout found

    base_dir = path.parent if path.name else Path.cwd()
    if isinstance(mission, Mission) and mission.robots:
        from agv_mission.missions.load.fleet_resolution import resolve_fleet

        loaded = resolve_fleet(
            mission, data, assigned, base_dir, path.stem or "mission", log, path_guard
        )
        return _found_from(loaded, path, base_dir, log)
    tree = None
    if isinstance(mission, Mission):
        for i, fault in enumerate(mission.faults):
            if fault.robot is not None:
                log.add(("faults", i, "robot"), "robot: names a fleet robot; this mission has one")
        log.raise_if_any()
        tree = assemble(tree_source(mission, data, log, base_dir, path_guard))
    from agv_mission.missions.load.resolve import resolve_setup

    loaded = resolve_setup(mission, base_dir, path.stem or "mission", log, path_guard, tree)
    return _found_from(loaded, path, base_dir, log)


def _found_from(
    loaded: LoadedMission, path: Path, base_dir: Path, log: ProblemLog
) -> LoadedMission:
    """``loaded`` read from ``path``: its warnings, and the tree files it names absolute
    (every file it names is read by now)."""
    loaded.source, loaded.warnings = path, list(log.warnings)
    loaded.mission = with_absolute_tree_files(loaded.mission, base_dir)
    return loaded


def _document(text: str, file: str) -> tuple[dict[str, Any], dict[FieldPath, int]]:
    """The mission's YAML as a mapping (a copy the loader may change) and its lines."""
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
    return copy.deepcopy(data), lines


def _validated(data: dict[str, Any], log: ProblemLog, tasks_required: bool) -> Setup:
    """``data`` as a :class:`Mission` (a :class:`Setup` when it may lack tasks), with the
    shape rules pydantic cannot say (a tree file ends in .xml; tasks or tree, not both)."""
    file = log.file
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
    return mission


def _read_text(path: Path, file: str) -> str:
    try:
        raw = read_input_bytes(path)
    except InputFileError as exc:
        raise MissionError([Problem(file, None, "", str(exc))]) from None
    return utf8_text(raw, file)


def remote_controlled(loaded: LoadedMission, time_limit: float = MAX_SIM_SECONDS) -> LoadedMission:
    """``loaded``'s setup (world, robots, starts, stacks) with one open-ended ``teleop`` task
    per robot instead of its behaviour: every robot under remote command, as the service's
    teleop task, the terminal and VDA 5050 vehicles drive them. A fleet keeps its robots
    and loses its fleet tasks (nothing is dispatched)."""
    teleop = [{"type": "teleop"}]
    doc = loaded.mission.model_dump(exclude={"tasks", "tree", "trees", "blackboard", "expect"})
    doc["limits"] = {**doc.get("limits", {}), "time": time_limit}
    entries = doc.get("robots") or []  # a fleet's robots: each its own, under robots:
    for entry in entries:
        entry["tasks"] = entry["tree"] = None
    if not entries:  # a one-robot mission's: at the top level
        doc["tasks"] = teleop
    return replace(
        loaded,
        mission=Mission.model_validate(doc),
        robots=[replace(r, tree=tasks_tree(teleop)) for r in loaded.robots],
        fleet_tasks=[],
    )
