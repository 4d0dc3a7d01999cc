"""Our VDA 5050 master against minimal vehicles written from the standard (tests/
vda5050_peers.py), and against our own vehicle: orders checked against the 2.1.0 schemas."""

from __future__ import annotations

import csv
import json
import threading
import time
from pathlib import Path

import pytest
import yaml

from agv_mission.vda5050.master import Master, load_plan, new_run_dir, write_outputs
from agv_mission.vda5050.transport import BrokerUrl, EmbeddedBroker, free_port
from agv_mission.vda5050.vehicle_set import VehicleSet, load_vehicles
from cli_in_process import agv
from vda5050_peers import MiniMaster, MiniVehicle, Mosquitto

WAREHOUSE = {
    "name": "warehouse-shift",
    "world": "warehouse",
    "seed": 4,
    "stack": {"localization": {"type": "ground_truth"}},
    "robots": [
        {"name": "agv1", "robot": "waffle", "start": {"x": -3.0, "y": -22.0, "yaw": 1.57}},
        {"name": "agv2", "robot": "waffle", "start": {"x": 3.0, "y": -22.0, "yaw": 1.57}},
    ],
    "tasks": [
        {"type": "visit_rooms", "rooms": ["cross_aisle", "back_aisle"], "robot": "agv1"},
        {"type": "visit_rooms", "rooms": ["cross_aisle", "west_aisle"], "robot": "agv2"},
        {
            "type": "go_to",
            "pose": {"x": 2.0, "y": -20.0, "yaw": 0.0},
            "actions": [{"type": "pick", "load_id": "pallet3"}],
        },
        {"type": "patrol", "waypoints": [{"x": -12.0, "y": -20.0}, {"x": 12.0, "y": -20.0}]},
    ],
    "limits": {"time": 40.0},
}


@pytest.fixture
def mosquitto(tmp_path: Path):
    mq = Mosquitto(tmp_path)
    mq.start()
    yield mq
    mq.stop()


def write(path: Path, doc: dict) -> Path:
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


def held_intervals(vehicle: MiniVehicle, node_id: str) -> list[tuple[float, float]]:
    """When ``node_id`` was granted to the vehicle: from its release to reaching the next node."""
    out, start, reached = [], None, False
    for t, kind, nid in vehicle.log:
        if kind == "released" and nid == node_id and start is None:
            start = t
        elif kind == "reached" and nid == node_id and start is not None:
            reached = True
        elif kind == "reached" and reached and start is not None:
            out.append((start, t))
            start, reached = None, False
    if start is not None:
        out.append((start, float("inf")))
    return out


def test_warehouse_mission_on_minimal_vehicles_with_traffic(
    mosquitto: Mosquitto, tmp_path: Path
) -> None:
    plan = load_plan(write(tmp_path / "warehouse.yaml", WAREHOUSE))
    assert plan.robots == ["agv1", "agv2"] and plan.map_id == "warehouse"
    watcher = MiniMaster(mosquitto.port)  # sees (and checks) the vehicles' messages too
    vehicles = [
        MiniVehicle(mosquitto.port, "agv1", -3.0, -22.0, "warehouse", speed=15.0),
        MiniVehicle(mosquitto.port, "agv2", 3.0, -22.0, "warehouse", speed=15.0),
    ]
    run_dir = new_run_dir(plan, tmp_path / "runs")
    master = Master(plan, BrokerUrl("127.0.0.1", mosquitto.port), reassign_timeout=5.0, lookahead=1)
    try:
        result = master.run()
    finally:
        for v in vehicles:
            v.close()
        watcher.close()
    write_outputs(run_dir, master, result)
    assert result["status"] == "succeeded", (
        result["tasks"],
        result["fleet"]["events"],
    )
    for v in vehicles:
        assert not v.invalid, v.invalid
        assert v.orders, "every vehicle got orders"
    assert not watcher.invalid, watcher.invalid
    assert {d["robot"] for d in result["fleet"]["dispatch"]} == {"agv1", "agv2"}
    # node by node: orders were extended by updates stitched at the decision point
    updates = [o for v in vehicles for o in v.orders if o["orderUpdateId"] > 0]
    assert updates and all(o["nodes"][0]["released"] for o in updates)
    # traffic: the cross aisle node was never granted to both vehicles at once
    a, b = held_intervals(vehicles[0], "cross_aisle"), held_intervals(vehicles[1], "cross_aisle")
    assert a and b
    for s1, e1 in a:
        for s2, e2 in b:
            assert e1 <= s2 or e2 <= s1, (a, b)
    doc = json.loads((run_dir / "result.json").read_text())
    assert set(doc["robots"]) == {"agv1", "agv2"} and doc["status"] == "succeeded"
    rows = list(csv.DictReader((run_dir / "trajectory.csv").open()))
    assert {r["robot"] for r in rows} == {"agv1", "agv2"}
    edges = [e["edgeId"] for v in vehicles for o in v.orders for e in o["edges"]]
    assert "cross_aisle-back_aisle" in edges
    # the go_to task's pick went to its goal node as a HARD node action, and was done
    picks = [a for v in vehicles for o in v.orders for n in o["nodes"] for a in n["actions"]]
    assert picks and {(a["actionType"], a["blockingType"]) for a in picks} == {("pick", "HARD")}
    assert {"key": "loadId", "value": "pallet3"} in picks[0]["actionParameters"]
    [done] = doc["tasks"][2]["actions"]
    assert done["type"] == "pick" and done["node"] == "goal3" and done["status"] == "FINISHED"


def test_a_vehicle_that_drops_off_has_its_task_redispatched(tmp_path: Path) -> None:
    embedded = EmbeddedBroker(port=free_port())
    url = embedded.start()
    mission = {
        **WAREHOUSE,
        "tasks": [{"type": "go_to", "pose": {"x": -12.0, "y": 20.0, "yaw": 0.0}, "robot": "agv1"}],
    }
    plan = load_plan(write(tmp_path / "w.yaml", mission))
    v1 = MiniVehicle(url.port, "agv1", -3.0, -22.0, "warehouse", speed=2.0)
    v2 = MiniVehicle(url.port, "agv2", 3.0, -22.0, "warehouse", speed=20.0)
    master = Master(plan, url, reassign_timeout=1.0)
    killer = threading.Timer(1.5, v1.kill)
    killer.start()
    try:
        result = master.run()
    finally:
        killer.cancel()
        v2.close()
        embedded.stop()
    events = [e["event"] for e in result["fleet"]["events"]]
    assert "connection_connectionbroken" in events and "task_redispatched" in events
    assert result["status"] == "succeeded", (
        result["tasks"],
        result["fleet"]["events"],
    )
    assert result["tasks"][0]["robot"] == "agv2"
    assert result["robots"]["agv1"]["connection"] == "CONNECTIONBROKEN"


def test_a_vehicle_that_never_comes_online_fails_the_mission(tmp_path: Path) -> None:
    embedded = EmbeddedBroker(port=free_port())
    url = embedded.start()
    plan = load_plan(
        write(
            tmp_path / "one.yaml",
            {
                **{k: v for k, v in WAREHOUSE.items() if k != "robots"},
                "robot": "waffle",
                "tasks": WAREHOUSE["tasks"][2:3],
            },
        )
    )
    try:
        result = Master(plan, url, reassign_timeout=0.5).run()
    finally:
        embedded.stop()
    assert result["status"] == "failed"
    assert "no other vehicle online" in result["reason"]


def test_our_master_drives_our_vehicle_end_to_end(tmp_path: Path) -> None:
    embedded = EmbeddedBroker(port=free_port())
    url = embedded.start()
    mission = {
        "name": "e2e",
        "world": "turtlebot3_world",
        "robot": "burger",
        "start": {"x": -2.0, "y": -0.5, "yaw": 0.0},
        "stack": {
            "localization": {"type": "ground_truth"},
            "global_planner": {"type": "cost_grid"},
            "local_planner": {"type": "pure_pursuit"},
        },
        "tasks": [
            {
                "type": "patrol",
                "waypoints": [{"x": -1.4, "y": -0.5}, {"x": -0.55, "y": -0.55, "yaw": 0.0}],
                "actions": [
                    {"type": "pick", "at": "wp1", "duration": 1.0, "load_id": "crate7"},
                    {"type": "drop", "duration": 1.0},
                ],
            }
        ],
        "limits": {"time": 90.0},
    }
    path = write(tmp_path / "e2e.yaml", mission)
    watcher = MiniMaster(url.port)
    fleet = VehicleSet(load_vehicles(path), url, time_scale=5.0)
    fleet.start()
    try:
        plan = load_plan(path)
        run_dir = new_run_dir(plan, tmp_path / "runs")
        master = Master(plan, url)
        result = master.run()
        write_outputs(run_dir, master, result)
    finally:
        fleet.stop()
        watcher.close()
        embedded.stop()
    assert result["status"] == "succeeded", (
        result["tasks"],
        result["fleet"]["events"],
    )
    assert not watcher.invalid, watcher.invalid
    last = watcher.of("agv1", "state")[-1]
    assert last["agvPosition"]["x"] == pytest.approx(-0.55, abs=0.1)
    # the task's pick at wp1 and drop at the last node went as HARD node actions, done
    done = [(a["type"], a["node"], a["status"], a["result"]) for a in result["tasks"][0]["actions"]]
    assert done == [("pick", "wp1", "FINISHED", "crate7"), ("drop", "wp2", "FINISHED", "crate7")]
    assert [e["action"] for e in result["fleet"]["events"] if e["event"] == "action_finished"] == [
        "pick",
        "drop",
    ]
    carrying = [s for s in watcher.of("agv1", "state") if s["loads"]]
    assert carrying and carrying[0]["loads"][0]["loadId"] == "crate7" and not last["loads"]
    assert (run_dir / "trajectory.csv").stat().st_size > 100


def test_dispatch_cli_bad_input_exits_2(tmp_path: Path) -> None:
    """Each answer called in this process (in make test now: no start-ups to wait for);
    test_mission_matrix.py starts ``vda5050 vehicles`` and ``dispatch`` as programs."""
    bad = write(
        tmp_path / "bad.yaml", {"name": "x", "world": "warehouse", "tasks": [{"type": "go_to"}]}
    )
    r = agv("vda5050", "dispatch", str(bad), "--broker", "mqtt://127.0.0.1:1")
    assert r.returncode == 2 and "bad.yaml" in r.stderr and "pose" in r.stderr
    good = write(
        tmp_path / "good.yaml",
        {"name": "x", "world": "warehouse", "tasks": [{"type": "go_to", "pose": {"x": 0, "y": 0}}]},
    )
    r = agv("vda5050", "dispatch", str(good), "--broker", "http://nowhere")
    assert r.returncode == 2 and "mqtt://HOST:PORT" in r.stderr
    r = agv("vda5050", "vehicles", str(tmp_path / "missing.yaml"))
    assert r.returncode == 2 and "missing.yaml" in r.stderr
    wrong = write(
        tmp_path / "wrong_at.yaml",
        {
            "name": "x",
            "world": "warehouse",
            "tasks": [
                {
                    "type": "go_to",
                    "pose": {"x": 0, "y": 0},
                    "actions": [{"type": "pick", "at": "wp9"}],
                }
            ],
        },
    )
    r = agv("vda5050", "dispatch", str(wrong), "--broker", "mqtt://127.0.0.1:1")
    assert (
        r.returncode == 2 and "wrong_at.yaml:10" in r.stderr and "tasks.0.actions.0.at" in r.stderr
    )
    assert "goal" in r.stderr


@pytest.mark.slow  # 12 s of broker down time
def test_master_rides_out_a_broker_restart(mosquitto: Mosquitto, tmp_path: Path) -> None:
    mission = {
        **WAREHOUSE,
        "tasks": [
            {
                "type": "patrol",
                "waypoints": [{"x": -3.0, "y": 0.0}, {"x": -3.0, "y": -22.0}],
                "robot": "agv1",
            }
        ],
    }
    plan = load_plan(write(tmp_path / "r.yaml", mission))
    vehicles = [
        MiniVehicle(mosquitto.port, name, x, -22.0, "warehouse", speed=4.0)
        for name, x in (("agv1", -3.0), ("agv2", 3.0))
    ]
    master = Master(
        plan, BrokerUrl("127.0.0.1", mosquitto.port), reassign_timeout=30.0, lookahead=1
    )

    def restart() -> None:
        mosquitto.stop()
        time.sleep(0.5)
        mosquitto.start()

    bounce = threading.Timer(2.0, restart)
    bounce.start()
    try:
        result = master.run()
    finally:
        bounce.cancel()
        for v in vehicles:
            v.close()
    assert result["status"] == "succeeded", result["fleet"]["events"]
    assert master.link.connects >= 2
    assert not any(e["event"] == "task_redispatched" for e in result["fleet"]["events"])
    assert all(not v.invalid for v in vehicles)


def test_node_reservations_are_places_not_ids():
    """Every patrol names its nodes wp1, wp2, ...: the master reserves where they are."""
    from agv_mission.vda5050.master import NodeReservations, RouteNode, place

    traffic = NodeReservations()
    a = RouteNode("wp1", 1.0, 2.0, None)
    b = RouteNode("wp1", 5.0, 2.0, None)  # another patrol's wp1, elsewhere
    same = RouteNode("goal0", 1.02, 1.98, None)  # a third task's node on a's spot
    assert traffic.grant("agv1", a) and traffic.grant("agv2", b)
    assert not traffic.grant("agv2", same)  # held by agv1
    traffic.keep_only("agv1", set())  # agv1 has left it
    assert traffic.grant("agv2", same) and place(same) == place(a)
