"""One assembly from whatever the user wrote to one py_trees tree.

A ``tasks:`` list (shorthand for a sequence of task nodes), a YAML ``tree:`` with named
``trees:``, or a BT.CPP v4 XML file all become :class:`NodeSpec` s (what was written,
where: file, line, field path), then one validated, expanded :class:`TreeSpec` (ports
checked against each node type's port model from the registry's ``behavior`` slot,
subtrees inlined with their ports remapped, blackboard reads checked against writes),
then one py_trees tree (:func:`build_tree`). Node types are found the way a third-party
node is: by name in the registry.

The blackboard is a dict per tree (:class:`~agv_mission.behaviors.context.TreeContext`),
not py_trees' ``PortsMixin`` and its blackboard: that storage is process-global, and one
process (the service's worker, regress's fork server) runs several missions. The BT.CPP
parser is ours too (``tree_xml``): py_trees' experimental one keeps no source lines.
"""

from __future__ import annotations

import dataclasses
import inspect
import types
import typing
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import py_trees
import yaml
from py_trees.common import Status
from pydantic import ValidationError

from agv_mission.behaviors.ports import NodePorts, blackboard_key
from agv_mission.missions.spec.errors import MissionError, Problem
from agv_mission.missions.spec.schema.base import MAX_TREE_NODES
from agv_mission.missions.spec.yaml_lines import FieldPath
from agv_mission.registry import UnknownPluginError, registry

if TYPE_CHECKING:  # the behaviours' modules load only when a tree is built
    from agv_mission.behaviors.context import TreeContext

Behaviour = py_trees.behaviour.Behaviour
SLOT = "behavior"
#: Nodes nested deeper than this are refused (building and ticking recurse per level).
MAX_TREE_DEPTH = 100
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


def tasks_tree(tasks: list[dict[str, Any]], file: str = "<tasks>") -> TreeSpec:
    """The tree of a ``tasks:`` list built in code (e.g. teleop's one task)."""
    return assemble(TreeSource(tasks_spec(tasks, file, {})))


# --------------------------------------------------------------------- validation


class _Scope:
    """How a subtree's ``{keys}`` map to its caller's (BT.CPP's SubTree ports)."""

    def __init__(
        self, parent: _Scope | None, remap: dict[str, Any], autoremap: bool, prefix: str
    ) -> None:
        self.parent, self.remap, self.autoremap, self.prefix = parent, remap, autoremap, prefix

    def resolve(self, key: str) -> tuple[str, Any]:
        """("key", the caller's key) or ("value", a literal remapped in)."""
        if key in self.remap:
            value = self.remap[key]
            outer = blackboard_key(value)
            if outer is None:
                return ("value", value)
            return self.parent.resolve(outer) if self.parent else ("key", outer)
        if self.parent is None:
            return ("key", key)
        if self.autoremap:
            return self.parent.resolve(key)
        return ("key", f"{self.prefix}.{key}")


ROOT_SCOPE = _Scope(None, {}, True, "")


@dataclass
class _Assembly:
    source: TreeSource
    problems: list[Problem] = field(default_factory=list)
    count: int = 0
    reads: list[tuple[str, Where, str]] = field(default_factory=list)  # key, where, port
    writes: set[str] = field(default_factory=set)
    expanding: list[str] = field(default_factory=list)
    instances: int = 0
    depth: int = 0

    def node(self, spec: NodeSpec, scope: _Scope) -> Node | None:
        self.depth += 1
        try:
            if self.depth > MAX_TREE_DEPTH:
                raise MissionError(
                    [spec.where.problem(f"the tree nests deeper than {MAX_TREE_DEPTH} nodes")]
                )
            return self._node(spec, scope)
        finally:
            self.depth -= 1

    def _node(self, spec: NodeSpec, scope: _Scope) -> Node | None:
        self.count += 1
        if self.count > MAX_TREE_NODES:
            raise MissionError(
                [
                    spec.where.problem(
                        f"the tree has more than {MAX_TREE_NODES} nodes once its "
                        "subtrees are expanded"
                    )
                ]  # fmt: skip
            )
        if spec.type == "subtree":
            return self.subtree(spec, scope)
        try:
            config = registry.config(SLOT, spec.type)
        except UnknownPluginError:
            known = ", ".join(registry.names(SLOT))
            self.problems.append(
                spec.where.problem(f"unknown node type {spec.type!r} (known: {known})", "type")
            )
            return None
        kind = config.kind
        n = len(spec.children)
        least, most = config.children_range or (1, 1 << 30)
        if kind == "decorator" and spec.single_child is False:
            self.problems.append(
                spec.where.problem(
                    f"a decorator ({spec.type}) takes exactly one `child`, got {n}", "child"
                )  # fmt: skip
            )
            self.problems.append(
                spec.where.problem(
                    f"`children:` is for control nodes; a decorator ({spec.type}) takes "
                    "`child:` (one node)",
                    "children",
                    spec.port_lines.get("children"),
                )  # fmt: skip
            )
        elif kind == "decorator" and n != 1:
            self.problems.append(
                spec.where.problem(
                    f"a decorator ({spec.type}) takes exactly one `child`, got {n}", "child"
                )  # fmt: skip
            )
        elif kind == "control" and (n == 0 or spec.single_child):
            line = spec.port_lines.get("child") if spec.single_child else None
            self.problems.append(
                spec.where.problem(
                    f"a control node ({spec.type}) needs a list of `children`", "children", line
                )  # fmt: skip
            )
        elif kind == "control" and not least <= n <= most:
            count = f"{least}" if least == most else f"{least} to {most}"
            self.problems.append(
                spec.where.problem(
                    f"a {spec.type} node has {count} children, got {n}",
                    "children",
                    spec.port_lines.get("children"),
                )  # fmt: skip
            )
        elif kind in ("action", "condition") and n:
            self.problems.append(
                spec.where.problem(
                    f"{'an' if kind == 'action' else 'a'} {kind} ({spec.type}) has no children",
                    "children",
                )
            )
        literal, bound = self.ports(spec, config, scope)
        children = [c for c in (self.node(child, scope) for child in spec.children) if c]
        model = None
        if literal is not None and not bound:
            model = config.model_validate({"type": spec.type, **literal})
        name = spec.name or _default_name(spec.type)
        node = Node(spec.type, name, kind, model, literal or {}, bound, children, spec.where)
        tree_file = (literal or {}).get("behavior_tree")
        if spec.type in NAVIGATORS and isinstance(tree_file, str) and literal is not None:
            return self.navigator(spec, node, tree_file)
        return node

    def navigator(self, spec: NodeSpec, node: Node, tree_file: str) -> Node | None:
        """A navigator node with its ``behavior_tree``: the file's main tree, expanded in a
        scope of its own (Nav2's navigator has its own blackboard) holding the goal."""
        where = Where(spec.where.file, spec.where.path, spec.port_lines.get("behavior_tree")
                      or spec.where.line)  # fmt: skip
        if self.source.load is None:
            self.problems.append(where.problem("no file can be read here", "behavior_tree"))
            return None
        try:
            loaded = self.source.load(tree_file, where)
        except MissionError as exc:
            self.problems.extend(exc.problems)
            return None
        if tree_file in self.expanding:
            chain = " -> ".join([*self.expanding, tree_file])
            raise MissionError([where.problem(f"the tree runs itself ({chain})", "behavior_tree")])
        self.instances += 1
        prefix = f"{loaded.main_id}#{self.instances}"
        self.writes.add(f"{prefix}.{NAVIGATORS[spec.type]}")
        outer, self.source = self.source, dataclasses.replace(loaded, load=self.source.load)
        self.expanding.append(tree_file)
        try:
            child = self.node(loaded.main, _Scope(ROOT_SCOPE, {}, False, prefix))
        finally:
            self.expanding.pop()
            self.source = outer
        if child is None:
            return None
        node.children = [child]
        node.tree_id, node.navigator = loaded.main_id, prefix
        return node

    def ports(
        self, spec: NodeSpec, config: type[NodePorts], scope: _Scope
    ) -> tuple[dict[str, Any] | None, dict[str, str]]:
        """The literal ports (validated) and the blackboard-bound ones; None on problems."""
        fields = config.model_fields
        literal: dict[str, Any] = {}
        bound: dict[str, str] = {}
        ok = True
        for port, raw in spec.ports.items():
            line = spec.port_lines.get(port)
            if port not in fields or port == "type":
                self.problems.append(
                    spec.where.problem(
                        f"unknown port {port!r} of {spec.type} (ports: "
                        f"{', '.join(f for f in fields if f != 'type') or 'none'})",
                        port,
                        line,
                    )  # fmt: skip
                )
                ok = False
                continue
            extra = fields[port].json_schema_extra or {}
            direction = extra.get("direction", "input") if isinstance(extra, dict) else "input"
            key = blackboard_key(raw)
            if key is not None:
                kind, target = scope.resolve(key)
                if kind == "value":
                    raw, key = target, blackboard_key(target)
                else:
                    key = target
            if direction == "output" or extra.get("entry"):
                name = key if key is not None else str(raw)
                if direction == "output":
                    self.writes.add(name)
                else:
                    self.reads.append((name, spec.where, port))
                literal[port] = name
                continue
            if key is not None:
                if config.kind in ("control", "decorator"):
                    self.problems.append(
                        spec.where.problem(
                            f"a {config.kind}'s ports are literals, not blackboard entries",
                            port,
                            line,
                        )  # fmt: skip
                    )
                    ok = False
                    continue
                bound[port] = key
                self.reads.append((key, spec.where, port))
                continue
            if spec.from_xml and isinstance(raw, str):
                try:
                    raw = _xml_value(raw, fields[port].annotation)
                except yaml.YAMLError:
                    self.problems.append(
                        spec.where.problem(f"cannot read {raw!r} as YAML flow text", port, line)
                    )
                    ok = False
                    continue
            literal[port] = raw
        for port, info in fields.items():  # entries read by default go through the scope too
            extra = info.json_schema_extra if isinstance(info.json_schema_extra, dict) else {}
            if extra.get("entry") and port not in spec.ports and isinstance(info.default, str):
                kind, target = scope.resolve(info.default)
                if kind == "key":
                    literal[port] = target
        if not ok:
            return None, bound
        try:
            config.model_validate({"type": spec.type, **literal}, strict=not spec.from_xml)
        except ValidationError as exc:
            for err in exc.errors(include_url=False):
                loc = [p for p in err["loc"]]
                if err["type"] == "missing" and loc and loc[0] in bound:
                    continue
                port = str(loc[0]) if loc else None
                detail = "".join(f"[{p}]" if isinstance(p, int) else f".{p}" for p in loc[1:])
                msg = err["msg"].removeprefix("Value error, ")
                if err["type"] == "missing" and len(loc) == 1:
                    msg = f"missing port {port!r} of {spec.type}"
                self.problems.append(
                    spec.where.problem(
                        f"{msg}{' at ' + detail if detail else ''}",
                        port,
                        spec.port_lines.get(port or ""),
                    )  # fmt: skip
                )
            return None, bound
        return literal, bound

    def subtree(self, spec: NodeSpec, scope: _Scope) -> Node | None:
        tree_id = spec.ports.get("id", spec.ports.get("ID"))
        if not isinstance(tree_id, str):
            self.problems.append(spec.where.problem("a subtree needs an `id` (a string)", "id"))
            return None
        body = self.source.trees.get(tree_id)
        if body is None:
            known = ", ".join(sorted(self.source.trees)) or "none"
            self.problems.append(
                spec.where.problem(f"unknown subtree id {tree_id!r} (trees: {known})", "id")
            )
            return None
        if tree_id in self.expanding:
            chain = " -> ".join([*self.expanding, tree_id])
            raise MissionError([spec.where.problem(f"subtree {tree_id!r} contains itself ({chain})",
                                                   "id")])  # fmt: skip
        auto = spec.ports.get("_autoremap", False)
        if isinstance(auto, str):
            auto = auto.strip().lower() == "true"
        remap = {k: v for k, v in spec.ports.items() if k not in ("id", "ID", "_autoremap")}
        self.instances += 1
        inner = _Scope(scope, remap, bool(auto), f"{tree_id}#{self.instances}")
        self.expanding.append(tree_id)
        try:
            child = self.node(body, inner)
        finally:
            self.expanding.pop()
        if child is None:
            return None
        name = spec.name or tree_id
        return Node("subtree", name, "decorator", None, {"id": tree_id}, {}, [child], spec.where,
                    tree_id=tree_id)  # fmt: skip


def _default_name(node_type: str) -> str:
    return node_type


def _xml_value(raw: str, annotation: Any) -> Any:
    """An XML attribute's value: a string port keeps it; others read it as YAML flow text."""
    if annotation is str:
        return raw
    return yaml.safe_load(raw)


def assemble(source: TreeSource) -> TreeSpec:
    """Validate and expand ``source``; every problem is raised together."""
    asm = _Assembly(source)
    asm.writes.update(source.blackboard)
    root = asm.node(source.main, ROOT_SCOPE)
    for key, where, port in asm.reads:
        if key not in asm.writes:
            asm.problems.append(
                where.problem(
                    f"reads blackboard entry {key!r}, which nothing writes and `blackboard:` "
                    "does not hold",
                    port,
                )
            )
    if asm.problems or root is None:
        raise MissionError(_unique(asm.problems))
    return TreeSpec(root, source, asm.count)


def _unique(problems: list[Problem]) -> list[Problem]:
    seen: set[Problem] = set()
    return [p for p in problems if not (p in seen or seen.add(p))]


# --------------------------------------------------------------------- building


@dataclass
class NodeRecord:
    """What the run reports of one node: starts and simulated running time."""

    path: str
    node: Node
    behaviour: Behaviour
    started: int = 0
    running: float = 0.0
    since: float | None = None
    last: str = "not_run"  # how it last ended: succeeded, failed or halted


@dataclass
class MissionTree:
    """The root, the task nodes in tree order, and every user node for reports."""

    root: Behaviour
    tasks: list[Behaviour]
    task_nodes: list[Node]  # the task nodes as validated (type, ports), as ``tasks``
    records: list[NodeRecord]
    context: TreeContext

    def render(self) -> str:
        return py_trees.display.unicode_tree(self.root, show_status=True)

    def repeats_until_the_limit(self) -> bool:
        """Whether a node meant to run until the mission's time limit (``repeat`` with
        ``num_cycles: -1``, ``keep_running_until_failure``) is running: the limit then
        ends the tree as it was written to end."""
        for rec in self.records:
            node = rec.node
            if rec.behaviour.status is not Status.RUNNING:
                continue
            if node.type == "keep_running_until_failure":
                return True
            if node.type == "repeat" and node.ports is not None and node.ports.num_cycles < 0:
                return True
        return False

    def report(self) -> list[dict[str, Any]]:
        """``result.json``'s ``tree``: every node the user's tree holds, pre-order."""
        now = self.context.handle.state.time
        out = []
        for rec in self.records:
            running = rec.running + (now - rec.since if rec.since is not None else 0.0)
            entry = {
                "path": rec.path,
                "type": rec.node.type,
                "name": rec.behaviour.name,
                "status": _final_status(rec),
                "started": rec.started,
                "running_time": round(running, 3),
                "source": ".".join(map(str, rec.node.where.path)),
            }
            out.append(entry)
        return out


def _final_status(record: NodeRecord) -> str:
    """Its status now, or how it last ended when its parent has reset it since."""
    status = record.behaviour.status
    if status is Status.INVALID:
        return record.last
    return {Status.SUCCESS: "succeeded", Status.FAILURE: "failed"}.get(status, "running")


def build_tree(spec: TreeSpec, context: TreeContext) -> MissionTree:
    """The py_trees tree of ``spec``; ``context`` is shared by its nodes."""
    builder = _Builder(context)
    root = builder.build(spec.root, "/")
    return MissionTree(root, builder.tasks, builder.task_nodes, builder.records, context)


@dataclass
class _Builder:
    context: TreeContext
    records: list[NodeRecord] = field(default_factory=list)
    tasks: list[Behaviour] = field(default_factory=list)
    task_nodes: list[Node] = field(default_factory=list)

    def build(self, node: Node, path: str) -> Behaviour:
        base = "" if path == "/" else path
        record = NodeRecord(path, node, None)  # type: ignore[arg-type]
        self.records.append(record)
        children = [self.build(c, f"{base}/{i}") for i, c in enumerate(node.children)]
        if node.type == "subtree":
            from agv_mission.behaviors.decorators import SubTree

            behaviour: Behaviour = SubTree(node.name, children[0], node.tree_id or "")
        elif node.navigator is not None:
            from agv_mission.behaviors.nav2_flow import BtNavigator

            behaviour = BtNavigator(node.name, children[0], self.context, node, node.navigator)
        else:
            config = registry.config(SLOT, node.type)
            cls = registry.get(SLOT, node.type)
            name = node.name
            if config.task:  # numbered in tree order, whether or not the node counts itself
                self.context.tasks = len(self.tasks)
                if node.name == node.type:
                    name = f"task {len(self.tasks) + 1}: {node.type}"
            if node.bound:
                behaviour = BlackboardPorts(name, cls, node, self.context)
            else:
                behaviour = construct(cls, config.kind, name, node.ports, children, self.context)
            if config.task:
                self.tasks.append(behaviour)
                self.task_nodes.append(node)
        record.behaviour = behaviour
        _instrument(record, self.context)
        return behaviour


def port_values(ports: NodePorts | None, literal: dict[str, Any]) -> dict[str, Any]:
    """The constructor's keyword arguments: every port (defaults filled in)."""
    if ports is None:
        return dict(literal)
    return {k: getattr(ports, k) for k in type(ports).model_fields if k != "type"}


def construct(
    cls: type,
    kind: str,
    name: str,
    ports: NodePorts | None,
    children: list[Behaviour],
    context: TreeContext,
    literal: dict[str, Any] | None = None,
) -> Behaviour:
    """``cls(name, handle|child|children, **ports)``, with ``handle`` and ``context``
    passed to constructors that ask for them."""
    kwargs = port_values(ports, literal or {})
    params = _parameters(cls)
    if "context" in params:
        kwargs["context"] = context
    if kind == "control":
        if "handle" in params:
            kwargs["handle"] = context.handle
        return cls(name, children, **kwargs)
    if kind == "decorator":
        if "handle" in params:
            kwargs["handle"] = context.handle
        return cls(name, children[0], **kwargs)
    return cls(name, context.handle, **kwargs)


_PARAMS: dict[type, frozenset[str]] = {}


def _parameters(cls: type) -> frozenset[str]:
    params = _PARAMS.get(cls)
    if params is None:
        params = frozenset(inspect.signature(cls.__init__).parameters)
        _PARAMS[cls] = params
    return params


def _instrument(record: NodeRecord, context: TreeContext) -> None:
    """Count starts and simulated running time through the node's own lifecycle calls."""
    node = record.behaviour
    initialise, stop = node.initialise, node.stop

    def counted_initialise() -> None:
        record.started += 1
        record.since = context.handle.state.time
        initialise()

    def timed_stop(new_status: Status = Status.INVALID) -> None:
        if new_status is Status.SUCCESS:
            record.last = "succeeded"
        elif new_status is Status.FAILURE:
            record.last = "failed"
        elif node.status is Status.RUNNING:
            record.last = "halted"
        if record.since is not None:
            record.running += context.handle.state.time - record.since
            record.since = None
        stop(new_status)

    node.initialise = counted_initialise  # type: ignore[method-assign]
    node.stop = timed_stop  # type: ignore[method-assign]


class BlackboardPorts(py_trees.behaviour.Behaviour):
    """A leaf whose ports read blackboard entries: the entries are read, the ports
    validated and the node built each time it starts (BT.CPP reads its inputs on tick)."""

    def __init__(self, name: str, cls: type, node: Node, context: TreeContext):
        super().__init__(name)
        self.cls, self.spec, self.context = cls, node, context
        self.inner: Behaviour | None = None
        self.task = bool(registry.config(SLOT, node.type).task)
        self._index = context.next_task() if self.task else 0
        if self.task:  # its number is kept however often it is rebuilt
            self.context = dataclasses.replace(context)

    def initialise(self) -> None:
        self.inner = None
        values = dict(self.spec.literal)
        bb = self.context.blackboard
        missing = [k for k in self.spec.bound.values() if k not in bb]
        self.feedback_message = ""
        if missing:
            self.feedback_message = f"no blackboard entry {missing[0]!r}"
            return
        for port, key in self.spec.bound.items():
            values[port] = bb[key]
        config = registry.config(SLOT, self.spec.type)
        if self.task:
            self.context.tasks = self._index
        try:
            ports = config.model_validate({"type": self.spec.type, **values})
            self.inner = construct(self.cls, self.spec.kind, self.name, ports, [], self.context)
            self.inner.ports_model = ports  # what result.json reports it ran with
        except (ValidationError, ValueError, KeyError) as exc:
            self.feedback_message = f"bad port value from the blackboard: {exc}".splitlines()[0]

    def update(self) -> Status:
        if self.inner is None:
            return Status.FAILURE
        for _ in self.inner.tick():
            pass
        self.feedback_message = self.inner.feedback_message
        return self.inner.status

    def terminate(self, new_status: Status) -> None:
        inner = self.inner
        if new_status is Status.INVALID and inner is not None and inner.status is Status.RUNNING:
            inner.stop(Status.INVALID)


def node_types() -> list[dict[str, Any]]:
    """Every registered node type: kind, description and ports (for ``tree nodes``)."""
    out = []
    for name in registry.names(SLOT):
        try:
            config = registry.config(SLOT, name)
        except UnknownPluginError:
            continue
        ports = []
        for port, info in config.model_fields.items():
            if port == "type":
                continue
            extra = info.json_schema_extra if isinstance(info.json_schema_extra, dict) else {}
            default = None if info.is_required() else info.get_default(call_default_factory=True)
            ports.append(
                {
                    "name": port,
                    "direction": extra.get("direction", "input"),
                    "type": _type_name(info.annotation),
                    "default": _plain(default),
                    "required": info.is_required(),
                    "description": info.description or "",
                }
            )
        doc = inspect.getdoc(config) or ""
        out.append(
            {
                "type": name,
                "kind": config.kind,
                "task": bool(config.task),
                "description": " ".join(doc.split("\n\n")[0].split()),
                "ports": ports,
            }
        )
    return out


def _plain(value: Any) -> Any:
    if hasattr(value, "model_dump"):
        return value.model_dump(mode="json")
    return value


def _type_name(annotation: Any) -> str:
    """A port's type as BT.CPP and Groot2 name it: ``double``, ``int``, ``bool``,
    ``std::string``, or one type name of ours (``Pose``, ``Goal``, ``PoseList``...)."""
    origin, args = typing.get_origin(annotation), typing.get_args(annotation)
    if origin in (typing.Union, types.UnionType):
        inner = [a for a in args if a is not type(None)]
        names = {_type_name(a) for a in inner}
        if names == {"Pose", "std::string"}:
            return "Goal"  # a pose or a room label
        return _type_name(inner[0]) if len(names) == 1 else "std::string"
    if origin is typing.Annotated:
        return _type_name(args[0])
    if origin is typing.Literal:
        return "std::string"
    if origin is list:
        item = _type_name(args[0]) if args else "Value"
        plain = {"double": "Double", "int": "Int", "bool": "Bool", "std::string": "String"}
        return f"{plain.get(item, item)}List"
    simple = {float: "double", int: "int", bool: "bool", str: "std::string"}
    if annotation in simple:
        return simple[annotation]
    if annotation is typing.Any or annotation is None:
        return "std::string"
    return getattr(annotation, "__name__", None) or "std::string"
