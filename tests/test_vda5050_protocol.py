"""The pydantic message models against the VDA 5050 2.1.0 JSON schemas the package ships
(the same as ../shared's): the same fields, the schema's required fields required, and
what the models produce valid."""

from __future__ import annotations

from typing import Any

import pytest
from pydantic import BaseModel, ValidationError

from agv_mission.robots.builtin_robots import BUILTIN_ROBOTS
from agv_mission.vda5050 import protocol as m
from agv_mission.vda5050.factsheet import factsheet_body
from agv_mission.vda5050.master import TaskRoute
from agv_mission.vda5050.schemas import TOPICS, load_schema
from agv_mission.vda5050.transport import BrokerUrl, BrokerUrlError, MqttLink
from vda5050_peers import SCHEMAS, SHARED_SCHEMAS, schema_validators


def schema(name: str) -> dict[str, Any]:
    return load_schema(name)


def test_the_package_ships_the_schemas_with_their_licence() -> None:
    """A plain install validates messages: the six schemas and the MIT licence are package
    data, byte for byte the standard's (compared with ../shared's copy when present)."""
    assert {p.name for p in SCHEMAS.iterdir()} >= {f"{t}.schema" for t in TOPICS} | {"LICENSE.txt"}
    licence = (SCHEMAS / "LICENSE.txt").read_text(encoding="utf-8")
    assert "MIT" in licence or "Permission is hereby granted" in licence
    assert "Verband der Automobilindustrie" in licence
    for topic in TOPICS:
        assert load_schema(topic)["title"] or load_schema(topic)["$schema"]
        if SHARED_SCHEMAS.is_dir():
            shipped = (SCHEMAS / f"{topic}.schema").read_bytes()
            assert shipped == (SHARED_SCHEMAS / f"{topic}.schema").read_bytes()
    with pytest.raises(KeyError, match="no VDA 5050 schema"):
        load_schema("nope")


def at(doc: dict[str, Any], path: str) -> dict[str, Any]:
    """The object schema at a dotted path (``[]`` steps into array items, ``#x`` into a definition)."""
    node = doc
    for part in path.split("."):
        if part.startswith("#"):
            node = doc["definitions"][part[1:]]
            continue
        items = part.endswith("[]")
        node = node["properties"][part.rstrip("[]")]
        if items:
            node = node["items"]
        if "$ref" in node:
            node = doc["definitions"][node["$ref"].rsplit("/", 1)[1]]
    return node


PAIRS: list[tuple[type[BaseModel], str, str | None]] = [
    (m.Order, "order", None),
    (m.Node, "order", "nodes[]"),
    (m.NodePosition, "order", "nodes[].nodePosition"),
    (m.Edge, "order", "edges[]"),
    (m.Action, "order", "#action"),
    (m.InstantActions, "instantActions", None),
    (m.State, "state", None),
    (m.NodeState, "state", "nodeStates[]"),
    (m.EdgeState, "state", "edgeStates[]"),
    (m.AgvPosition, "state", "agvPosition"),
    (m.Velocity, "state", "velocity"),
    (m.Load, "state", "loads[]"),
    (m.ActionState, "state", "actionStates[]"),
    (m.BatteryState, "state", "batteryState"),
    (m.Error, "state", "errors[]"),
    (m.ErrorReference, "state", "errors[].errorReferences[]"),
    (m.SafetyState, "state", "safetyState"),
    (m.Information, "state", "information[]"),
    (m.Visualization, "visualization", None),
    (m.Connection, "connection", None),
    (m.Factsheet, "factsheet", None),
]


@pytest.mark.parametrize(("model", "topic", "path"), PAIRS, ids=[f"{p[0].__name__}" for p in PAIRS])
def test_models_have_the_schema_fields(
    model: type[BaseModel], topic: str, path: str | None
) -> None:
    doc = schema(topic)
    node = at(doc, path) if path else doc
    props = set(node["properties"])
    fields = set(model.model_fields)
    assert fields <= props, f"{model.__name__}: fields not in the schema: {fields - props}"
    required = {name for name, f in model.model_fields.items() if f.is_required()}
    assert (
        set(node.get("required", []))
        <= required
        | {"version", "manufacturer", "serialNumber", "headerId", "timestamp"} & required
    )
    assert set(node.get("required", [])) <= required, (
        f"{model.__name__}: optional here, required there"
    )


def test_what_the_models_produce_validates() -> None:
    validators = schema_validators()
    link = MqttLink(BrokerUrl("127.0.0.1", 1), "c", "agv-mission", "agv1", lambda *a: None, [])
    robot = BUILTIN_ROBOTS["waffle"]
    fact = m.Factsheet.model_validate(
        link.stamp("factsheet", factsheet_body(robot, 1.0, 0.1))
    ).doc()
    assert not list(validators["factsheet"].iter_errors(fact))
    conn = m.Connection.model_validate(
        link.stamp("connection", {"connectionState": "CONNECTIONBROKEN"})
    ).doc()
    assert not list(validators["connection"].iter_errors(conn))
    assert conn["headerId"] == 0 and link.stamp("connection", {})["headerId"] == 1  # per topic
    assert link.stamp("state", {})["headerId"] == 0


def test_incoming_orders_are_parsed_strictly() -> None:
    base = {
        "headerId": 0,
        "timestamp": "2026-01-01T00:00:00.00Z",
        "version": "2.1.0",
        "manufacturer": "m",
        "serialNumber": "s",
        "orderId": "o",
        "orderUpdateId": 0,
        "edges": [],
    }
    ok = m.Order.model_validate(
        {**base, "nodes": [{"nodeId": "a", "sequenceId": 0, "released": True, "actions": []}]}
    )
    assert ok.nodes[0].nodeId == "a"
    for bad in (
        {**base, "nodes": []},  # an order needs a node
        {**base, "nodes": [{"nodeId": "a", "sequenceId": "0", "released": True, "actions": []}]},
        {**base, "nodes": [{"nodeId": "a", "sequenceId": 0, "released": True}]},
        {
            **base,
            "orderUpdateId": -1,
            "nodes": [{"nodeId": "a", "sequenceId": 0, "released": True, "actions": []}],
        },
    ):
        with pytest.raises(ValidationError):
            m.Order.model_validate(bad)
    assert m.split_topic("uagv/v2/acme/agv7/state") == ("acme", "agv7", "state")
    assert m.split_topic("uagv/v1/acme/agv7/state") is None
    assert TaskRoute(0, "go_to", []).status == "pending"


def test_broker_urls() -> None:
    assert str(BrokerUrl.parse("mqtt://10.0.0.2:1884")) == "mqtt://10.0.0.2:1884"
    assert BrokerUrl.parse("mqtts://broker.local").port == 8883
    assert BrokerUrl.parse("mqtt://u:p@h:1").username == "u"
    for bad in ("http://h:1", "mqtt://", "h:1883", "mqtt://h:99999"):
        with pytest.raises(BrokerUrlError):
            BrokerUrl.parse(bad)
