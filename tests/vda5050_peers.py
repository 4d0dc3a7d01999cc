"""Independent VDA 5050 2.1 peers for the tests, written from the standard's text (not from
the project's code): a minimal master that sends raw JSON and checks every message it
receives against the 2.1.0 schemas, a minimal kinematic vehicle, and a mosquitto broker."""

from __future__ import annotations

import json
import math
import shutil
import socket
import subprocess
import threading
import time
from collections.abc import Callable
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import jsonschema
import paho.mqtt.client as mqtt
import pytest

from agv_mission.vda5050.schemas import schema_dir

#: the 2.1.0 schemas as the package ships them (with their MIT licence): a plain clone has them
SCHEMAS = schema_dir()
#: the same schemas in ../shared, when it is there (the package's copy is checked against it)
SHARED_SCHEMAS = (
    Path(__file__).resolve().parents[2] / "shared" / "spec" / "vda5050" / "json_schemas"
)
TOPICS = ("connection", "factsheet", "state", "visualization", "order", "instantActions")


def schema_validators() -> dict[str, jsonschema.protocols.Validator]:
    """One validator per topic, from the schemas the package ships."""
    out = {}
    for name in TOPICS:
        schema = json.loads((SCHEMAS / f"{name}.schema").read_text(encoding="utf-8"))
        cls = jsonschema.validators.validator_for(schema)
        out[name] = cls(schema, format_checker=cls.FORMAT_CHECKER)
    return out


def stamp() -> str:
    now = datetime.now(timezone.utc)
    return now.strftime("%Y-%m-%dT%H:%M:%S.") + f"{now.microsecond // 10000:02d}Z"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Mosquitto:
    """Debian's mosquitto on a free loopback port with a config file of our own."""

    def __init__(self, workdir: Path) -> None:
        exe = shutil.which("mosquitto") or (
            "/usr/sbin/mosquitto" if Path("/usr/sbin/mosquitto").exists() else None
        )
        if exe is None:
            pytest.skip("mosquitto is not installed (apt-get install -y mosquitto)")
        self.exe, self.port = exe, free_port()
        self.conf = workdir / "mosquitto.conf"
        self.conf.write_text(
            f"listener {self.port} 127.0.0.1\nallow_anonymous true\npersistence false\n"
        )
        self.proc: subprocess.Popen[bytes] | None = None

    def start(self) -> None:
        self.proc = subprocess.Popen(
            [self.exe, "-c", str(self.conf)], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
        )
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline:
            try:
                socket.create_connection(("127.0.0.1", self.port), 0.2).close()
                return
            except OSError:
                time.sleep(0.05)
        raise RuntimeError("mosquitto did not start")

    def stop(self) -> None:
        if self.proc is not None:
            self.proc.terminate()
            self.proc.wait(5)
            self.proc = None


class Header:
    """headerId per topic, counted by the sender (6.4)."""

    def __init__(self, manufacturer: str, serial: str) -> None:
        self.manufacturer, self.serial = manufacturer, serial
        self.ids: dict[str, int] = {}

    def __call__(self, topic: str, **body: Any) -> dict[str, Any]:
        n = self.ids.get(topic, -1) + 1
        self.ids[topic] = n
        return {
            "headerId": n,
            "timestamp": stamp(),
            "version": "2.1.0",
            "manufacturer": self.manufacturer,
            "serialNumber": self.serial,
            **body,
        }


class MiniMaster:
    """A master control reduced to what the standard says a master sends and receives."""

    def __init__(self, port: int, manufacturer: str = "agv-mission") -> None:
        self.validators = schema_validators()
        self.manufacturer = manufacturer
        self.messages: list[tuple[float, str, dict[str, Any], bool]] = []
        self.invalid: list[str] = []
        self.cond = threading.Condition()
        self.headers: dict[str, Header] = {}
        self.client = mqtt.Client(
            mqtt.CallbackAPIVersion.VERSION2, client_id=f"mini-master-{port}-{id(self)}"
        )
        self.client.on_message = self._message
        self.client.on_connect = lambda c, *_a: c.subscribe(f"uagv/v2/{manufacturer}/+/#", 1)
        self.client.connect("127.0.0.1", port)
        self.client.loop_start()

    def _message(self, _c: Any, _u: Any, msg: mqtt.MQTTMessage) -> None:
        kind = msg.topic.rsplit("/", 1)[-1]
        if kind in ("order", "instantActions"):
            return  # our own
        doc = json.loads(msg.payload)
        errors = [e.message for e in self.validators[kind].iter_errors(doc)]
        if errors:
            self.invalid.append(f"{msg.topic}: {errors[:3]}")
        with self.cond:
            self.messages.append((time.monotonic(), msg.topic, doc, bool(msg.retain)))
            self.cond.notify_all()

    def of(self, serial: str, kind: str, since: float = 0.0) -> list[dict[str, Any]]:
        with self.cond:
            return [
                d
                for t, topic, d, _r in self.messages
                if t >= since and topic == self.topic(serial, kind)
            ]

    def topic(self, serial: str, kind: str) -> str:
        return f"uagv/v2/{self.manufacturer}/{serial}/{kind}"

    def wait(
        self,
        serial: str,
        kind: str,
        pred: Callable[[dict[str, Any]], bool],
        timeout: float = 30.0,
        since: float = 0.0,
    ) -> dict[str, Any]:
        deadline = time.monotonic() + timeout
        with self.cond:
            while True:
                for t, topic, doc, _r in self.messages:
                    if t >= since and topic == self.topic(serial, kind) and pred(doc):
                        return doc
                left = deadline - time.monotonic()
                if left <= 0:
                    last = [d for _t, tp, d, _r in self.messages if tp == self.topic(serial, kind)][
                        -1:
                    ]
                    raise AssertionError(
                        f"no {kind} of {serial} as expected within {timeout} s; last: {json.dumps(last)[:1500]}"
                    )
                self.cond.wait(left)

    def send(self, serial: str, kind: str, **body: Any) -> dict[str, Any]:
        header = self.headers.setdefault(serial, Header(self.manufacturer, serial))
        doc = header(kind, **body)
        assert not list(self.validators[kind].iter_errors(doc)), "the test sends valid messages"
        self.client.publish(self.topic(serial, kind), json.dumps(doc), qos=0)
        return doc

    def raw(self, serial: str, kind: str, payload: bytes | str) -> None:
        self.client.publish(self.topic(serial, kind), payload, qos=0)

    def close(self) -> None:
        self.client.loop_stop()
        self.client.disconnect()


def node(
    node_id: str,
    seq: int,
    x: float,
    y: float,
    map_id: str,
    released: bool = True,
    actions: list | None = None,
    **pos: Any,
) -> dict[str, Any]:
    return {
        "nodeId": node_id,
        "sequenceId": seq,
        "released": released,
        "nodePosition": {"x": x, "y": y, "mapId": map_id, **pos},
        "actions": actions or [],
    }


def edge(a: dict[str, Any], b: dict[str, Any], **extra: Any) -> dict[str, Any]:
    return {
        "edgeId": f"{a['nodeId']}-{b['nodeId']}",
        "sequenceId": a["sequenceId"] + 1,
        "released": b["released"],
        "startNodeId": a["nodeId"],
        "endNodeId": b["nodeId"],
        "actions": [],
        **extra,
    }


def action(action_id: str, kind: str, blocking: str = "HARD", **params: Any) -> dict[str, Any]:
    out: dict[str, Any] = {"actionId": action_id, "actionType": kind, "blockingType": blocking}
    if params:
        out["actionParameters"] = [{"key": k, "value": v} for k, v in params.items()]
    return out


class MiniVehicle:
    """A vehicle reduced to the standard: drives its base along straight edges at ``speed``,
    stops at the decision point, stitches updates, reports state at 5 Hz and on change,
    connection with last will. Every order it receives is checked against the schema; one
    that fails it is rejected with a ``validationError`` (6.6.4.1). Node actions run as 6.12
    says: in list order, HARD alone, SOFT and HARD stop driving; an action takes its
    ``duration`` parameter in seconds (0 by default); ``startCharging`` / ``stopCharging``
    set ``batteryState.charging`` (the charge rises 20 % a second while charging)."""

    def __init__(
        self,
        port: int,
        serial: str,
        x: float,
        y: float,
        map_id: str,
        manufacturer: str = "agv-mission",
        speed: float = 1.5,
    ) -> None:
        self.validators = schema_validators()
        self.serial, self.map_id, self.speed = serial, map_id, speed
        self.x, self.y, self.theta = x, y, 0.0
        self.header = Header(manufacturer, serial)
        self.base = f"uagv/v2/{manufacturer}/{serial}"
        self.invalid: list[str] = []
        self.orders: list[dict[str, Any]] = []
        self.order_id, self.update_id = "", 0
        self.nodes: list[dict[str, Any]] = []
        self.edges: list[dict[str, Any]] = []
        self.last_node, self.last_seq = "", 0
        self.actions: dict[str, dict[str, Any]] = {}  # actionStates, by actionId
        self.running: list[dict[str, Any]] = []  # triggered node actions, in list order
        self.errors: list[dict[str, Any]] = []
        self.battery, self.charging = 50.0, False
        self.lock = threading.Lock()
        self.stopped = threading.Event()
        #: (time, "released" | "reached" | "started" | "finished", nodeId or actionId);
        #: reached entries also in ``visits`` as (nodeId, sequenceId, x, y, theta)
        self.log: list[tuple[float, str, str]] = []
        self.visits: list[tuple[str, int, float, float, float | None]] = []
        self._seen: list[tuple[int, str]] = []
        c = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=f"mini-{serial}-{port}")
        c.will_set(
            f"{self.base}/connection",
            json.dumps(self.header("connection", connectionState="CONNECTIONBROKEN")),
            1,
            True,
        )
        c.on_connect = self._connected
        c.on_message = self._message
        self.client = c
        c.connect("127.0.0.1", port, keepalive=5)
        c.loop_start()
        self.thread = threading.Thread(target=self._loop, daemon=True)
        self.thread.start()

    def _connected(self, c: Any, *_a: Any) -> None:
        c.subscribe(f"{self.base}/order", 0)
        c.subscribe(f"{self.base}/instantActions", 0)
        c.publish(
            f"{self.base}/connection",
            json.dumps(self.header("connection", connectionState="ONLINE")),
            1,
            True,
        )

    def _reject(self, kind: str, text: str, **refs: Any) -> None:
        self.errors.append(
            {
                "errorType": kind,
                "errorLevel": "WARNING",
                "errorDescription": text[:200],
                "errorReferences": [
                    {"referenceKey": k, "referenceValue": str(v)} for k, v in refs.items()
                ],
            }
        )

    def _message(self, _c: Any, _u: Any, msg: mqtt.MQTTMessage) -> None:
        kind = msg.topic.rsplit("/", 1)[-1]
        doc = json.loads(msg.payload)
        errors = [e.message for e in self.validators[kind].iter_errors(doc)]
        if errors:
            self.invalid.append(f"{kind}: {errors[:3]}")
            with self.lock:
                self._reject("validationError", f"{kind}: {errors[0]}", topic=kind)
            return
        with self.lock:
            if kind == "instantActions":
                self._instant(doc)
            else:
                self._order(doc)

    def _instant(self, doc: dict[str, Any]) -> None:
        for a in doc["actions"]:
            self.actions[a["actionId"]] = {
                "actionId": a["actionId"],
                "actionType": a["actionType"],
                "actionStatus": "FINISHED",
            }
            if a["actionType"] in ("startCharging", "stopCharging"):
                self.charging = a["actionType"] == "startCharging"
            elif a["actionType"] == "cancelOrder":
                self.nodes, self.edges, self.running = [], [], []

    def _order(self, doc: dict[str, Any]) -> None:
        self.orders.append(doc)
        nodes, edges = doc["nodes"], doc["edges"]
        if len(edges) != len(nodes) - 1 or any(
            e["startNodeId"] != a["nodeId"] or e["endNodeId"] != b["nodeId"]
            for e, a, b in zip(edges, nodes, nodes[1:], strict=False)
        ):
            self._reject("orderError", "nodes and edges do not join", orderId=doc["orderId"])
            return
        if doc["orderId"] != self.order_id:
            if self.nodes:
                self._reject("orderUpdateError", "an order runs", orderId=doc["orderId"])
                return
            self.errors = []
            self.order_id, self.update_id = doc["orderId"], doc["orderUpdateId"]
            self.nodes, self.edges = list(nodes), list(edges)
            first = self.nodes.pop(0)  # where we stand
            self.last_node, self.last_seq = first["nodeId"], first["sequenceId"]
            self._trigger(first)
        elif doc["orderUpdateId"] > self.update_id:
            base = [n for n in self.nodes if n["released"]]
            decision = (
                (base[-1]["nodeId"], base[-1]["sequenceId"])
                if base
                else (self.last_node, self.last_seq)
            )
            if (nodes[0]["nodeId"], nodes[0]["sequenceId"]) != decision:
                self._reject("orderUpdateError", "not stitched", orderId=doc["orderId"])
                return
            self.update_id = doc["orderUpdateId"]
            self.nodes = base + nodes[1:]
            self.edges = [e for e in self.edges if e["released"]] + list(edges)
        else:
            return
        for n in self.nodes:
            for a in n.get("actions", []):
                self.actions.setdefault(
                    a["actionId"],
                    {
                        "actionId": a["actionId"],
                        "actionType": a["actionType"],
                        "actionStatus": "WAITING",
                    },
                )
            if n["released"] and not any(
                e == (n["sequenceId"], doc["orderId"]) for e in self._seen
            ):
                self._seen.append((n["sequenceId"], doc["orderId"]))
                self.log.append((time.monotonic(), "released", n["nodeId"]))

    def _trigger(self, n: dict[str, Any]) -> None:
        for a in n.get("actions", []):
            self.actions.setdefault(
                a["actionId"],
                {
                    "actionId": a["actionId"],
                    "actionType": a["actionType"],
                    "actionStatus": "WAITING",
                },
            )
            params = {p["key"]: p["value"] for p in a.get("actionParameters", [])}
            self.running.append(
                {"action": a, "duration": float(params.get("duration", 0.0)), "ends": None}
            )

    def _run_actions(self) -> None:
        """6.12: in list order; a HARD action alone; finished ones leave the list."""
        now = time.monotonic()
        for r in self.running:
            if r["ends"] is not None and now >= r["ends"]:
                a = r["action"]
                self.actions[a["actionId"]]["actionStatus"] = "FINISHED"
                self.log.append((now, "finished", a["actionId"]))
                if a["actionType"] in ("startCharging", "stopCharging"):
                    self.charging = a["actionType"] == "startCharging"
        self.running = [
            r
            for r in self.running
            if self.actions[r["action"]["actionId"]]["actionStatus"] != "FINISHED"
        ]
        for r in self.running:
            if r["ends"] is not None:
                if r["action"]["blockingType"] == "HARD":
                    return
                continue
            active = [x for x in self.running if x["ends"] is not None]
            hard = r["action"]["blockingType"] == "HARD"
            if hard and active:
                return
            r["ends"] = now + r["duration"]
            self.actions[r["action"]["actionId"]]["actionStatus"] = "RUNNING"
            self.log.append((now, "started", r["action"]["actionId"]))
            if hard:
                return

    def _may_drive(self) -> bool:
        return not any(r["action"]["blockingType"] in ("SOFT", "HARD") for r in self.running)

    def _state(self, driving: bool) -> dict[str, Any]:
        return self.header(
            "state",
            orderId=self.order_id,
            orderUpdateId=self.update_id,
            lastNodeId=self.last_node,
            lastNodeSequenceId=self.last_seq,
            nodeStates=[
                {"nodeId": n["nodeId"], "sequenceId": n["sequenceId"], "released": n["released"]}
                for n in self.nodes
            ],
            edgeStates=[
                {"edgeId": e["edgeId"], "sequenceId": e["sequenceId"], "released": e["released"]}
                for e in self.edges
            ],
            agvPosition={
                "x": self.x,
                "y": self.y,
                "theta": self.theta,
                "mapId": self.map_id,
                "positionInitialized": True,
            },
            driving=driving,
            actionStates=[dict(a) for a in self.actions.values()],
            batteryState={"batteryCharge": round(self.battery, 3), "charging": self.charging},
            operatingMode="AUTOMATIC",
            errors=list(self.errors),
            safetyState={"eStop": "NONE", "fieldViolation": False},
        )

    def _loop(self) -> None:
        dt = 0.05
        n = 0
        while not self.stopped.is_set():
            driving = False
            with self.lock:
                before = json.dumps([self.actions, self.last_seq, self.errors, self.charging])
                self._run_actions()
                if self.charging:
                    self.battery = min(100.0, self.battery + 20.0 * dt)
                if self.nodes and self.nodes[0]["released"] and self._may_drive():
                    target = self.nodes[0]["nodePosition"]
                    dx, dy = target["x"] - self.x, target["y"] - self.y
                    dist = math.hypot(dx, dy)
                    step = self.speed * dt
                    if dist <= step:
                        self.x, self.y = target["x"], target["y"]
                        if "theta" in target:
                            self.theta = target["theta"]
                        done = self.nodes.pop(0)
                        if self.edges:
                            self.edges.pop(0)
                        self.last_node, self.last_seq = done["nodeId"], done["sequenceId"]
                        self.log.append((time.monotonic(), "reached", done["nodeId"]))
                        self.visits.append(
                            (
                                done["nodeId"],
                                done["sequenceId"],
                                self.x,
                                self.y,
                                target.get("theta"),
                            )
                        )
                        self._trigger(done)
                        self._run_actions()
                    else:
                        self.x += step * dx / dist
                        self.y += step * dy / dist
                        self.theta = math.atan2(dy, dx)
                        driving = True
                changed = before != json.dumps(
                    [self.actions, self.last_seq, self.errors, self.charging]
                )
                if changed or n % 4 == 0:
                    self.client.publish(f"{self.base}/state", json.dumps(self._state(driving)), 0)
            n += 1
            time.sleep(dt)

    def kill(self) -> None:
        """Vanish without DISCONNECT: the broker publishes the last will."""
        self.stopped.set()
        self.client.loop_stop()
        sock = self.client.socket()
        if sock is not None:
            sock.close()

    def close(self) -> None:
        self.stopped.set()
        self.client.publish(
            f"{self.base}/connection",
            json.dumps(self.header("connection", connectionState="OFFLINE")),
            1,
            True,
        ).wait_for_publish(2)
        self.client.disconnect()
        self.client.loop_stop()
