"""What a mission sent over HTTP may read: built-in worlds and robots, files under --data.

The loader asks :func:`DataDirGuard.__call__` before it opens any file a mission names;
paths are compared after resolving ``..`` and symbolic links, and files that name further
files (a ROS map YAML's ``image``, a world file's ``rooms``) are checked as well.
"""

from __future__ import annotations

from pathlib import Path

import yaml

from agv_mission.atomic import input_path

MAX_NESTED_FILE = 1_000_000  # bytes of a world YAML read to look for nested paths


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
        if path.is_dir():
            path = path / "map.yaml"
        try:
            if not path.is_file() or path.stat().st_size > MAX_NESTED_FILE:
                return None  # the loader reports a missing file; a huge one is no world
            doc = yaml.safe_load(path.read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError, yaml.YAMLError):
            return None  # the loader reports it
        if not isinstance(doc, dict):
            return None
        for key in ("image", "rooms"):
            nested = doc.get(key)
            if isinstance(nested, str):
                target = input_path(nested, path.parent)
                if not self.inside(target):
                    return f"{key} {nested!r} of {path.name}: " + refusal.split(": ", 1)[1]
        return None
