"""The py_trees tree a robot ticks, built from a validated
:class:`~agv_mission.missions.load.tree_spec.TreeSpec`: each node's behaviour from the
registry's ``behavior`` slot, instrumented so the run can report every node's starts and
running time (:class:`MissionTree`)."""

from __future__ import annotations

import dataclasses
import inspect
from dataclasses import dataclass, field
from typing import Any

import py_trees
from py_trees.common import Status
from pydantic import ValidationError

from agv_mission.behaviors.context import TreeContext
from agv_mission.behaviors.ports import NodePorts
from agv_mission.missions.load.tree_spec import SLOT, Node, TreeSpec
from agv_mission.registry import registry

Behaviour = py_trees.behaviour.Behaviour


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
