"""One assembly from whatever the user wrote to one validated tree.

The :class:`~agv_mission.missions.load.tree_spec.TreeSource` (a ``tasks:`` list, a YAML
``tree:`` with named ``trees:``, or a BT.CPP v4 XML file) becomes one validated,
expanded :class:`~agv_mission.missions.load.tree_spec.TreeSpec`: ports checked against
each node type's port model from the registry's ``behavior`` slot, subtrees inlined with
their ports remapped, blackboard reads checked against writes. Node types are found the
way a third-party node is: by name in the registry. The run builds the py_trees tree of
it (:func:`agv_mission.missions.run.behaviour_tree.build_tree`).

The blackboard is a dict per tree (:class:`~agv_mission.behaviors.context.TreeContext`),
not py_trees' ``PortsMixin`` and its blackboard: that storage is process-global, and one
process (the service's worker, regress's fork server) runs several missions. The BT.CPP
parser is ours too (``tree_xml``): py_trees' experimental one keeps no source lines.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

import yaml
from pydantic import ValidationError

from agv_mission.behaviors.ports import NodePorts, blackboard_key
from agv_mission.missions.load.errors import MissionError, Problem
from agv_mission.missions.load.schema.base import MAX_TREE_NODES
from agv_mission.missions.load.tree_spec import (
    NAVIGATORS,
    SLOT,
    Node,
    NodeSpec,
    TreeSource,
    TreeSpec,
    Where,
    tasks_spec,
)
from agv_mission.missions.load.yaml_lines import load_with_lines
from agv_mission.registry import UnknownPluginError, registry

#: Nodes nested deeper than this are refused (building and ticking recurse per level).
MAX_TREE_DEPTH = 100


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
                except (yaml.YAMLError, RecursionError) as exc:
                    why = getattr(exc, "problem", None) or "nests too deeply"
                    shown = repr(raw) if len(raw) <= 60 else repr(raw[:60]) + "..."
                    self.problems.append(
                        spec.where.problem(
                            f"cannot read {shown} as YAML flow text ({why[:200]})", port, line
                        )
                    )
                    ok = False
                    continue
            literal[port] = raw
        _default_entries(spec, fields, scope, literal)
        if not ok or not self.valid(spec, config, literal, bound):
            return None, bound
        return literal, bound

    def valid(
        self,
        spec: NodeSpec,
        config: type[NodePorts],
        literal: dict[str, Any],
        bound: dict[str, str],
    ) -> bool:
        """Whether the literal ports make a valid port model (a port bound to the
        blackboard may be missing); each problem at its port's line."""
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
            return False
        return True

    def subtree(self, spec: NodeSpec, scope: _Scope) -> Node | None:
        tree_id = spec.ports.get("id", spec.ports.get("ID"))
        if not isinstance(tree_id, str):
            self.problems.append(spec.where.problem("a subtree needs an `id` (a string)", "id"))
            return None
        body = self.source.trees.get(tree_id)
        if body is None and spec.from_xml and tree_id == self.source.main_id:
            chain = " -> ".join([tree_id, *self.expanding, tree_id])  # back to the main tree
            self.problems.append(spec.where.problem(f"subtree {tree_id!r} contains itself "
                                                    f"({chain})", "id"))  # fmt: skip
            return None
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


def _default_entries(
    spec: NodeSpec, fields: dict[str, Any], scope: _Scope, literal: dict[str, Any]
) -> None:
    """Blackboard entries a node reads by default (not written in ``spec``) go through
    the subtree's scope too."""
    for port, info in fields.items():
        extra = info.json_schema_extra if isinstance(info.json_schema_extra, dict) else {}
        if extra.get("entry") and port not in spec.ports and isinstance(info.default, str):
            kind, target = scope.resolve(info.default)
            if kind == "key":
                literal[port] = target


def _default_name(node_type: str) -> str:
    return node_type


def _xml_value(raw: str, annotation: Any) -> Any:
    """An XML attribute's value: a string port keeps it; others read it as YAML flow text."""
    if annotation is str:
        return raw
    return load_with_lines(raw)[0]  # its aliases bounded, as a mission file's


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
