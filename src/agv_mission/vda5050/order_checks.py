"""What a VDA 5050 vehicle reports of an order and itself, as plain functions: why an order
cannot be taken (6.6.4.2), node states, the battery, a validation error's first line."""

from __future__ import annotations

import math
from typing import Any

from pydantic import ValidationError

from agv_mission.vda5050 import factsheet as fs
from agv_mission.vda5050.body import BodySnapshot
from agv_mission.vda5050.protocol import Node, Order


def order_problems(order: Order, map_id: str) -> list[tuple[str, str, str]]:
    """What makes ``order`` one a vehicle on map ``map_id`` cannot take (6.6.4.2): (key,
    value, why) of each problem, the reference key first."""
    out: list[tuple[str, str, str]] = []
    nodes, edges = order.nodes, order.edges
    if len(nodes) > fs.MAX_NODES:
        out.append(("orderId", order.orderId, f"more than {fs.MAX_NODES} nodes"))
    if len(edges) != len(nodes) - 1:
        out.append(
            (
                "orderId",
                order.orderId,
                f"{len(nodes)} nodes need {len(nodes) - 1} edges, not {len(edges)}",
            )
        )
        return out
    if not nodes[0].released:
        out.append(("nodeId", nodes[0].nodeId, "the first node is not released"))
    released = True
    for i, node in enumerate(nodes):
        if node.sequenceId != nodes[0].sequenceId + 2 * i:
            out.append(("nodeId", node.nodeId, f"sequenceId {node.sequenceId} out of order"))
        if node.nodePosition is None:
            out.append(
                (
                    "nodeId",
                    node.nodeId,
                    "no nodePosition (this vehicle navigates freely to positions)",
                )
            )
        elif node.nodePosition.mapId != map_id:
            out.append(
                (
                    "nodeId",
                    node.nodeId,
                    f"mapId {node.nodePosition.mapId!r}: this vehicle is on {map_id!r}",
                )
            )
        if node.released and not released:
            out.append(("nodeId", node.nodeId, "a released node after the horizon began"))
        released = released and node.released
        if len(node.actions) > fs.MAX_NODE_ACTIONS:
            out.append(("nodeId", node.nodeId, f"more than {fs.MAX_NODE_ACTIONS} actions"))
        for action in node.actions:
            spec = fs.ACTIONS.get(action.actionType)
            if spec is None or "NODE" not in spec["scopes"]:
                why = "unknown action" if spec is None else "not allowed on a node"
                out.append(("actionId", action.actionId, f"{action.actionType}: {why}"))
    for i, edge in enumerate(edges):
        a, b = nodes[i], nodes[i + 1]
        if (
            edge.sequenceId != a.sequenceId + 1
            or edge.startNodeId != a.nodeId
            or edge.endNodeId != b.nodeId
        ):
            out.append(("edgeId", edge.edgeId, f"does not join {a.nodeId} and {b.nodeId}"))
        if edge.released and not b.released or not edge.released and b.released:
            out.append(("edgeId", edge.edgeId, "released differs from its end node's"))
        if edge.trajectory is not None:
            out.append(("edgeId", edge.edgeId, "trajectory: this vehicle plans its own path"))
        if edge.actions:
            out.append(
                (
                    "edgeId",
                    edge.edgeId,
                    "edge actions are not supported (factsheet: edge.actions 0)",
                )
            )
        if edge.maxSpeed is not None and edge.maxSpeed <= 0:
            out.append(("edgeId", edge.edgeId, f"maxSpeed {edge.maxSpeed} must be positive"))
    return out


def battery_state(snap: BodySnapshot) -> dict[str, Any]:
    """``batteryState`` from the robot's battery; a robot without one reports the standard's
    "good" level (80 %), as an AGV that only knows good or bad does."""
    if snap.battery is None:
        return {"batteryCharge": 80.0, "charging": False}
    out: dict[str, Any] = {
        "batteryCharge": round(100.0 * snap.battery, 3),
        "charging": snap.charging,
    }
    if snap.voltage is not None:
        out["batteryVoltage"] = snap.voltage
    return out


def node_state(n: Node) -> dict[str, Any]:
    d: dict[str, Any] = {"nodeId": n.nodeId, "sequenceId": n.sequenceId, "released": n.released}
    if n.nodePosition is not None:
        d["nodePosition"] = n.nodePosition.doc()
    return d


def first_error(exc: ValidationError) -> str:
    e = exc.errors()[0]
    where = ".".join(str(p) for p in e["loc"])
    return f"{where}: {e['msg']}"[:300]


def number(value: Any, default: float) -> float:
    try:
        out = float(value)
    except (TypeError, ValueError):
        return default
    return out if math.isfinite(out) and out >= 0 else default
