"""Bad input as :class:`Problem` s naming file, line and field: pydantic's validation errors
and YAML's syntax errors in the words of the mission format."""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass, field
from typing import Any

import yaml
from pydantic import ValidationError

from agv_mission.missions.load.errors import MissionError, Problem
from agv_mission.missions.load.schema import Mission, Setup
from agv_mission.missions.load.yaml_lines import DocumentError, FieldPath, document_nodes, line_of
from agv_mission.registry import registry
from agv_mission.suggest import unknown_key


@dataclass
class ProblemLog:
    """The problems found in one mission document, each placed where the user can fix it:
    at its line in ``file``, or at the ``--set``/``--seed`` that gave the value."""

    file: str
    lines: dict[FieldPath, int]
    override_paths: dict[FieldPath, str]
    problems: list[Problem] = field(default_factory=list)
    type_swaps: dict[FieldPath, str] = field(default_factory=dict)  # block -> its --set type
    #: what was taken as near as it could be, not as written: the run goes on, saying so
    warnings: list[Problem] = field(default_factory=list)

    def at(self, field_path: FieldPath, message: str) -> Problem:
        """The problem at ``field_path``; a value an override gave blames the override
        (the one that wrote it, else one that wrote inside it), and a key of a block whose
        plugin an override chose also names that choice."""
        dotted = ".".join(spell(p) for p in field_path)
        spelled = tuple(map(str, field_path))  # --set tasks.0=... and stack.5=... alike
        above = [
            (len(o), item)
            for o, item in ((tuple(map(str, p)), i) for p, i in self.override_paths.items())
            if spelled[: len(o)] == o
        ]
        below = [
            item
            for opath, item in self.override_paths.items()
            if tuple(map(str, opath))[: len(spelled)] == spelled
        ]
        if above or below:
            item = max(above)[1] if above else below[0]
            for block, swap in self.type_swaps.items():
                b = tuple(map(str, block))
                if swap != item and len(spelled) > len(b) and spelled[: len(b)] == b:
                    item += f"; the block's plugin from {swap}"
            return Problem(self.file, None, dotted, f"{message} (from {item})")
        return Problem(self.file, line_of(field_path, self.lines), dotted, message)

    def add(self, field_path: FieldPath, message: str) -> None:
        """Note a problem and go on, so one ``validate`` names them all."""
        self.problems.append(self.at(field_path, message))

    def warn(self, field_path: FieldPath, message: str) -> None:
        """Note a warning (once) at its file, line and field."""
        warning = self.at(field_path, message)
        if warning not in self.warnings:
            self.warnings.append(warning)

    def raise_if_any(self) -> None:
        """Stop here when a problem so far makes the next step meaningless."""
        if self.problems:
            raise MissionError(self.problems)


def validation_problems(
    log: ProblemLog, exc: ValidationError, data: Any, model: type[Setup] = Mission
) -> list[Problem]:
    """pydantic's errors in the mission format's words, once per field and message."""
    problems: list[Problem] = []
    seen: set[tuple[FieldPath, str]] = set()
    for err in exc.errors(include_url=False):
        field_path = data_path(tuple(err["loc"]), data)
        message = error_message(err, data, model)
        if (field_path, message) in seen:
            continue
        seen.add((field_path, message))
        problems.append(log.at(field_path, message))
    return problems


def non_string_keys(data: Any, limit: int = 10) -> list[tuple[Any, ...]]:
    """Paths of mapping keys that YAML read as numbers, booleans, null or dates."""
    found: list[tuple[Any, ...]] = []
    for path, node in document_nodes(data):
        if isinstance(node, dict):
            found += [(*path, key) for key in node if not isinstance(key, str)]
        if len(found) >= limit:
            break
    return sorted(found[:limit], key=str)


def non_finite_numbers(data: Any, limit: int = 10) -> list[tuple[FieldPath, float]]:
    """Paths of ``.inf``/``.nan`` values anywhere in the document (every block, plugin
    configs included: no number of a mission may be infinite)."""
    found: list[tuple[FieldPath, float]] = []
    for path, node in document_nodes(data):
        if isinstance(node, float) and not math.isfinite(node):
            found.append((path, node))
            if len(found) >= limit:
                break
    return sorted(found, key=lambda item: tuple(map(str, item[0])))


def data_path(loc: tuple, data: Any) -> FieldPath:
    """Drop pydantic's union tags from an error location, keeping the document's own path."""
    path: list[str | int] = []
    node = data
    for i, part in enumerate(loc):
        last = i == len(loc) - 1
        if (
            isinstance(node, dict)
            and part in node
            or isinstance(node, list)
            and isinstance(part, int)
            and 0 <= part < len(node)
        ):
            path.append(part)
            node = node[part]
        elif last and isinstance(part, str) and not is_tag(part):
            path.append(part)  # a missing field: named, but not in the document
        # otherwise a union tag such as 'go_to', 'Pose' or 'function-after[...]': skip
    return tuple(path)


def is_tag(part: str) -> bool:
    return part in {"str", "int", "float", "bool", "Pose"} or "[" in part


def error_message(err: dict, data: Any = None, model: type[Setup] = Mission) -> str:
    kind = err["type"]
    if kind == "missing":
        return "required field is missing"
    if kind == "extra_forbidden":
        return unknown_key(model, tuple(err["loc"]))
    if kind == "union_tag_invalid":
        ctx = err.get("ctx", {})
        tag = ctx.get("tag")
        broken = [why for name, why in registry.errors().items() if name.endswith(f".{tag}")]
        if broken:
            return f"plugin {tag!r} is installed but failed to load: {broken[0]}"
        return f"unknown type {tag!r}; expected one of {ctx.get('expected_tags')}"
    if kind == "union_tag_not_found":
        tags = expected_tags(tuple(err["loc"]), data, model)
        return "missing 'type'" + (f"; expected one of {tags}" if tags else "")
    msg = err["msg"]
    if kind in ("model_type", "model_attributes_type", "dict_type"):
        msg = "expected a mapping"
    if kind.endswith("_type") and isinstance(err.get("input"), (dict, list)):
        msg += " (got a list)" if isinstance(err["input"], list) else " (got a mapping)"
    if msg.startswith("Value error, "):
        msg = msg[len("Value error, ") :]
    if (
        "input" in err
        and kind not in ("union_tag_invalid",)
        and not isinstance(err["input"], (dict, list))
    ):
        got = repr(err["input"])  # a 3 MB string is shown by its start, not in full
        msg = f"{msg} (got {got if len(got) <= 80 else got[:76] + '...'})"
    return msg


def expected_tags(loc: tuple, data: Any, model: type[Setup] = Mission) -> str | None:
    """The ``type`` values a block without one could have: ask the schema with a bad one."""
    field_path = data_path(loc, data)
    try:
        probe = copy.deepcopy(data)
        node = probe
        for part in field_path:
            node = node[part]
        if not isinstance(node, dict):
            return None
        node["type"] = "\x00"
        model.model_validate(probe)
    except ValidationError as exc:
        for err in exc.errors(include_url=False):
            if err["type"] == "union_tag_invalid" and data_path(err["loc"], probe) == field_path:
                return err.get("ctx", {}).get("expected_tags")
    except Exception:  # the message just lists no types
        return None
    return None


def one_line(message: str) -> str:
    """A multi-line message from a file loader as one line."""
    lines = [line.strip() for line in message.splitlines() if line.strip()]
    if len(lines) > 1 and lines[0].endswith(":"):
        return f"{lines[0]} " + "; ".join(lines[1:])
    return "; ".join(lines)


def spell(part: Any) -> str:
    """A path part as YAML spells it (true, not True)."""
    if isinstance(part, bool) or part is None:
        return yaml.safe_dump(part).splitlines()[0]
    return str(part)


def yaml_problem(file: str, exc: yaml.YAMLError, source: str) -> Problem:
    if isinstance(exc, DocumentError):
        line = exc.problem_mark.line + 1 if exc.problem_mark is not None else None
        dotted = ".".join(str(p) for p in exc.field_path)
        return Problem(file, line, dotted, f"invalid YAML: {exc.problem}")
    if isinstance(exc, yaml.reader.ReaderError):  # a character YAML does not allow
        line = source[: exc.position].count("\n") + 1
        char = exc.character if isinstance(exc.character, int) else ord(exc.character)
        return Problem(
            file, line, "", f"YAML syntax error: unacceptable character #x{char:04x} ({exc.reason})"
        )
    mark = getattr(exc, "problem_mark", None)
    line = mark.line + 1 if mark is not None else None
    problem = getattr(exc, "problem", None) or str(exc)
    context = getattr(exc, "context", None)
    start = getattr(exc, "context_mark", None)
    if context and start is not None and start.line + 1 != line:
        context += f" started on line {start.line + 1}"  # e.g. the unclosed '{' or '"'
    text = f"YAML syntax error: {problem}" + (f" ({context})" if context else "")
    return Problem(file, line, "", text)


def os_message(exc: BaseException) -> str:
    if isinstance(exc, OSError) and exc.strerror:
        return exc.strerror
    return first_line(exc)


def first_error(exc: ValidationError) -> str:
    errors = exc.errors(include_url=False)
    err = errors[0]
    where = ".".join(str(p) for p in err["loc"])
    msg = "field required" if err["type"] == "missing" else err["msg"]
    more = f" (and {len(errors) - 1} more)" if len(errors) > 1 else ""
    return (f"{where}: {msg}" if where else msg) + more


def kind_of(value: Any) -> str:
    return type(value).__name__ if value is not None else "nothing"


def first_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return text[0] if text else type(exc).__name__
