"""The JSON Schema of a mission file: pydantic's, with the loader's defaults spelled out."""

from __future__ import annotations

from typing import Any

from agv_mission.missions.load.schema.fleet import DEFAULT_FLEET_PLUGINS
from agv_mission.missions.load.schema.mission import ROBOT_NAME_PATTERN, Mission
from agv_mission.missions.load.schema.stack import DEFAULT_PLUGINS
from agv_mission.registry import registry

JSON_SCHEMA_DIALECT = "https://json-schema.org/draft/2020-12/schema"


def mission_json_schema() -> dict[str, Any]:
    """The JSON Schema of a mission file (what ``agv-mission schema`` prints).

    A stack block without ``type`` is the slot's default plugin, as the loader reads it.
    """
    schema = Mission.model_json_schema()
    slots = schema["$defs"]["Stack"]["properties"]
    for slot, name in DEFAULT_PLUGINS.items():
        union = slots[slot]
        mapping = union.get("discriminator", {}).get("mapping", {})
        if name not in mapping:
            continue
        slots[slot] = {
            "title": union.get("title", slot),
            "description": f"a plugin chosen by `type`; without one: {name}, or the one "
            "plugin whose options the block uses",
            "if": {"type": "object", "not": {"required": ["type"]}},
            "then": {"anyOf": [{"$ref": ref} for ref in mapping.values()]},
            "else": {k: v for k, v in union.items() if k != "title"},
        }
    # ``output: runs`` is the contract's spelling of ``output: {dir: runs}``
    output = schema["properties"]["output"]
    schema["properties"]["output"] = {
        "description": output["description"],
        "anyOf": [{"type": "string"}, {"$ref": output["$ref"]}],
    }
    _tree_nodes(schema)
    _fleet_tasks(schema)
    _fleet_slots(schema)
    return {"$schema": JSON_SCHEMA_DIALECT, **schema}


def _fleet_tasks(schema: dict[str, Any]) -> None:
    """A mission's own ``tasks`` may carry ``robot:`` (fleet.md: the robot a fleet task is
    assigned to; the loader takes it out before the task model sees it)."""
    defs = schema["$defs"]
    items = schema["properties"]["tasks"]["items"]
    robot = {
        "type": "string",
        "pattern": ROBOT_NAME_PATTERN,
        "description": "a fleet mission's task: the robot (robots[].name) it is assigned to",
    }
    for option in items["oneOf"]:
        name = option["$ref"].rsplit("/", 1)[-1]
        fleet = {**defs[name], "properties": {**defs[name]["properties"], "robot": robot}}
        defs[f"Fleet{name}"] = fleet
        option["$ref"] = f"#/$defs/Fleet{name}"
    mapping = items.get("discriminator", {}).get("mapping", {})
    for key, ref in mapping.items():
        mapping[key] = ref.replace("#/$defs/", "#/$defs/Fleet")


def _fleet_slots(schema: dict[str, Any]) -> None:
    """A ``fleet`` slot block without ``type`` is the slot's default plugin."""
    slots = schema["$defs"]["Fleet"]["properties"]
    for slot, name in DEFAULT_FLEET_PLUGINS.items():
        union = slots[slot]
        refs = union.get("discriminator", {}).get("mapping", {})
        if name not in refs:
            continue
        slots[slot] = {
            "description": union.get("description", slot),
            "if": {"type": "object", "not": {"required": ["type"]}},
            "then": {"$ref": refs[name]},
            "else": {k: v for k, v in union.items() if k != "title"},
        }


def _tree_nodes(schema: dict[str, Any]) -> None:
    """``tree`` and ``trees`` as nodes whose ``type`` is a registered node type (their
    ports are each type's; ``agv-mission tree nodes`` lists them)."""
    types = [*registry.names("behavior"), "subtree"]
    schema["$defs"]["TreeNode"] = {
        "type": "object",
        "description": "a node: type, optional name, its ports, and children (controls) or "
        "child (decorators)",
        "required": ["type"],
        "properties": {
            "type": {"enum": types},
            "name": {"type": "string"},
            "children": {"type": "array", "items": {"$ref": "#/$defs/TreeNode"}},
            "child": {"$ref": "#/$defs/TreeNode"},
        },
    }
    props = schema["properties"]
    props["tree"] = {
        "description": props["tree"]["description"],
        "anyOf": [
            {"$ref": "#/$defs/TreeNode"},
            {"type": "string", "pattern": r"\.xml\s*$"},
        ],
    }
    props["trees"]["additionalProperties"] = {"$ref": "#/$defs/TreeNode"}
