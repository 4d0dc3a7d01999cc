"""The node types a tree may use, as ``agv-mission tree nodes`` and Groot2's palette list
them: every registered ``behavior`` node with its kind, description and typed ports."""

from __future__ import annotations

import inspect
import types
import typing
from collections.abc import Collection
from typing import Any

from agv_mission.missions.load.tree_spec import SLOT
from agv_mission.registry import UnknownPluginError, registry


def node_types(only: Collection[str] | None = None) -> list[dict[str, Any]]:
    """Every registered node type (or those of ``only``): kind, description and ports
    (for ``tree nodes``), in name order. ``only`` loads just those types' plugins: a
    run's ``tree.btlog`` names the few its tree uses, and loading every type imported
    each port module of the package (~0.2 s a process)."""
    out = []
    for name in registry.names(SLOT):
        if only is not None and name not in only:
            continue
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
