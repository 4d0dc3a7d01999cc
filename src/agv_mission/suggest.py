"""Unknown keys answered with the nearest known ones ("did you mean 'dwell'?").

Every input format here is a pydantic model with ``extra="forbid"``; pydantic reports an
unknown key with its location only. The keys that were allowed there are read from the
model's JSON Schema, following the location through references, lists, mappings and
unions (a union's tag in the location picks its branch).
"""

from __future__ import annotations

import difflib
from collections.abc import Iterable, Sequence
from functools import cache
from typing import Any

from pydantic import BaseModel

MAX_LISTED = 12  # an unknown key with no near match lists the allowed keys up to this many


def unknown_key_message(key: Any, known: Iterable[str]) -> str:
    """``unknown key 'dwel' (did you mean 'dwell'?)``, or the keys allowed here."""
    known = sorted(set(known))
    text = f"unknown key {str(key)!r}"
    close = _nearest(str(key), known)
    if not close:
        lowered = {k.lower(): k for k in known}
        close = [lowered[str(key).lower()]] if str(key).lower() in lowered else []
    if close:
        return f"{text} (did you mean {' or '.join(repr(c) for c in close)}?)"
    if known and len(known) <= MAX_LISTED:
        return f"{text} (allowed here: {', '.join(known)})"
    return f"{text} (not allowed here)"


def _nearest(key: str, known: list[str], cutoff: float = 0.6) -> list[str]:
    """The known keys most like ``key`` (ties all), none under ``cutoff``."""
    scored = [(difflib.SequenceMatcher(None, key, k).ratio(), k) for k in known]
    best = max((score for score, _ in scored), default=0.0)
    return [k for score, k in scored if score == best] if best >= cutoff else []


def unknown_key(model: type[BaseModel], loc: Sequence[Any]) -> str:
    """The message for pydantic's ``extra_forbidden`` error at ``loc`` of ``model``."""
    return unknown_key_message(loc[-1] if loc else "", allowed_keys(model, tuple(loc[:-1])))


def allowed_keys(model: type[BaseModel], loc: tuple[Any, ...]) -> set[str]:
    """The keys the model allows in the mapping at ``loc`` (empty when unknown)."""
    schema = _schema(model)
    return _keys_at(schema, schema, loc, 0)


@cache
def _schema(model: type[BaseModel]) -> dict[str, Any]:
    try:
        return model.model_json_schema()
    except Exception:  # noqa: BLE001 (a plugin config without a schema: no suggestions)
        return {}


def _resolve(root: dict[str, Any], node: Any) -> Any:
    for _ in range(32):
        if not isinstance(node, dict) or "$ref" not in node:
            break
        name = node["$ref"].rsplit("/", 1)[-1]
        node = {
            **root.get("$defs", {}).get(name, {}),
            **{k: v for k, v in node.items() if k != "$ref"},
        }
    return node


def _branches(node: dict[str, Any]) -> list[Any]:
    return [*node.get("anyOf", []), *node.get("oneOf", []), *node.get("allOf", [])]


def _tag_of(root: dict[str, Any], branch: Any) -> set[str]:
    """The names a union's location may use for this branch: its title and ``type`` value."""
    branch = _resolve(root, branch)
    if not isinstance(branch, dict):
        return set()
    names = {branch["title"]} if isinstance(branch.get("title"), str) else set()
    kind = branch.get("properties", {}).get("type", {})
    if isinstance(kind, dict):
        if "const" in kind:
            names.add(str(kind["const"]))
        names.update(str(v) for v in kind.get("enum", []) if len(kind.get("enum", [])) == 1)
        if "default" in kind and isinstance(kind["default"], str):
            names.add(kind["default"])
    return names


def _keys_at(root: dict[str, Any], node: Any, loc: tuple[Any, ...], depth: int) -> set[str]:
    node = _resolve(root, node)
    if not isinstance(node, dict) or depth > 64:
        return set()
    branches = _branches(node)
    if branches:
        mapping = node.get("discriminator", {}).get("mapping", {})
        if loc and str(loc[0]) in mapping:
            return _keys_at(root, {"$ref": mapping[str(loc[0])]}, loc[1:], depth + 1)
        if loc:
            tagged = [b for b in branches if str(loc[0]) in _tag_of(root, b)]
            if tagged:
                return _keys_at(root, tagged[0], loc[1:], depth + 1)
        found: set[str] = set()
        for branch in branches:
            found |= _keys_at(root, branch, loc, depth + 1)
        return found | set(node.get("properties", {}))
    if not loc:
        return set(node.get("properties", {}))
    part, rest = loc[0], loc[1:]
    properties = node.get("properties", {})
    if isinstance(part, str) and part in properties:
        return _keys_at(root, properties[part], rest, depth + 1)
    if isinstance(part, int) and "items" in node:
        return _keys_at(root, node["items"], rest, depth + 1)
    if isinstance(node.get("additionalProperties"), dict):
        return _keys_at(root, node["additionalProperties"], rest, depth + 1)
    if isinstance(part, str) and ("[" in part or part in {"str", "int", "float", "bool"}):
        return _keys_at(root, node, rest, depth + 1)  # a validator's or union's tag
    return set()
