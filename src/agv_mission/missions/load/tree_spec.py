"""A behaviour tree as the user wrote it, and as the assembly validated it.

A ``tasks:`` list (shorthand for a sequence of task nodes), a YAML ``tree:`` with named
``trees:``, or a BT.CPP v4 XML file (:mod:`~agv_mission.missions.load.tree_xml`) all
become :class:`NodeSpec` s (what was written, where: file, line, field path) in a
:class:`TreeSource`; the assembly (:mod:`~agv_mission.missions.load.tree_assembly`)
makes one validated, expanded :class:`TreeSpec` of :class:`Node` s from it.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Any

from agv_mission.behaviors.ports import NodePorts
from agv_mission.missions.load.errors import MissionError, Problem
from agv_mission.missions.load.yaml_lines import FieldPath
from agv_mission.registry import registry

SLOT = "behavior"
#: Keys of a YAML node that are not ports.
STRUCTURE_KEYS = ("type", "name", "children", "child")


@dataclass(frozen=True)
class Where:
    """Where a node was written: the file, its field path and line."""

    file: str
    path: FieldPath
    line: int | None

    def problem(self, message: str, port: str | None = None, line: int | None = None) -> Problem:
        path = self.path + ((port,) if port else ())
        return Problem(self.file, line or self.line, ".".join(map(str, path)), message)


@dataclass
class NodeSpec:
    """A node as written: its type, name, ports (XML: attribute strings) and children."""

    type: str
    where: Where
    name: str | None = None
    ports: dict[str, Any] = field(default_factory=dict)
    port_lines: dict[str, int] = field(default_factory=dict)
    children: list[NodeSpec] = field(default_factory=list)
    from_xml: bool = False
    #: YAML: whether ``child:`` (a decorator's one child) rather than ``children:`` held them
    single_child: bool | None = None


#: Reads a ``behavior_tree`` file a navigator node names (relative to the mission file).
TreeLoader = Callable[[str, Where], "TreeSource"]
#: Node types that run a navigator tree of their own given ``behavior_tree`` (Nav2's
#: NavigateToPose and NavigateThroughPoses actions), and the entry they set in it.
NAVIGATORS = {"navigate_to_pose": "goal", "navigate_through_poses": "goals"}


@dataclass
class TreeSource:
    """What the user wrote: the main tree, the named subtrees, the initial blackboard."""

    main: NodeSpec
    trees: dict[str, NodeSpec] = field(default_factory=dict)
    blackboard: dict[str, Any] = field(default_factory=dict)
    main_id: str = "MainTree"
    load: TreeLoader | None = None  # how navigator nodes read their behavior_tree files


@dataclass
class Node:
    """A validated node of the expanded tree."""

    type: str
    name: str
    kind: str
    ports: NodePorts | None  # None while some input port is a blackboard entry
    literal: dict[str, Any]  # the literal ports (validated values)
    bound: dict[str, str]  # input port -> blackboard key read when the node starts
    children: list[Node]
    where: Where
    tree_id: str | None = None  # a subtree's root: the subtree's ID; a navigator's tree's
    navigator: str | None = None  # a navigator running a tree: its entries' prefix


@dataclass
class TreeSpec:
    """A validated, expanded tree: the root and every node with its path."""

    root: Node
    source: TreeSource
    count: int

    def nodes(self) -> Iterator[tuple[str, Node]]:
        """(path, node), pre-order; the path is ``/``-joined child indices from the root."""
        stack: list[tuple[str, Node]] = [("/", self.root)]
        while stack:
            path, node = stack.pop()
            yield path, node
            base = "" if path == "/" else path
            for i in reversed(range(len(node.children))):
                stack.append((f"{base}/{i}", node.children[i]))

    def checks(self) -> Iterator[tuple[FieldPath, NodePorts]]:
        """Each node with literal ports and its field path, for the world checks."""
        for _, node in self.nodes():
            if node.ports is not None and node.where.path and node.where.file == _main_file(self):
                yield node.where.path, node.ports

    def task_types(self) -> list[str]:
        """The task nodes' types, in tree order (as their indices number them)."""
        return [n.type for _, n in self.nodes() if _is_task(n.type)]


def _main_file(spec: TreeSpec) -> str:
    return spec.root.where.file


def _is_task(node_type: str) -> bool:
    if node_type == "subtree":  # the assembly's own node: a subtree's expansion, not a plugin
        return False
    return bool(getattr(registry.config(SLOT, node_type), "task", False))


# --------------------------------------------------------------------- YAML sources


def yaml_spec(value: Any, path: FieldPath, file: str, lines: dict[FieldPath, int]) -> NodeSpec:
    """A YAML node mapping (already checked to be a mapping with a string ``type``)."""
    line = lines.get(path)
    where = Where(file, path, line)
    if not isinstance(value, dict):
        raise MissionError([where.problem(f"a node is a mapping with a type, got {value!r}")])
    node_type = value.get("type")
    if not isinstance(node_type, str):
        raise MissionError(
            [where.problem("a node needs a `type` (a string)", "type", lines.get(path + ("type",)))]
        )
    name = value.get("name")
    if name is not None and not isinstance(name, str):
        raise MissionError([where.problem("name is a string", "name", lines.get(path + ("name",)))])
    ports = {k: v for k, v in value.items() if k not in STRUCTURE_KEYS}
    port_lines = {k: lines[path + (k,)] for k in ports if path + (k,) in lines}
    for key in ("child", "children", "type", "name"):  # where a wrong structure is reported
        if path + (key,) in lines:
            port_lines[key] = lines[path + (key,)]
    spec = NodeSpec(node_type, where, name, ports, port_lines)
    if "child" in value and "children" in value:
        raise MissionError([where.problem("give `child` or `children`, not both", "children")])
    if "child" in value:
        spec.single_child = True
        spec.children = [yaml_spec(value["child"], path + ("child",), file, lines)]
    elif "children" in value:
        children = value["children"]
        if not isinstance(children, list):
            raise MissionError([where.problem("children is a list of nodes", "children")])
        spec.single_child = False
        spec.children = [
            yaml_spec(c, path + ("children", i), file, lines) for i, c in enumerate(children)
        ]
    return spec


def tasks_spec(
    tasks: list[dict[str, Any]],
    file: str,
    lines: dict[FieldPath, int],
    base: FieldPath = ("tasks",),
    indices: list[int] | None = None,
) -> NodeSpec:
    """``tasks:`` (at ``base``; the tasks' own ``indices`` there, default 0, 1, ...) as the
    tree it is shorthand for: a sequence named ``mission``."""
    children = []
    for i, task in zip(indices or range(len(tasks)), tasks, strict=True):
        where = Where(file, (*base, i), lines.get((*base, i)))
        ports = {k: v for k, v in task.items() if k not in ("type", "robot")}
        children.append(NodeSpec(task["type"], where, None, ports))
    return NodeSpec("sequence", Where(file, base, lines.get(base)), "mission", {},
                    {}, children)  # fmt: skip
