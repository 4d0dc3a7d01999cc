"""``--set KEY=VALUE`` (and ``--sweep``) overrides: parsed as YAML, applied to the document
before validation, in the order given.

Each override writes one key; a later one wins over an earlier one of the same key. A
``stack.<slot>.type=<other>`` override selects another plugin: the block the file wrote
is dropped (its keys mean nothing to the new plugin), but what earlier overrides wrote
into the block is kept, so ``--set stack.global_planner.planner=RRTstar --set
stack.global_planner.type=ompl`` and the reverse order give the same block. A kept key
the new plugin does not have is then an error that names both overrides.
"""

from __future__ import annotations

import copy
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import yaml

from agv_mission.missions.load.errors import MissionError, Problem
from agv_mission.missions.load.problems import kind_of
from agv_mission.missions.load.schema import with_default_plugin_types
from agv_mission.missions.load.yaml_lines import FieldPath
from agv_mission.yaml_safe import safe_load


@dataclass(frozen=True)
class Override:
    """One ``KEY=VALUE`` and the option that gave it (``--set``, ``--sweep``)."""

    item: str
    option: str = "--set"
    shown: str | None = None  # how the user wrote it, when not ``OPTION KEY=VALUE``

    @property
    def label(self) -> str:
        return self.shown or f"{self.option} {self.item}"


def as_override(item: str | Override) -> Override:
    """A plain string is a ``--set`` item."""
    return item if isinstance(item, Override) else Override(item)


@dataclass
class Applied:
    """What the overrides wrote: each path with the option that wrote it (the last one
    wins), and for each plugin block whose ``type`` an override changed, that option."""

    paths: dict[FieldPath, str] = field(default_factory=dict)
    type_swaps: dict[FieldPath, str] = field(default_factory=dict)
    #: keys written with list indices in brackets, taken in the dotted spelling
    hints: list[Problem] = field(default_factory=list)


#: ``tasks[0]``: a list index in brackets (the dotted ``tasks.0`` is the one spelling)
BRACKET_INDEX = re.compile(r"\[\s*(\d+)\s*\]")


def dotted_key(key: str) -> str:
    """``tasks[0].loops`` -> ``tasks.0.loops``: the field path as the command line, the
    service and every message spell it."""
    return BRACKET_INDEX.sub(r".\1", key).lstrip(".")


def override_error(item: str, message: str, option: str = "--set") -> MissionError:
    """A bad override item: the problem names the option and item, as no file line holds it."""
    return MissionError([Problem(option, None, item, message)])


def override_value(raw: str) -> Any:
    """The VALUE of ``KEY=VALUE`` as YAML reads it (empty: null); text YAML cannot read
    stays text."""
    try:
        return safe_load(raw) if raw.strip() else None
    except yaml.YAMLError:
        return raw


def parse_override(override: str | Override) -> tuple[FieldPath, Any]:
    o = as_override(override)
    key, sep, raw = o.item.partition("=")
    if not sep or not key.strip():
        raise override_error(
            o.item, "expected KEY=VALUE, e.g. stack.global_planner.planner=RRTstar", o.option
        )
    try:
        value = override_value(raw)
    except RecursionError:  # [[[[...]]]]: YAML's parser recurses per level
        item = o.item if len(o.item) <= 80 else o.item[:80] + "..."
        raise override_error(item, "the VALUE nests too deeply", o.option) from None
    parts: list[str | int] = [
        int(p) if p.isascii() and p.isdigit() else p for p in dotted_key(key.strip()).split(".")
    ]  # not int("²"): str.isdigit() takes superscripts
    return tuple(parts), value


def bracket_hint(override: Override) -> Problem | None:
    """A hint for a key written ``tasks[0].loops``: taken as ``tasks.0.loops``, the one
    spelling of a field's path."""
    key = override.item.partition("=")[0].strip()
    if not BRACKET_INDEX.search(key):
        return None
    return Problem(
        override.option,
        None,
        override.item,
        f"{key} is spelled {dotted_key(key)} (list indices after a dot, as every message "
        "spells a field's path); taken as that",
    )


def apply_overrides(data: dict, overrides: Sequence[str | Override]) -> Applied:
    """Apply every override to ``data`` (in place), first to last."""
    applied = Applied()
    written: list[tuple[FieldPath, Any]] = []
    for override in map(as_override, overrides):
        field_path, value = parse_override(override)
        hint = bracket_hint(override)
        if hint is not None:
            applied.hints.append(hint)
        block = plugin_block(field_path)
        if block is not None and swaps_plugin(data, block, value):
            kept = earlier_writes(block, written)
            set_path(data, block, {**kept, "type": value}, override)
            applied.type_swaps[block] = override.label
        else:
            field_path = set_path(data, field_path, copy.deepcopy(value), override)
        written.append((field_path, value))
        applied.paths[field_path] = override.label
    return applied


def plugin_block(field_path: FieldPath) -> FieldPath | None:
    """``stack.<slot>`` for ``stack.<slot>.type``: the block a plugin swap replaces."""
    if len(field_path) == 3 and field_path[0] == "stack" and field_path[2] == "type":
        return field_path[:2]
    return None


def swaps_plugin(data: dict, block_path: FieldPath, value: Any) -> bool:
    """The block at ``block_path`` is another plugin than ``value`` (a block without a
    ``type`` is the plugin its keys imply, as validation will read it)."""
    block = data.get(block_path[0]) if isinstance(data, dict) else None
    block = block.get(block_path[1]) if isinstance(block, dict) else None
    if not isinstance(block, dict):
        return False
    probe = {"stack": {block_path[1]: dict(block)}}
    current = with_default_plugin_types(probe)["stack"][block_path[1]].get("type")
    return current != value


def earlier_writes(block: FieldPath, written: list[tuple[FieldPath, Any]]) -> dict[str, Any]:
    """What earlier overrides wrote inside ``block`` (its ``type`` aside), replayed in order."""
    kept: dict[str, Any] = {}
    n = len(block)
    for path, value in written:
        if path[:n] == block[: len(path)] and len(path) <= n:  # wrote the block (or above)
            sub: Any = value
            for part in block[len(path) :]:
                sub = sub.get(part) if isinstance(sub, dict) else None
            if isinstance(sub, dict):
                kept = {k: copy.deepcopy(v) for k, v in sub.items() if k != "type"}
        elif path[:n] == block and path[n] != "type":
            node: Any = kept
            for part in path[n:-1]:
                if not isinstance(node.get(part), dict):
                    node[part] = {}
                node = node[part]
            node[path[-1]] = copy.deepcopy(value)
    return kept


def set_path(data: dict, field_path: FieldPath, value: Any, override: Override) -> FieldPath:
    """Write ``value`` at ``field_path``; returns the path with list items named by their
    ``name`` (``robots.agv1``, fleet.md) replaced by their indices."""
    node: Any = data
    resolved: list[str | int] = []
    for i, part in enumerate(field_path):
        last = i == len(field_path) - 1
        if isinstance(node, list) and isinstance(part, str):  # an item by its name
            names = [item.get("name") if isinstance(item, dict) else None for item in node]
            if part in names:
                part = names.index(part)
            elif any(isinstance(name, str) for name in names):
                raise override_error(
                    override.item,
                    f"no item named {part!r} "
                    f"(names: {', '.join(n for n in names if isinstance(n, str))})",
                    override.option,
                )
        resolved.append(part)
        if isinstance(node, list):
            if not isinstance(part, int) or not -len(node) <= part < len(node):
                raise override_error(
                    override.item,
                    f"{part!r} is not an index of a list of {len(node)}",
                    override.option,
                )
            if last:
                node[part] = value
            else:
                node = node[part]
        elif isinstance(node, dict):
            key: str | int = part
            if isinstance(part, int) and part not in node:  # a mapping's keys are strings
                key = str(part)
            if last:
                node[key] = value
            else:
                if not isinstance(node.get(key), (dict, list)):
                    node[key] = {}
                node = node[key]
        else:
            raise override_error(
                override.item, f"cannot set a key inside a {kind_of(node)}", override.option
            )
    return tuple(resolved)
