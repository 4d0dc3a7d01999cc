"""A fleet mission (``robots:``) resolved (its layout made ready to validate in
:mod:`~agv_mission.missions.load.layout`): each robot resolved as a one-robot mission of its own against the one world, names unique, starts
apart, the fleet's tasks assigned or left to the dispatcher."""

from __future__ import annotations

import contextlib
from dataclasses import replace
from pathlib import Path
from typing import Any

from agv_mission.missions.load.errors import MissionError, Problem
from agv_mission.missions.load.problems import ProblemLog
from agv_mission.missions.load.resolve import resolve_setup
from agv_mission.missions.load.resolved import FleetTask, Layout, LoadedMission, PathGuard
from agv_mission.missions.load.schema import (
    MAX_NAME_LENGTH,
    Mission,
)
from agv_mission.missions.load.tree_assembly import assemble
from agv_mission.missions.load.tree_sources import node_checks, tree_loader, xml_source
from agv_mission.missions.load.tree_spec import TreeSource, TreeSpec, tasks_spec, yaml_spec
from agv_mission.missions.load.yaml_lines import FieldPath
from agv_mission.robots.robot_files import load_robot


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
        source = xml_source(robot.tree, (*base, "tree"), log, base_dir, path_guard)
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


def resolve_fleet(
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
    _check_names(mission, names, assigned, log)
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
            for where, ports, report in node_checks(task.tree, log):
                checks.append((where, ports, report if reporter else _silent))
        with contextlib.suppress(MissionError):  # its problems are in robot_log
            resolved.append(
                resolve_setup(view, base_dir, stem, robot_log, path_guard, trees[i], checks)  # type: ignore[arg-type]
            )
        robot_log.merge()
    log.raise_if_any()
    _starts_apart(resolved, names, log)
    log.raise_if_any()
    first = resolved[0]
    first.mission = mission
    first.name = mission.name or stem[:MAX_NAME_LENGTH]
    first.robots = [replace(r.lead, name=names[i]) for i, r in enumerate(resolved)]
    first.layout = Layout.FLEET
    first.fleet_tasks = fleet_tasks
    return first


def _check_names(
    mission: Mission, names: list[str], assigned: dict[int, str], log: ProblemLog
) -> None:
    """Robot names unique; tasks and faults name robots of the fleet; a kidnap names one."""
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


def _starts_apart(resolved: list[LoadedMission], names: list[str], log: ProblemLog) -> None:
    """No two robots start closer than their footprints allow."""
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


def _silent(field_path: FieldPath, message: str) -> None:
    """A reporter for checks another robot reports."""


def _footprint(robot: str, base_dir: Path) -> float:
    """A robot's footprint radius, 0 when its description does not load (reported later)."""
    try:
        return load_robot(robot, base_dir).footprint_radius
    except Exception:
        return 0.0
