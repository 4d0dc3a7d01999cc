"""Gazebo worlds (``.world`` / ``.sdf``, SDF 1.4-1.9) read directly (robots-and-worlds.md).

Every static model's ``<collision>`` geometry becomes a body of the world: a box with one
axis upright, an upright cylinder, a sphere; each posed model -> link -> collision, a
model's (or link's) pose in the file's ``<state>`` winning over its own ``<pose>``, as
Gazebo loads a saved world (it sets the state's poses, link poses in the world frame, after
building the models). The ground plane (a plane through z = 0 facing up,
``model://ground_plane``) is the floor.

Our worlds are planar: each body is what the lidar's scan plane cuts from it (a sphere is
the disc it cuts), standing on the floor. A body the scan plane does not cut (under it or
above it) is left out and listed in :attr:`SdfWorld.not_cut`.

What cannot be read that way (a mesh, a heightmap, a tilted cylinder, an ``<include>`` of a
model the file does not hold, a non-static model, a model with a plugin: DynaBARN's
obstacles are static models a plugin moves) is refused at its line, every refusal
together, unless ``skip_unsupported``: then each is skipped and listed in
:attr:`SdfWorld.skipped`.

Hostile XML: a document that declares entities or names external ones is refused before
anything expands them (defusedxml's rules, checked with defusedxml's own parser; lxml
expands entities in attribute values even with ``resolve_entities=False``). lxml then
parses with its limits on (no network, no DTD loading, no huge trees) and gives every
element its line.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from defusedxml import DefusedXmlException
from defusedxml import ElementTree as DefusedTree

from agv_mission.atomic import InputFileError, read_input_bytes
from agv_mission.geometry import MAX_COORDINATE
from agv_mission.maps.sdf_pose import (
    IDENTITY,
    Transform,
    compose,
    rotation_quaternion,
    rotation_rpy,
)
from agv_mission.maps.worlds import Box, Cylinder

SDF_SUFFIXES = (".world", ".sdf")
SDF_MAX_BYTES = 32 * 1024 * 1024  # a saved Gazebo world holds each model twice: they grow
SDF_VERSIONS = ("1.4", "1.5", "1.6", "1.7", "1.8", "1.9")
UPRIGHT = 1.0 - 1e-6  # |cos| of an axis to the vertical that counts as upright
MAX_PROBLEMS = 50  # refusals named before the rest are counted
FLOOR_MODELS = ("ground_plane",)  # model:// names that are the floor
IGNORED_MODELS = ("sun",)  # model:// names without geometry (Gazebo's light)
UNSUPPORTED_GEOMETRY = ("mesh", "heightmap", "capsule", "ellipsoid", "polyline", "image")


class SdfError(ValueError):
    """A Gazebo world that cannot be read; ``problems`` holds one ``file:line: element:
    message`` line a problem."""

    def __init__(self, message: str, problems: list[str]) -> None:
        super().__init__(message)
        self.problems = problems


@dataclass
class SdfWorld:
    """What a Gazebo world file holds, cut at the scan height."""

    name: str
    boxes: list[Box] = field(default_factory=list)
    cylinders: list[Cylinder] = field(default_factory=list)
    skipped: list[dict[str, Any]] = field(default_factory=list)  # refused, then skipped
    not_cut: list[dict[str, Any]] = field(default_factory=list)  # above or under the scan
    #: where each body was read (``file:line: <box>: model 'a' ...``), boxes then cylinders
    box_sources: list[str] = field(default_factory=list)
    cylinder_sources: list[str] = field(default_factory=list)


def is_sdf_path(path: Path) -> bool:
    return path.suffix.lower() in SDF_SUFFIXES  # as Gazebo names its worlds


def read_sdf_world(path: Path, scan_height: float, skip_unsupported: bool = False) -> SdfWorld:
    """The bodies of the Gazebo world at ``path`` cut at ``scan_height`` (m above the floor).

    Raises :class:`SdfError` naming the file and the line of every problem.
    """
    try:
        data = read_input_bytes(path, SDF_MAX_BYTES)
    except InputFileError as exc:
        raise SdfError(f"{path}: {exc}", [f"{path}: {exc}"]) from None
    _refuse_entities(path, data)
    from lxml import etree  # a built-in world is no Gazebo world to parse

    parser = etree.XMLParser(
        resolve_entities=False,
        no_network=True,
        load_dtd=False,
        huge_tree=False,
        remove_comments=True,
        remove_pis=True,
    )
    try:
        root = etree.fromstring(data, parser)
    except etree.XMLSyntaxError as exc:
        line = exc.lineno or (exc.position[0] if exc.position else None)
        problem = f"{path}:{line}: not well-formed XML: {exc.msg}"
        raise SdfError(problem, [problem]) from None
    reader = _Reader(path, scan_height, skip_unsupported)
    world = reader.read(root)
    if reader.problems:
        shown = reader.problems[:MAX_PROBLEMS]
        more = len(reader.problems) - len(shown)
        if more:
            shown.append(f"{path}: ... and {more} more")
        hint = "(world_import: {skip_unsupported: true} skips them)"
        raise SdfError(
            f"{path}: cannot read this Gazebo world {hint}:\n" + "\n".join(f"  {p}" for p in shown),
            shown,
        )
    return world


def _refuse_entities(path: Path, data: bytes) -> None:
    """defusedxml's rules for hostile XML, before any parser expands an entity: no entity
    declarations, no external references (a DTD without them is allowed)."""
    if b"<!DOCTYPE" not in data and b"<!ENTITY" not in data:
        return  # nothing can be declared, nothing can expand
    try:
        DefusedTree.fromstring(data, forbid_dtd=False, forbid_entities=True, forbid_external=True)
    except DefusedXmlException as exc:
        name = getattr(exc, "name", None)
        match = re.search(rb"<!ENTITY\s+%?\s*" + re.escape((name or "").encode()), data)
        match = match or re.search(rb"<!ENTITY|<!DOCTYPE", data)
        line = data.count(b"\n", 0, match.start()) + 1 if match else None
        what = f"the entity {name!r}" if name else "an external reference"
        problem = (
            f"{path}:{line}: <!ENTITY>: {what} refused without expanding it: a world file "
            "may not declare entities or name external ones (defusedxml's rules)"
        )
        raise SdfError(problem, [problem]) from None
    except Exception:  # not well-formed: lxml names the line next
        return


# --------------------------------------------------------------------------- the reader


class _Refused(Exception):
    """An element that cannot be read (message; the element it is at)."""

    def __init__(self, element: Any, message: str) -> None:
        super().__init__(message)
        self.element = element
        self.message = message


def _children(el: Any, tag: str) -> list[Any]:
    return el.findall(tag)  # direct children, searched in C


def _child(el: Any, tag: str) -> Any | None:
    return el.find(tag)


def _name(el: Any) -> str:
    return el.get("name") or "(unnamed)"


class _Reader:
    """One pass over a world's elements: bodies, refusals, what the scan plane misses."""

    def __init__(self, path: Path, scan_height: float, skip: bool) -> None:
        self.path, self.h, self.skip = path, scan_height, skip
        self.problems: list[str] = []
        self.world = SdfWorld(name=path.stem)

    # ---------------------------------------------------------------- bookkeeping
    def refuse(self, exc: _Refused, where: str) -> None:
        el = exc.element
        line = el.sourceline
        if self.skip:
            self.world.skipped.append(
                {
                    "file": str(self.path),
                    "line": line,
                    "element": el.tag,
                    "item": where,
                    "reason": exc.message,
                }
            )
        else:
            self.problems.append(f"{self.path}:{line}: <{el.tag}>: {where}: {exc.message}")

    def number_list(self, el: Any, count: tuple[int, ...], what: str) -> list[float]:
        try:
            values = [float(v) for v in (el.text or "").split()]
        except ValueError:
            values = []
        if len(values) not in count or not all(math.isfinite(v) for v in values):
            want = " or ".join(str(c) for c in count)
            raise _Refused(el, f"{what}: expected {want} numbers, got {el.text!r}")
        return values

    def positive(self, parent: Any, tag: str, default: float | None = None) -> float:
        el = _child(parent, tag)
        if el is None:
            if default is None:
                raise _Refused(parent, f"<{tag}> is missing")
            return default
        (value,) = self.number_list(el, (1,), f"<{tag}>")
        if not 0 < value <= MAX_COORDINATE:
            raise _Refused(
                el, f"<{tag}> must be positive and at most {MAX_COORDINATE:.0e} m, got {value:g}"
            )
        return value

    def pose(self, el: Any | None, relative_ok: tuple[str, ...] = ("", "world")) -> Transform:
        """The transform of a ``<pose>`` element (identity when absent)."""
        if el is None:
            return IDENTITY
        frame = (el.get("relative_to") or el.get("frame") or "").strip()
        if frame not in relative_ok:
            raise _Refused(el, f"a pose relative to the frame {frame!r} is not read")
        quat = el.get("rotation_format", "euler_rpy").strip() == "quat_xyzw"
        v = self.number_list(el, (7,) if quat else (6,), "<pose>")
        far = [
            f"{a} {c:.4g} m" for a, c in zip("xyz", v[:3], strict=False) if abs(c) > MAX_COORDINATE
        ]
        if far:
            raise _Refused(el, f"<pose>: {far[0]} is farther than {MAX_COORDINATE:.0e} m")
        if quat:
            if math.hypot(*v[3:]) < 1e-9:
                raise _Refused(el, "<pose>: a zero quaternion")
            rotation = rotation_quaternion(*v[3:])
        else:
            angles = v[3:]
            if el.get("degrees", "false").strip().lower() in ("true", "1"):
                angles = [math.radians(a) for a in angles]
            rotation = rotation_rpy(*angles)
        return rotation, np.array(v[:3])

    def source(self, el: Any, where: str) -> str:
        """``file:line: <tag>: where``: a body's origin, for errors about it."""
        return f"{self.path}:{el.sourceline}: <{el.tag}>: {where}"

    # ---------------------------------------------------------------- the document
    def read(self, root: Any) -> SdfWorld:
        if root.tag != "sdf":
            self.problems.append(
                f"{self.path}:{root.sourceline}: <{root.tag}>: not a Gazebo world "
                "(the root element of an SDF file is <sdf>)"
            )
            return self.world
        version = (root.get("version") or "").strip()
        if version not in SDF_VERSIONS:
            self.problems.append(
                f"{self.path}:{root.sourceline}: <sdf>: version {version!r} is not read "
                f"(SDF {SDF_VERSIONS[0]}-{SDF_VERSIONS[-1]})"
            )
            return self.world
        worlds = _children(root, "world")
        if len(worlds) != 1:
            where = worlds[1].sourceline if len(worlds) > 1 else root.sourceline
            self.problems.append(
                f"{self.path}:{where}: <sdf>: a world file holds one <world>, "
                f"this one {len(worlds)}"
            )
            return self.world
        world = worlds[0]
        self.world.name = world.get("name") or self.path.stem
        if self.world.name == "default":  # Gazebo's own name for every saved world
            self.world.name = self.path.stem
        models = {_name(m): m for m in _children(world, "model")}
        states = self.states(world)
        deleted = states.pop("__deleted__", set())
        for state in _children(world, "state"):
            for insertion in _children(state, "insertions"):
                for m in _children(insertion, "model"):
                    models.setdefault(_name(m), m)
        for el in world:
            try:
                if el.tag == "model" and _name(el) not in deleted:
                    self.model(el, IDENTITY, states.get(_name(el)), _name(el))
                elif el.tag == "include":
                    self.include(el, models, states)
                elif el.tag in ("actor", "population", "road"):
                    raise _Refused(el, f"<{el.tag}> is not read (moving or generated bodies)")
            except _Refused as exc:
                self.refuse(exc, f"{el.tag} {self.label(el)}")
        for state in _children(world, "state"):
            for insertion in _children(state, "insertions"):
                for m in _children(insertion, "model"):
                    try:
                        self.model(m, IDENTITY, states.get(_name(m)), _name(m))
                    except _Refused as exc:
                        self.refuse(exc, f"model {_name(m)!r}")
        return self.world

    @staticmethod
    def label(el: Any) -> str:
        """How a refusal names a world's child: a model by name, an include by its uri."""
        if el.tag == "include":
            uri = _child(el, "uri")
            return repr((uri.text or "").strip()) if uri is not None else "(no uri)"
        return repr(_name(el))

    def states(self, world: Any) -> dict[str, Any]:
        """Each model's ``<state>`` element by name (the last state wins), and the names
        the state deletes under ``__deleted__``."""
        out: dict[str, Any] = {}
        deleted: set[str] = set()
        for state in _children(world, "state"):
            for m in _children(state, "model"):
                out[_name(m)] = m
            for deletions in _children(state, "deletions"):
                deleted |= {(n.text or "").strip() for n in _children(deletions, "name")}
        out["__deleted__"] = deleted
        return out

    def include(self, el: Any, models: dict[str, Any], states: dict[str, Any]) -> None:
        uri_el = _child(el, "uri")
        uri = (uri_el.text or "").strip() if uri_el is not None else ""
        target = uri.removeprefix("model://").strip("/")
        if target in FLOOR_MODELS or target in IGNORED_MODELS:
            return
        if target not in models:
            raise _Refused(
                uri_el if uri_el is not None else el,
                f"<include> of {uri!r}: a model the file does not hold (include it as a "
                "<model> with its geometry)",
            )
        name_el = _child(el, "name")
        name = (name_el.text or "").strip() if name_el is not None else target
        placed = self.pose(_child(el, "pose"))
        static_el = _child(el, "static")
        self.model(models[target], IDENTITY, states.get(name), name, placed, static_el)

    def model(
        self,
        el: Any,
        parent: Transform,
        state: Any | None,
        name: str,
        placed: Transform | None = None,
        static_el: Any | None = None,
        parent_static: bool = False,
    ) -> None:
        """A model's bodies (``parent``: its parent model's world transform; ``placed``: an
        include's pose instead of the model's own)."""
        static_el = static_el if static_el is not None else _child(el, "static")
        static = parent_static or (
            static_el is not None and (static_el.text or "").strip().lower() in ("1", "true")
        )
        if not static:
            raise _Refused(static_el if static_el is not None else el, "not a static model")
        for plugin in _children(el, "plugin"):
            raise _Refused(plugin, "a model plugin may move or change it (DynaBARN's do)")
        for inner in _children(el, "include"):
            raise _Refused(inner, "an <include> inside a model is not read")
        state_pose = _child(state, "pose") if state is not None else None
        if state_pose is not None:
            transform = self.pose(state_pose)
        else:
            own = placed if placed is not None else self.pose(_child(el, "pose"))
            transform = compose(parent, own)
        scale = _child(state, "scale") if state is not None else None
        if scale is not None and any(
            abs(s - 1.0) > 1e-9 for s in self.number_list(scale, (3,), "<scale>")
        ):
            raise _Refused(scale, "a scaled model is not read")
        link_states = {_name(s): s for s in _children(state, "link")} if state is not None else {}
        for link in _children(el, "link"):
            link_state = link_states.get(_name(link))
            link_pose = _child(link_state, "pose") if link_state is not None else None
            if link_pose is not None:  # Gazebo saves (and sets) a link's world pose
                link_transform = self.pose(link_pose)
            else:
                own = self.pose(_child(link, "pose"), ("", _name(el), "__model__"))
                link_transform = compose(transform, own)
            for collision in _children(link, "collision"):
                where = f"model {name!r} link {_name(link)!r} collision {_name(collision)!r}"
                try:
                    own = self.pose(_child(collision, "pose"), ("", _name(link)))
                    self.collision(collision, compose(link_transform, own), where)
                except _Refused as exc:
                    self.refuse(exc, where)
        nested_states = (
            {_name(m): m for m in _children(state, "model")} if state is not None else {}
        )
        for nested in _children(el, "model"):
            nested_name = f"{name}::{_name(nested)}"
            try:
                self.model(
                    nested,
                    transform,
                    nested_states.get(_name(nested)),
                    nested_name,
                    parent_static=True,
                )
            except _Refused as exc:
                self.refuse(exc, f"model {nested_name!r}")

    def collision(self, el: Any, transform: Transform, where: str) -> None:
        geometry = _child(el, "geometry")
        if geometry is None:
            raise _Refused(el, "a collision without <geometry>")
        shapes = [c for c in geometry if isinstance(c.tag, str)]
        for shape in shapes:
            self.shape(shape, transform, where)

    def shape(self, el: Any, transform: Transform, where: str) -> None:
        rotation, (x, y, z) = transform
        tag = el.tag
        if tag == "empty":
            return
        if tag == "plane":
            normal_el = _child(el, "normal")
            normal = np.array(
                self.number_list(normal_el, (3,), "<normal>")
                if normal_el is not None
                else [0, 0, 1]
            )
            n = rotation @ (normal / (np.linalg.norm(normal) or 1.0))
            if n[2] < UPRIGHT or abs(z) > 1e-6:
                raise _Refused(el, "a plane that is not the floor (z = 0, facing up)")
            return
        if tag in UNSUPPORTED_GEOMETRY:
            what = {"mesh": "a mesh", "heightmap": "a heightmap"}.get(tag, f"a <{tag}>")
            uri = _child(el, "uri")
            named = f" ({(uri.text or '').strip()})" if uri is not None else ""
            raise _Refused(el, f"{what}{named} is not read: only boxes, cylinders and spheres")
        if tag == "box":
            size_el = _child(el, "size")
            if size_el is None:
                raise _Refused(el, "<size> is missing")
            size = self.number_list(size_el, (3,), "<size>")
            if min(size) <= 0:
                raise _Refused(size_el, f"<size> must be positive, got {size_el.text!r}")
            if max(size) > MAX_COORDINATE:
                raise _Refused(
                    size_el, f"<size> is more than {MAX_COORDINATE:.0e} m: {max(size):g}"
                )
            up = [k for k in range(3) if abs(rotation[2, k]) >= UPRIGHT]
            if not up:
                raise _Refused(el, "a tilted box (no axis upright) is not read")
            k = up[0]
            i, j = [a for a in range(3) if a != k]
            half_z = size[k] / 2.0
            if not self.cut(z - half_z, z + half_z, where, el):
                return
            yaw = math.atan2(rotation[1, i], rotation[0, i])
            self.world.boxes.append(Box(float(x), float(y), size[i] / 2.0, size[j] / 2.0, yaw))
            self.world.box_sources.append(self.source(size_el, where))
            return
        if tag == "cylinder":
            radius = self.positive(el, "radius")
            length = self.positive(el, "length")
            if abs(rotation[2, 2]) < UPRIGHT:
                raise _Refused(el, "a tilted cylinder (its axis not upright) is not read")
            if self.cut(z - length / 2.0, z + length / 2.0, where, el):
                self.world.cylinders.append(Cylinder(float(x), float(y), radius))
                self.world.cylinder_sources.append(self.source(el, where))
            return
        if tag == "sphere":
            radius = self.positive(el, "radius")
            if self.cut(z - radius, z + radius, where, el):
                cut = math.sqrt(max(radius * radius - (self.h - z) ** 2, 0.0))
                self.world.cylinders.append(Cylinder(float(x), float(y), cut))
                self.world.cylinder_sources.append(self.source(el, where))
            return
        raise _Refused(el, f"unknown geometry <{tag}>")

    def cut(self, z0: float, z1: float, where: str, el: Any) -> bool:
        """Whether the scan plane cuts a body spanning z0..z1 (else it is noted)."""
        if z0 < self.h < z1:
            return True
        self.world.not_cut.append(
            {
                "line": el.sourceline,
                "item": where,
                "z": [round(z0, 4), round(z1, 4)],
                "scan_height": self.h,
            }
        )
        return False
