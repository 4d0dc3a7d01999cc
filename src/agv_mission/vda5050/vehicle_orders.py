"""How a vehicle takes orders: acceptance as the standard's figure 8 (6.6.2), rejection as
its 6.6.4, updates stitched at the decision point. A part of :class:`~agv_mission.vda5050.
vehicle.Vehicle`, which holds the lock every method here runs under."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from pydantic import ValidationError

from agv_mission.geometry import Pose2D
from agv_mission.vda5050.body import VehicleBody
from agv_mission.vda5050.order_checks import first_error, order_problems
from agv_mission.vda5050.protocol import Edge, Node, Order
from agv_mission.vda5050.vehicle_actions import FINAL, ActionRun

START_RANGE = 0.5  # m: a new order's first node counts as reached within this (or its deviation)
#: Errors that stay until a new order is accepted (6.6.4).
ORDER_ERRORS = ("validationError", "orderError", "orderUpdateError", "noRouteError")


@dataclass
class OrderState:
    order_id: str = ""
    update_id: int = 0
    nodes: list[Node] = field(default_factory=list)  # not yet traversed, base then horizon
    edges: list[Edge] = field(default_factory=list)  # not yet left
    goal_id: int | None = None  # the body's goal for nodes[0]
    cancelled: bool = False


class VehicleOrders:
    """The order side of a vehicle: what it was sent, what it still has to traverse.

    Mixed into :class:`~agv_mission.vda5050.vehicle.Vehicle`, whose ``_error`` reports what
    is refused and whose ``_traverse`` reports a node as passed."""

    body: VehicleBody
    order: OrderState
    last_node_id: str
    last_node_seq: int
    actions: dict[str, ActionRun]
    errors: list[dict[str, Any]]

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
        if order.orderId != self.order.order_id:
            self._receive_new_order(order)
        else:
            self._receive_update(order)

    def _receive_new_order(self, order: Order) -> None:
        """A new ``orderId``: taken when the vehicle has no order running and stands at its
        first node (figure 8)."""
        o = self.order
        busy = bool(o.nodes) or any(
            a.status not in FINAL for a in self.actions.values() if a.node_seq is not None
        )
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

    def _receive_update(self, order: Order) -> None:
        """An update of the running order: newer, not cancelled, stitched at the decision
        point (6.6.2); one received twice is ignored (6.6.4.3)."""
        o = self.order
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
