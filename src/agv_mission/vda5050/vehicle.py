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
import math
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from agv_mission.atomic import atomic_write_text
from agv_mission.geometry import Pose2D, wrap_angle
from agv_mission.robots.description import RobotDescription
from agv_mission.vda5050 import factsheet as fs
from agv_mission.vda5050.body import BodySnapshot, VehicleBody, yaw_or_free
from agv_mission.vda5050.messages import (
    VERSION,
    Action,
    Edge,
    InstantActions,
    Node,
    Order,
    schema_angle,
)
from agv_mission.vda5050.order_checks import (
    battery_state,
    first_error,
    node_state,
    number,
    order_problems,
)
from agv_mission.vda5050.transport import BrokerUrl, MqttLink

STATE_INTERVAL = 1.0  # s: state at least this often (the contract: >= 1 Hz)
VIZ_INTERVAL = 0.1  # s: visualization at 10 Hz
START_RANGE = 0.5  # m: a new order's first node counts as reached within this (or its deviation)
DRIVING_SPEED = 1e-3  # m/s or rad/s below which the vehicle stands still
FINAL = ("FINISHED", "FAILED")
#: Errors that stay until a new order is accepted (6.6.4).
ORDER_ERRORS = ("validationError", "orderError", "orderUpdateError", "noRouteError")


@dataclass
class ActionRun:
    """One action the vehicle holds: where it came from and how far it got."""

    action: Action
    status: str = "WAITING"
    node_seq: int | None = None  # the node it triggers on; None: an instant action
    started: float | None = None  # simulated time it started
    result: str | None = None
    elapsed: float = 0.0  # simulated seconds of work done (frozen while paused)
    request: int = 0  # the body's charge request it waits for (start/stopCharging)
    #: its node was reached: it starts as soon as the blocking types let it (still WAITING)
    triggered: bool = False

    def doc(self) -> dict[str, Any]:
        d = {
            "actionId": self.action.actionId,
            "actionType": self.action.actionType,
            "actionStatus": self.status,
        }
        if self.action.actionDescription:
            d["actionDescription"] = self.action.actionDescription
        if self.result is not None:
            d["resultDescription"] = self.result
        return d


@dataclass
class OrderState:
    order_id: str = ""
    update_id: int = 0
    nodes: list[Node] = field(default_factory=list)  # not yet traversed, base then horizon
    edges: list[Edge] = field(default_factory=list)  # not yet left
    goal_id: int | None = None  # the body's goal for nodes[0]
    cancelled: bool = False


class Vehicle:
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
        from agv_mission.vda5050.messages import topic

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

    def _receive_instant(self, doc: dict[str, Any]) -> None:
        try:
            msg = InstantActions.model_validate(doc)
        except ValidationError as exc:
            self._error(
                "validationError", f"instantActions: {first_error(exc)}", topic="instantActions"
            )
            return
        if len(msg.actions) > fs.MAX_INSTANT_ACTIONS:
            self._error(
                "validationError", f"instantActions: more than {fs.MAX_INSTANT_ACTIONS} actions"
            )
            return
        for action in msg.actions:
            run = ActionRun(action)
            self.actions[action.actionId] = run
            spec = fs.ACTIONS.get(action.actionType)
            if spec is None or "INSTANT" not in spec["scopes"]:
                run.status = "FAILED"
                what = "unknown action" if spec is None else "not an instant action"
                self._error(
                    "actionError",
                    f"{action.actionType}: {what}",
                    actionId=action.actionId,
                    actionType=action.actionType,
                )
                continue
            self._start_action(run, self.body.snapshot())

    # ---------------------------------------------------------------- orders (6.6.2, 6.6.4)

    def _receive_order(self, doc: dict[str, Any]) -> None:
        try:
            order = Order.model_validate(doc)
        except ValidationError as exc:
            self._error(
                "validationError",
                f"order: {first_error(exc)}",
                topic="order",
                orderId=doc.get("orderId"),
            )
            return
        problems = order_problems(order, self.body.map_id)
        if problems:
            key, value, text = problems[0]
            refs = {"orderId": order.orderId, "orderUpdateId": order.orderUpdateId, key: value}
            self._error("orderError", text, **refs)
            return
        o = self.order
        busy = bool(o.nodes) or any(
            a.status not in FINAL for a in self.actions.values() if a.node_seq is not None
        )
        if order.orderId != o.order_id:
            if busy:
                self._error(
                    "orderUpdateError",
                    f"order {order.orderId}: order {o.order_id} is still running (cancel it first)",
                    orderId=order.orderId,
                )
                return
            first = order.nodes[0]
            if not self._at_node(first, self.body.snapshot().pose) and not (
                first.nodeId == self.last_node_id and first.sequenceId == self.last_node_seq
            ):
                self._error(
                    "noRouteError",
                    f"order {order.orderId}: its first node {first.nodeId} is not where the vehicle is",
                    orderId=order.orderId,
                    nodeId=first.nodeId,
                )
                return
            self._accept_new(order)
            return
        if order.orderUpdateId < o.update_id:
            self._error(
                "orderUpdateError",
                f"order {order.orderId}: update {order.orderUpdateId} is older than {o.update_id}",
                orderId=order.orderId,
                orderUpdateId=order.orderUpdateId,
            )
            return
        if order.orderUpdateId == o.update_id:
            return  # received twice: ignored (6.6.4.3)
        if o.cancelled:
            self._error(
                "orderUpdateError",
                f"order {order.orderId} was cancelled: send a new order",
                orderId=order.orderId,
                orderUpdateId=order.orderUpdateId,
            )
            return
        first = order.nodes[0]
        base = [n for n in o.nodes if n.released]
        decision = (
            (base[-1].nodeId, base[-1].sequenceId)
            if base
            else (self.last_node_id, self.last_node_seq)
        )
        if (first.nodeId, first.sequenceId) != decision:
            self._error(
                "orderUpdateError",
                f"order {order.orderId} update {order.orderUpdateId}: first node "
                f"{first.nodeId}/{first.sequenceId} is not the decision point {decision[0]}/{decision[1]}",
                orderId=order.orderId,
                nodeId=first.nodeId,
            )
            return
        self._stitch(order, base)

    def _at_node(self, node: Node, pose: Pose2D) -> bool:
        p = node.nodePosition
        assert p is not None
        reach = p.allowedDeviationXY if p.allowedDeviationXY else START_RANGE
        return math.hypot(p.x - pose.x, p.y - pose.y) <= max(reach, START_RANGE)

    def _clear_order_errors(self) -> None:
        self.errors = [e for e in self.errors if e["errorType"] not in ORDER_ERRORS]

    def _accept_new(self, order: Order) -> None:
        self.errors = []  # warnings of the last order and of actions: a new start
        self.body.cancel()
        self.actions = {
            k: a for k, a in self.actions.items() if a.node_seq is None and a.status not in FINAL
        }
        self.order = OrderState(
            order.orderId, order.orderUpdateId, list(order.nodes), list(order.edges)
        )
        for node in order.nodes:
            self._hold_actions(node)
        first = self.order.nodes[0]
        self._traverse(first, self.body.snapshot())

    def _stitch(self, order: Order, base: list[Node]) -> None:
        self._clear_order_errors()
        o = self.order
        kept_nodes = base  # the base already sent cannot change; the old horizon goes
        kept_seq = {n.sequenceId for n in kept_nodes}
        kept_edges = [e for e in o.edges if e.released]
        for node in o.nodes:
            if node.sequenceId not in kept_seq:
                self._drop_actions(node)
        new_nodes = order.nodes[1:]  # the stitching node keeps the content first sent
        o.nodes = kept_nodes + new_nodes
        o.edges = kept_edges + list(order.edges)
        o.update_id = order.orderUpdateId
        for node in new_nodes:
            self._hold_actions(node)

    def _hold_actions(self, node: Node) -> None:
        for action in node.actions:
            self.actions[action.actionId] = ActionRun(action, node_seq=node.sequenceId)

    def _drop_actions(self, node: Node) -> None:
        for action in node.actions:
            run = self.actions.get(action.actionId)
            if run is not None and run.status == "WAITING":
                del self.actions[action.actionId]

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

    def _blocked(self) -> bool:
        """A SOFT or HARD action stops driving while it runs or waits to run (6.12)."""
        return any(
            a.action.blockingType != "NONE"
            and (a.status in ("INITIALIZING", "RUNNING") or (a.triggered and a.status == "WAITING"))
            for a in self.actions.values()
        )

    # ---------------------------------------------------------------- actions (6.8, 6.11, 6.12)

    def _run_actions(self, snap: BodySnapshot) -> None:
        """Carry the running actions on, then start the triggered ones in list order as
        their blocking types allow (6.12, figure 17): a HARD action starts only when no
        other action runs, and nothing starts while it runs; SOFT and NONE run beside
        each other (SOFT and HARD stop driving: :meth:`_blocked`)."""
        for run in list(self.actions.values()):
            if run.status == "RUNNING":
                self._continue_action(run, snap)
        for run in list(self.actions.values()):
            if not (run.triggered and run.status == "WAITING"):
                continue
            active = [a for a in self.actions.values() if a.status in ("INITIALIZING", "RUNNING")]
            if any(a.action.blockingType == "HARD" for a in active):
                break
            if run.action.blockingType == "HARD" and active:
                break  # waits for what runs now; the actions after it wait for it
            self._start_action(run, snap)
            if run.action.blockingType == "HARD" and run.status == "RUNNING":
                break

    def _start_action(self, run: ActionRun, snap: BodySnapshot) -> None:
        a, kind = run.action, run.action.actionType
        run.started, run.elapsed = snap.time, 0.0
        run.status = "RUNNING"
        if kind == "startPause":
            self.paused = True
            self.body.pause()
            run.status = "FINISHED"
        elif kind == "stopPause":
            self.paused = False
            self.body.resume()
            run.status = "FINISHED"
        elif kind == "cancelOrder":
            self._cancel_order(run)
        elif kind == "stateRequest":
            run.status = "FINISHED"  # the state published after this message is the answer
        elif kind == "factsheetRequest":
            self.publish_factsheet()
            run.status = "FINISHED"
        elif kind == "logReport":
            self._log_report(run)
        elif kind == "initPosition":
            self._init_position(run)
        elif kind in ("startCharging", "stopCharging"):
            run.request = self.body.charge(kind == "startCharging")  # RUNNING until answered
        elif kind == "drop" and not self.loads:
            run.status, run.result = "FAILED", "no load to drop"
            self._error("loadError", "drop: the vehicle carries no load", actionId=a.actionId)
        # pick, drop, waitForTrigger: RUNNING until done (_continue_action) or cancelled

    def _continue_action(self, run: ActionRun, snap: BodySnapshot) -> None:
        kind = run.action.actionType
        if kind in ("startCharging", "stopCharging"):
            if snap.charge_id < run.request:
                return  # the body has not handled it yet (communication with the charger)
            if snap.charge_error is None:
                run.status, run.result = "FINISHED", snap.dock or "not charging"
            else:
                run.status, run.result = "FAILED", snap.charge_error
                self._error(
                    "chargingError", f"{kind}: {snap.charge_error}", actionId=run.action.actionId
                )
            return
        if kind == "cancelOrder":
            if not self._driving(snap) and not any(
                a.status not in FINAL for a in self.actions.values() if a.node_seq is not None
            ):
                run.status = "FINISHED"
            return
        if kind not in ("pick", "drop"):
            return
        if not self.paused and run.started is not None:
            run.elapsed += max(0.0, snap.time - run.started)
        run.started = snap.time
        duration = number(run.action.param("duration"), 5.0)
        if run.elapsed + 1e-9 < duration:
            return
        if kind == "pick":
            self._load_count += 1
            load_id = str(run.action.param("loadId") or f"{self.serial}-load{self._load_count}")
            load: dict[str, Any] = {"loadId": load_id, "loadPosition": "deck"}
            if run.action.param("loadType"):
                load["loadType"] = str(run.action.param("loadType"))
            self.loads.append(load)
            run.result = load_id
        else:
            wanted = run.action.param("loadId")
            idx = next(
                (i for i, ld in enumerate(self.loads) if wanted in (None, ld["loadId"])), None
            )
            if idx is None:
                run.status, run.result = "FAILED", f"no load {wanted}"
                return
            run.result = self.loads.pop(idx)["loadId"]
        run.status = "FINISHED"

    def trigger(self, action_id: str) -> bool:
        """The trigger a ``waitForTrigger`` waits for (a button on the vehicle)."""
        with self._lock:
            run = self.actions.get(action_id)
            if run is None or run.action.actionType != "waitForTrigger" or run.status != "RUNNING":
                return False
            run.status = "FINISHED"
            self._advance(self.body.snapshot())
        self.publish_state()
        return True

    def _cancel_order(self, run: ActionRun) -> None:
        o = self.order
        active = bool(o.nodes) or any(
            a.status not in FINAL for a in self.actions.values() if a.node_seq is not None
        )
        if not active or o.cancelled:
            run.status = "FAILED"
            self._error(
                "noOrderToCancel",
                "cancelOrder: the vehicle has no order",
                actionId=run.action.actionId,
            )
            return
        self.body.cancel()
        o.nodes.clear()
        o.edges.clear()
        o.goal_id, o.cancelled = None, True
        for a in self.actions.values():
            if a.node_seq is not None and a.status not in FINAL:
                a.status, a.result = "FAILED", "order cancelled"
        run.status = "RUNNING"  # FINISHED once the vehicle stands still

    def _init_position(self, run: ActionRun) -> None:
        a = run.action
        try:
            x, y, theta = (float(a.param(k)) for k in ("x", "y", "theta"))
        except (TypeError, ValueError):
            run.status, run.result = "FAILED", "x, y and theta must be numbers"
            self._error(
                "validationError",
                "initPosition: x, y and theta must be numbers",
                actionId=a.actionId,
            )
            return
        map_id = a.param("mapId", self.body.map_id)
        if map_id != self.body.map_id or not all(map(math.isfinite, (x, y, theta))):
            run.status, run.result = "FAILED", f"not a pose on map {self.body.map_id}"
            self._error(
                "initPositionError",
                f"initPosition: map {map_id!r}, x={x}, y={y}",
                actionId=a.actionId,
            )
            return
        self.body.set_pose(Pose2D(x, y, wrap_angle(theta)))
        if a.param("lastNodeId") is not None:
            self.last_node_id = str(a.param("lastNodeId"))
        run.status = "FINISHED"

    def _log_report(self, run: ActionRun) -> None:
        name = f"{self.serial}-{time.strftime('%Y%m%dT%H%M%S')}-{run.action.actionId}.json"[:120]
        doc = {"reason": str(run.action.param("reason", "")), "state": self.state_body()}
        try:
            self.log_dir.mkdir(parents=True, exist_ok=True)
            atomic_write_text(self.log_dir / name, json.dumps(doc, indent=2) + "\n")
        except OSError as exc:
            run.status, run.result = "FAILED", f"cannot store the report: {exc}"
            return
        run.status, run.result = "FINISHED", str(self.log_dir / name)
