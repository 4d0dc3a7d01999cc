"""The rooms file of the public contract::

    rooms:
      livingroom:
        polygon: [[-2.3, -5.3], [4.6, -5.3], [4.6, 0.0], [-2.3, 0.0]]   # map frame, metres
        anchor: {x: 3.0, y: -2.0, yaw: 0.0}    # optional
    docks:                                     # optional: chargers by name
      charger: {x: 3.5, y: -5.1, yaw: -1.5708} # the docked robot's pose, facing the charger

A polygon needs at least three [x, y] points and a non-zero area; the anchor is
optional (``yaw`` defaults to 0). Errors name the file, the line, the room and the
field.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Annotated, Any

import yaml
from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    ValidationError,
    field_validator,
    model_validator,
)

from agv_mission.atomic import InputFileError, read_input_text
from agv_mission.geometry import Pose2D
from agv_mission.maps.docks import Dock, DockModel
from agv_mission.maps.rooms import Room

Point = tuple[float, float]


class RoomsFileError(ValueError):
    """An invalid rooms file. ``problems`` holds (line or None, room or None, message)."""

    def __init__(self, path: Path, problems: list[tuple[int | None, str | None, str]]):
        self.path = Path(path)
        self.problems = problems
        lines = []
        for line, room, msg in problems:
            where = f"{self.path}:{line}" if line else f"{self.path}"
            lines.append(f"{where}: room {room!r}: {msg}" if room else f"{where}: {msg}")
        super().__init__("\n".join(lines))

    @classmethod
    def from_validation(
        cls, path: Path, exc: ValidationError, text: str | None = None
    ) -> RoomsFileError:
        """Turn a pydantic error on a ``{"rooms": ...}`` document into file/line/room
        messages (lines only when the YAML ``text`` is given)."""
        root = _compose(text) if text is not None else None
        problems = []
        for err in exc.errors():
            loc = tuple(err["loc"])
            room = str(loc[1]) if len(loc) >= 2 and loc[0] == "rooms" else None
            field = ".".join(str(p) for p in (loc[2:] if room else loc))
            line = line_of(root, loc) if root is not None else None
            msg = "field required" if err["type"] == "missing" else err["msg"]
            msg = msg.removeprefix("Value error, ")
            problems.append((line, room, f"{field}: {msg}" if field else msg))
        return cls(path, problems)


class AnchorModel(BaseModel):
    model_config = ConfigDict(extra="forbid")

    x: float = Field(..., allow_inf_nan=False)
    y: float = Field(..., allow_inf_nan=False)
    yaw: float = Field(0.0, allow_inf_nan=False)


MAX_POLYGON_POINTS = 1000


class RoomModel(BaseModel):
    model_config = ConfigDict(extra="forbid")

    polygon: Annotated[list[Point], Field(min_length=3, max_length=MAX_POLYGON_POINTS)]
    anchor: AnchorModel | None = None

    @model_validator(mode="after")
    def _simple_and_anchored_inside(self) -> RoomModel:
        """The rules a visit relies on: one inside (no edges crossing), and the anchor in
        it (a visit ends by checking that the robot is in the polygon)."""
        room = Room("", tuple(self.polygon))
        crossing = room.self_intersection()
        if crossing is not None:
            i, j = crossing
            raise ValueError(
                f"polygon is not simple: edge {i} ({_point(self.polygon[i])} -> "
                f"{_point(self.polygon[(i + 1) % len(self.polygon)])}) crosses edge {j}"
            )
        if self.anchor is not None and not room.contains(self.anchor.x, self.anchor.y):
            raise ValueError(
                f"anchor ({self.anchor.x:g}, {self.anchor.y:g}) lies outside the room's polygon"
            )
        return self

    @field_validator("polygon")
    @classmethod
    def _proper_polygon(cls, polygon: list[Point]) -> list[Point]:
        if not all(math.isfinite(v) for p in polygon for v in p):
            raise ValueError("polygon coordinates must be finite numbers")
        area2 = sum(
            x0 * y1 - x1 * y0
            for (x0, y0), (x1, y1) in zip(polygon, polygon[1:] + polygon[:1], strict=True)
        )
        if abs(area2) < 1e-12:
            raise ValueError("polygon has zero area")
        return polygon


class RoomsModel(BaseModel):
    model_config = ConfigDict(extra="forbid")

    rooms: dict[str, RoomModel] = Field(default_factory=dict)
    docks: dict[str, DockModel] = Field(default_factory=dict)


def _point(p: Point) -> str:
    return f"({p[0]:g}, {p[1]:g})"


def rooms_from_model(model: RoomsModel) -> dict[str, Room]:
    rooms = {}
    for label, room in model.rooms.items():
        anchor = room.anchor
        pose = Pose2D(anchor.x, anchor.y, anchor.yaw) if anchor is not None else None
        rooms[label] = Room(label, tuple((float(x), float(y)) for x, y in room.polygon), pose)
    return rooms


def docks_from_model(model: RoomsModel, path: Path, text: str | None) -> dict[str, Dock]:
    """The model's docks, each knowing the file and line it was written on."""
    root = _compose(text) if text is not None else None
    docks = {}
    for name, d in model.docks.items():
        line = line_of(root, ("docks", name)) if root is not None else None
        source = f"{path}:{line}" if line else str(path)
        docks[name] = Dock(name, Pose2D(d.x, d.y, d.yaw), source)
    return docks


def load_rooms(path: str | os.PathLike[str]) -> dict[str, Room]:
    """Read a rooms file into ``{label: Room}`` (in file order)."""
    return load_rooms_file(path)[0]


def load_rooms_file(path: str | os.PathLike[str]) -> tuple[dict[str, Room], dict[str, Dock]]:
    """Read a rooms file: its rooms and its docks (each in file order)."""
    path = Path(path)
    try:
        text = read_input_text(path)
    except InputFileError as exc:
        message = "rooms file not found" if exc.missing else f"rooms file: {exc}"
        raise RoomsFileError(path, [(None, None, message)]) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise RoomsFileError(path, [(None, None, f"cannot read rooms file: {exc}")]) from exc
    try:
        doc = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        line = mark.line + 1 if mark is not None else None
        raise RoomsFileError(path, [(line, None, f"invalid YAML: {exc}")]) from exc
    duplicate = _duplicate_label(text)
    if duplicate is not None:
        raise RoomsFileError(path, [duplicate])
    if not isinstance(doc, dict) or not ("rooms" in doc or "docks" in doc):
        raise RoomsFileError(
            path,
            [
                (
                    None,
                    None,
                    "a rooms file is a mapping with a top-level 'rooms' key (and/or 'docks')",
                )
            ],
        )
    try:
        model = RoomsModel.model_validate(doc)
    except ValidationError as exc:
        raise RoomsFileError.from_validation(path, exc, text) from exc
    return rooms_from_model(model), docks_from_model(model, path, text)


# --------------------------------------------------------------------------- line numbers


def _duplicate_label(text: str) -> tuple[int, str, str] | None:
    """A room label given twice under ``rooms`` (YAML would keep the last silently)."""
    root = _compose(text)
    if not isinstance(root, yaml.MappingNode):
        return None
    rooms = next((v for k, v in root.value if getattr(k, "value", None) == "rooms"), None)
    if not isinstance(rooms, yaml.MappingNode):
        return None
    first: dict[str, int] = {}
    for key, _ in rooms.value:
        if not isinstance(key, yaml.ScalarNode):
            continue
        line = key.start_mark.line + 1
        if key.value in first:
            return (line, key.value, f"room label given twice (first on line {first[key.value]})")
        first[key.value] = line
    return None


def _compose(text: str) -> yaml.Node | None:
    try:
        return yaml.compose(text, Loader=yaml.SafeLoader)
    except yaml.YAMLError:
        return None


def line_of(node: Any, loc: Sequence[str | int]) -> int | None:
    """1-based line of the deepest YAML node along ``loc`` (a mapping entry: its key)."""
    line = node.start_mark.line + 1
    for part in loc:
        child = None
        if isinstance(node, yaml.MappingNode):
            for key, value in node.value:
                if isinstance(key, yaml.ScalarNode) and key.value == str(part):
                    child, line = value, key.start_mark.line + 1
                    break
        elif (
            isinstance(node, yaml.SequenceNode)
            and isinstance(part, int)
            and 0 <= part < len(node.value)
        ):
            child = node.value[part]
            line = child.start_mark.line + 1
        if child is None:
            break
        node = child
    return line
