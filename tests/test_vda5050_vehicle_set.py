"""A fleet mission's robots as VDA 5050 vehicles on the mission's one world (fleet.md,
vda5050.md): one run holds every robot, each vehicle drives its own robot, the robots'
lidars see each other and their contacts count. Against Debian's mosquitto and a minimal
master written from the standard (tests/vda5050_peers.py)."""

from __future__ import annotations

import math
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from agv_mission.missions.load.resolved import Layout
from agv_mission.vda5050.body import VehicleWorld
from agv_mission.vda5050.transport import BrokerUrl
from agv_mission.vda5050.vehicle_set import VehicleSet, load_vehicles
from vda5050_peers import MiniMaster, Mosquitto, action, edge, node

MAP = "turtlebot3_world"
STARTS = {"agv1": (0.55, -0.55, 0.0), "agv2": (1.55, -0.55, math.pi)}  # facing, 1 m apart
FLEET = {
    "name": "vda-fleet",
    "world": MAP,
    "seed": 2,
    "stack": {
        "localization": {"type": "ground_truth"},
        "global_planner": {"type": "cost_grid"},
        "local_planner": {"type": "pure_pursuit"},
    },
    "robots": [
        {"name": name, "robot": "burger", "start": {"x": x, "y": y, "yaw": yaw}}
        for name, (x, y, yaw) in STARTS.items()
    ],
    # ignored by the vehicles (a master's business), with the master's node actions
    "tasks": [{"type": "go_to", "pose": {"x": -1.6, "y": -0.5}, "actions": [{"type": "pick"}]}],
}
TIME_SCALE = 5.0


def start_fleet(folder: Path, port: int, mission: dict[str, Any] = FLEET) -> VehicleSet:
    path = folder / "fleet.yaml"
    path.write_text(yaml.safe_dump(mission))
    fleet = VehicleSet(load_vehicles(path), BrokerUrl("127.0.0.1", port), time_scale=TIME_SCALE)
    fleet.start()
    return fleet


def ahead(scan: Any) -> float:
    """The closest return within +-5 beams of straight ahead."""
    n = len(scan.ranges)
    return float(np.nanmin(scan.ranges[np.r_[0:5, n - 5 : n]]))


@pytest.fixture(scope="module")
def broker(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Mosquitto]:
    mq = Mosquitto(tmp_path_factory.mktemp("mosquitto"))
    mq.start()
    yield mq
    mq.stop()


def test_two_vehicles_of_a_fleet_share_one_world(broker: Mosquitto, tmp_path: Path) -> None:
    master = MiniMaster(broker.port)
    fleet = start_fleet(tmp_path, broker.port)
    try:
        for serial in STARTS:
            master.wait(serial, "state", lambda d: True, 30)
        run = fleet.world.run
        assert run is not None
        # one run, one MuJoCo world, both robots' bodies in it
        assert sorted(run.by_name) == ["agv1", "agv2"]
        assert sorted(run.world.bodies) == ["agv1", "agv2"]
        assert [v.serial for v in fleet.vehicles] == ["agv1", "agv2"]
        assert {v.body.robot_name for v in fleet.vehicles} == {"agv1", "agv2"}
        # agv1's lidar sees agv2's hull 1 m ahead (the wall behind it is twice as far),
        # and agv2's sees agv1
        radius = run.by_name["agv2"].robot.footprint_radius
        for serial in STARTS:
            deadline = time.monotonic() + 10
            scan = None
            while scan is None and time.monotonic() < deadline:
                sensing = run.by_name[serial].sensing
                scan = None if sensing is None else sensing.scan
                time.sleep(0.05)
            assert scan is not None, f"{serial} scanned"
            assert ahead(scan) == pytest.approx(1.0 - radius, abs=0.08), serial
        # orders to both, at once: each robot reaches its own nodes
        goals = {"agv1": (-0.55, -0.55), "agv2": (1.5, -1.6)}
        t0 = time.monotonic()
        for serial, (gx, gy) in goals.items():
            x, y, _ = STARTS[serial]
            a, b = node("s", 0, x, y, MAP), node("g", 2, gx, gy, MAP, allowedDeviationXY=0.1)
            master.send(
                serial, "order", orderId=f"o-{serial}", orderUpdateId=0, nodes=[a, b],
                edges=[edge(a, b)],
            )  # fmt: skip
        for serial, (gx, gy) in goals.items():
            done = master.wait(
                serial,
                "state",
                lambda s, serial=serial: (
                    s["orderId"] == f"o-{serial}"
                    and s["lastNodeId"] == "g"
                    and not s["nodeStates"]
                    and not s["driving"]
                ),
                90,
                t0,
            )
            pos = done["agvPosition"]
            assert math.hypot(pos["x"] - gx, pos["y"] - gy) < 0.15, (serial, pos)
            assert not [e for e in done["errors"] if e["errorLevel"] == "FATAL"], done["errors"]
        # the two moved in the same world: their bodies are where their states say
        for serial, (gx, gy) in goals.items():
            truth = run.by_name[serial].sim.true_pose()
            assert math.hypot(truth.x - gx, truth.y - gy) < 0.15, (serial, truth)
        assert fleet.failed() is None
    finally:
        fleet.stop()
        master.close()
    assert not master.invalid, master.invalid


def test_robots_touching_end_the_fleet_simulation(broker: Mosquitto, tmp_path: Path) -> None:
    """initPosition of agv2 onto agv1's spot (ground truth: the body is placed there): the
    world counts the robot-robot contact and, with no collision allowed, the simulation
    ends for every vehicle with a FATAL error saying which robots touched."""
    master = MiniMaster(broker.port)
    fleet = start_fleet(tmp_path, broker.port)
    try:
        for serial in STARTS:
            master.wait(serial, "state", lambda d: True, 30)
        t0 = time.monotonic()
        x, y, _ = STARTS["agv1"]
        init = action(
            "i1", "initPosition", "NONE", x=x + 0.1, y=y, theta=0.0, mapId=MAP, lastNodeId="here"
        )
        master.send("agv2", "instantActions", actions=[init])
        for serial in STARTS:
            fatal = master.wait(
                serial,
                "state",
                lambda s: any(e["errorLevel"] == "FATAL" for e in s["errors"]),
                30,
                t0,
            )
            why = [e["errorDescription"] for e in fatal["errors"] if e["errorLevel"] == "FATAL"]
            assert "agv1 and agv2 collided" in why[0] or "agv2 and agv1 collided" in why[0], why
        problem = fleet.failed()
        assert problem is not None and "collided" in problem
        log = fleet.world.run.fleet_log  # type: ignore[union-attr]
        assert log["robot_robot_collisions"] and log["robot_robot_min_distance"] < 0.01
    finally:
        fleet.stop()
        master.close()
    assert not master.invalid, master.invalid


def test_a_one_robot_mission_is_one_vehicle_agv1(tmp_path: Path) -> None:
    one = {k: v for k, v in FLEET.items() if k not in ("robots", "tasks")}
    one |= {"robot": "burger", "start": {"x": 0.55, "y": -0.55, "yaw": 0.0}}
    path = tmp_path / "one.yaml"
    path.write_text(yaml.safe_dump(one))
    mission = load_vehicles(path)
    assert [(v.serial, v.description.name) for v in mission.vehicles] == [("agv1", "burger")]
    assert mission.loaded.layout is Layout.ROBOT
    assert [r.name for r in mission.loaded.robots] == ["robot"]


def test_fleet_vehicles_keep_each_robots_stack_and_only_teleop(tmp_path: Path) -> None:
    path = tmp_path / "fleet.yaml"
    path.write_text(yaml.safe_dump(FLEET))
    mission = load_vehicles(path, ["robots.agv2.stack.local_planner.type=mpc"])
    world = VehicleWorld(mission.loaded, TIME_SCALE)  # not started: no simulation yet
    agv1, agv2 = world.loaded.robots
    assert (agv1.stack.local_planner.type, agv2.stack.local_planner.type) == (
        "pure_pursuit",
        "mpc",
    )
    assert agv1.tree.task_types() == agv2.tree.task_types() == ["teleop"]
    assert world.loaded.fleet_tasks == [] and world.loaded.mission.tasks is None
    assert sorted(world.bodies) == ["agv1", "agv2"]
