"""A fleet view of VDA 5050 vehicles, as a master control sees them: their
``visualization``, ``state`` and ``connection`` on a broker, shown on the world's map in a
web page (``agv-mission vda5050 watch``).

Any vehicle counts, ours or anyone's: the view subscribes ``uagv/v2/{manufacturer}/+/...``
(manufacturer ``+`` by default). The vda5050 package stands beside ``service/`` on floor 7
and neither imports the other, so the view is a small HTTP server of its own (the page
polls one JSON document a few times a second) that reuses the dashboard's map drawing,
``service/static/mapview.js`` and ``app.css``, as files. The map a vehicle reports
(``mapId``) is a built-in world of that name or one of the worlds given.
"""

from __future__ import annotations

import contextlib
import json
import re
import threading
import time
from dataclasses import dataclass, field
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any
from urllib.parse import parse_qs, urlparse

from agv_mission.maps.builtin_worlds import BUILTIN_WORLDS
from agv_mission.maps.grid_image import grid_png
from agv_mission.maps.worlds import World
from agv_mission.missions.report.palette import robot_colour
from agv_mission.vda5050.protocol import split_topic
from agv_mission.vda5050.transport import BrokerUrl, MqttLink

TOPICS = ("state", "visualization", "connection")
STATIC = Path(__file__).parent / "static"
#: the dashboard's map drawing and style, shared as files (no import across floor 7)
DASHBOARD_STATIC = Path(__file__).parent.parent / "service" / "static"
FILES = {
    "/": (STATIC / "watch.html", "text/html; charset=utf-8"),
    "/static/watch.js": (STATIC / "watch.js", "text/javascript; charset=utf-8"),
    "/static/mapview.js": (DASHBOARD_STATIC / "mapview.js", "text/javascript; charset=utf-8"),
    "/static/app.css": (DASHBOARD_STATIC / "app.css", "text/css; charset=utf-8"),
}
MAX_ERRORS = 10  # per vehicle, the newest shown


@dataclass
class Watched:
    """One vehicle: the newest of each message, and when it came."""

    manufacturer: str
    serial: str
    connection: str | None = None
    state: dict[str, Any] = field(default_factory=dict)
    position: dict[str, Any] | None = None  # the newest agvPosition (state or visualization)
    velocity: dict[str, Any] | None = None
    seen: float = 0.0  # monotonic time of the last message
    messages: dict[str, int] = field(default_factory=dict)

    def doc(self, now: float) -> dict[str, Any]:
        s = self.state
        battery = s.get("batteryState") or {}
        actions = [
            {k: a.get(k) for k in ("actionId", "actionType", "actionStatus", "resultDescription")}
            for a in s.get("actionStates") or []
            if isinstance(a, dict)
        ]
        return {
            "manufacturer": self.manufacturer,
            "serial": self.serial,
            "connection": self.connection,
            "position": self.position,
            "velocity": self.velocity,
            "driving": s.get("driving"),
            "paused": s.get("paused"),
            "battery": battery.get("batteryCharge"),
            "charging": battery.get("charging"),
            "voltage": battery.get("batteryVoltage"),
            "order": s.get("orderId"),
            "orderUpdate": s.get("orderUpdateId"),
            "lastNode": s.get("lastNodeId"),
            "nodes": [
                {"nodeId": n.get("nodeId"), "released": n.get("released"), **n["nodePosition"]}
                for n in s.get("nodeStates") or []
                if isinstance(n, dict) and isinstance(n.get("nodePosition"), dict)
            ],
            "loads": [ld.get("loadId") for ld in s.get("loads") or [] if isinstance(ld, dict)],
            "actions": actions[-8:],
            "errors": [
                {k: e.get(k) for k in ("errorType", "errorLevel", "errorDescription")}
                for e in (s.get("errors") or [])[-MAX_ERRORS:]
                if isinstance(e, dict)
            ],
            "age": round(now - self.seen, 3),
            "messages": dict(self.messages),
        }


class FleetWatch:
    """The vehicles on a broker, kept up to date by their messages (MQTT's thread)."""

    def __init__(
        self, url: BrokerUrl, manufacturer: str = "+", worlds: list[World] | None = None
    ) -> None:
        self.url = url
        self.worlds = {w.name: w for w in worlds or []}
        self.vehicles: dict[tuple[str, str], Watched] = {}
        self._lock = threading.Lock()
        self._maps: dict[str, dict[str, Any] | None] = {}
        self.link = MqttLink(
            url,
            f"agv-mission-watch-{id(self):x}",
            manufacturer,
            "watch",
            self._message,
            [(f"uagv/v2/{manufacturer}/+/{name}", 0) for name in TOPICS],
        )

    def start(self, wait: float | None = 10.0) -> None:
        self.link.start(wait)

    def stop(self) -> None:
        self.link.stop()

    def _message(self, topic: str, payload: bytes, _retain: bool) -> None:
        parts = split_topic(topic)
        if parts is None or parts[2] not in TOPICS:
            return
        try:
            doc = json.loads(payload)
        except ValueError:
            return
        if not isinstance(doc, dict):
            return
        manufacturer, serial, kind = parts
        with self._lock:
            v = self.vehicles.setdefault((manufacturer, serial), Watched(manufacturer, serial))
            v.seen = time.monotonic()
            v.messages[kind] = v.messages.get(kind, 0) + 1
            if kind == "connection":
                v.connection = str(doc.get("connectionState"))
                return
            if kind == "state":
                v.state = doc
            if isinstance(doc.get("agvPosition"), dict):
                v.position = doc["agvPosition"]
            if isinstance(doc.get("velocity"), dict):
                v.velocity = doc["velocity"]

    def snapshot(self) -> dict[str, Any]:
        now = time.monotonic()
        with self._lock:
            vehicles = [v.doc(now) for _k, v in sorted(self.vehicles.items(), key=_serial_order)]
        # run.png's and the dashboard's colours: a fleet's vehicles (one manufacturer) in
        # serial order, as its mission lists its robots
        fleets: dict[str, int] = {}
        for v in vehicles:
            k = fleets[v["manufacturer"]] = fleets.get(v["manufacturer"], -1) + 1
            v["colour"] = robot_colour(k)
        return {
            "broker": str(self.url),
            "connected": self.link.connected.is_set(),
            "vehicles": vehicles,
        }

    def map_doc(self, map_id: str) -> dict[str, Any] | None:
        """The map ``map_id`` as the dashboard draws it (PNG grid, docks, rooms); None: no
        world of that name."""
        if map_id not in self._maps:
            world = self.worlds.get(map_id)
            if world is None and map_id in BUILTIN_WORLDS:
                world = BUILTIN_WORLDS[map_id]()
            self._maps[map_id] = None if world is None else _map_doc(world)
        return self._maps[map_id]


def _serial_order(item: tuple[tuple[str, str], Watched]) -> tuple[Any, ...]:
    """Vehicles by manufacturer, then serial number in natural order (agv2 before agv10):
    a fleet mission's robots named in order keep their order, and so their colours."""
    (manufacturer, serial), _ = item
    parts = re.split(r"(\d+)", serial)
    return (manufacturer, [(0, int(p), "") if p.isdigit() else (1, 0, p) for p in parts if p])


def _map_doc(world: World) -> dict[str, Any]:
    """The world's static map as map_saver writes it (254 free, 0 occupied, 205 unknown),
    PNG with row 0 at the top: the format of the dashboard's ``map`` message."""
    return {
        "type": "map",
        **grid_png(world.map),
        "docks": [
            {"name": d.name, "x": d.pose.x, "y": d.pose.y, "yaw": d.pose.yaw}
            for d in world.docks.values()
        ],
        "rooms": [
            {"label": r.label, "polygon": [[x, y] for x, y in r.polygon], "anchor": None}
            for r in world.rooms.values()
        ],
    }


class WatchServer(ThreadingHTTPServer):
    """``GET /`` the page, ``/api/vehicles`` the fleet, ``/api/map?id=MAP`` a map."""

    daemon_threads = True

    def __init__(self, watch: FleetWatch, host: str = "127.0.0.1", port: int = 8050) -> None:
        self.watch = watch
        super().__init__((host, port), _Handler)


class _Handler(BaseHTTPRequestHandler):
    server: WatchServer

    def do_GET(self) -> None:  # noqa: N802 (http.server's name)
        url = urlparse(self.path)
        if url.path in FILES:
            path, kind = FILES[url.path]
            self._send(HTTPStatus.OK, path.read_bytes(), kind)
        elif url.path == "/api/vehicles":
            self._json(self.server.watch.snapshot())
        elif url.path == "/api/map":
            map_id = (parse_qs(url.query).get("id") or [""])[0]
            doc = self.server.watch.map_doc(map_id)
            if doc is None:
                self._json({"detail": f"no world named {map_id!r}"}, HTTPStatus.NOT_FOUND)
            else:
                self._json(doc)
        else:
            self._json({"detail": "not found"}, HTTPStatus.NOT_FOUND)

    def _json(self, doc: Any, status: HTTPStatus = HTTPStatus.OK) -> None:
        self._send(status, json.dumps(doc).encode(), "application/json")

    def _send(self, status: HTTPStatus, body: bytes, kind: str) -> None:
        self.send_response(status)
        self.send_header("Content-Type", kind)
        self.send_header("Content-Length", str(len(body)))
        self.send_header("Cache-Control", "no-store")
        self.end_headers()
        with contextlib.suppress(BrokenPipeError, ConnectionResetError):
            self.wfile.write(body)

    def log_message(self, format: str, *args: Any) -> None:  # noqa: A002
        """Quiet: a page polling several times a second is not news."""
