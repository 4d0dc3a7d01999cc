"""A robot by name (a built-in one) or from a YAML file (a :class:`RobotDescription`
document), with errors that name the file, the line and the field; and the JSON Schema
of a robot file."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import yaml
from pydantic import (
    ValidationError,
)

from agv_mission.atomic import InputFileError, input_path, read_input_text
from agv_mission.robots.builtin_robots import BUILTIN_ROBOTS
from agv_mission.robots.description import RobotDescription
from agv_mission.suggest import unknown_key
from agv_mission.yaml_safe import safe_load


class RobotFileError(ValueError):
    """A robot file that cannot be used; names the file, the line and the field."""

    def __init__(
        self,
        path: Path,
        line: int | None,
        field: str,
        message: str,
        more: Sequence[tuple[int | None, str, str]] = (),
    ) -> None:
        self.path, self.line, self.field, self.message = path, line, field, message
        self.problems = [(line, field, message), *more]  # every (line, field, message)
        super().__init__(
            "\n".join(
                (f"line {ln}: " if ln is not None else "") + (f"{f}: " if f else "") + m
                for ln, f, m in self.problems
            )
        )


def load_robot(spec: str, base_dir: Path | None = None) -> RobotDescription:
    """A built-in robot by name, or a robot YAML file (a :class:`RobotDescription` document).

    Raises ``FileNotFoundError`` for a name that is neither, and :class:`RobotFileError`
    (file, line, field) for a file that is not a valid robot description.
    """
    if spec in BUILTIN_ROBOTS:
        return BUILTIN_ROBOTS[spec]
    path = input_path(spec, base_dir) if base_dir is not None else Path(spec).expanduser()
    try:
        text = read_input_text(path)
    except InputFileError as exc:
        if exc.missing:
            raise FileNotFoundError(str(path)) from None
        raise RobotFileError(path, None, "", str(exc)) from None
    except UnicodeDecodeError:
        raise RobotFileError(path, None, "", "not a UTF-8 text file") from None
    try:
        doc = safe_load(text)
        root = yaml.compose(text, Loader=yaml.SafeLoader)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise RobotFileError(
            path, mark.line + 1 if mark else None, "", f"invalid YAML: {problem}"
        ) from None
    if doc is None:
        doc = {}
    if not isinstance(doc, dict):
        raise RobotFileError(path, 1, "", "expected a mapping of robot parameters")
    doc.setdefault("name", path.stem)
    try:
        return RobotDescription.model_validate(doc)
    except ValidationError as exc:
        problems = [_robot_problem(root, err) for err in exc.errors(include_url=False)]
        raise RobotFileError(path, *problems[0], more=problems[1:]) from None


def _robot_problem(root: Any, err: Any) -> tuple[int | None, str, str]:
    """One validation error as (line, field, message)."""
    loc = tuple(err["loc"])
    msg = "field required" if err["type"] == "missing" else err["msg"]
    if err["type"] == "extra_forbidden":
        msg = unknown_key(RobotDescription, loc)
    elif "input" in err and not isinstance(err["input"], (dict, list)):
        msg = f"{msg} (got {err['input']!r})"
    return _line_of(root, loc), ".".join(map(str, loc)), msg.removeprefix("Value error, ")


def _line_of(node: Any, loc: tuple[Any, ...]) -> int | None:
    """1-based line of the deepest part of ``loc`` the document holds."""
    line = node.start_mark.line + 1 if node is not None else None
    for part in loc:
        if isinstance(node, yaml.MappingNode):
            hit = next(((k, v) for k, v in node.value if k.value == str(part)), None)
            if hit is None:
                return line
            line, node = hit[0].start_mark.line + 1, hit[1]
        elif isinstance(node, yaml.SequenceNode) and isinstance(part, int):
            if not 0 <= part < len(node.value):
                return line
            node = node.value[part]
            line = node.start_mark.line + 1
        else:
            return line
    return line


def robot_json_schema() -> dict[str, Any]:
    """The JSON Schema of a robot file (``name`` may be left out: the file's stem)."""
    schema = RobotDescription.model_json_schema()
    schema["required"] = [k for k in schema.get("required", []) if k != "name"]
    schema["properties"]["name"]["description"] = "default: the file's stem"
    return {"$schema": "https://json-schema.org/draft/2020-12/schema", **schema}
