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

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Annotated, Any

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from agv_mission.atomic import InputFileError, read_input_text
from agv_mission.geometry import Pose2D
from agv_mission.maps.docks import Dock, DockModel
from agv_mission.maps.rooms import Room
from agv_mission.suggest import unknown_key
from agv_mission.yaml_safe import safe_load


class RoomsFileError(ValueError):
    """An invalid rooms file. ``problems`` holds (line or None, room or None, message),
    one per problem, each at its own line."""

    def __init__(self, path: Path, problems: list[tuple[int | None, str | None, str]]):
        self.path = Path(path)
        self.problems = problems
        super().__init__("\n".join(self.lines()))

    def lines(self) -> list[str]:
        """Each problem as ``file:line: room 'label': message``."""
        lines = []
        for line, room, msg in self.problems:
            where = f"{self.path}:{line}" if line else f"{self.path}"
            lines.append(f"{where}: room {room!r}: {msg}" if room else f"{where}: {msg}")
        return lines


class AnchorModel(BaseModel):
    model_config = ConfigDict(extra="forbid", defer_build=True)

    x: float = Field(..., allow_inf_nan=False)
    y: float = Field(..., allow_inf_nan=False)
    yaw: float = Field(0.0, allow_inf_nan=False)


MAX_POLYGON_POINTS = 1000


class RoomModel(BaseModel):
    """One room's shape: a polygon of [x, y] points and an optional anchor. What a visit
    relies on beyond the shape (a simple polygon of some area, the anchor inside it) is
    checked by :func:`room_problems`."""

    model_config = ConfigDict(extra="forbid", defer_build=True)

    polygon: Annotated[
        list[tuple[Annotated[float, Field(allow_inf_nan=False)], ...]],
        Field(min_length=3, max_length=MAX_POLYGON_POINTS),
    ]
    anchor: AnchorModel | None = None


class RoomsModel(BaseModel):
    model_config = ConfigDict(extra="forbid", defer_build=True)

    rooms: dict[str, RoomModel] = Field(default_factory=dict)
    docks: dict[str, DockModel] = Field(default_factory=dict)


def _point(p: Sequence[float]) -> str:
    return f"({p[0]:g}, {p[1]:g})"


Loc = tuple[Any, ...]
RoomProblem = tuple[Loc, str]  # (location inside the room, message)


def room_problems(raw: Any) -> tuple[RoomModel | None, list[RoomProblem]]:
    """One room's document checked: the model (None if invalid) and every problem, each
    at its own key, in this tool's words."""
    try:
        model = RoomModel.model_validate(raw)
    except ValidationError as exc:
        return None, [_room_error(err) for err in exc.errors(include_url=False)]
    problems: list[RoomProblem] = []
    polygon = model.polygon
    for i, p in enumerate(polygon):
        if len(p) != 2:
            problems.append(
                (("polygon", i), f"polygon point {i} must be [x, y] (two numbers), got {list(p)}")
            )
    if problems:
        return None, problems
    area2 = sum(
        x0 * y1 - x1 * y0
        for (x0, y0), (x1, y1) in zip(polygon, polygon[1:] + polygon[:1], strict=True)
    )
    if abs(area2) < 1e-12:
        return None, [(("polygon",), "the polygon has zero area (its points are on one line)")]
    room = Room("", tuple((float(x), float(y)) for x, y in polygon))
    crossing = room.self_intersection()
    if crossing is not None:
        i, j = crossing
        problems.append(
            (
                ("polygon",),
                f"polygon is not simple: edge {i} ({_point(polygon[i])} -> "
                f"{_point(polygon[(i + 1) % len(polygon)])}) crosses edge {j}",
            )
        )
    anchor = model.anchor
    if anchor is not None and not room.contains(anchor.x, anchor.y):
        problems.append(
            (("anchor",), f"anchor ({anchor.x:g}, {anchor.y:g}) lies outside the room's polygon")
        )
    return (None if problems else model), problems


def _room_error(err: Any) -> RoomProblem:
    """A pydantic error inside one room, in the rooms file's words."""
    loc: Loc = tuple(err["loc"])
    kind = err["type"]
    got = f", got {err['input']!r}" if "input" in err and kind != "missing" else ""
    ctx = err.get("ctx") or {}
    if loc[:1] == ("polygon",) and len(loc) >= 2:
        what = f"polygon point {loc[1]}"
        if kind == "missing" or kind in ("too_short", "too_long") or len(loc) == 2:
            return loc[:2], f"{what} must be [x, y] (two numbers){got}"
        return loc[:2], f"{what}: {'x' if loc[2] == 0 else 'y'} must be a finite number{got}"
    if loc == ("polygon",):
        if kind == "missing":
            return (), "has no polygon (a room needs 'polygon': at least 3 [x, y] points)"
        if kind == "too_short":
            return (
                loc,
                f"a room's polygon needs at least 3 points, this one has {ctx.get('actual_length')}",
            )
        if kind == "too_long":
            return loc, f"the polygon has more than {MAX_POLYGON_POINTS} points"
        return loc, f"the polygon must be a list of [x, y] points{got}"
    if kind == "extra_forbidden":
        return loc, unknown_key(RoomModel, loc)
    if loc[:1] == ("anchor",):
        if len(loc) == 1:
            return loc, f"the anchor must be a mapping {{x, y, yaw}}{got}"
        if kind == "missing":
            return loc[:1], f"the anchor has no {loc[1]!r} (an anchor is {{x, y, yaw}})"
        return loc, f"anchor.{loc[1]} must be a finite number{got}"
    if not loc:
        return loc, f"a room must be a mapping with 'polygon' (and optionally 'anchor'){got}"
    return loc, str(err["msg"]).removeprefix("Value error, ")


def rooms_from_doc(
    path: Path, rooms: Any, root: yaml.Node | None = None, prefix: Loc = ("rooms",)
) -> dict[str, Room]:
    """The rooms of a ``rooms:`` mapping (from a rooms file or a world file at ``path``),
    or :class:`RoomsFileError` with every problem at its line (when ``root``, the file's
    YAML node tree, is given)."""

    def line(loc: Loc) -> int | None:
        return node_line(root, loc) if root is not None else None

    if not isinstance(rooms, dict):
        what = "nothing" if rooms is None else type(rooms).__name__
        raise RoomsFileError(
            path, [(line(prefix), None, f"'rooms' must be a mapping of room labels, got {what}")]
        )
    found: dict[str, Room] = {}
    problems: list[tuple[int | None, str | None, str]] = []
    for label, raw in rooms.items():
        if not isinstance(label, str):
            problems.append((line(prefix), None, f"room label {label!r} must be text (quote it)"))
            continue
        model, errors = room_problems(raw)
        for loc, message in errors:
            problems.append((line((*prefix, label, *loc)), label, message))
        if model is not None:
            anchor = model.anchor
            pose = Pose2D(anchor.x, anchor.y, anchor.yaw) if anchor is not None else None
            found[label] = Room(label, tuple((float(x), float(y)) for x, y in model.polygon), pose)
    if problems:
        raise RoomsFileError(path, problems)
    return found


def docks_from_doc(
    path: Path, docks: Any, root: yaml.Node | None = None, prefix: Loc = ("docks",)
) -> dict[str, Dock]:
    """The docks of a ``docks:`` mapping, each knowing the file and line it was written
    on, or :class:`RoomsFileError` with every problem at its line."""

    def line(loc: Loc) -> int | None:
        return node_line(root, loc) if root is not None else None

    if not isinstance(docks, dict):
        what = "nothing" if docks is None else type(docks).__name__
        raise RoomsFileError(
            path, [(line(prefix), None, f"'docks' must be a mapping of dock names, got {what}")]
        )
    found: dict[str, Dock] = {}
    problems: list[tuple[int | None, str | None, str]] = []
    for name, raw in docks.items():
        try:
            d = DockModel.model_validate(raw)
        except ValidationError as exc:
            for err in exc.errors(include_url=False):
                loc = tuple(err["loc"])
                field = ".".join(str(p) for p in (*prefix, name, *loc))
                if err["type"] == "missing":
                    msg = f"{field}: missing (a dock is {{x, y, yaw}})"
                elif err["type"] == "extra_forbidden":
                    msg = f"{field}: {unknown_key(DockModel, loc)}"
                elif loc:
                    msg = f"{field}: must be a finite number, got {err['input']!r}"
                else:
                    msg = f"{field}: a dock is a mapping {{x, y, yaw}}, got {err['input']!r}"
                problems.append((line((*prefix, name, *loc)), None, msg))
            continue
        where = line((*prefix, name))
        found[str(name)] = Dock(
            str(name), Pose2D(d.x, d.y, d.yaw), f"{path}:{where}" if where else str(path)
        )
    if problems:
        raise RoomsFileError(path, problems)
    return found


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
        doc = safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        line = mark.line + 1 if mark is not None else None
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise RoomsFileError(path, [(line, None, f"invalid YAML: {problem}")]) from exc
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
    root = compose_nodes(text)
    extra = [key for key in doc if key not in ("rooms", "docks")]
    if extra:
        raise RoomsFileError(
            path,
            [(node_line(root, (key,)), None, unknown_key(RoomsModel, (key,))) for key in extra],
        )
    rooms = rooms_from_doc(path, doc["rooms"], root) if "rooms" in doc else {}
    docks = docks_from_doc(path, doc["docks"], root) if "docks" in doc else {}
    return rooms, docks


# --------------------------------------------------------------------------- line numbers


def _duplicate_label(text: str) -> tuple[int, str, str] | None:
    """A room label given twice under ``rooms`` (YAML would keep the last silently)."""
    root = compose_nodes(text)
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


def compose_nodes(text: str) -> yaml.Node | None:
    try:
        return yaml.compose(text, Loader=yaml.SafeLoader)
    except yaml.YAMLError:
        return None


def node_line(node: Any, loc: Sequence[str | int]) -> int | None:
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
