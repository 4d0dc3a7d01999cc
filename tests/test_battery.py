"""The battery and docks: the power model, robot/world/rooms files, the conditions on a
real robot handle, and runs that dock, charge, undock, or run flat."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest
from py_trees.common import Status

from agv_mission.behaviors.battery import (
    Charge,
    IsBatteryCharging,
    IsBatteryLow,
    Undock,
)
from agv_mission.maps.builtin_worlds import BUILTIN_WORLDS
from agv_mission.maps.costmap import Costmap
from agv_mission.maps.rooms_file import RoomsFileError, load_rooms_file
from agv_mission.maps.world_loader import WorldError, load_world
from agv_mission.missions.load.errors import MissionError
from agv_mission.missions.load.loader import load_mission
from agv_mission.missions.load.schema.expect import Expectations
from agv_mission.missions.report.expectations import check
from agv_mission.missions.report.outputs import make_run_dir, write_run
from agv_mission.missions.run.runner import MissionRun, run_mission
from agv_mission.navigation.navigator import NavStatus
from agv_mission.robots.battery import WH, Battery, BatterySpec, battery_for
from agv_mission.robots.builtin_robots import BUILTIN_ROBOTS
from agv_mission.robots.robot_files import RobotFileError, load_robot

REPO = Path(__file__).resolve().parents[1]
BURGER = BUILTIN_ROBOTS["burger"]

SETUP = """\
name: {name}
world: turtlebot3_world
robot: {robot}
start: {{x: -2.0, y: -0.5, yaw: 0.0}}
seed: 3
simulation: {{battery_level: {level}}}
stack:
  localization: {{type: ground_truth}}
  global_planner: {{type: ompl, planner: RRTConnect, time_limit: 1.0}}
  local_planner: {{type: mpc}}
limits: {{time: {limit}}}
tasks:
"""


def mission(tmp_path: Path, tasks: str, *, level: float = 1.0, limit: float = 120.0, **kw):
    name = kw.pop("name", "battery")
    text = SETUP.format(name=name, robot=kw.pop("robot", "burger"), level=level, limit=limit)
    path = tmp_path / f"{name}.yaml"
    path.write_text(text + tasks)
    return load_mission(path)


# --------------------------------------------------------------------------- the model


def spec(**kw: float) -> BatterySpec:
    base = {"capacity": 10.0, "idle_power": 5.0, "charge_power": 20.0}
    return BatterySpec(**{**base, **kw})


def test_standing_still_draws_the_idle_load_exactly() -> None:
    battery = Battery(spec(), mass=1.0, inertia=0.01, track=0.16)
    for _ in range(1000):
        battery.step(0.0, 0.0, 0.1)
    assert battery.energy_used == pytest.approx(5.0 * 100.0)
    assert battery.level == pytest.approx(1.0 - 500.0 / (10.0 * WH))
    assert battery.minimum == battery.level and battery.start == 1.0


def test_driving_adds_friction_and_acceleration_but_braking_gives_nothing_back() -> None:
    s = spec(rolling_resistance=0.05, drive_efficiency=0.5)
    b = Battery(s, mass=2.0, inertia=0.0, track=0.2)
    # accelerate 0 -> 0.2 m/s in 0.1 s: m a v + mu m g v, over the efficiency
    power = b.motion_power(0.2, 0.0, 0.1)
    assert power == pytest.approx((2.0 * 2.0 * 0.2 + 0.05 * 2.0 * 9.81 * 0.2) / 0.5)
    b.step(0.2, 0.0, 0.1)
    cruise = b.motion_power(0.2, 0.0, 0.1)
    assert cruise == pytest.approx(0.05 * 2.0 * 9.81 * 0.2 / 0.5)
    b.step(0.2, 0.0, 0.1)
    braking = b.motion_power(0.0, 0.0, 0.1)
    assert braking == 0.0  # standing at the end, and no regeneration
    # turning in place: the wheels roll at w * track / 2
    assert b.motion_power(0.0, 0.0, 0.1) < Battery(s, 2.0, 0.0, 0.2).motion_power(0.0, 1.0, 0.1)


def test_charging_raises_the_level_at_charge_power_and_stops_at_full() -> None:
    b = Battery(spec(), 1.0, 0.01, 0.16, level=0.5)
    b.charging = True
    for _ in range(100):  # 10 s at 20 W: 200 J of 36 kJ
        b.step(0.0, 0.0, 0.1)
    assert b.level == pytest.approx(0.5 + 200.0 / 36000.0)
    assert b.charging_time == pytest.approx(10.0) and b.energy_used == 0.0
    for _ in range(20000):
        b.step(0.0, 0.0, 0.1)
    assert b.level == 1.0


def test_level_never_falls_below_zero() -> None:
    b = Battery(spec(capacity=0.001), 1.0, 0.01, 0.16)
    for _ in range(100):
        b.step(0.2, 0.0, 0.1)
    assert b.level == 0.0 and b.empty


def test_builtin_batteries_are_the_turtlebot3_pack() -> None:
    for name in ("burger", "waffle"):
        battery = BUILTIN_ROBOTS[name].battery
        assert battery is not None
        assert battery.capacity == pytest.approx(11.1 * 1.8)  # 19.98 Wh
    # ROBOTIS: about 2 h 30 min (burger) and 2 h (waffle pi) of operation on one charge
    for name, hours in (("burger", 2.5), ("waffle", 2.0)):
        robot = BUILTIN_ROBOTS[name]
        b = battery_for(robot.battery, robot.mass, robot.footprint_radius, robot.wheel_separation)
        cruise = robot.max_linear_velocity
        b.step(cruise, 0.0, 0.1)
        power = robot.battery.idle_power + b.motion_power(cruise, 0.0, 0.1)
        assert robot.battery.capacity / power == pytest.approx(hours, rel=0.02)
    assert BUILTIN_ROBOTS["rosbots"].battery is not None


# --------------------------------------------------------------------------- files


def test_robot_file_battery_errors_name_line_and_field(tmp_path: Path) -> None:
    path = tmp_path / "bot.yaml"
    path.write_text(
        "wheel_radius: 0.03\nwheel_separation: 0.2\nfootprint_radius: 0.1\n"
        "max_linear_velocity: 0.3\nmax_angular_velocity: 2.0\n"
        "encoder: {ticks_per_meter: 1000}\n"
        "battery:\n  capacity: 20\n  initial_level: 1.5\n  idle_power: 5\n  charge_power: 20\n"
    )
    with pytest.raises(RobotFileError) as exc:
        load_robot(str(path))
    assert (exc.value.line, exc.value.field) == (9, "battery.initial_level")
    path.write_text(path.read_text().replace("1.5", "0.5"))
    robot = load_robot(str(path))
    assert robot.battery is not None and robot.battery.initial_level == 0.5


def test_builtin_worlds_have_a_charger_the_waffle_fits_on() -> None:
    for name, make in BUILTIN_WORLDS.items():
        world = make()
        dock = world.docks["charger"]
        costmap = Costmap.from_grid(world.map, BUILTIN_ROBOTS["waffle"].footprint_radius)
        for pose in (dock.pose, dock.staging()):
            assert costmap.is_free([pose.x, pose.y]), (name, pose)
        # by a wall: within 0.35 m of an obstacle straight ahead of the docked robot
        ahead = [dock.pose.x + 0.36 * math.cos(dock.pose.yaw)]
        ahead.append(dock.pose.y + 0.36 * math.sin(dock.pose.yaw))
        assert not costmap.is_free(ahead), name


WORLD = """\
spawn: {x: 0.0, y: 0.0}
boxes:
  - {x: 0.0, y: 2.05, half_x: 2.0, half_y: 0.05}
  - {x: 0.0, y: -2.05, half_x: 2.0, half_y: 0.05}
  - {x: 2.05, y: 0.0, half_x: 0.05, half_y: 2.1}
  - {x: -2.05, y: 0.0, half_x: 0.05, half_y: 2.1}
docks:
  charger: {x: 0.0, y: 1.7, yaw: 1.5708}
  wall: {x: 2.05, y: 0.0}
"""


def test_world_file_docks_are_checked_with_file_and_line(tmp_path: Path) -> None:
    path = tmp_path / "arena.yaml"
    path.write_text(WORLD)
    with pytest.raises(WorldError) as exc:
        load_world(str(path))
    assert f"{path}:9: docks.wall:" in str(exc.value)
    assert "not on a free cell" in str(exc.value)
    path.write_text(WORLD.replace("{x: 2.05, y: 0.0}", "{x: 9.0, y: 0.0}"))
    with pytest.raises(WorldError, match=r"arena.yaml:9: docks.wall: .* outside the map"):
        load_world(str(path))
    path.write_text(WORLD.replace("  wall: {x: 2.05, y: 0.0}\n", ""))
    world = load_world(str(path))
    assert world.docks["charger"].pose.y == 1.7
    path.write_text(WORLD.replace("yaw: 1.5708}", "yaw: east}"))
    with pytest.raises(WorldError) as exc:
        load_world(str(path))
    assert any(p.startswith(f"{path}:8: docks.charger.yaw: ") for p in exc.value.problems)


def test_rooms_file_docks_and_their_problems(tmp_path: Path) -> None:
    rooms = tmp_path / "rooms.yaml"
    rooms.write_text("docks:\n  base: {x: -1.0, y: 0.0, yaw: 3.1416}\n  bad: {x: 1.0, z: 2}\n")
    with pytest.raises(RoomsFileError, match=r"docks\.bad\.z"):
        load_rooms_file(rooms)
    rooms.write_text(
        "docks:\n  base: {x: -2.0, y: -0.5, yaw: 3.1416}\n  pillar: {x: 0.0, y: 0.0}\n"
    )
    _, docks = load_rooms_file(rooms)
    assert docks["pillar"].source == f"{rooms}:3"
    text = SETUP.format(name="m", robot="burger", level=1.0, limit=10)
    path = tmp_path / "m.yaml"
    path.write_text(text.replace("seed: 3", "seed: 3\nrooms: rooms.yaml") + "  - {type: undock}\n")
    with pytest.raises(MissionError) as exc:
        load_mission(path)
    [problem] = exc.value.problems
    assert problem.field == "rooms" and problem.line == 6
    assert f"{rooms}:3: docks.pillar: (0, 0) is not on a free cell" in problem.message


def test_dock_and_charge_tasks_are_validated(tmp_path: Path) -> None:
    with pytest.raises(MissionError) as exc:
        mission(tmp_path, "  - {type: dock, dock: kitchen}\n  - {type: charge, until: 1.5}\n")
    [problem] = exc.value.problems
    assert (problem.line, problem.field) == (14, "tasks.1.until")
    with pytest.raises(MissionError) as exc:
        mission(tmp_path, "  - {type: dock, dock: kitchen}\n")
    [problem] = exc.value.problems
    assert (problem.line, problem.field) == (13, "tasks.0.dock")
    assert "unknown dock 'kitchen'; known docks: charger" in problem.message
    bot = tmp_path / "nobattery.yaml"
    bot.write_text(
        "wheel_radius: 0.033\nwheel_separation: 0.16\nfootprint_radius: 0.105\n"
        "max_linear_velocity: 0.22\nmax_angular_velocity: 2.84\n"
        "encoder: {ticks_per_meter: 19756}\n"
    )
    with pytest.raises(MissionError) as exc:
        mission(tmp_path, "  - {type: charge}\n", robot="nobattery.yaml")
    [problem] = exc.value.problems
    assert problem.field == "tasks.0" and "has no battery" in problem.message


# --------------------------------------------------------------------------- behaviours


def test_battery_conditions_on_a_real_handle(tmp_path: Path) -> None:
    run = MissionRun(mission(tmp_path, "  - {type: undock}\n", level=0.25), None)
    handle = run.handle
    assert handle.battery is run.lead.battery and handle.docks["charger"].name == "charger"
    low = IsBatteryLow("low?", handle, min_battery=0.3)
    charging = IsBatteryCharging("charging?", handle)
    low.tick_once()
    charging.tick_once()
    assert (low.status, charging.status) == (Status.SUCCESS, Status.FAILURE)
    handle.battery.level = 0.31
    low.tick_once()
    assert low.status is Status.FAILURE
    handle.battery.charging = True
    charging.tick_once()
    assert charging.status is Status.SUCCESS
    with pytest.raises(ValueError):
        IsBatteryLow("bad", handle, min_battery=1.5)
    # not docked: charging fails at once, undocking too; both leave the robot standing
    for action in (Charge("charge", handle, until=0.9), Undock("undock", handle)):
        handle.drive(0.1, 0.0)
        action.tick_once()
        assert action.status is Status.FAILURE and action.feedback_message == "not docked"
    assert handle.battery.charging is False


def run_dir_of(tmp_path: Path, loaded):
    run_dir = make_run_dir(tmp_path / "runs", loaded.name)
    record = run_mission(loaded, run_dir)
    doc = write_run(run_dir, loaded, record)
    return record, doc, run_dir


def test_dock_charge_undock_run(tmp_path: Path) -> None:
    loaded = mission(
        tmp_path,
        "  - {type: dock}\n  - {type: charge, until: 0.45}\n  - {type: undock}\n",
        level=0.4,
        limit=400,
    )
    record, doc, run_dir = run_dir_of(tmp_path, loaded)
    assert doc["status"] == "succeeded", doc["reason"]
    events = {e["event"]: e for e in doc["events"]}
    assert {"dock_staged", "docked", "charging", "charged", "undocked"} <= set(events)
    dock = loaded.docks["charger"]
    traj = record.trajectory
    docked_row = traj[abs(traj[:, 0] - events["docked"]["t"]).argmin()]
    # ground truth localisation: the docked robot stands on the dock pose, on its axis
    assert math.hypot(docked_row[1] - dock.pose.x, docked_row[2] - dock.pose.y) < 0.03
    staging = dock.staging()
    assert math.hypot(traj[-1, 1] - staging.x, traj[-1, 2] - staging.y) < 0.03
    battery = doc["metrics"]["battery"]
    assert battery["start"] == 0.4 and battery["dockings"] == 1
    assert battery["minimum"] < 0.4 and events["charged"]["level"] == pytest.approx(0.45)
    assert 0.449 < battery["end"] < 0.45  # backing out drew from it again
    # charging at 19.98 W from the minimum to 0.45 of 19.98 Wh
    expected = (0.45 - battery["minimum"]) * 3600.0
    assert battery["charging_time"] == pytest.approx(expected, abs=0.2)
    assert battery["energy_charged"] == pytest.approx(19.98 * expected / 3600.0, rel=1e-3)
    levels = record.battery
    assert levels is not None and len(levels) == len(traj)
    t = traj[:, 0]
    charging = (t > events["charging"]["t"] + 0.05) & (t < events["charged"]["t"] - 0.05)
    assert (levels[charging][1:] > levels[charging][:-1]).all()
    assert (abs(traj[charging, 7]) == 0.0).all()  # the robot stands while charging
    ok = Expectations(dockings_min=1, battery_min_min=0.35, battery_end_min=0.44)
    assert check(ok, doc) == []
    bad = Expectations(dockings_min=2, battery_min_min=0.399, battery_energy_used_max=0.01)
    assert {f.metric for f in check(bad, doc)} == {
        "dockings_min",
        "battery_min_min",
        "battery_energy_used_max",
    }
    result = json.loads((run_dir / "result.json").read_text())
    assert result["metrics"]["battery"] == battery


def test_flat_battery_stops_the_robot_and_fails_the_mission(tmp_path: Path) -> None:
    # 0.1 % of 19.98 Wh at ~8 W: about 9 s of driving, short of the 3.3 m leg
    loaded = mission(
        tmp_path, "  - {type: go_to, pose: {x: 1.13, y: -1.6, yaw: 0.0}}\n", level=0.001
    )
    record, doc, _ = run_dir_of(tmp_path, loaded)
    assert doc["status"] == "failed"
    assert doc["reason"].startswith("battery empty at t=") and "the robot stopped" in doc["reason"]
    assert doc["tasks"][0]["status"] == "failed"
    assert doc["metrics"]["battery"]["end"] == 0.0 == record.battery[-1]
    assert record.trajectory[-1, 7] == 0.0 and record.trajectory[-1, 8] == 0.0
    assert 6.0 < record.sim_time < 12.0


def test_a_halted_dock_stops_the_robot_and_cancels_its_goal(tmp_path: Path) -> None:
    run = MissionRun(mission(tmp_path, "  - {type: dock}\n"), None)
    for _ in range(30):
        assert run.step()
    dock = run.tree.tasks[0]
    assert dock.status is Status.RUNNING and run.navigator.goal is not None
    assert run.handle.command != (0.0, 0.0)
    run.tree.root.stop(Status.INVALID)  # a reactive parent halting it
    assert run.handle.command == (0.0, 0.0)
    assert run.navigator.status is NavStatus.IDLE


@pytest.mark.slow  # 15-20 s: a whole charge cycle; the dock, charge and low-battery tests above are fast
def test_a_reactive_tree_patrols_docks_when_low_charges_and_patrols_on(tmp_path: Path) -> None:
    """The battery-aware patrol as the contract's ``tree:``: a reactive fallback that
    re-checks is_battery_low every tick, over a patrol it halts."""
    text = SETUP.format(name="guard", robot="burger", level=0.1012, limit=400)
    text = text.removesuffix("tasks:\n") + (
        "tree:\n"
        "  type: repeat\n"
        "  num_cycles: -1\n"
        "  child:\n"
        "    type: reactive_fallback\n"
        "    children:\n"
        "      - type: sequence\n"
        "        name: recharge\n"
        "        children:\n"
        "          - {type: is_battery_low, min_battery: 0.1}\n"
        "          - {type: dock, dock: charger}\n"
        "          - {type: charge, until: 0.105}\n"
        "          - {type: undock}\n"
        "      - type: sequence\n"
        "        name: patrol\n"
        "        children:\n"
        "          - {type: navigate_to_pose, goal: {x: 0.55, y: -1.95, yaw: 0.0}}\n"
        "          - {type: navigate_to_pose, goal: {x: -2.0, y: -0.5, yaw: 0.0}}\n"
    )
    path = tmp_path / "guard.yaml"
    path.write_text(text)
    run = MissionRun(load_mission(path), None)
    handle = run.handle
    while run.step():
        pass
    events = [e["event"] for e in handle.events]
    # repeat -1 runs until the time limit: the mission ends there, as it was meant to
    assert run.status == "succeeded", run.reason
    # low after ~11 s: docks, charges, patrols on until low again, and again
    assert events[:5] == ["dock_staged", "docked", "charging", "charged", "undocked"]
    assert events.count("docked") >= 3 and events.count("undocked") >= 3
    second_dock = events.index("dock_staged", 1)
    assert events[5:second_dock].count("goal_reached") >= 2  # patrolled on after charging
    # never lower than the guard's 10 % less what docking takes (about 0.4 %)
    assert run.lead.battery.minimum > 0.095 and run.lead.battery.charging_time > 60.0


def test_the_battery_patrol_is_a_dashboard_template_and_validates() -> None:
    packaged = REPO / "src" / "agv_mission" / "data" / "missions" / "battery_patrol.yaml"
    example = REPO / "missions" / "battery_patrol.yaml"
    assert packaged.read_bytes() == example.read_bytes()
    loaded = load_mission(example)
    assert [t.type for t in loaded.mission.tasks] == [
        "patrol",
        "dock",
        "charge",
        "undock",
        "patrol",
    ]
    assert loaded.mission.simulation.battery_level == 0.3


def test_a_dock_the_robot_does_not_fit_on_is_refused(tmp_path: Path) -> None:
    """0.15 m from the south wall's face: a free cell, but a waffle (r = 0.22 m) cannot
    stand there; the burger (r = 0.105 m) can."""
    rooms = tmp_path / "rooms.yaml"
    rooms.write_text("docks:\n  tight: {x: 0.55, y: -2.35, yaw: -1.5708}\n")
    for robot, ok in (("waffle", False), ("burger", True)):
        text = SETUP.format(name=robot, robot=robot, level=1.0, limit=10)
        path = tmp_path / f"{robot}.yaml"
        path.write_text(text.replace("seed: 3", "seed: 3\nrooms: rooms.yaml"))
        path.write_text(path.read_text() + "  - {type: dock, dock: tight}\n")
        if ok:
            assert load_mission(path).docks["tight"].source == f"{rooms}:2"
            continue
        with pytest.raises(MissionError) as exc:
            load_mission(path)
        [problem] = exc.value.problems
        assert problem.field == "tasks.0.dock"
        assert "dock 'tight' at (0.55, -2.35) is inside or too close to an obstacle" in (
            problem.message
        )


@pytest.mark.parametrize("world", sorted(BUILTIN_WORLDS))
def test_every_builtin_charger_is_reachable_by_the_waffle_with_amcl(
    tmp_path: Path, world: str
) -> None:
    path = tmp_path / "dock.yaml"
    path.write_text(
        f"name: dock-{world}\nworld: {world}\nrobot: waffle\nseed: 2\n"
        "stack: {localization: {type: amcl}}\nlimits: {time: 200}\n"
        "tasks: [{type: dock}, {type: undock}]\n"
    )
    loaded = load_mission(path)
    record = run_mission(loaded)
    assert record.status == "succeeded", record.reason
    assert record.metrics["collisions"] == 0
    dock = loaded.docks["charger"]
    [docked] = [e for e in record.events if e["event"] == "docked"]
    row = record.trajectory[abs(record.trajectory[:, 0] - docked["t"]).argmin()]
    assert math.hypot(row[1] - dock.pose.x, row[2] - dock.pose.y) < 0.06  # the true pose
