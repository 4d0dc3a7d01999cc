"""YAML documents with the line number of every key and list item."""

from __future__ import annotations

from typing import Any

import yaml

FieldPath = tuple[str | int, ...]


def load_with_lines(text: str) -> tuple[Any, dict[FieldPath, int]]:
    """Parse ``text`` (safe YAML) and map each field path to its 1-based line.

    Raises ``yaml.YAMLError`` (with a ``problem_mark``) on syntax errors.
    """
    data = yaml.safe_load(text)
    node = yaml.compose(text, Loader=yaml.SafeLoader)
    lines: dict[FieldPath, int] = {}
    if node is not None:
        _walk(node, (), lines)
    return data, lines


def _walk(node: yaml.Node, path: FieldPath, lines: dict[FieldPath, int]) -> None:
    if isinstance(node, yaml.MappingNode):
        for key, value in node.value:
            if not isinstance(key, yaml.ScalarNode):
                continue
            child = (*path, key.value)
            lines[child] = key.start_mark.line + 1
            _walk(value, child, lines)
    elif isinstance(node, yaml.SequenceNode):
        for i, item in enumerate(node.value):
            child = (*path, i)
            lines[child] = item.start_mark.line + 1
            _walk(item, child, lines)


def line_of(path: FieldPath, lines: dict[FieldPath, int]) -> int | None:
    """Line of the deepest prefix of ``path`` that the document holds."""
    for n in range(len(path), 0, -1):
        if path[:n] in lines:
            return lines[path[:n]]
    return None
