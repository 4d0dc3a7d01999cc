"""``--set KEY=VALUE`` overrides: parsed as YAML, applied to the document before validation."""

from __future__ import annotations

from typing import Any

import yaml

from agv_mission.missions.errors import MissionError, Problem
from agv_mission.missions.problems import kind_of
from agv_mission.missions.yaml_lines import FieldPath


def override_error(item: str, message: str) -> MissionError:
    """A bad ``--set`` item: the problem names the item, as no file line holds it."""
    return MissionError([Problem("--set", None, item, message)])


def override_value(raw: str) -> Any:
    """The VALUE of ``KEY=VALUE`` as YAML reads it (empty: null); text YAML cannot read
    stays text."""
    try:
        return yaml.safe_load(raw) if raw.strip() else None
    except yaml.YAMLError:
        return raw


def parse_override(file: str, item: str) -> tuple[FieldPath, Any]:
    key, sep, raw = item.partition("=")
    if not sep or not key.strip():
        raise override_error(item, "expected KEY=VALUE, e.g. stack.global_planner.planner=RRTstar")
    value = override_value(raw)
    parts: list[str | int] = [
        int(p) if p.isascii() and p.isdigit() else p for p in key.strip().split(".")
    ]  # not int("²"): str.isdigit() takes superscripts
    return tuple(parts), value


def apply(data: dict, field_path: FieldPath, value: Any, file: str, item: str) -> None:
    node: Any = data
    for i, part in enumerate(field_path):
        last = i == len(field_path) - 1
        if isinstance(node, list):
            if not isinstance(part, int) or not -len(node) <= part < len(node):
                raise override_error(item, f"{part!r} is not an index of a list of {len(node)}")
            if last:
                node[part] = value
            else:
                node = node[part]
        elif isinstance(node, dict):
            key: str | int = part
            if isinstance(part, int) and part not in node:  # a mapping's keys are strings
                key = str(part)
            if last:
                if swaps_plugin(field_path, node, value):
                    node.clear()  # the old plugin's keys mean nothing to the new one
                node[key] = value
            else:
                if not isinstance(node.get(key), (dict, list)):
                    node[key] = {}
                node = node[key]
        else:
            raise override_error(item, f"cannot set a key inside a {kind_of(node)}")


def swaps_plugin(field_path: FieldPath, block: dict, value: Any) -> bool:
    """``--set stack.<slot>.type=<other>`` selects another plugin with its own defaults."""
    return (
        len(field_path) == 3
        and field_path[0] == "stack"
        and field_path[2] == "type"
        and block.get("type", value) != value
    )
