"""The collision monitor (people-and-zones.md): stop, slowdown and approach zones on raw
lidar points between the controller and the wheels, its events and metrics."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from agv_mission.missions.load.errors import MissionError
from agv_mission.missions.load.loader import load_mission
from agv_mission.missions.run.runner import run_mission
from agv_mission.planners.collision_monitor import (
    CollisionMonitor,
    CollisionMonitorConfig,
    default_zones,
)

R = 0.105  # the burger's footprint radius


def monitor(zones: list[dict] | None = None) -> CollisionMonitor:
    config = CollisionMonitorConfig.model_validate({"zones": zones} if zones else {})
    return CollisionMonitor(config, R, 0.1)


def wall(x: float) -> np.ndarray:
    """Lidar points of a wall across the robot's way, ``x`` metres ahead of its centre."""
    return np.column_stack([np.full(41, x), np.linspace(-1.0, 1.0, 41)])


def test_default_zones_from_the_footprint() -> None:
    stop, slow, ttc = default_zones(R)
    assert (stop.type, slow.type, ttc.type) == ("stop", "slowdown", "approach")
    assert max(p[0] for p in stop.polygon) == pytest.approx(R + 0.05)
    assert max(abs(p[1]) for p in stop.polygon) == pytest.approx(R)


def test_stop_needs_min_points_and_only_ahead() -> None:
    cm = monitor()
    one = np.array([[R + 0.02, 0.0]])
    assert cm(0.2, 0.0, one).action != "stop"  # one point is noise (min_points 2)
    two = np.array([[R + 0.02, 0.0], [R + 0.03, 0.01]])
    out = cm(0.2, 0.1, two)
    # stopped, but free to turn on the spot (a round footprint sweeps nothing new)
    assert (out.action, out.zone, out.v, out.w) == ("stop", "stop", 0.0, 0.1)
    assert cm.changed
    back = cm(-0.1, 0.0, two)  # backing away from it is allowed
    assert back.action == "none" and back.v == -0.1
    assert cm(0.0, 1.0, two).w == 1.0  # turning in place sweeps nothing new
    # Walls beside the robot (a doorway 0.5 m wide) do not stop it.
    door = np.array([[x, s * 0.25] for x in np.linspace(0.0, 0.5, 11) for s in (-1, 1)])
    assert cm(0.2, 0.0, door).action == "none"


def test_slowdown_and_approach() -> None:
    cm = monitor(
        [
            {"name": "slow", "type": "slowdown", "radius": 0.6, "slowdown_ratio": 0.3},
            {"name": "ttc", "type": "approach", "time_before_collision": 1.5},
        ]
    )
    out = cm(0.2, 0.2, np.array([[0.5, 0.3], [0.5, 0.31]]))
    assert (
        out.action == "slowdown" and out.v == pytest.approx(0.06) and out.w == pytest.approx(0.06)
    )
    cm = monitor([{"name": "ttc", "type": "approach", "time_before_collision": 1.0}])
    assert cm(0.2, 0.0, wall(R + 0.5)).action == "none"  # 2.5 s away
    out = cm(0.2, 0.0, wall(R + 0.1))  # 0.5 s away at 0.2 m/s
    # reaching it no sooner than 1 s at the new speed: at most 0.1 m/s, to the 0.1 s step
    assert out.action == "approach" and 0.07 <= out.v <= 0.1 + 1e-9


def test_zone_shapes_are_validated(tmp_path: Path) -> None:
    path = tmp_path / "m.yaml"
    path.write_text(
        "world: turtlebot3_world\nstack:\n  collision_monitor:\n    zones:\n"
        "      - {name: a, type: approach, radius: 0.5}\n"
        "      - {name: s, type: stop, radius: 0.5}\n"
        "tasks:\n  - {type: go_to, pose: {x: -0.55, y: -0.55, yaw: 0.0}}\n"
    )
    with pytest.raises(MissionError) as exc:
        load_mission(path)
    found = {(p.line, p.field) for p in exc.value.problems}
    assert found == {(5, "stack.collision_monitor.zones.0"), (6, "stack.collision_monitor.zones.1")}


MISSION = """\
name: cm
world: turtlebot3_world
start: {{x: -2.0, y: -0.5, yaw: 0.0}}
seed: 9
stack:
  localization: {{type: ground_truth}}
  local_planner: {{type: pure_pursuit}}
  costmap: {{obstacles: {{enabled: false}}}}
  collision_monitor: {{enabled: {enabled}}}
obstacles:
  - {{type: cylinder, x: -1.3, y: -0.5, radius: 0.12}}
tasks:
  - {{type: go_to, pose: {{x: -0.55, y: -0.55, yaw: 0.0}}}}
limits: {{time: 6.0, collisions: 5}}
"""


def test_the_monitor_stops_a_blind_controller_before_an_unmapped_obstacle(tmp_path: Path) -> None:
    """Pure pursuit ignores obstacles and the obstacle layer is off: without the monitor
    the robot drives into the cylinder; with it, it stops short, with events."""
    records = {}
    for enabled in ("true", "false"):
        path = tmp_path / f"cm_{enabled}.yaml"
        path.write_text(MISSION.format(enabled=enabled))
        records[enabled] = run_mission(load_mission(path))
    on, off = records["true"], records["false"]
    assert off.metrics["collisions"] >= 1
    assert on.metrics["collisions"] == 0 and on.metrics["min_clearance"] > 0.0
    stats = on.metrics["collision_monitor"]
    assert stats["stop"]["activations"] >= 1 and stats["stop"]["time"] > 1.0
    actions = [e["action"] for e in on.events if e["event"] == "collision_monitor"]
    assert actions[-1] == "stop" and "slowdown" in actions
    assert off.metrics["collision_monitor"]["stop"]["activations"] == 0
