"""A VDA 5050 2.1 vehicle: orders and instant actions in, state, visualization out.

The protocol side only: it drives a :class:`~agv_mission.vda5050.body.VehicleBody`. Order
acceptance follows the standard's figure 8 (6.6.2) and rejection its 6.6.4; node traversal
and action triggering its 6.10.2; action states and blocking types 6.11 and 6.12. All state
is guarded by one lock: MQTT callbacks (paho's thread) and the vehicle's own 10 Hz loop
both change it, and every change is published at once (``state`` on change).
"""

from __future__ import annotations

import contextlib
import json
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

from agv_mission.robots.description import RobotDescription
from agv_mission.vda5050 import factsheet as fs
from agv_mission.vda5050.body import BodySnapshot, VehicleBody, yaw_or_free
from agv_mission.vda5050.order_checks import (
    battery_state,
    node_state,
)
from agv_mission.vda5050.protocol import (
    VERSION,
    Node,
    schema_angle,
)
from agv_mission.vda5050.transport import BrokerUrl, MqttLink
from agv_mission.vda5050.vehicle_actions import FINAL, ActionRun, VehicleActions
from agv_mission.vda5050.vehicle_orders import OrderState, VehicleOrders

STATE_INTERVAL = 1.0  # s: state at least this often (the contract: >= 1 Hz)
VIZ_INTERVAL = 0.1  # s: visualization at 10 Hz
DRIVING_SPEED = 1e-3  # m/s or rad/s below which the vehicle stands still


class Vehicle(VehicleOrders, VehicleActions):
    """The vehicle: connect with :meth:`start`, leave cleanly with :meth:`stop`."""

    def __init__(
        self,
        body: VehicleBody,
        robot: RobotDescription,
        broker: BrokerUrl,
        serial: str,
        manufacturer: str = "agv-mission",
        log_dir: Path | None = None,
    ) -> None:
        self.body, self.robot, self.serial, self.manufacturer = body, robot, serial, manufacturer
        self.log_dir = log_dir or Path(tempfile.gettempdir()) / "agv-mission-vda5050"
        self._lock = threading.RLock()
        self.order = OrderState()
        self.last_node_id, self.last_node_seq = "", 0
        self.actions: dict[str, ActionRun] = {}  # by actionId, in arrival order
        self.errors: list[dict[str, Any]] = []
        self.loads: list[dict[str, Any]] = []
        self.paused = False
        self._prev_driving = False
        self._faulted = False
        self._load_count = 0
        self._stop = threading.Event()
        self._wake = threading.Event()
        self._thread: threading.Thread | None = None
        self.link = MqttLink(
            broker,
            f"{manufacturer}-{serial}",
            manufacturer,
            serial,
            self._on_message,
            [(self._topic("order"), 0), (self._topic("instantActions"), 0)],
            will=("connection", {"connectionState": "CONNECTIONBROKEN"}),
            on_connect=self._on_connect,
        )

    def _topic(self, name: str) -> str:
        from agv_mission.vda5050.protocol import topic

        return topic(self.manufacturer, self.serial, name)

    # ---------------------------------------------------------------- life

    def start(self, wait: float | None = 10.0) -> None:
        self.link.start(wait)
        self._thread = threading.Thread(
            target=self._loop, name=f"vda5050-{self.serial}", daemon=True
        )
        self._thread.start()

    def stop(self) -> None:
        """Leave cleanly: ``OFFLINE`` (retained), then DISCONNECT (no last will)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(2.0)
        info = self.link.client.publish(
            self._topic("connection"),
            json.dumps(self.link.stamp("connection", {"connectionState": "OFFLINE"})),
            qos=1,
            retain=True,
        )
        with contextlib.suppress(RuntimeError, ValueError):
            info.wait_for_publish(2.0)
        self.link.stop()

    def wake(self) -> None:
        """The body changed: look at it before the next tick."""
        self._wake.set()

    def _on_connect(self) -> None:
        self.link.publish("connection", {"connectionState": "ONLINE"}, qos=1, retain=True)
        self.publish_factsheet()
        self.publish_state()

    def _loop(self) -> None:
        next_viz = next_state = time.monotonic()
        while not self._stop.is_set():
            now = time.monotonic()
            snap = self.body.snapshot()
            with self._lock:
                if snap.fault and not self._faulted:
                    self._faulted = True
                    self._error("simulationError", snap.fault, "FATAL")
                changed = self._advance(snap)
                driving = self._driving(snap)
                if driving != self._prev_driving:
                    self._prev_driving, changed = driving, True
            if changed or now >= next_state:
                self.publish_state(snap)
                next_state = now + STATE_INTERVAL
            if now >= next_viz:
                self.publish_visualization(snap)
                next_viz += VIZ_INTERVAL
                if next_viz < now:
                    next_viz = now + VIZ_INTERVAL
            self._wake.wait(max(0.0, min(next_viz, next_state) - time.monotonic()))
            self._wake.clear()

    # ---------------------------------------------------------------- publishing

    def publish_factsheet(self) -> dict[str, Any]:
        body = fs.factsheet_body(self.robot, STATE_INTERVAL, VIZ_INTERVAL)
        return self.link.publish("factsheet", body, qos=1, retain=True)

    def _position(self, snap: BodySnapshot) -> dict[str, Any]:
        p = snap.pose
        return {
            "x": p.x,
            "y": p.y,
            "theta": schema_angle(p.yaw),  # [-pi, pi] as the standard's agvPosition
            "mapId": self.body.map_id,
            "positionInitialized": True,
        }

    def _velocity(self, snap: BodySnapshot) -> dict[str, Any]:
        return {"vx": snap.v, "vy": 0.0, "omega": snap.w}

    def publish_visualization(self, snap: BodySnapshot | None = None) -> dict[str, Any]:
        snap = snap or self.body.snapshot()
        return self.link.publish(
            "visualization", {"agvPosition": self._position(snap), "velocity": self._velocity(snap)}
        )

    @staticmethod
    def _driving(snap: BodySnapshot) -> bool:
        return abs(snap.v) > DRIVING_SPEED or abs(snap.w) > DRIVING_SPEED

    def state_body(self, snap: BodySnapshot | None = None) -> dict[str, Any]:
        snap = snap or self.body.snapshot()
        with self._lock:
            o = self.order
            return {
                "orderId": o.order_id,
                "orderUpdateId": o.update_id,
                "lastNodeId": self.last_node_id,
                "lastNodeSequenceId": self.last_node_seq,
                "nodeStates": [node_state(n) for n in o.nodes],
                "edgeStates": [
                    {"edgeId": e.edgeId, "sequenceId": e.sequenceId, "released": e.released}
                    for e in o.edges
                ],
                "agvPosition": self._position(snap),
                "velocity": self._velocity(snap),
                "loads": list(self.loads),
                "driving": self._driving(snap),
                "paused": self.paused,
                "newBaseRequest": bool(o.nodes) and all(not n.released for n in o.nodes),
                "actionStates": [a.doc() for a in self.actions.values()],
                "batteryState": battery_state(snap),
                "operatingMode": "AUTOMATIC",
                "errors": list(self.errors),
                "safetyState": {"eStop": "NONE", "fieldViolation": False},
            }

    def publish_state(self, snap: BodySnapshot | None = None) -> dict[str, Any]:
        with self._lock:
            return self.link.publish("state", self.state_body(snap))

    # ---------------------------------------------------------------- errors

    def _error(self, kind: str, description: str, level: str = "WARNING", **refs: Any) -> None:
        err: dict[str, Any] = {
            "errorType": kind,
            "errorLevel": level,
            "errorDescription": description[:500],
        }
        if refs:
            err["errorReferences"] = [
                {"referenceKey": k, "referenceValue": str(v)} for k, v in refs.items()
            ]
        self.errors.append(err)
        del self.errors[:-20]  # the newest twenty: a flood of bad messages stays bounded

    # ---------------------------------------------------------------- incoming

    def _on_message(self, topic_name: str, payload: bytes, _retain: bool) -> None:
        kind = topic_name.rsplit("/", 1)[-1]
        with self._lock:
            try:
                doc = self._parse(kind, payload)
                if doc is None:
                    pass
                elif kind == "order":
                    self._receive_order(doc)
                elif kind == "instantActions":
                    self._receive_instant(doc)
                self._advance(self.body.snapshot())
            except Exception as exc:  # noqa: BLE001 (a message must never go unanswered)
                self._error(
                    "validationError" if kind in ("order", "instantActions") else "internalError",
                    f"{kind}: cannot be handled: {exc!r}",
                    topic=kind,
                )
        self.publish_state()

    def _parse(self, kind: str, payload: bytes) -> dict[str, Any] | None:
        """The message as a dict, or None with a ``validationError`` (6.6.4.1)."""
        if len(payload) > fs.MAX_MESSAGE:
            self._error(
                "validationError",
                f"{kind}: message of {len(payload)} bytes exceeds msgLen {fs.MAX_MESSAGE}",
                topic=kind,
            )
            return None
        try:
            doc = json.loads(payload)
        except (ValueError, UnicodeDecodeError) as exc:
            self._error("validationError", f"{kind}: not JSON: {exc}", topic=kind)
            return None
        if not isinstance(doc, dict):
            self._error("validationError", f"{kind}: not a JSON object", topic=kind)
            return None
        if doc.get("version") != VERSION:
            self._error(
                "validationError",
                f"{kind}: version {doc.get('version')!r}, this vehicle speaks {VERSION}",
                topic=kind,
                headerId=doc.get("headerId"),
            )
            return None
        if doc.get("serialNumber") != self.serial or doc.get("manufacturer") != self.manufacturer:
            self._error(
                "validationError",
                f"{kind}: addressed to {doc.get('manufacturer')}/{doc.get('serialNumber')}, "
                f"this is {self.manufacturer}/{self.serial}",
                topic=kind,
                serialNumber=doc.get("serialNumber"),
            )
            return None
        return doc

    # ---------------------------------------------------------------- progress (6.10.2)

    def _traverse(self, node: Node, snap: BodySnapshot) -> None:
        """``node`` counts as traversed: report it and trigger its actions."""
        o = self.order
        if o.nodes and o.nodes[0].sequenceId == node.sequenceId:
            o.nodes.pop(0)
        if (
            o.edges
            and o.edges[0].endNodeId == node.nodeId
            and o.edges[0].sequenceId < node.sequenceId
        ):
            o.edges.pop(0)
        o.goal_id = None
        self.last_node_id, self.last_node_seq = node.nodeId, node.sequenceId
        for action in node.actions:
            run = self.actions.get(action.actionId)
            if run is not None and run.status == "WAITING":
                run.triggered = True  # started in list order by _run_actions

    def _advance(self, snap: BodySnapshot) -> bool:
        """Move the order and the actions on; True when something changed."""
        before = self._fingerprint()
        self._run_actions(snap)
        o = self.order
        if o.nodes and not o.cancelled and not self.paused and not self._blocked():
            target = o.nodes[0]
            if target.released and o.goal_id is None:
                self._drive_to(target, snap)
            elif o.goal_id is not None and snap.goal_id == o.goal_id:
                if snap.nav == "succeeded":
                    self._traverse(target, snap)
                    self._run_actions(snap)
                    if o.nodes and o.nodes[0].released and not self._blocked():
                        self._drive_to(o.nodes[0], snap)
                elif snap.nav == "failed":
                    o.goal_id = None
                    self._error(
                        "noRouteError",
                        f"cannot reach node {target.nodeId}: {snap.reason}",
                        nodeId=target.nodeId,
                        orderId=o.order_id,
                    )
                    o.nodes.clear()
                    o.edges.clear()
                    for run in self.actions.values():
                        if run.node_seq is not None and run.status not in FINAL:
                            run.status, run.result = "FAILED", "order aborted: node unreachable"
        return self._fingerprint() != before

    def _fingerprint(self) -> tuple[Any, ...]:
        o = self.order
        return (
            o.order_id,
            o.update_id,
            len(o.nodes),
            len(o.edges),
            self.last_node_seq,
            tuple((a.status, a.result) for a in self.actions.values()),
            len(self.errors),
            self.paused,
            len(self.loads),
        )

    def _drive_to(self, node: Node, snap: BodySnapshot) -> None:
        o = self.order
        p = node.nodePosition
        assert p is not None
        edge = o.edges[0] if o.edges and o.edges[0].endNodeId == node.nodeId else None
        pose, free_yaw = yaw_or_free(p.theta, snap.pose, p.x, p.y)
        yaw_tol = free_yaw if free_yaw is not None else (p.allowedDeviationTheta or None)
        o.goal_id = self.body.navigate_to(
            pose, p.allowedDeviationXY or None, yaw_tol, edge.maxSpeed if edge is not None else None
        )
