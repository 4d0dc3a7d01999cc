"""The master: a mission's tasks as VDA 5050 orders to any vehicles, followed to a result.

Each task becomes one order (:mod:`~agv_mission.vda5050.routes`: ``go_to`` one node,
``patrol`` its waypoints loop by loop, ``visit_rooms`` its rooms' goals, ``dock`` /
``undock`` / ``charge`` with ``startCharging`` / ``stopCharging``), sent as
:mod:`~agv_mission.vda5050.master_orders` builds it: from the vehicle's current position under
its ``lastNodeId`` (6.6.3.1). Nodes are released through :class:`NodeReservations`, the
stand-in for the fleet layer's traffic control: a node is granted to one vehicle at a time,
at most ``lookahead`` nodes past the vehicle's last node; the rest of the route is horizon,
extended by order updates as the vehicle moves on (6.6.2). A vehicle that goes
``CONNECTIONBROKEN`` (or never comes online) keeps its reservations; after
``reassign_timeout`` its tasks go to another vehicle, an event in the result.

One thread decides: MQTT callbacks only queue messages.
"""

from __future__ import annotations

import json
import math
import queue
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from agv_mission.fleet.base import DispatchError, FleetTask, RobotWork
from agv_mission.geometry import Pose2D
from agv_mission.vda5050.master_orders import ActiveOrder, cancel_body, order_body, start_order
from agv_mission.vda5050.master_report import (
    TRAJECTORY_HEADER,
    master_result,
    new_run_dir,
    write_outputs,
)
from agv_mission.vda5050.protocol import split_topic
from agv_mission.vda5050.routes import (
    ChargeAction,
    MasterPlan,
    NodeAction,
    NodeReservations,
    RouteNode,
    TaskRoute,
    load_plan,
    place,
)
from agv_mission.vda5050.transport import BrokerUrl, MqttLink

__all__ = [
    "TRAJECTORY_HEADER",
    "ChargeAction",
    "Master",
    "MasterPlan",
    "NodeAction",
    "NodeReservations",
    "RouteNode",
    "TaskRoute",
    "load_plan",
    "new_run_dir",
    "place",
    "write_outputs",
]

ORDER_ERRORS = ("validationError", "orderError", "orderUpdateError", "noRouteError")
RESEND_AFTER = 2.0  # s: an order (update) the state does not show by then is sent again
ORDER_TIMEOUT = 15.0  # s: an order the vehicle has not taken by then fails its task


@dataclass
class Peer:
    """A vehicle as the master sees it."""

    serial: str
    connection: str | None = None
    state: dict[str, Any] | None = None
    since: float = 0.0  # when the connection last changed (or the start)
    queue: list[TaskRoute] = field(default_factory=list)
    order: ActiveOrder | None = None
    orders: int = 0
    updates: int = 0
    distance: float = 0.0
    last_xy: tuple[float, float] | None = None
    orders_made: int = 0

    @property
    def online(self) -> bool:
        return self.connection == "ONLINE" or (self.connection is None and self.state is not None)


class Master:
    """Dispatch ``plan`` over the broker at ``url`` until every task ended."""

    def __init__(
        self,
        plan: MasterPlan,
        url: BrokerUrl,
        manufacturer: str = "agv-mission",
        reassign_timeout: float = 10.0,
        lookahead: int = 2,
        run_dir: Path | None = None,
    ) -> None:
        self.plan, self.url, self.manufacturer = plan, url, manufacturer
        self.reassign_timeout, self.lookahead = reassign_timeout, max(1, lookahead)
        self.peers = {name: Peer(name) for name in plan.robots}
        self.traffic = NodeReservations()
        self.events: list[dict[str, Any]] = []
        self.dispatch: list[dict[str, Any]] = []
        self.rows: list[tuple[Any, ...]] = []
        self.inbox: queue.SimpleQueue[tuple[str, bytes]] = queue.SimpleQueue()
        self.run_dir = run_dir
        self.start = time.monotonic()
        self.link = MqttLink(
            url,
            f"master-{plan.name}-{id(self):x}"[:64],
            manufacturer,
            "master",
            lambda t, p, _r: self.inbox.put((t, p)),
            [
                (f"uagv/v2/{manufacturer}/+/{name}", 1)
                for name in ("state", "connection", "visualization")
            ],
        )

    def now(self) -> float:
        return time.monotonic() - self.start

    def event(self, kind: str, **details: Any) -> None:
        self.events.append({"t": round(self.now(), 3), "event": kind, **details})

    # ---------------------------------------------------------------- the loop

    def run(self, stop: Any = None) -> dict[str, Any]:
        """Until every task ended, the time limit passed or ``stop`` (an Event) is set."""
        self.start = time.monotonic()
        for peer in self.peers.values():
            peer.since = 0.0
        for task in self.plan.tasks:
            if task.robot is not None:
                self._assign(task, self.peers[task.robot])
        self.link.start(wait=30.0)
        status, reason = "failed", None
        try:
            while True:
                self._drain()
                self._assign_free_tasks()
                for peer in self.peers.values():
                    self._follow(peer)
                ended = self._ended()
                if ended is not None:
                    status, reason = ended
                    break
                if self.now() > self.plan.time_limit:
                    status, reason = "failed", f"time limit ({self.plan.time_limit:.0f} s) reached"
                    break
                if stop is not None and stop.is_set():
                    status, reason = "aborted", "interrupted"
                    break
                time.sleep(0.05)
        except KeyboardInterrupt:
            status, reason = "aborted", "interrupted by the user (Ctrl-C)"
        finally:
            if status != "succeeded":
                self._cancel_all()
            self.link.stop()
        return master_result(self, status, reason)

    def _drain(self) -> None:
        while True:
            try:
                topic_name, payload = self.inbox.get_nowait()
            except queue.Empty:
                return
            parts = split_topic(topic_name)
            if parts is None or parts[1] not in self.peers:
                continue
            peer = self.peers[parts[1]]
            try:
                doc = json.loads(payload)
            except ValueError:
                continue
            if not isinstance(doc, dict):
                continue
            if parts[2] == "connection":
                self._connection(peer, str(doc.get("connectionState")))
            elif parts[2] in ("state", "visualization"):
                if parts[2] == "state":
                    peer.state = doc
                    if peer.connection is None:
                        peer.connection, peer.since = "ONLINE", self.now()
                self._track(peer, doc)

    def _connection(self, peer: Peer, state: str) -> None:
        if state == peer.connection:
            return
        was = peer.connection
        peer.connection, peer.since = state, self.now()
        if state != "ONLINE":
            self.event("connection_" + state.lower(), robot=peer.serial)
        elif was is not None:
            self.event("reconnected", robot=peer.serial)

    def _track(self, peer: Peer, doc: dict[str, Any]) -> None:
        pos = doc.get("agvPosition")
        if not isinstance(pos, dict):
            return
        try:
            x, y, th = float(pos["x"]), float(pos["y"]), float(pos["theta"])
        except (KeyError, TypeError, ValueError):
            return
        vel = doc.get("velocity") or {}
        if peer.last_xy is not None:
            peer.distance += math.hypot(x - peer.last_xy[0], y - peer.last_xy[1])
        peer.last_xy = (x, y)
        self.rows.append(
            (peer.serial, round(self.now(), 3), x, y, th, vel.get("vx", 0.0), vel.get("omega", 0.0))
        )

    # ---------------------------------------------------------------- dispatch

    def _assign(self, task: TaskRoute, peer: Peer) -> None:
        task.assigned = peer.serial
        peer.queue.append(task)
        self.dispatch.append({"task": task.number, "robot": peer.serial, "t": round(self.now(), 3)})

    def _assign_free_tasks(self) -> None:
        for task in self.plan.tasks:
            if task.status != "pending" or task.assigned is not None:
                continue
            candidates = [p for p in self.peers.values() if p.online and p.last_xy is not None]
            if not candidates:
                continue
            goals = tuple(Pose2D(n.x, n.y, n.theta or 0.0) for n in task.nodes)
            work = [self._work(p) for p in candidates]
            if not goals:  # charge/undock where it stands: the robot with the least held
                best = min(work, key=lambda w: w.held_time)
                self._assign(task, self.peers[best.name])
                continue
            try:
                got = self.plan.dispatcher.assign(
                    FleetTask(str(task.index), goals), work, self._travel_time
                )
            except DispatchError as exc:
                self.event("dispatch_failed", task=task.number, reason=str(exc))
                continue
            self._assign(task, self.peers[got.robot])

    def _travel_time(self, robot: str, a: Pose2D, b: Pose2D) -> float:
        return float(self.plan.travel(a, b))

    def _work(self, peer: Peer) -> RobotWork:
        """What the dispatcher knows of ``peer``: where its held work ends and how long it
        takes (its order's nodes not yet reached, then its queue), travelled over the map."""
        assert peer.last_xy is not None
        here = Pose2D(peer.last_xy[0], peer.last_xy[1], 0.0)
        nodes: list[RouteNode] = []
        if peer.order is not None:
            nodes += peer.order.nodes[peer.order.last_first :]
        for task in peer.queue:
            nodes += task.nodes
        held = 0.0
        for n in nodes:
            goal = Pose2D(n.x, n.y, n.theta or 0.0)
            held += self._travel_time(peer.serial, here, goal)
            here = goal
        return RobotWork(peer.serial, here, held if math.isfinite(held) else 1e9)

    def _reassign(self, peer: Peer, why: str) -> None:
        """``peer``'s tasks (running and queued) go back to the pool (or fail)."""
        tasks = ([peer.order.task] if peer.order is not None else []) + peer.queue
        peer.order, peer.queue = None, []
        # held while it was away; now only where it was last seen stays its own
        last = (peer.state or {}).get("lastNodeId")
        nodes = [n for t in tasks for n in t.nodes] if last else []
        self.traffic.keep_only(peer.serial, {place(n) for n in nodes if n.node_id == last})
        others = [p for p in self.peers.values() if p is not peer and p.online]
        for task in tasks:
            task.status, task.assigned = "pending", None
            if task.robot is not None and not others:
                task.status, task.reason = "failed", f"{peer.serial} {why}; no other vehicle online"
                continue
            task.robot = None
            self.event("task_redispatched", task=task.number, robot=peer.serial, reason=why)

    # ---------------------------------------------------------------- following a vehicle

    def _follow(self, peer: Peer) -> None:
        if not peer.online:
            if peer.order is not None or peer.queue:
                waited = self.now() - peer.since
                if waited >= self.reassign_timeout:
                    why = (
                        "never came online"
                        if peer.connection is None
                        else f"went {peer.connection}"
                    )
                    self._reassign(peer, why)
            return
        order = peer.order
        if order is None:
            if peer.queue and peer.state is not None:
                self._send_new(peer, peer.queue.pop(0))
            return
        state = peer.state
        if state is None or state.get("orderId") != order.order_id:
            error = self._order_error(state, order) if state is not None else None
            if error is not None:
                self._finish(peer, "failed", error)
            elif self.now() - order.sent_at > ORDER_TIMEOUT:
                self._finish(peer, "failed", "the vehicle did not take the order")
            elif self.now() - order.last_sent > RESEND_AFTER:  # lost on the way (QoS 0)
                self._publish_order(peer, order, order.last_first)
            return
        if (
            int(state.get("orderUpdateId", 0)) < order.update_id
            and self.now() - order.last_sent > RESEND_AFTER
        ):
            self._publish_order(peer, order, order.last_first)
        error = self._order_error(state, order) or self._follow_actions(peer, order, state)
        last_seq = int(state.get("lastNodeSequenceId", -1))
        final_seq = 2 * (len(order.nodes) - 1)
        actions_done = all(
            a.get("actionStatus") in ("FINISHED", "FAILED") for a in state.get("actionStates", [])
        )
        if error is not None:
            self._finish(peer, "failed", error)
        elif not state.get("nodeStates") and last_seq == final_seq and actions_done:
            if order.task.charged(state):
                self._finish(peer, "succeeded", None)
        elif not state.get("nodeStates") and last_seq != final_seq:
            self._finish(
                peer, "failed", f"the vehicle dropped the order at node {state.get('lastNodeId')}"
            )
        else:
            self._extend(peer, order, last_seq // 2 if last_seq >= 0 else 0)

    def _follow_actions(self, peer: Peer, order: ActiveOrder, state: dict[str, Any]) -> str | None:
        """Note how the order's pick/drop went (in the task, an event when one ends); why
        the task fails when one failed."""
        task, failed = order.task, None
        for a in state.get("actionStates", []):
            action_id = a.get("actionId")
            if action_id not in order.actions:
                continue
            at, act = order.actions[action_id]
            status = str(a.get("actionStatus"))
            done = {
                "type": act.type,
                "node": order.nodes[at].node_id,
                "robot": peer.serial,
                "status": status,
                "result": a.get("resultDescription"),
            }
            before = task.actions.get(action_id, {}).get("status")
            task.actions[action_id] = done
            if status in ("FINISHED", "FAILED") and before != status:
                self.event(
                    f"action_{status.lower()}",
                    task=task.number,
                    robot=peer.serial,
                    action=act.type,
                    node=done["node"],
                    result=done["result"],
                )
            if status == "FAILED" and failed is None:
                failed = f"{act.type} at {done['node']} failed: {done['result'] or 'no reason'}"
        return failed

    def _order_error(self, state: dict[str, Any], order: ActiveOrder) -> str | None:
        for err in state.get("errors", []):
            refs = {
                r.get("referenceKey"): r.get("referenceValue")
                for r in err.get("errorReferences", [])
            }
            if err.get("errorLevel") == "FATAL" or (
                err.get("errorType") in ORDER_ERRORS and refs.get("orderId") == order.order_id
            ):
                return f"{err.get('errorType')}: {err.get('errorDescription', '')}".strip()
        return None

    def _finish(self, peer: Peer, status: str, reason: str | None) -> None:
        order = peer.order
        assert order is not None
        task = order.task
        peer.order = None
        self.traffic.keep_only(peer.serial, {place(order.nodes[-1])})
        if status == "failed" and task.retries > 0:
            task.retries -= 1
            self.event("task_retry", task=task.number, robot=peer.serial, reason=reason)
            peer.queue.insert(0, task)
            return
        task.status, task.reason = status, reason
        if status == "failed" and task.on_failure == "skip":
            task.status = "skipped"
        self.event(f"task_{task.status}", task=task.number, robot=peer.serial, reason=reason)

    def _send_new(self, peer: Peer, task: TaskRoute) -> None:
        peer.orders_made += 1
        order = start_order(
            task,
            f"{self.plan.name}-t{task.index}-{peer.serial}-{peer.orders_made}",
            peer.state or {},
            peer.last_xy,
        )
        order.released = self._grantable(peer, order, 0)
        order.sent_at = self.now()
        task.status = "running"
        peer.order = order
        peer.orders += 1
        self._publish_order(peer, order, 0)
        self.event("order_sent", task=task.number, robot=peer.serial, order=order.order_id)

    def _grantable(self, peer: Peer, order: ActiveOrder, last: int) -> int:
        """The furthest node index that may be released, ``lookahead`` past ``last``."""
        end = max(order.released, 0)
        for i in range(end + 1, min(last + self.lookahead, len(order.nodes) - 1) + 1):
            if not self.traffic.grant(peer.serial, order.nodes[i]):
                break
            end = i
        return end

    def _extend(self, peer: Peer, order: ActiveOrder, last: int) -> None:
        held = {place(n) for n in order.nodes[last : order.released + 1]}
        self.traffic.keep_only(peer.serial, held)
        end = self._grantable(peer, order, last)
        if end > order.released:
            start = order.released
            order.released = end
            order.update_id += 1
            peer.updates += 1
            self._publish_order(peer, order, start)

    def _publish_order(self, peer: Peer, order: ActiveOrder, first: int) -> None:
        """Nodes ``first``.. of ``order`` (the stitching node first on an update)."""
        body = order_body(order, first, self.plan)
        order.last_first, order.last_sent = first, self.now()
        self.link.publish("order", body, qos=0, serial=peer.serial)

    def _cancel_all(self) -> None:
        for peer in self.peers.values():
            if peer.order is not None and peer.online:
                body = cancel_body(peer.order)
                self.link.publish("instantActions", body, qos=0, serial=peer.serial)

    # ---------------------------------------------------------------- the end

    def _ended(self) -> tuple[str, str | None] | None:
        tasks = self.plan.tasks
        failed = [t for t in tasks if t.status == "failed" and t.on_failure != "skip"]
        if failed:
            t = failed[0]
            return "failed", f"task {t.number} ({t.type}) failed on {t.assigned}: {t.reason}"
        if all(t.status in ("succeeded", "skipped") for t in tasks):
            return "succeeded", None
        return None
