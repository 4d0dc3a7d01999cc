"""A mission document made ready to validate, before its schema sees it: a fleet's layout
(each robot's stack merged over the mission's, fleet tasks' ``robot:`` taken out) and the
localisation ``map: none`` defaults to.

Plain data in, plain data out: a file that fails here or in the schema is reported without
the world's machinery (maps, distance transforms) ever being imported.
"""

from __future__ import annotations

import copy
from typing import Any

from agv_mission.missions.load.problems import ProblemLog, kind_of
from agv_mission.missions.load.schema import NO_MAP


def fleet_layout(data: dict[str, Any], log: ProblemLog) -> dict[int, str]:
    """A fleet mission's data made ready to validate (in place): each robot's ``stack``
    merged over the mission's, and the fleet tasks' ``robot:`` taken out (returned by
    task index). Top-level ``robot:``/``start:`` beside ``robots:`` are refused."""
    robots = data.get("robots")
    if not isinstance(robots, list) or not robots:
        return {}
    for key in ("robot", "start"):
        if key in data:
            log.add(
                (key,),
                f"a fleet mission (with `robots:`) names each robot's {key} in its entry "
                f"under robots:, not a top-level `{key}:`",
            )
            del data[key]  # reported; the rest is still checked
    shared = data.get("stack")
    for robot in robots:
        if isinstance(robot, dict) and isinstance(shared, dict):
            own = robot.get("stack")
            if own is None or isinstance(own, dict):
                robot["stack"] = _merged(shared, own or {})
    assigned: dict[int, str] = {}
    for i, task in enumerate(data.get("tasks") or []):
        if isinstance(task, dict) and "robot" in task:
            name = task.pop("robot")
            if not isinstance(name, str):
                log.add(("tasks", i, "robot"), f"expected a robot's name, got {kind_of(name)}")
            else:
                assigned[i] = name
    return assigned


def _merged(base: dict[str, Any], over: dict[str, Any]) -> dict[str, Any]:
    """``over`` merged into a copy of ``base``, mapping by mapping; a plugin block whose
    ``type`` differs replaces the base's block whole."""
    out = copy.deepcopy(base)
    for key, value in over.items():
        old = out.get(key)
        swap = (
            isinstance(old, dict)
            and isinstance(value, dict)
            and ("type" in value and old.get("type", value["type"]) != value["type"])
        )
        if isinstance(old, dict) and isinstance(value, dict) and not swap:
            out[key] = _merged(old, value)
        else:
            out[key] = copy.deepcopy(value)
    return out


def names_no_map(value: Any) -> bool:
    """Whether a mission's ``map:`` value is ``none``."""
    return isinstance(value, str) and value.strip() == NO_MAP


def default_to_odometry(data: Any) -> None:
    """A ``map: none`` mission (its data, in place, before the plugin types are filled in)
    that names no localisation localises by odometry."""
    if not isinstance(data, dict) or not names_no_map(data.get("map")):
        return
    stack = data.setdefault("stack", {})
    if isinstance(stack, dict) and "localization" not in stack:
        stack["localization"] = {"type": "odometry"}
