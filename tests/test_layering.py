"""The floors of ``architecture.md`` stay true: a module imports only from floors below its
own (or from its own package), and the packages of floor 3 and of floor 7 (the front
doors) do not import each other."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "src" / "agv_mission"

FLOORS = {
    "cli": 8,
    "service": 7,
    "regress": 7,
    "barn": 7,
    "teleop": 7,
    "bags": 7,
    "vda5050": 7,
    "missions": 6,
    # missions/ by concern, data flowing one way: the mission loaded, its run, its report
    "missions.report": 6.3,
    "missions.run": 6.2,
    "missions.load": 6.1,
    "plugin_check": 6,  # drives a plugin of any slot: floor-3 ones, and behaviour nodes (5)
    "behaviors": 5,
    "navigation": 4,
    "fleet": 4,
    "robots": 3,
    "planners": 3,
    "localization": 3,
    "mapping": 3,
    "world": 2,
    "maps": 1,
    "geometry": 0,
    "registry": 0,
    "atomic": 0,
    "stored": 0,
    "job_pool": 0,
    "sensor_msgs": 0,
    "json_values": 0,
    "suggest": 0,
    "yaml_safe": 0,
}
GROUND = 0  # the floor-0 modules are the ground everything stands on: they may share


def unit_of(module: str) -> str:
    """``agv_mission.maps.grid`` -> ``maps``; ``agv_mission.cli`` -> ``cli``;
    ``agv_mission.missions.run.runner`` -> ``missions.run`` (a floor of its own)."""
    parts = module.split(".")
    if len(parts) > 2 and f"{parts[1]}.{parts[2]}" in FLOORS:
        return f"{parts[1]}.{parts[2]}"
    return parts[1] if len(parts) > 1 else ""


def imports_of(module: str, source: str, is_package: bool = False) -> list[tuple[int, str]]:
    """Every agv_mission module ``source`` imports (module level or inside functions)."""
    package = module if is_package else module.rsplit(".", 1)[0]
    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            found += [(node.lineno, a.name) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:  # relative: resolve against this package
                parts = package.split(".")
                base = parts[: len(parts) - node.level + 1]
                name = ".".join(base + ([node.module] if node.module else []))
            else:
                name = node.module or ""
            found.append((node.lineno, name))
    return [(line, name) for line, name in found if name.startswith("agv_mission.")]


def module_problems(module: str, source: str, is_package: bool = False) -> list[str]:
    mine = unit_of(module)
    if not mine:
        return []  # the package's own __init__
    if mine not in FLOORS:
        return [f"{module}: not on any floor (add it to FLOORS and architecture.md)"]
    problems = []
    for line, name in imports_of(module, source, is_package):
        theirs = unit_of(name)
        if theirs == mine:
            continue
        if theirs not in FLOORS:
            problems.append(f"{module}:{line} imports {name}, which is on no floor")
        elif FLOORS[theirs] > FLOORS[mine] or (FLOORS[theirs] == FLOORS[mine] != GROUND):
            problems.append(
                f"{module}:{line} (floor {FLOORS[mine]}) imports {name} (floor {FLOORS[theirs]})"
            )
    return problems


def violations() -> list[str]:
    problems = []
    for path in sorted(PACKAGE.rglob("*.py")):
        parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
        is_package = parts[-1] == "__init__"
        module = ".".join(parts[:-1] if is_package else parts)
        problems += module_problems(module, path.read_text(encoding="utf-8"), is_package)
    return problems


def test_every_module_imports_only_from_floors_below() -> None:
    problems = violations()
    assert not problems, "layering broken:\n" + "\n".join(problems)


def test_the_loaded_mission_does_not_reach_into_its_run_or_report() -> None:
    """Inside ``missions/`` the data flows load -> run -> report: a load module importing
    the run, or the run importing the report, is caught; the other way is fine."""
    up = "from agv_mission.missions.run.record import RunRecord\n"
    [problem] = module_problems("agv_mission.missions.load.probe", up)
    assert "(floor 6.2)" in problem
    [problem] = module_problems(
        "agv_mission.missions.run.probe", "from agv_mission.missions.report import outputs\n"
    )
    assert "(floor 6.3)" in problem
    assert module_problems("agv_mission.missions.report.probe", up) == []


@pytest.mark.parametrize(
    ("source", "expected"),
    [
        ("from agv_mission.missions.run.runner import run_mission\n", "(floor 6.2)"),
        ("def f():\n    from agv_mission.mapping.slam import GridSlam\n", "(floor 3)"),
        ("from ..teleop import session\n", "(floor 7)"),
    ],
)
def test_the_walker_sees_an_upward_import(source: str, expected: str) -> None:
    """A planner (floor 3) importing the runner, SLAM (inside a function) or a front door
    (relative import): all caught; its own package and the floors below are fine."""
    [problem] = module_problems("agv_mission.planners.probe", source)
    assert expected in problem
    fine = "from agv_mission.planners.base import PlannedPath\nfrom agv_mission.maps import grid\n"
    assert module_problems("agv_mission.planners.probe", fine) == []
