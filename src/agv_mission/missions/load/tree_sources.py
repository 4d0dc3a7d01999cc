"""Where a mission's trees come from: its ``tasks:``, a YAML ``tree:`` or a BT.CPP XML
file (read under the front door's path guard), and the nodes the world checks look at."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from agv_mission.atomic import InputFileError, input_path, read_input_bytes
from agv_mission.missions.load.errors import MissionError, utf8_text
from agv_mission.missions.load.problems import (
    ProblemLog,
    os_message,
)
from agv_mission.missions.load.schema import Mission, Setup
from agv_mission.missions.load.tree_spec import TreeSource, TreeSpec, Where, tasks_spec, yaml_spec
from agv_mission.missions.load.tree_xml import parse_xml
from agv_mission.missions.load.yaml_lines import FieldPath

if TYPE_CHECKING:  # the resolved mission's module brings the maps: a tree needs none
    from agv_mission.missions.load.resolved import PathGuard


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
    source = xml_source(mission.tree, ("tree",), log, base_dir, path_guard)
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
            raw = read_input_bytes(xml_path)
        except InputFileError as exc:
            raise MissionError(
                [where.problem(f"cannot read {name!r}: {exc}", "behavior_tree")]
            ) from None
        except OSError as exc:
            message = f"cannot read {name!r}: {os_message(exc)}"
            raise MissionError([where.problem(message, "behavior_tree")]) from None
        return parse_xml(utf8_text(raw, str(xml_path)), str(xml_path))

    return load


def xml_source(
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
        raw = read_input_bytes(xml_path)
    except InputFileError as exc:
        log.add(field_path, f"cannot read {name!r}: {exc}")
        raise MissionError(log.problems) from None
    except OSError as exc:
        log.add(field_path, f"cannot read {name!r}: {os_message(exc)}")
        raise MissionError(log.problems) from None
    return parse_xml(utf8_text(raw, str(xml_path)), str(xml_path))


def node_checks(tree: TreeSpec | None, log: ProblemLog) -> list[Any]:
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


def with_absolute_tree_files(mission: Setup, base_dir: Path) -> Setup:
    """``mission`` (a copy) with the XML tree file it names (and each of a fleet's robots)
    and every navigator's ``behavior_tree`` file in their trees absolute, read from
    ``base_dir``: the mission, written into a run directory, still names its files."""

    def absolute(spec: str) -> str:
        return str(input_path(spec.strip(), base_dir).resolve())

    def tree_files(holder: Any) -> dict[str, Any]:
        update: dict[str, Any] = {}
        tree = getattr(holder, "tree", None)
        if isinstance(tree, str):
            update["tree"] = absolute(tree)
        elif tree is not None:
            update["tree"] = _absolute_behavior_trees(tree, absolute)
        if getattr(holder, "trees", None):
            update["trees"] = _absolute_behavior_trees(holder.trees, absolute)
        return update

    update = tree_files(mission)
    if getattr(mission, "robots", None):
        update["robots"] = [r.model_copy(update=tree_files(r)) for r in mission.robots]
    return mission.model_copy(update=update) if update else mission


def _absolute_behavior_trees(value: Any, absolute: Callable[[str], str]) -> Any:
    """A copy of ``value`` with every mapping's ``behavior_tree`` file made absolute."""
    if isinstance(value, list):
        return [_absolute_behavior_trees(item, absolute) for item in value]
    if isinstance(value, dict):
        out = {k: _absolute_behavior_trees(v, absolute) for k, v in value.items()}
        if isinstance(value.get("behavior_tree"), str):
            out["behavior_tree"] = absolute(value["behavior_tree"])
        return out
    return value
