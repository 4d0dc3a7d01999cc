"""The vehicle's factsheet (6.15), from the robot description and the vehicle's own limits."""

from __future__ import annotations

import math
from typing import Any

from agv_mission.robots.description import RobotDescription

#: What the vehicle can do, per action: the scopes the standard's table 6.8.1 allows it in
#: and its parameters. ``pick``/``drop`` are a simulated load handler.
ACTIONS: dict[str, dict[str, Any]] = {
    "startPause": {"scopes": ["INSTANT"], "params": []},
    "stopPause": {"scopes": ["INSTANT"], "params": []},
    "cancelOrder": {"scopes": ["INSTANT"], "params": []},
    "stateRequest": {"scopes": ["INSTANT"], "params": []},
    "factsheetRequest": {"scopes": ["INSTANT"], "params": []},
    "logReport": {"scopes": ["INSTANT"], "params": [("reason", "STRING")]},
    "initPosition": {
        "scopes": ["INSTANT", "NODE"],
        "params": [
            ("x", "FLOAT"),
            ("y", "FLOAT"),
            ("theta", "FLOAT"),
            ("mapId", "STRING"),
            ("lastNodeId", "STRING"),
        ],
    },
    "startCharging": {"scopes": ["INSTANT", "NODE"], "params": []},
    "stopCharging": {"scopes": ["INSTANT", "NODE"], "params": []},
    "pick": {
        "scopes": ["NODE"],
        "params": [("duration", "FLOAT"), ("loadId", "STRING"), ("loadType", "STRING")],
    },
    "drop": {"scopes": ["NODE"], "params": [("duration", "FLOAT"), ("loadId", "STRING")]},
    "waitForTrigger": {"scopes": ["NODE"], "params": [("triggerType", "STRING")]},
}

#: The vehicle's protocol limits (it checks incoming messages against them).
MAX_MESSAGE = 256 * 1024  # bytes of one order or instantActions message
MAX_ID = 128  # characters of an id
MAX_NODES = 1000
MAX_NODE_ACTIONS = 16
MAX_INSTANT_ACTIONS = 32

#: Payload of the TurtleBot3 models (ROBOTIS e-manual specifications), kg.
PAYLOAD = {"burger": 15.0, "waffle": 30.0, "waffle_pi": 30.0}


def factsheet_body(
    robot: RobotDescription, state_interval: float, viz_interval: float
) -> dict[str, Any]:
    """The factsheet's fields after the header."""
    r = robot.footprint_radius
    outline = [
        {"x": round(r * math.cos(k * math.pi / 4), 4), "y": round(r * math.sin(k * math.pi / 4), 4)}
        for k in range(8)
    ]
    if robot.footprint is not None:  # the robot's own outline
        outline = [{"x": round(x, 4), "y": round(y, 4)} for x, y in robot.footprint]
    return {
        "typeSpecification": {
            "seriesName": robot.name,
            "seriesDescription": "agv-mission simulated differential-drive robot (MuJoCo)",
            "agvKinematic": "DIFF",
            "agvClass": "CARRIER",
            "maxLoadMass": PAYLOAD.get(robot.name, 0.0),
            "localizationTypes": ["NATURAL"],
            "navigationTypes": ["AUTONOMOUS"],
        },
        "physicalParameters": {
            "speedMin": 0.0,
            "speedMax": robot.max_linear_velocity,
            "angularSpeedMin": 0.0,
            "angularSpeedMax": robot.max_angular_velocity,
            "accelerationMax": robot.max_linear_acceleration,
            "decelerationMax": robot.max_linear_acceleration,
            "heightMin": robot.lidar.height,
            "heightMax": robot.lidar.height,
            "width": 2 * r,
            "length": 2 * r,
        },
        "protocolLimits": {
            "maxStringLens": {"msgLen": MAX_MESSAGE, "idLen": MAX_ID, "idNumericalOnly": False},
            "maxArrayLens": {
                "order.nodes": MAX_NODES,
                "order.edges": MAX_NODES - 1,
                "node.actions": MAX_NODE_ACTIONS,
                "edge.actions": 0,
                "instantActions": MAX_INSTANT_ACTIONS,
            },
            "timing": {
                "minOrderInterval": 0.0,
                "minStateInterval": 0.0,
                "defaultStateInterval": state_interval,
                "visualizationInterval": viz_interval,
            },
        },
        "protocolFeatures": {
            "optionalParameters": [
                {"parameter": "order.nodes.nodePosition", "support": "REQUIRED"},
                {"parameter": "order.nodes.nodePosition.theta", "support": "SUPPORTED"},
                {
                    "parameter": "order.nodes.nodePosition.allowedDeviationXY",
                    "support": "SUPPORTED",
                },
                {
                    "parameter": "order.nodes.nodePosition.allowedDeviationTheta",
                    "support": "SUPPORTED",
                },
                {"parameter": "order.edges.maxSpeed", "support": "SUPPORTED"},
            ],
            "agvActions": [
                {
                    "actionType": name,
                    "actionScopes": spec["scopes"],
                    "actionParameters": [
                        {"key": key, "valueDataType": kind, "isOptional": True}
                        for key, kind in spec["params"]
                    ],
                }
                for name, spec in ACTIONS.items()
            ],
        },
        "agvGeometry": {"envelopes2d": [{"set": "footprint", "polygonPoints": outline}]},
        "loadSpecification": {"loadPositions": ["deck"]},
    }
