"""Our VDA 5050 vehicle against a minimal master written from the standard (tests/
vda5050_peers.py), over Debian's mosquitto: every message the master receives validates
against the 2.1.0 schemas the package ships."""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from agv_mission.vda5050.body import VehicleWorld
from agv_mission.vda5050.transport import BrokerUrl, EmbeddedBroker, free_port
from agv_mission.vda5050.vehicle import Vehicle
from agv_mission.vda5050.vehicle_set import load_vehicles
from vda5050_peers import MiniMaster, Mosquitto, action, edge, node

MAP = "turtlebot3_world"
SERIAL = "agv1"
MISSION = {
    "name": "vda-vehicle",
    "world": MAP,
    "robot": "burger",
    "start": {"x": -2.0, "y": -0.5, "yaw": 0.0},
    "seed": 1,
    "simulation": {"battery_level": 0.6},
    "stack": {
        "localization": {"type": "ground_truth"},
        "global_planner": {"type": "cost_grid"},
        "local_planner": {"type": "pure_pursuit"},
    },
}
TIME_SCALE = 5.0


def mission_file(folder: Path, **changes: object) -> Path:
    path = folder / "vehicle.yaml"
    path.write_text(yaml.safe_dump({**MISSION, **changes}))
    return path


def start_vehicle(
    path: Path, url: BrokerUrl, log_dir: Path, serial: str = SERIAL
) -> tuple[Vehicle, VehicleWorld]:
    mission = load_vehicles(path)
    spec = mission.vehicles[0]
    world = VehicleWorld(mission.loaded, TIME_SCALE)
    body = world.bodies[spec.robot]
    vehicle = Vehicle(body, spec.description, url, serial, log_dir=log_dir)
    body.on_change = vehicle.wake
    world.start()
    assert world.ready.wait(60)
    vehicle.start()
    return vehicle, world


@pytest.fixture(scope="module")
def broker(tmp_path_factory: pytest.TempPathFactory):
    mq = Mosquitto(tmp_path_factory.mktemp("mosquitto"))
    mq.start()
    yield mq
    mq.stop()


@pytest.fixture(scope="module")
def rig(broker: Mosquitto, tmp_path_factory: pytest.TempPathFactory):
    folder = tmp_path_factory.mktemp("vehicle")
    master = MiniMaster(broker.port)
    vehicle, world = start_vehicle(
        mission_file(folder), BrokerUrl("127.0.0.1", broker.port), folder / "logs"
    )
    master.wait(SERIAL, "state", lambda d: True)
    yield master, vehicle, world
    vehicle.stop()
    world.stop()
    master.close()
    assert not master.invalid, master.invalid


def here(master: MiniMaster) -> tuple[float, float]:
    s = master.of(SERIAL, "state")[-1]
    return s["agvPosition"]["x"], s["agvPosition"]["y"]


def errors_of(state: dict, kind: str) -> list[dict]:
    return [e for e in state["errors"] if e["errorType"] == kind]


def ref(error: dict, key: str) -> str | None:
    return {r["referenceKey"]: r["referenceValue"] for r in error.get("errorReferences", [])}.get(
        key
    )


def test_connection_factsheet_and_headers(rig) -> None:
    master, vehicle, _world = rig
    late = MiniMaster(master.client._port)  # subscribes after the vehicle published: retained
    try:
        conn = late.wait(SERIAL, "connection", lambda d: True, 10)
        assert conn["connectionState"] == "ONLINE"
        fact = late.wait(SERIAL, "factsheet", lambda d: True, 10)
        facts = [(m[3], m[2]["headerId"]) for m in late.messages if m[1].endswith("/factsheet")]
        assert any(r for r, _ in facts), (facts, vehicle.link.connects)  # retained
    finally:
        late.close()
    assert fact["physicalParameters"]["speedMax"] == pytest.approx(0.22)  # burger
    assert fact["typeSpecification"]["agvKinematic"] == "DIFF"
    actions = {a["actionType"] for a in fact["protocolFeatures"]["agvActions"]}
    assert {"pick", "drop", "cancelOrder", "initPosition", "waitForTrigger"} <= actions
    master.wait(SERIAL, "visualization", lambda d: True, 5)
    for kind in ("state", "visualization"):
        ids = [d["headerId"] for d in master.of(SERIAL, kind)]
        assert ids == list(range(ids[0], ids[0] + len(ids))), f"{kind} headerIds count up by one"
        assert all(
            d["version"] == "2.1.0" and d["timestamp"].endswith("Z")
            for d in master.of(SERIAL, kind)
        )
    state = master.of(SERIAL, "state")[-1]
    assert state["operatingMode"] == "AUTOMATIC" and state["agvPosition"]["mapId"] == MAP


def test_order_horizon_stitching_pick_and_drop(rig) -> None:
    master, _vehicle, _world = rig
    x, y = here(master)
    a = node("a", 0, x, y, MAP)
    b = node("b", 2, -1.5, -0.5, MAP, allowedDeviationXY=0.1)
    c = node("c", 4, -0.55, -0.55, MAP, released=False)
    t0 = time.monotonic()
    master.send(
        SERIAL,
        "order",
        orderId="o-horizon",
        orderUpdateId=0,
        nodes=[a, b, c],
        edges=[edge(a, b), edge(b, c)],
    )
    at_b = master.wait(
        SERIAL, "state", lambda s: s["lastNodeId"] == "b" and not s["driving"], 60, t0
    )
    assert [(n["nodeId"], n["released"]) for n in at_b["nodeStates"]] == [("c", False)]
    assert [(e["edgeId"], e["released"]) for e in at_b["edgeStates"]] == [("b-c", False)]
    assert at_b["newBaseRequest"] is True
    time.sleep(1.0)  # the decision point: the vehicle waits there for the base to grow
    still = master.of(SERIAL, "state")[-1]
    assert (
        still["lastNodeId"] == "b"
        and math.hypot(still["agvPosition"]["x"] + 1.5, still["agvPosition"]["y"] + 0.5) < 0.15
    )
    c_released = {
        **c,
        "released": True,
        "actions": [action("pick1", "pick", duration=0.5, loadId="box7")],
    }
    b_again = {**b, "actions": []}
    t1 = time.monotonic()
    master.send(
        SERIAL,
        "order",
        orderId="o-horizon",
        orderUpdateId=1,
        nodes=[b_again, c_released],
        edges=[edge(b_again, c_released)],
    )
    done = master.wait(
        SERIAL,
        "state",
        lambda s: (
            s["lastNodeId"] == "c"
            and any(
                a["actionId"] == "pick1" and a["actionStatus"] == "FINISHED"
                for a in s["actionStates"]
            )
        ),
        60,
        t1,
    )
    assert (
        done["orderUpdateId"] == 1 and done["nodeStates"] == [] and done["lastNodeSequenceId"] == 4
    )
    assert [ld["loadId"] for ld in done["loads"]] == ["box7"]
    # an update older than the running one: rejected, the order untouched (6.6.4.3)
    t2 = time.monotonic()
    master.send(
        SERIAL,
        "order",
        orderId="o-horizon",
        orderUpdateId=0,
        nodes=[b_again, c_released],
        edges=[edge(b_again, c_released)],
    )
    old = master.wait(SERIAL, "state", lambda s: errors_of(s, "orderUpdateError"), 10, t2)
    assert old["orderUpdateId"] == 1 and old["lastNodeId"] == "c"
    assert ref(errors_of(old, "orderUpdateError")[0], "orderId") == "o-horizon"
    # a new order starting where the vehicle stands: accepted, the warning gone; drop
    x, y = here(master)
    s0 = node("c", 0, x, y, MAP)
    s1 = node("b", 2, -1.5, -0.5, MAP, actions=[action("drop1", "drop", duration=0.3)])
    t3 = time.monotonic()
    master.send(
        SERIAL, "order", orderId="o-drop", orderUpdateId=0, nodes=[s0, s1], edges=[edge(s0, s1)]
    )
    dropped = master.wait(
        SERIAL,
        "state",
        lambda s: any(
            a["actionId"] == "drop1" and a["actionStatus"] == "FINISHED" for a in s["actionStates"]
        ),
        60,
        t3,
    )
    assert dropped["loads"] == [] and dropped["orderId"] == "o-drop"
    assert not errors_of(dropped, "orderUpdateError")


def test_rejections_leave_the_vehicle_running(rig) -> None:
    master, _vehicle, _world = rig
    x, y = here(master)
    t0 = time.monotonic()
    master.raw(SERIAL, "order", b"{not json")
    master.wait(
        SERIAL,
        "state",
        lambda s: any(
            "not JSON" in e.get("errorDescription", "") for e in errors_of(s, "validationError")
        ),
        10,
        t0,
    )
    wrong = {
        "headerId": 1,
        "timestamp": "2026-01-01T00:00:00.00Z",
        "version": "1.1.0",
        "manufacturer": "agv-mission",
        "serialNumber": SERIAL,
        "orderId": "v1",
        "orderUpdateId": 0,
        "nodes": [],
        "edges": [],
    }
    master.raw(SERIAL, "order", json.dumps(wrong))
    master.wait(
        SERIAL,
        "state",
        lambda s: any(
            "1.1.0" in e.get("errorDescription", "") for e in errors_of(s, "validationError")
        ),
        10,
        t0,
    )
    other = {
        **wrong,
        "version": "2.1.0",
        "serialNumber": "agv99",
        "nodes": [node("a", 0, x, y, MAP)],
    }
    master.raw(SERIAL, "order", json.dumps(other))
    master.wait(
        SERIAL,
        "state",
        lambda s: any(ref(e, "serialNumber") == "agv99" for e in errors_of(s, "validationError")),
        10,
        t0,
    )
    master.raw(SERIAL, "order", b'{"pad": "' + b"x" * (1 << 20) + b'"}')
    master.wait(
        SERIAL,
        "state",
        lambda s: any(
            "msgLen" in e.get("errorDescription", "") for e in errors_of(s, "validationError")
        ),
        10,
        t0,
    )
    master.raw(SERIAL, "instantActions", b"[1, 2")
    master.wait(
        SERIAL,
        "state",
        lambda s: any(ref(e, "topic") == "instantActions" for e in errors_of(s, "validationError")),
        10,
        t0,
    )
    missing = {
        **other,
        "serialNumber": SERIAL,
        "nodes": [{"nodeId": "a", "sequenceId": 0, "released": True}],
    }
    master.raw(SERIAL, "order", json.dumps(missing))  # no actions list: a schema error
    master.wait(
        SERIAL,
        "state",
        lambda s: any(ref(e, "orderId") == "v1" for e in errors_of(s, "validationError")),
        10,
        t0,
    )
    a, b = (
        node("a", 0, x, y, MAP),
        node("b", 2, -1.0, -0.5, MAP, actions=[action("x1", "jumpAround")]),
    )
    master.send(
        SERIAL, "order", orderId="o-unknown", orderUpdateId=0, nodes=[a, b], edges=[edge(a, b)]
    )
    bad = master.wait(SERIAL, "state", lambda s: errors_of(s, "orderError"), 10, t0)
    assert ref(errors_of(bad, "orderError")[0], "actionId") == "x1"
    assert bad["orderId"] != "o-unknown" and bad["nodeStates"] == []
    far = node("far", 0, x + 3.0, y, MAP)
    master.send(SERIAL, "order", orderId="o-far", orderUpdateId=0, nodes=[far], edges=[])
    master.wait(
        SERIAL,
        "state",
        lambda s: any(ref(e, "nodeId") == "far" for e in errors_of(s, "noRouteError")),
        10,
        t0,
    )
    t1 = time.monotonic()
    master.send(SERIAL, "instantActions", actions=[action("sr1", "stateRequest", "NONE")])
    alive = master.wait(
        SERIAL,
        "state",
        lambda s: any(
            a["actionId"] == "sr1" and a["actionStatus"] == "FINISHED" for a in s["actionStates"]
        ),
        10,
        t1,
    )
    assert alive["orderId"] != "o-far"


def test_instant_actions(rig, tmp_path: Path) -> None:
    master, _vehicle, _world = rig
    x, y = here(master)
    a = node("p0", 0, x, y, MAP)
    b = node("p1", 2, -0.55, -0.55, MAP)
    t0 = time.monotonic()
    master.send(
        SERIAL, "order", orderId="o-pause", orderUpdateId=0, nodes=[a, b], edges=[edge(a, b)]
    )
    master.wait(SERIAL, "state", lambda s: s["orderId"] == "o-pause" and s["driving"], 30, t0)
    master.send(SERIAL, "instantActions", actions=[action("pause1", "startPause")])
    paused = master.wait(SERIAL, "state", lambda s: s["paused"] and not s["driving"], 10, t0)
    assert [n["nodeId"] for n in paused["nodeStates"]] == ["p1"]
    master.send(SERIAL, "instantActions", actions=[action("resume1", "stopPause")])
    master.wait(SERIAL, "state", lambda s: not s["paused"] and s["driving"], 10, t0)
    master.send(SERIAL, "instantActions", actions=[action("cancel1", "cancelOrder")])
    cancelled = master.wait(
        SERIAL,
        "state",
        lambda s: any(
            a["actionId"] == "cancel1" and a["actionStatus"] == "FINISHED"
            for a in s["actionStates"]
        ),
        20,
        t0,
    )
    assert (
        cancelled["nodeStates"] == []
        and not cancelled["driving"]
        and cancelled["orderId"] == "o-pause"
    )
    # an update of the cancelled order: rejected, a new order is needed (6.6.3.1)
    t_upd = time.monotonic()
    master.send(SERIAL, "order", orderId="o-pause", orderUpdateId=1, nodes=[b], edges=[])
    upd = master.wait(SERIAL, "state", lambda s: errors_of(s, "orderUpdateError"), 10, t_upd)
    assert upd["nodeStates"] == []
    assert ref(errors_of(upd, "orderUpdateError")[-1], "orderId") == "o-pause"
    master.send(SERIAL, "instantActions", actions=[action("cancel2", "cancelOrder")])
    none = master.wait(SERIAL, "state", lambda s: errors_of(s, "noOrderToCancel"), 10, t0)
    assert ref(errors_of(none, "noOrderToCancel")[0], "actionId") == "cancel2"
    assert {a["actionId"]: a["actionStatus"] for a in none["actionStates"]}["cancel2"] == "FAILED"
    t1 = time.monotonic()
    master.send(
        SERIAL,
        "instantActions",
        actions=[
            action(
                "init1", "initPosition", x=-1.9, y=-0.45, theta=0.3, mapId=MAP, lastNodeId="home"
            ),
            action("charge1", "startCharging"),
            action("log1", "logReport", reason="test"),
            action("fs1", "factsheetRequest", "NONE"),
        ],
    )
    s = master.wait(
        SERIAL,
        "state",
        lambda s: (
            s["lastNodeId"] == "home" and s["agvPosition"]["theta"] == pytest.approx(0.3, abs=0.05)
        ),
        10,
        t1,
    )
    status = {a["actionId"]: a for a in s["actionStates"]}
    assert status["init1"]["actionStatus"] == "FINISHED"
    assert status["charge1"]["actionStatus"] == "FAILED" and errors_of(s, "chargingError")
    assert (
        status["log1"]["actionStatus"] == "FINISHED"
        and Path(status["log1"]["resultDescription"]).is_file()
    )
    master.wait(SERIAL, "factsheet", lambda d: True, 10, t1)
    # waitForTrigger holds the order until the master cancels it (6.8.2: then FAILED)
    x, y = here(master)
    a, b = (
        node("h", 0, x, y, MAP),
        node(
            "w",
            2,
            -1.6,
            -0.5,
            MAP,
            actions=[action("wait1", "waitForTrigger", triggerType="button")],
        ),
    )
    t2 = time.monotonic()
    master.send(
        SERIAL, "order", orderId="o-wait", orderUpdateId=0, nodes=[a, b], edges=[edge(a, b)]
    )
    master.wait(
        SERIAL,
        "state",
        lambda s: any(
            a["actionId"] == "wait1" and a["actionStatus"] == "RUNNING" for a in s["actionStates"]
        ),
        30,
        t2,
    )
    master.send(SERIAL, "instantActions", actions=[action("cancel3", "cancelOrder")])
    master.wait(
        SERIAL,
        "state",
        lambda s: any(
            a["actionId"] == "wait1" and a["actionStatus"] == "FAILED" for a in s["actionStates"]
        ),
        10,
        t2,
    )


def charge_status(state: dict, action_id: str) -> str | None:
    return {a["actionId"]: a["actionStatus"] for a in state["actionStates"]}.get(action_id)


def test_charging_at_the_dock_with_the_robots_battery(rig) -> None:
    """The master sends the vehicle to the charging node (the world's dock ``charger``) with
    ``startCharging`` on it: the vehicle connects there, the level rises at the battery's
    charge power until ``stopCharging``."""
    master, vehicle, _world = rig
    battery = vehicle.body.robot.battery
    assert battery is not None and battery.voltage is not None
    s0 = master.of(SERIAL, "state")[-1]["batteryState"]
    # started at 60 % (how far it drained depends on how long the tests before it took)
    assert s0["charging"] is False and 0.0 < s0["batteryCharge"] <= 60.0
    assert s0["batteryVoltage"] == battery.voltage
    dock = vehicle.body.loaded.world.docks["charger"].pose
    x, y = here(master)
    a = node("c0", 0, x, y, MAP)
    b = node("stage", 2, dock.x, dock.y + 0.6, MAP)
    c = node(
        "charger",
        4,
        dock.x,
        dock.y,
        MAP,
        actions=[action("chg1", "startCharging")],
        theta=dock.yaw,
    )
    t0 = time.monotonic()
    master.send(
        SERIAL,
        "order",
        orderId="o-charge",
        orderUpdateId=0,
        nodes=[a, b, c],
        edges=[edge(a, b), edge(b, c)],
    )
    on = master.wait(SERIAL, "state", lambda s: s["batteryState"]["charging"], 90, t0)
    assert charge_status(on, "chg1") == "FINISHED" and on["lastNodeId"] == "charger"
    assert not errors_of(on, "chargingError")
    level_on, t_on = on["batteryState"]["batteryCharge"], time.monotonic()
    later = master.wait(
        SERIAL, "state", lambda s: s["batteryState"]["batteryCharge"] > level_on + 0.05, 30, t_on
    )
    assert later["batteryState"]["charging"] and not later["driving"]
    t1 = time.monotonic()
    master.send(SERIAL, "instantActions", actions=[action("stop1", "stopCharging")])
    off = master.wait(SERIAL, "state", lambda s: charge_status(s, "stop1") == "FINISHED", 10, t1)
    assert off["batteryState"]["charging"] is False
    level_off, t_off = off["batteryState"]["batteryCharge"], time.monotonic()
    drained = master.wait(
        SERIAL, "state", lambda s: s["batteryState"]["batteryCharge"] < level_off, 30, t_off
    )
    assert drained["batteryState"]["charging"] is False
    # away from the dock startCharging fails with an error naming the nearest dock
    x, y = here(master)
    a, b = node("d0", 0, x, y, MAP), node("away", 2, dock.x, dock.y + 0.6, MAP)
    t2 = time.monotonic()
    master.send(
        SERIAL, "order", orderId="o-away", orderUpdateId=0, nodes=[a, b], edges=[edge(a, b)]
    )
    master.wait(SERIAL, "state", lambda s: s["lastNodeId"] == "away", 60, t2)
    master.send(SERIAL, "instantActions", actions=[action("chg2", "startCharging")])
    failed = master.wait(SERIAL, "state", lambda s: charge_status(s, "chg2") == "FAILED", 10, t2)
    err = [e for e in errors_of(failed, "chargingError") if ref(e, "actionId") == "chg2"]
    assert err and "charger" in err[0]["errorDescription"]
    assert failed["batteryState"]["charging"] is False


def test_clean_stop_and_last_will_on_the_embedded_broker(tmp_path: Path) -> None:
    embedded = EmbeddedBroker(port=free_port())
    url = embedded.start()
    master = MiniMaster(url.port)
    try:
        v1, w1 = start_vehicle(mission_file(tmp_path), url, tmp_path, "agv1")
        v2, w2 = start_vehicle(mission_file(tmp_path), url, tmp_path, "agv2")
        for serial in ("agv1", "agv2"):
            master.wait(serial, "connection", lambda d: d["connectionState"] == "ONLINE", 10)
            master.wait(serial, "state", lambda d: True, 10)
        v1.stop()
        master.wait("agv1", "connection", lambda d: d["connectionState"] == "OFFLINE", 10)
        v2.link.kill()  # the process vanishing, as far as the broker can tell
        master.wait("agv2", "connection", lambda d: d["connectionState"] == "CONNECTIONBROKEN", 30)
        w1.stop()
        w2.stop()
        v2._stop.set()
    finally:
        master.close()
        embedded.stop()
    assert not master.invalid, master.invalid


def test_kill_9_of_a_vehicle_process_is_connectionbroken(broker: Mosquitto, tmp_path: Path) -> None:
    fleet = {k: v for k, v in MISSION.items() if k not in ("robot", "start")}
    fleet["robots"] = [{"name": "agv9", "robot": "burger", "start": MISSION["start"]}]
    path = tmp_path / "fleet.yaml"
    path.write_text(yaml.safe_dump(fleet))
    master = MiniMaster(broker.port)
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "agv_mission.cli",
            "vda5050",
            "vehicles",
            str(path),
            "--broker",
            f"mqtt://127.0.0.1:{broker.port}",
            "--time-scale",
            "2",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
    )
    try:
        master.wait("agv9", "state", lambda d: True, 90)
        master.wait("agv9", "connection", lambda d: d["connectionState"] == "ONLINE", 10)
        t0 = time.monotonic()
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(10)
        master.wait(
            "agv9", "connection", lambda d: d["connectionState"] == "CONNECTIONBROKEN", 30, t0
        )
    finally:
        if proc.poll() is None:
            proc.kill()
        master.close()
    assert not master.invalid, master.invalid


def test_broker_restart_vehicle_keeps_driving_its_base(tmp_path: Path) -> None:
    mq = Mosquitto(tmp_path)
    mq.start()
    master = MiniMaster(mq.port)
    vehicle, world = start_vehicle(
        mission_file(tmp_path), BrokerUrl("127.0.0.1", mq.port), tmp_path
    )
    try:
        master.wait(SERIAL, "state", lambda d: True, 10)
        x, y = here(master)
        a, b = node("r0", 0, x, y, MAP), node("r1", 2, -0.55, -0.55, MAP)
        t0 = time.monotonic()
        master.send(
            SERIAL, "order", orderId="o-restart", orderUpdateId=0, nodes=[a, b], edges=[edge(a, b)]
        )
        master.wait(SERIAL, "state", lambda s: s["orderId"] == "o-restart" and s["driving"], 90, t0)
        mq.stop()
        time.sleep(0.5)
        t1 = time.monotonic()
        mq.start()
        master.wait(SERIAL, "connection", lambda d: d["connectionState"] == "ONLINE", 30, t1)
        done = master.wait(
            SERIAL, "state", lambda s: s["lastNodeId"] == "r1" and s["nodeStates"] == [], 60, t1
        )
        assert done["orderId"] == "o-restart"
        assert vehicle.link.connects >= 2
    finally:
        vehicle.stop()
        world.stop()
        master.close()
        mq.stop()
    assert not master.invalid, master.invalid
