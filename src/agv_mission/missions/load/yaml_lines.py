"""YAML documents with the line number of every key and list item."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import yaml

from agv_mission.yaml_safe import INT_TAG, MAX_INT_DIGITS, FastSafeLoader, SafeLoader

FieldPath = tuple[str | int, ...]

#: Values a document may hold once its aliases are expanded: far above any real mission
#: (a 4 MB file of plain values holds about two million), far below what would exhaust
#: memory once an alias of an alias of ... (a "billion laughs") is copied out by the
#: checks and the tree assembly.
MAX_EXPANDED_VALUES = 2_000_000


class DocumentError(yaml.MarkedYAMLError):
    """Well-formed YAML that is still not a usable document (a duplicate key, a lone
    surrogate); ``field_path`` names where, as far as known."""

    def __init__(self, problem: str, mark: Any, field_path: FieldPath = ()) -> None:
        super().__init__(problem=problem, problem_mark=mark)
        self.field_path = field_path


def load_with_lines(text: str) -> tuple[Any, dict[FieldPath, int]]:
    """Parse ``text`` (safe YAML) and map each field path to its 1-based line.

    Raises ``yaml.YAMLError`` (with a ``problem_mark``) on syntax errors, and
    :class:`DocumentError` on a key given twice in one mapping or a string that is
    not valid Unicode (a lone surrogate from a ``\\ud800`` escape).

    Parsed by libyaml (four times faster: a 3 MB polygon took 25 s in pure Python); a
    syntax error is told by PyYAML's own parser, whose messages say what it found where
    libyaml's only say what it did not ("expected ',' or '}', but got ':'").
    """
    try:
        return _load(text, FastSafeLoader)
    except DocumentError:
        raise
    except yaml.YAMLError:
        return _load(text, SafeLoader)


def _load(text: str, loader_class: type) -> tuple[Any, dict[FieldPath, int]]:
    loader = loader_class(text)  # parsed once: the lines from its nodes, then the data
    try:
        node = loader.get_single_node()
        lines: dict[FieldPath, int] = {}
        walked: Exception | None = None
        if node is not None:
            lines[()] = node.start_mark.line + 1  # where the document itself starts
            try:  # before the data is built: a merge key (<<) rewrites its mapping's node
                _walk(node, (), lines, set())
                _check_expansion(node)
            except (DocumentError, RecursionError) as exc:
                walked = exc  # the data's own errors are told first
        try:
            data = loader.construct_document(node) if node is not None else None
        except yaml.constructor.ConstructorError:
            if isinstance(walked, DocumentError):  # e.g. a number too long: told with its field
                raise walked from None
            raise
    finally:
        loader.dispose()
    if walked is not None:
        raise walked
    return data, lines


def _walk(node: yaml.Node, path: FieldPath, lines: dict[FieldPath, int], seen: set[int]) -> None:
    # Each node once: an alias shares its anchor's node (and may even contain itself).
    if id(node) in seen:
        return
    seen.add(id(node))
    if isinstance(node, yaml.ScalarNode):
        _check_text(node, path)
        if node.tag == INT_TAG and len(node.value) > MAX_INT_DIGITS:  # digits, signs, _
            digits = sum(c.isdigit() for c in node.value)
            if digits > MAX_INT_DIGITS:
                message = f"a number of {digits} digits (at most {MAX_INT_DIGITS})"
                raise DocumentError(message, node.start_mark, path)
    elif isinstance(node, yaml.MappingNode):
        first: dict[tuple[str, str], int] = {}
        for key, value in node.value:
            if not isinstance(key, yaml.ScalarNode):
                continue
            _check_text(key, path)
            child = (*path, key.value)
            line = key.start_mark.line + 1
            tagged = (key.tag, key.value)
            if tagged in first and key.tag != "tag:yaml.org,2002:merge":
                raise DocumentError(
                    f"duplicate key {key.value!r} (first given on line {first[tagged]})",
                    key.start_mark,
                    child,
                )
            first[tagged] = line
            lines[child] = line
            _walk(value, child, lines, seen)
    elif isinstance(node, yaml.SequenceNode):
        for i, item in enumerate(node.value):
            child = (*path, i)
            lines[child] = item.start_mark.line + 1
            _walk(item, child, lines, seen)


def _check_expansion(root: yaml.Node) -> None:
    """Refuse a document whose aliases expand to more than :data:`MAX_EXPANDED_VALUES`
    values, naming the outermost key whose value does (counted without expanding it)."""
    sizes: dict[int, int] = {}

    def size(node: yaml.Node) -> int:
        known = sizes.get(id(node))
        if known is not None:
            return known
        sizes[id(node)] = 1  # a node that contains itself counts once (told elsewhere)
        total = 1
        if isinstance(node, yaml.MappingNode):
            total += sum(size(key) + size(value) for key, value in node.value)
        elif isinstance(node, yaml.SequenceNode):
            total += sum(size(item) for item in node.value)
        sizes[id(node)] = total
        return total

    if size(root) <= MAX_EXPANDED_VALUES:
        return
    node, path, mark = root, (), root.start_mark
    while isinstance(node, yaml.MappingNode):  # down to the key whose value is too large
        big = [(k, v) for k, v in node.value if isinstance(k, yaml.ScalarNode)]
        key, value = max(big, key=lambda kv: sizes[id(kv[1])], default=(None, None))
        if key is None or sizes[id(value)] <= MAX_EXPANDED_VALUES:
            break
        node, path, mark = value, (*path, key.value), key.start_mark
    raise DocumentError(
        f"its aliases expand to more than {MAX_EXPANDED_VALUES:,} values (an alias bomb?)",
        mark,
        path,
    )


def _check_text(node: yaml.ScalarNode, path: FieldPath) -> None:
    try:
        node.value.encode("utf-8")
    except UnicodeEncodeError:
        raise DocumentError(
            f"{node.value!r} is not valid Unicode text (a lone surrogate escape)",
            node.start_mark,
            path,
        ) from None


def line_of(path: FieldPath, lines: dict[FieldPath, int]) -> int | None:
    """Line of the deepest prefix of ``path`` that the document holds.

    A key the YAML parser turned into a number, bool or null (``1:``, ``true:``) is
    matched by its spelling.
    """
    for n in range(len(path), 0, -1):
        if path[:n] in lines:
            return lines[path[:n]]
    spelled = {_spelling(p): line for p, line in lines.items()}
    for n in range(len(path), 0, -1):
        line = spelled.get(_spelling(path[:n]))
        if line is not None:
            return line
    return None


def _spelling(path: FieldPath) -> tuple[str, ...]:
    out = []
    for part in path:
        if part is None or part in ("~", "null", "Null", "NULL", ""):
            out.append("null")
        else:
            out.append(str(part).lower())
    return tuple(out)


def document_nodes(data: Any) -> Iterator[tuple[FieldPath, Any]]:
    """Every value of a parsed document with its path, depth first; a mapping or list that
    appears twice (a YAML alias) is visited once, so a document that contains itself ends."""
    seen: set[int] = set()
    stack: list[tuple[Any, FieldPath]] = [(data, ())]
    while stack:
        node, path = stack.pop()
        if isinstance(node, (dict, list)):
            if id(node) in seen:
                continue
            seen.add(id(node))
        yield path, node
        if isinstance(node, dict):
            stack.extend((value, (*path, key)) for key, value in node.items())
        elif isinstance(node, list):
            stack.extend((item, (*path, i)) for i, item in enumerate(node))
