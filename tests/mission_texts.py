"""Small missions in turtlebot3_world, written once for the tests and benchmarks that need
a mission file's text: the small world and short legs keep them fast."""

from __future__ import annotations

from pathlib import Path

GROUND_TRUTH = "{localization: {type: ground_truth}}"

# Two waypoints 0.4 m apart, a million rounds: only the time limit (or a signal) ends it.
ENDLESS_PATROL = """\
type: patrol
    waypoints: [{x: -1.6, y: -0.5, yaw: 0.0}, {x: -2.0, y: -0.5, yaw: 3.14}]
    loops: 1000000"""


def tb3_mission(
    *tasks: str,
    limits: str,
    robot: str | None = "burger",
    yaw: float = 0.0,
    stack: str = GROUND_TRUTH,
    name: str | None = None,
) -> str:
    """A mission from the usual start (-2.0, -0.5) facing ``yaw``; each task is one YAML
    list item (a flow mapping, or a block whose further lines are indented four spaces).
    ``robot=None`` leaves the line out (the default robot, the burger)."""
    return (
        (f"name: {name}\n" if name else "")
        + "world: turtlebot3_world\n"
        + (f"robot: {robot}\n" if robot else "")
        + f"start: {{x: -2.0, y: -0.5, yaw: {yaw}}}\n"
        + f"stack: {stack}\ntasks:\n"
        + "".join(f"  - {task}\n" for task in tasks)
        + f"limits: {limits}\n"
    )


def mission_file(folder: Path, text: str, name: str = "m") -> Path:
    """``text`` written to ``folder/name.yaml``."""
    path = folder / f"{name}.yaml"
    path.write_text(text)
    return path
