"""What a mission sent over HTTP may read: built-in worlds and robots, files under --data.

The loader asks :func:`DataDirGuard.__call__` before it opens any file a mission names;
paths are compared after resolving ``..`` and symbolic links, and files that name further
files (a ROS map YAML's ``image``, a world file's ``rooms``) are checked as well.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import yaml

from agv_mission.atomic import input_path
from agv_mission.yaml_safe import safe_load

MAX_NESTED_FILE = 1_000_000  # bytes of a world YAML read to look for nested paths

PathGuard = Callable[[str, Path], "str | None"]


class DataDirGuard:
    """A loader path guard that refuses anything outside ``root``."""

    def __init__(self, root: Path) -> None:
        self.root = root.resolve()

    def inside(self, path: Path) -> bool:
        try:
            resolved = path.resolve(strict=False)
        except (OSError, RuntimeError):  # a symlink loop
            return False
        return resolved == self.root or self.root in resolved.parents

    def __call__(self, field: str, path: Path) -> str | None:
        refusal = (
            f"{str(path)!r} is not allowed: a mission sent to the service may name built-in "
            "worlds and robots, and files under the service's data directory only"
        )
        if not self.inside(path):
            return refusal
        if field != "world":
            return None
        world = world_file(path)
        for key, target in nested_files(world).items():
            if not self.inside(target):
                return f"{key} {target.name!r} of {world.name}: " + refusal.split(": ", 1)[1]
        return None


def world_file(path: Path) -> Path:
    """The YAML file a mission's ``world:`` path stands for (a folder holds ``map.yaml``)."""
    return path / "map.yaml" if path.is_dir() else path


def nested_files(world: Path) -> dict[str, Path]:
    """The files a world YAML names (a ROS map's ``image``, a world file's ``rooms``), by
    key; empty when it is no readable YAML mapping (the loader reports that)."""
    try:
        if not world.is_file() or world.stat().st_size > MAX_NESTED_FILE:
            return {}  # the loader reports a missing file; a huge one is no world
        doc = safe_load(world.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, yaml.YAMLError):
        return {}
    if not isinstance(doc, dict):
        return {}
    return {
        key: input_path(doc[key], world.parent)
        for key in ("image", "rooms")
        if isinstance(doc.get(key), str)
    }


class NamedFiles:
    """A path guard that asks another one and notes every file the mission names (its
    world's nested files too): which files may travel with a mission."""

    def __init__(self, guard: PathGuard | None = None) -> None:
        self.guard = guard
        self.paths: list[Path] = []

    def __call__(self, field: str, path: Path) -> str | None:
        refusal = self.guard(field, path) if self.guard is not None else None
        if refusal is None:
            if field == "world":
                world = world_file(path)
                self.paths += [world, *nested_files(world).values()]
            else:
                self.paths.append(path)
        return refusal
