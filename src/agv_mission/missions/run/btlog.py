"""A run's tree as BehaviorTree.CPP's FileLogger2 writes it (``tree.btlog``), which
Groot2 replays: the bytes ``BTCPP4-FileLogger2``, a protocol byte (1), the tree's XML
(a ``_uid`` on every node) behind its little-endian int32 length, the int64 start time in
microseconds, then one 9-byte record per status change: 48-bit microseconds since the
start, 16-bit node uid, 8-bit status (0 idle, 1 running, 2 success, 3 failure). Times are
simulated time (the start is 0). Format: BT.CPP's ``src/loggers/bt_file_logger_v2.cpp``.
"""

from __future__ import annotations

import struct
from typing import TYPE_CHECKING, Any
from xml.sax.saxutils import quoteattr

from py_trees.common import Status

from agv_mission.missions.load.tree_spec import Node, TreeSpec
from agv_mission.missions.run.behaviour_tree import MissionTree

if TYPE_CHECKING:
    from agv_mission.navigation.handle import RobotHandle

MAGIC = b"BTCPP4-FileLogger2"
PROTOCOL = 1
IDLE, RUNNING, SUCCESS, FAILURE = 0, 1, 2, 3
_STATUS = {Status.SUCCESS: SUCCESS, Status.FAILURE: FAILURE, Status.INVALID: IDLE,
           Status.RUNNING: RUNNING}  # fmt: skip


class TreeLog:
    """Records every status change of the tree's nodes as they happen (through their
    lifecycle calls), in simulated time."""

    def __init__(self, spec: TreeSpec, tree: MissionTree, handle: RobotHandle) -> None:
        self.spec, self.handle = spec, handle
        self.changes: list[tuple[float, int, int]] = []  # (simulated s, uid, status)
        self._last = [IDLE] * (len(tree.records) + 1)  # by uid
        for uid, record in enumerate(tree.records, start=1):
            self._hook(uid, record.behaviour)

    def _hook(self, uid: int, behaviour: Any) -> None:
        initialise, stop = behaviour.initialise, behaviour.stop

        def logged_initialise() -> None:
            self._log(uid, RUNNING)
            initialise()

        def logged_stop(new_status: Status = Status.INVALID) -> None:
            stop(new_status)
            self._log(uid, _STATUS.get(new_status, IDLE))

        behaviour.initialise = logged_initialise
        behaviour.stop = logged_stop

    def _log(self, uid: int, status: int) -> None:
        if self._last[uid] != status:  # a tree ticks at 10 Hz: encode once, at the end
            self._last[uid] = status
            self.changes.append((self.handle.state.time, uid, status))

    @property
    def records(self) -> bytes:
        """The 9-byte transition records, in order."""
        out = bytearray()
        for t, uid, status in self.changes:
            usec = max(int(round(t * 1e6)), 0) & 0xFFFFFFFFFFFF
            out += usec.to_bytes(6, "little") + struct.pack("<HB", uid, status)
        return bytes(out)

    def to_bytes(self) -> bytes:
        xml = tree_xml(self.spec).encode("utf-8")
        head = MAGIC + bytes([PROTOCOL]) + struct.pack("<i", len(xml)) + xml
        return head + struct.pack("<q", 0) + self.records


def _entries(node_type: str) -> list[str]:
    """The ports of ``node_type`` whose value names a blackboard entry."""
    from agv_mission.missions.load.tree_spec import SLOT
    from agv_mission.registry import UnknownPluginError, registry

    try:
        fields = registry.config(SLOT, node_type).model_fields
    except UnknownPluginError:
        return []
    out = []
    for port, info in fields.items():
        extra = info.json_schema_extra if isinstance(info.json_schema_extra, dict) else {}
        if extra.get("entry") or extra.get("direction") == "output":
            out.append(port)
    return out


def tree_xml(spec: TreeSpec) -> str:
    """The expanded tree as BT.CPP's ``WriteTreeToXML`` has it: each subtree (and each
    navigator's tree) its own ``<BehaviorTree>`` with its ``_fullpath``, a ``_uid`` on
    every node (pre-order from 1, as the run's node records)."""
    from agv_mission.missions.load.tree_xml import _flow, _ports_to_xml, nodes_model, xml_id

    trees: list[tuple[str, str, list[str]]] = []  # (ID, fullpath, lines)
    counter = [0]
    used: set[str] = set()

    def element(node: Node, path: str, depth: int, out: list[str]) -> None:
        counter[0] += 1
        uid = counter[0]
        used.add(node.type)
        pad = "  " * depth
        ports = {**node.literal, **{k: f"{{{v}}}" for k, v in node.bound.items()}}
        for port in _entries(node.type):  # entries a port names, written as BT.CPP does
            if isinstance(ports.get(port), str):
                ports[port] = f"{{{ports[port]}}}"
        name = xml_id(node.type) if node.name == node.type else node.name
        inner = f"{path}/{node.tree_id}::{uid}" if path else f"{node.tree_id}::{uid}"
        if node.type == "subtree":
            attrs = {"ID": node.tree_id or "", "name": name, "_fullpath": inner}
        else:
            attrs = {"name": name, **_ports_to_xml(node.type, ports)}
        attrs["_uid"] = uid
        text = "".join(f" {k}={quoteattr(_flow(v))}" for k, v in attrs.items() if v is not None)
        tag = "SubTree" if node.type == "subtree" else xml_id(node.type)
        if node.type == "subtree" or node.navigator is not None:
            out.append(f"{pad}<{tag}{text}/>")
            sub: list[str] = []
            trees.append((node.tree_id or "", inner, sub))
            element(node.children[0], inner, 2, sub)
            return
        if not node.children:
            out.append(f"{pad}<{tag}{text}/>")
            return
        out.append(f"{pad}<{tag}{text}>")
        for child in node.children:
            element(child, path, depth + 1, out)
        out.append(f"{pad}</{tag}>")

    main: list[str] = []
    main_id = spec.source.main_id
    trees.append((main_id, "", main))
    element(spec.root, "", 2, main)
    out = ['<root BTCPP_format="4">']
    for tree_id, path, lines in trees:
        out.append(f"  <BehaviorTree ID={quoteattr(tree_id)} _fullpath={quoteattr(path)}>")
        out.extend(lines)
        out.append("  </BehaviorTree>")
    out.append(nodes_model(used, indent=1))
    out.append("</root>")
    return "\n".join(out) + "\n"
