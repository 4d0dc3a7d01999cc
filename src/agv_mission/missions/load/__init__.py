"""The mission as the user wrote it, checked and resolved.

Owns the schema (pydantic models of mission-format.md), YAML with line numbers, the one
problem shape (:class:`Problem`, :class:`MissionError`: file, line, field), ``--set``
overrides, the checks against the world, the people's routes, and the tree assembly
(a ``tasks:`` list, a YAML tree or a BT.CPP XML file -> one :class:`TreeSpec`). It ends
in a :class:`LoadedMission`: everything the mission names loaded, nothing run.

Nothing here imports MuJoCo or casadi (``validate`` and ``schema`` stay light); the names
below load on first use.
"""

from __future__ import annotations

from importlib import import_module
from typing import Any

_EXPORTS = {
    "LoadedMission": "resolved",
    "RobotSetup": "resolved",
    "MissionError": "errors",
    "Problem": "errors",
    "Override": "overrides",
    "load_mission": "loader",
    "load_demo_mission": "loader",
    "TreeSpec": "tree_spec",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(import_module(f"{__name__}.{module}"), name)
