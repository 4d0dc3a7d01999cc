"""What the master sends: a task's route as a VDA 5050 order, the order's updates, its cancel.

An order starts where the vehicle stands, under its ``lastNodeId`` (6.6.3.1), then visits the
task's nodes; node ``i`` has sequence id ``2 i``, the edge into it ``2 i - 1``, and edge ids
are ``from-to``. Nodes up to the decision point (``released``) are base, the rest horizon; an
update resends the route from its stitching node (6.6.2). The dispatch loop that decides what
to send and when is :class:`~agv_mission.vda5050.master.Master`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from agv_mission.vda5050.protocol import deviation_angle, schema_angle
from agv_mission.vda5050.routes import MasterPlan, OrderAction, RouteNode, TaskRoute

START_DEVIATION = 0.5  # m: the first node is where the vehicle stands, within this


@dataclass
class ActiveOrder:
    """A task's order on one vehicle, as far as it was sent."""

    task: TaskRoute
    order_id: str
    nodes: list[RouteNode]  # the start node first
    update_id: int = 0
    released: int = 0  # index of the decision point (last released node)
    sent_at: float = 0.0
    last_first: int = 0  # the first node index of the message last sent
    #: node actions by actionId: (node index, the action)
    actions: dict[str, tuple[int, OrderAction]] = field(default_factory=dict)
    last_sent: float = 0.0


def start_order(
    task: TaskRoute,
    order_id: str,
    state: dict[str, Any],
    last_xy: tuple[float, float] | None,
) -> ActiveOrder:
    """``task`` as order ``order_id``, its first node where the vehicle stands: its state's
    ``agvPosition`` (optional), else where its visualization last showed it."""
    x, y = last_xy or (0.0, 0.0)
    pos = state.get("agvPosition") or {"x": x, "y": y}
    here = RouteNode(
        str(state.get("lastNodeId") or "start"),
        float(pos.get("x", x)),
        float(pos.get("y", y)),
        None,
        task.start_actions,
    )
    order = ActiveOrder(task, order_id, [here, *task.nodes])
    for i, n in enumerate(order.nodes):
        for k, act in enumerate(n.actions):
            order.actions[f"{order.order_id}-n{2 * i}-{k}-{act.type}"] = (i, act)
    return order


def order_body(order: ActiveOrder, first: int, plan: MasterPlan) -> dict[str, Any]:
    """The ``order`` message's body: nodes ``first``.. of ``order`` and the edges between."""
    nodes, edges = [], []
    for i in range(first, len(order.nodes)):
        n = order.nodes[i]
        released = i <= order.released
        nodes.append(
            {
                "nodeId": n.node_id,
                "sequenceId": 2 * i,
                "released": released,
                "nodePosition": _node_position(n, i == 0, plan),
                "actions": [
                    act.doc(action_id) for action_id, (at, act) in order.actions.items() if at == i
                ],
            }
        )
        if i > first:
            a = order.nodes[i - 1]
            edges.append(
                {
                    "edgeId": f"{a.node_id}-{n.node_id}",
                    "sequenceId": 2 * i - 1,
                    "released": released,
                    "startNodeId": a.node_id,
                    "endNodeId": n.node_id,
                    "actions": [],
                }
            )
    return {
        "orderId": order.order_id,
        "orderUpdateId": order.update_id,
        "nodes": nodes,
        "edges": edges,
    }


def _node_position(n: RouteNode, start: bool, plan: MasterPlan) -> dict[str, Any]:
    """The start node: where the vehicle stands, any heading; the others: the mission's
    goal tolerances, ``theta`` when the task gives a heading."""
    pos: dict[str, Any] = {"x": n.x, "y": n.y, "mapId": plan.map_id}
    if start:
        pos["allowedDeviationXY"] = START_DEVIATION
        return pos
    pos["allowedDeviationXY"] = plan.xy_tolerance
    if n.theta is not None:  # within the schema's [-pi, pi] after rounding
        pos["theta"] = schema_angle(n.theta)
        pos["allowedDeviationTheta"] = deviation_angle(plan.yaw_tolerance)
    return pos


def cancel_body(order: ActiveOrder) -> dict[str, Any]:
    """The ``instantActions`` body that cancels ``order`` (6.8.1 ``cancelOrder``)."""
    return {
        "actions": [
            {
                "actionId": f"cancel-{order.order_id}",
                "actionType": "cancelOrder",
                "blockingType": "HARD",
            }
        ]
    }
