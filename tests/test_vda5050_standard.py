"""VDA 5050 as the standard says, checked by peers written from the standard (tests/
vda5050_peers.py) over Debian's mosquitto:

* our master dispatching a mission to independent vehicles: every order valid against the
  2.1.0 schemas (angles within [-pi, pi] after rounding), every task kind whole (a patrol's
  loops, visit_rooms, dock / charge / undock, go_to reached), a fleet robot's own tasks;
* our vehicle driven by an independent master: an order update that does not join gets an
  ``errors`` entry at once, and the blocking types of 6.12 (HARD: nothing else runs;
  SOFT: driving stops, other actions run; NONE: it drives on).
"""

from __future__ import annotations

import json
import math
import time
from pathlib import Path

import pytest
import yaml

from agv_mission.missions.load.errors import MissionError
from agv_mission.vda5050.master import Master, load_plan
from agv_mission.vda5050.protocol import ANGLE_BOUND
from agv_mission.vda5050.transport import BrokerUrl
from test_vda5050_vehicle import MAP, SERIAL, errors_of, here, mission_file, start_vehicle
from vda5050_peers import MiniMaster, MiniVehicle, Mosquitto, action, edge, node

WAREHOUSE = {
    "name": "warehouse-standard",
    "world": "warehouse",
    "seed": 4,
    "stack": {"localization": {"type": "ground_truth"}},
    "robots": [
        {"name": "agv1", "robot": "waffle", "start": {"x": -3.0, "y": -22.0, "yaw": 1.57}},
    ],
    "tasks": [
        {"type": "go_to", "pose": {"x": 2.0, "y": -20.0, "yaw": 3.1416}},  # yaw as written
        {
            "type": "patrol",
            "waypoints": [{"x": -6.0, "y": -20.0, "yaw": -3.1416}, {"x": 6.0, "y": -20.0}],
            "loops": 2,
        },
        {"type": "visit_rooms", "rooms": ["cross_aisle", "west_aisle"]},
        {"type": "dock", "dock": "charger"},
        {"type": "charge", "until": 0.8},
        {"type": "undock"},
    ],
    "limits": {"time": 60.0},
}


@pytest.fixture(scope="module")
def broker(tmp_path_factory: pytest.TempPathFactory):
    mq = Mosquitto(tmp_path_factory.mktemp("mosquitto"))
    mq.start()
    yield mq
    mq.stop()


def write(path: Path, doc: dict) -> Path:
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


def dispatch(broker: Mosquitto, plan_path: Path, *vehicles: MiniVehicle) -> dict:
    plan = load_plan(plan_path)
    watcher = MiniMaster(broker.port)  # checks the orders the master sends, too
    try:
        result = Master(plan, BrokerUrl("127.0.0.1", broker.port), lookahead=1).run()
    finally:
        for v in vehicles:
            v.close()
        watcher.close()
    assert not watcher.invalid, watcher.invalid
    return result


# ------------------------------------------------------------ our master, their vehicles


@pytest.fixture(scope="module")
def warehouse_run(broker: Mosquitto, tmp_path_factory: pytest.TempPathFactory):
    folder = tmp_path_factory.mktemp("master")
    vehicle = MiniVehicle(broker.port, "agv1", -3.0, -22.0, "warehouse", speed=15.0)
    result = dispatch(broker, write(folder / "warehouse.yaml", WAREHOUSE), vehicle)
    return result, vehicle


def test_master_orders_are_valid_with_angles_within_bounds(warehouse_run) -> None:
    result, vehicle = warehouse_run
    assert not vehicle.invalid, vehicle.invalid  # the vehicle rejected nothing
    thetas = [
        n["nodePosition"]["theta"]
        for o in vehicle.orders
        for n in o["nodes"]
        if "theta" in n["nodePosition"]
    ]
    assert thetas and all(-ANGLE_BOUND <= t <= ANGLE_BOUND for t in thetas)
    assert any(abs(abs(t) - math.pi) < 1e-3 for t in thetas)  # the 3.1416 went out wrapped
    devs = [
        n["nodePosition"].get("allowedDeviationTheta", 0.0)
        for o in vehicle.orders
        for n in o["nodes"]
    ]
    assert all(0.0 <= d <= math.pi for d in devs)
    assert result["status"] == "succeeded", (result["reason"], result["fleet"]["events"])
    assert [t["status"] for t in result["tasks"]] == ["succeeded"] * 6


def test_master_go_to_is_reached(warehouse_run) -> None:
    _result, vehicle = warehouse_run
    goal = [v for v in vehicle.visits if v[0] == "goal1"]
    assert goal and math.hypot(goal[0][2] - 2.0, goal[0][3] + 20.0) < 1e-6


def test_master_patrol_is_driven_loop_after_loop(warehouse_run) -> None:
    _result, vehicle = warehouse_run
    patrol = [
        (v[0], round(v[2], 3), round(v[3], 3)) for v in vehicle.visits if v[0] in ("wp1", "wp2")
    ]
    assert patrol == [("wp1", -6.0, -20.0), ("wp2", 6.0, -20.0)] * 2
    seqs = [v[1] for v in vehicle.visits if v[0] in ("wp1", "wp2")]
    assert seqs == sorted(seqs) and len(set(seqs)) == 4  # one sequenceId per visit


def test_master_visit_rooms_and_dock_charge_undock(warehouse_run) -> None:
    result, vehicle = warehouse_run
    visited = [v[0] for v in vehicle.visits]
    assert visited.index("cross_aisle") < visited.index("west_aisle")
    assert visited[-3:] == ["charger_staging", "charger", "charger_staging"]
    kinds = {
        a["actionId"]: a["actionType"]
        for o in vehicle.orders
        for n in o["nodes"]
        for a in n["actions"]
    }
    assert sorted(kinds.values()) == ["startCharging", "startCharging", "stopCharging"]
    assert vehicle.battery >= 80.0 and not vehicle.charging  # charged to 0.8, then undocked
    charge = result["tasks"][4]
    assert charge["type"] == "charge" and charge["status"] == "succeeded"


def test_master_sends_a_fleet_robots_own_tasks_to_it_first(
    broker: Mosquitto, tmp_path: Path
) -> None:
    doc = {
        **WAREHOUSE,
        "robots": [
            {
                "name": "agv1",
                "robot": "waffle",
                "start": {"x": -3.0, "y": -22.0, "yaw": 1.57},
                "tasks": [{"type": "go_to", "pose": {"x": -3.0, "y": -20.5, "yaw": 0.0}}],
            },
            {"name": "agv2", "robot": "waffle", "start": {"x": 3.0, "y": -22.0, "yaw": 1.57}},
        ],
        "tasks": [{"type": "go_to", "pose": {"x": 3.0, "y": -20.5}, "robot": "agv2"}],
    }
    v1 = MiniVehicle(broker.port, "agv1", -3.0, -22.0, "warehouse", speed=15.0)
    v2 = MiniVehicle(broker.port, "agv2", 3.0, -22.0, "warehouse", speed=15.0)
    result = dispatch(broker, write(tmp_path / "own.yaml", doc), v1, v2)
    assert result["status"] == "succeeded", result["reason"]
    assert [(t["robot"], t["status"]) for t in result["tasks"]] == [
        ("agv1", "succeeded"),
        ("agv2", "succeeded"),
    ]
    assert (v1.x, v1.y) == (-3.0, -20.5) and (v2.x, v2.y) == (3.0, -20.5)


def test_master_refuses_what_an_order_cannot_carry(tmp_path: Path) -> None:
    tree = {k: v for k, v in WAREHOUSE.items() if k not in ("tasks", "robots")}
    tree |= {"robot": "waffle", "start": {"x": -3.0, "y": -22.0, "yaw": 0.0}}
    with pytest.raises(MissionError, match="tree") as exc:
        load_plan(write(tmp_path / "t.yaml", {**tree, "tree": {"type": "wait", "seconds": 1}}))
    assert exc.value.problems[0].field == "tree"
    with pytest.raises(MissionError, match="wander: not a task") as exc:
        load_plan(
            write(tmp_path / "w.yaml", {**tree, "tasks": [{"type": "wander", "duration": 5.0}]})
        )
    assert exc.value.problems[0].field == "tasks.0.type"
    fleet = {**WAREHOUSE, "robots": [dict(WAREHOUSE["robots"][0])]}
    fleet["robots"][0]["tasks"] = [{"type": "go_to", "pose": {"x": -3.0, "y": -18.0}}]
    with pytest.raises(MissionError, match="obstacle") as exc:  # a robot's own task, as written
        load_plan(write(tmp_path / "f.yaml", fleet))
    problem = exc.value.problems[0]
    assert problem.field == "robots.0.tasks.0.pose" and problem.line is not None
    text = (tmp_path / "f.yaml").read_text().splitlines()
    assert "-18.0" in "\n".join(text[problem.line - 1 : problem.line + 3])


# ------------------------------------------------------------- their master, our vehicle


@pytest.fixture(scope="module")
def rig(broker: Mosquitto, tmp_path_factory: pytest.TempPathFactory):
    folder = tmp_path_factory.mktemp("vehicle")
    master = MiniMaster(broker.port)
    vehicle, world = start_vehicle(
        mission_file(folder), BrokerUrl("127.0.0.1", broker.port), folder / "logs"
    )
    master.wait(SERIAL, "state", lambda d: True)
    yield master, vehicle
    vehicle.stop()
    world.stop()
    master.close()
    assert not master.invalid, master.invalid


def statuses(states: list[dict], *ids: str) -> list[tuple[str, ...]]:
    """Each state's action statuses of ``ids``, in order (absent: "-")."""
    out = []
    for s in states:
        by = {a["actionId"]: a["actionStatus"] for a in s["actionStates"]}
        out.append(tuple(by.get(i, "-") for i in ids))
    return out


def test_vehicle_reports_an_update_whose_nodes_do_not_join(rig) -> None:
    master, _vehicle = rig
    x, y = here(master)
    a, b = node("j0", 0, x, y, MAP), node("j1", 2, x + 0.3, y, MAP)
    c = node("j2", 4, x + 0.6, y, MAP, released=False)
    master.send(
        SERIAL, "order", orderId="o-join", orderUpdateId=0, nodes=[a, b, c],
        edges=[edge(a, b), edge(b, c)],
    )  # fmt: skip
    master.wait(SERIAL, "state", lambda s: s["orderId"] == "o-join" and s["lastNodeId"] == "j1", 30)
    t0 = time.monotonic()
    master.send(
        SERIAL, "order", orderId="o-join", orderUpdateId=1,
        nodes=[b, {**c, "released": True}], edges=[],
    )  # fmt: skip
    s = master.wait(SERIAL, "state", lambda s: s["errors"], 5, t0)
    (err,) = [e for e in s["errors"] if e["errorType"] in ("orderError", "validationError")]
    refs = {r["referenceKey"]: r["referenceValue"] for r in err["errorReferences"]}
    assert refs["orderId"] == "o-join" and refs["orderUpdateId"] == "1"
    assert s["orderUpdateId"] == 0 and s["lastNodeId"] == "j1"  # the running order untouched
    c2 = {**c, "released": True}
    master.send(
        SERIAL, "order", orderId="o-join", orderUpdateId=2, nodes=[b, c2], edges=[edge(b, c2)]
    )  # the same update, joined: taken, and the warning goes
    done = master.wait(SERIAL, "state", lambda s: s["lastNodeId"] == "j2", 30, t0)
    assert done["orderUpdateId"] == 2 and not done["errors"]


def _order_with(master: MiniMaster, order_id: str, actions: list[dict]) -> float:
    """An order: here -> a node 0.3 m on holding ``actions`` -> a released node beyond."""
    x, y = here(master)
    a = node("s0", 0, x, y, MAP)
    b = node("s1", 2, x + 0.3, y, MAP, actions=actions)
    c = node("s2", 4, x + 0.7, y, MAP)
    t0 = time.monotonic()
    master.send(
        SERIAL, "order", orderId=order_id, orderUpdateId=0, nodes=[a, b, c],
        edges=[edge(a, b), edge(b, c)],
    )  # fmt: skip
    return t0


def test_vehicle_hard_action_runs_alone_and_stops_driving(rig) -> None:
    master, _vehicle = rig
    t0 = _order_with(
        master,
        "o-hard",
        [
            action("p-none", "pick", "NONE", duration=3.0, loadId="h1"),
            action("d-hard", "drop", "HARD", duration=2.0, loadId="h1"),
        ],
    )
    master.wait(
        SERIAL, "state", lambda s: s["lastNodeId"] == "s2" and s["orderId"] == "o-hard", 90, t0
    )
    states = [s for s in master.of(SERIAL, "state", t0) if s["orderId"] == "o-hard"]
    seen = statuses(states, "p-none", "d-hard")
    assert ("RUNNING", "WAITING") in seen and ("FINISHED", "RUNNING") in seen
    assert not any(p == "RUNNING" and d in ("RUNNING", "FINISHED") for p, d in seen)
    # the pick (NONE) would let it drive on: the HARD drop after it holds it at s1
    for s, (_p, d) in zip(states, seen, strict=True):
        if s["lastNodeId"] == "s1" and d != "FINISHED":
            assert not s["driving"], seen


def test_vehicle_soft_actions_run_together_without_driving(rig) -> None:
    master, _vehicle = rig
    t0 = _order_with(
        master,
        "o-soft",
        [
            action("p-soft", "pick", "SOFT", duration=3.0, loadId="s1"),
            action("p-soft2", "pick", "SOFT", duration=3.0, loadId="s2"),
        ],
    )
    master.wait(
        SERIAL, "state", lambda s: s["lastNodeId"] == "s2" and s["orderId"] == "o-soft", 90, t0
    )
    states = [s for s in master.of(SERIAL, "state", t0) if s["orderId"] == "o-soft"]
    seen = statuses(states, "p-soft", "p-soft2")
    assert ("RUNNING", "RUNNING") in seen  # in parallel
    for s, (p, q) in zip(states, seen, strict=True):
        if "RUNNING" in (p, q):
            assert s["lastNodeId"] == "s1" and not s["driving"]
    last = master.of(SERIAL, "state")[-1]
    assert {ld["loadId"] for ld in last["loads"]} >= {"s1", "s2"}
    # leave the deck empty for the next test
    x, y = here(master)
    a = node(
        "s2",
        0,
        x,
        y,
        MAP,
        actions=[
            action("d1", "drop", "NONE", loadId="s1"),
            action("d2", "drop", "NONE", loadId="s2"),
        ],
    )
    t1 = time.monotonic()
    master.send(SERIAL, "order", orderId="o-unload", orderUpdateId=0, nodes=[a], edges=[])
    master.wait(SERIAL, "state", lambda s: s["orderId"] == "o-unload" and not s["loads"], 30, t1)


def test_vehicle_drives_on_while_a_none_action_runs(rig) -> None:
    master, _vehicle = rig
    t0 = _order_with(master, "o-none", [action("p-free", "pick", "NONE", duration=20.0)])
    moving = master.wait(
        SERIAL,
        "state",
        lambda s: (
            s["orderId"] == "o-none" and s["driving"] and statuses([s], "p-free") == [("RUNNING",)]
        ),
        60,
        t0,
    )
    assert moving["lastNodeId"] == "s1"
    master.wait(
        SERIAL, "state", lambda s: s["lastNodeId"] == "s2" and s["orderId"] == "o-none", 60, t0
    )
    master.wait(SERIAL, "state", lambda s: statuses([s], "p-free") == [("FINISHED",)], 60, t0)


def test_vehicle_theta_is_within_bounds_and_angle_bounds_are_kept(rig) -> None:
    master, _vehicle = rig
    x, y = here(master)
    t0 = time.monotonic()
    master.send(
        SERIAL,
        "instantActions",
        actions=[action("ip1", "initPosition", "NONE", x=x, y=y, theta=3.14159, mapId=MAP)],
    )
    master.wait(
        SERIAL, "state",
        lambda s: {a["actionId"]: a["actionStatus"] for a in s["actionStates"]}.get("ip1") == "FINISHED",
        10, t0,
    )  # fmt: skip
    time.sleep(0.5)
    for kind in ("state", "visualization"):
        thetas = [d["agvPosition"]["theta"] for d in master.of(SERIAL, kind, t0)]
        assert thetas and all(-math.pi <= t <= math.pi for t in thetas), kind
    bad = node("far", 0, x, y, MAP, theta=3.1416)  # above the schema's bound
    t1 = time.monotonic()
    master.raw(
        SERIAL,
        "order",
        json.dumps(
            {
                "headerId": 900, "timestamp": "2026-01-01T00:00:00.00Z", "version": "2.1.0",
                "manufacturer": "agv-mission", "serialNumber": SERIAL, "orderId": "o-theta",
                "orderUpdateId": 0, "nodes": [bad], "edges": [],
            }
        ),
    )  # fmt: skip
    s = master.wait(SERIAL, "state", lambda s: errors_of(s, "validationError"), 5, t1)
    assert any("theta" in e["errorDescription"] for e in errors_of(s, "validationError"))
    assert s["orderId"] != "o-theta"


def test_init_position_off_the_map_fails_and_the_vehicle_stays_put(rig) -> None:
    """initPosition at x = 1e300 (finite, on no map): FAILED with an initPositionError, and
    the vehicle still reports where it stands, not a belief 1e300 m away."""
    master, _vehicle = rig
    x, y = here(master)
    t0 = time.monotonic()
    far = action("ip-far", "initPosition", "NONE", x=1e300, y=y, theta=0.0, mapId=MAP)
    master.send(SERIAL, "instantActions", actions=[far])
    s = master.wait(SERIAL, "state", lambda s: statuses([s], "ip-far") == [("FAILED",)], 10, t0)
    assert any("1e+300" in e["errorDescription"] for e in errors_of(s, "initPositionError"))
    assert math.hypot(s["agvPosition"]["x"] - x, s["agvPosition"]["y"] - y) < 0.5


# ------------------------------------------------------------- our master, our vehicle


@pytest.mark.slow  # about 40 s: the vehicle drives at 8x real time
def test_our_master_docks_charges_and_undocks_our_vehicle(tmp_path: Path) -> None:
    """The whole dock / charge / undock of a mission, with a goal written ``yaw: 3.1416``,
    through our master to our simulated vehicle: the charge rises to ``until``, and the
    vehicle leaves the dock uncharged."""
    from agv_mission.vda5050.transport import EmbeddedBroker, free_port
    from agv_mission.vda5050.vehicle_set import VehicleSet, load_vehicles

    mission = {
        "name": "dock-e2e",
        "world": "turtlebot3_world",
        "robot": "burger",
        "start": {"x": -2.0, "y": -0.5, "yaw": 0.0},
        "simulation": {"battery_level": 0.6},
        "stack": {
            "localization": {"type": "ground_truth"},
            "global_planner": {"type": "cost_grid"},
            "local_planner": {"type": "pure_pursuit"},
        },
        "tasks": [
            {"type": "go_to", "pose": {"x": -1.5, "y": -0.5, "yaw": 3.1416}},
            {"type": "dock", "dock": "charger"},
            {"type": "charge", "until": 0.62},
            {"type": "undock"},
        ],
        "limits": {"time": 120.0},
    }
    path = write(tmp_path / "dock.yaml", mission)
    embedded = EmbeddedBroker(port=free_port())
    url = embedded.start()
    watcher = MiniMaster(url.port)
    fleet = VehicleSet(load_vehicles(path), url, time_scale=8.0)
    fleet.start()
    try:
        result = Master(load_plan(path), url).run()
    finally:
        fleet.stop()
        watcher.close()
        embedded.stop()
    assert result["status"] == "succeeded", (result["tasks"], result["fleet"]["events"])
    assert not watcher.invalid, watcher.invalid
    states = watcher.of("agv1", "state")
    charging = [s for s in states if s["batteryState"]["charging"]]
    assert charging and max(s["batteryState"]["batteryCharge"] for s in charging) >= 62.0
    assert states[-1]["batteryState"]["charging"] is False  # undocked
    assert [a["type"] for t in result["tasks"] for a in t["actions"]] == [
        "startCharging",
        "startCharging",
        "stopCharging",
    ]
