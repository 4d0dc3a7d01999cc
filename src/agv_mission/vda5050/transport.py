"""MQTT for VDA 5050: broker URLs, the embedded broker (amqtt) and a paho-mqtt 2 client.

The embedded broker runs amqtt's asyncio broker on its own thread, so ``agv-mission vda5050
vehicles`` needs nothing installed; any other broker (mosquitto, EMQX, HiveMQ) is named by
URL. The client keeps paho's own network thread and reconnect loop: after a broker restart
it reconnects (1 s to 8 s back-off), subscribes again and calls ``on_connect`` so the owner
can publish its retained messages anew.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import os
import socket
import threading
from collections.abc import Callable
from dataclasses import dataclass
from itertools import count
from typing import Any
from urllib.parse import urlsplit

import paho.mqtt.client as mqtt

from agv_mission.vda5050.protocol import TOPIC_MODELS, VERSION, timestamp, topic

DEFAULT_HOST, DEFAULT_PORT = "127.0.0.1", 1883
KEEPALIVE = 15  # seconds; the standard suggests "around 15 seconds" for the heartbeat (6.14)
MAX_PAYLOAD = 4 * 1024 * 1024  # bytes a client takes before JSON parsing (1 MB orders fit)


class BrokerUrlError(ValueError):
    """A ``--broker`` that is not ``mqtt://HOST[:PORT]`` or ``mqtts://HOST[:PORT]``."""


@dataclass(frozen=True)
class BrokerUrl:
    host: str
    port: int
    tls: bool = False
    username: str | None = None
    password: str | None = None

    @classmethod
    def parse(cls, url: str, username: str | None = None, password: str | None = None) -> BrokerUrl:
        """``mqtt://HOST:PORT`` or ``mqtts://...``; user and password from the URL, the
        arguments or ``MQTT_USERNAME`` / ``MQTT_PASSWORD``."""
        parts = urlsplit(url)
        if parts.scheme not in ("mqtt", "mqtts") or not parts.hostname:
            raise BrokerUrlError(
                f"--broker {url!r}: expected mqtt://HOST:PORT or mqtts://HOST:PORT"
            )
        try:
            port = parts.port or (8883 if parts.scheme == "mqtts" else 1883)
        except ValueError as exc:
            raise BrokerUrlError(f"--broker {url!r}: {exc}") from None
        return cls(
            parts.hostname,
            port,
            parts.scheme == "mqtts",
            username or parts.username or os.environ.get("MQTT_USERNAME"),
            password or parts.password or os.environ.get("MQTT_PASSWORD"),
        )

    def __str__(self) -> str:
        return f"{'mqtts' if self.tls else 'mqtt'}://{self.host}:{self.port}"


def free_port(host: str = DEFAULT_HOST) -> int:
    with socket.socket() as s:
        s.bind((host, 0))
        return int(s.getsockname()[1])


class EmbeddedBroker:
    """amqtt's broker on a thread of its own: ``start()`` returns once it listens."""

    def __init__(self, host: str = DEFAULT_HOST, port: int = DEFAULT_PORT) -> None:
        self.url = BrokerUrl(host, port)
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._broker: Any = None

    def start(self, timeout: float = 10.0) -> BrokerUrl:
        from amqtt.broker import Broker

        config = {
            "listeners": {"default": {"type": "tcp", "bind": f"{self.url.host}:{self.url.port}"}},
            "plugins": {
                "amqtt.plugins.authentication.AnonymousAuthPlugin": {"allow_anonymous": True}
            },
        }
        for name in ("amqtt", "transitions"):
            logging.getLogger(name).setLevel(logging.CRITICAL)
        ready = threading.Event()
        failure: list[BaseException] = []
        loop = asyncio.new_event_loop()

        def serve() -> None:
            asyncio.set_event_loop(loop)
            try:
                self._broker = Broker(config, loop=loop)
                loop.run_until_complete(self._broker.start())
            except BaseException as exc:  # noqa: BLE001 (reported to start())
                failure.append(exc)
                ready.set()
                return
            ready.set()
            loop.run_forever()

        self._loop = loop
        self._thread = threading.Thread(target=serve, name="mqtt-broker", daemon=True)
        self._thread.start()
        if not ready.wait(timeout):
            raise RuntimeError(f"the embedded broker did not start within {timeout} s")
        if failure:
            raise OSError(f"the embedded broker cannot listen on {self.url}: {failure[0]}")
        return self.url

    def stop(self) -> None:
        loop, broker = self._loop, self._broker
        if loop is None or broker is None or not loop.is_running():
            return
        with contextlib.suppress(Exception):  # stopping anyway
            asyncio.run_coroutine_threadsafe(broker.shutdown(), loop).result(5.0)
        loop.call_soon_threadsafe(loop.stop)
        if self._thread is not None:
            self._thread.join(5.0)


Handler = Callable[[str, bytes, bool], None]


class MqttLink:
    """One paho client with a VDA 5050 identity: header ids counted per topic."""

    def __init__(
        self,
        url: BrokerUrl,
        client_id: str,
        manufacturer: str,
        serial: str,
        on_message: Handler,
        subscriptions: list[tuple[str, int]],
        will: tuple[str, dict[str, Any]] | None = None,
        on_connect: Callable[[], None] | None = None,
    ) -> None:
        self.url, self.manufacturer, self.serial = url, manufacturer, serial
        self._header_ids: dict[str, count[int]] = {}
        self._lock = threading.Lock()
        self._subs = subscriptions
        self._on_connect_cb = on_connect
        self._handler = on_message
        self.connected = threading.Event()
        self.connects = 0
        c = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=client_id, clean_session=True)
        if url.username:
            c.username_pw_set(url.username, url.password)
        if url.tls:
            c.tls_set()
        c.reconnect_delay_set(1, 8)
        c.max_queued_messages_set(0)
        if will is not None:
            name, body = will
            c.will_set(self.topic(name), json.dumps(self.stamp(name, body)), qos=1, retain=True)
        c.on_connect = self._connected
        c.on_disconnect = self._disconnected
        c.on_message = self._message
        self.client = c

    def topic(self, name: str, serial: str | None = None, manufacturer: str | None = None) -> str:
        return topic(manufacturer or self.manufacturer, serial or self.serial, name)

    def stamp(self, name: str, body: dict[str, Any], serial: str | None = None) -> dict[str, Any]:
        """``body`` with the header of topic ``name`` (the next headerId of that topic)."""
        key = f"{serial or self.serial}/{name}"
        with self._lock:
            ids = self._header_ids.setdefault(key, count())
            header_id = next(ids)
        return {
            "headerId": header_id,
            "timestamp": timestamp(),
            "version": VERSION,
            "manufacturer": self.manufacturer,
            "serialNumber": serial or self.serial,
            **body,
        }

    def start(self, wait: float | None = 10.0) -> None:
        """Connect (retrying in the background while the broker is away)."""
        try:
            self.client.connect(self.url.host, self.url.port, keepalive=KEEPALIVE)
        except OSError:
            self.client.connect_async(self.url.host, self.url.port, keepalive=KEEPALIVE)
        self.client.loop_start()
        if wait and not self.connected.wait(wait):
            raise ConnectionError(f"no MQTT broker answers at {self.url}")

    def publish(
        self,
        name: str,
        body: dict[str, Any],
        *,
        qos: int = 0,
        retain: bool = False,
        serial: str | None = None,
    ) -> dict[str, Any]:
        """Stamp ``body`` with its header, build it through the topic's model (so what goes
        out has the schema's shape) and publish it on topic ``name``; the message."""
        doc = TOPIC_MODELS[name].model_validate(self.stamp(name, body, serial)).doc()
        self.client.publish(self.topic(name, serial), json.dumps(doc), qos=qos, retain=retain)
        return doc

    def publish_raw(
        self, topic_name: str, payload: bytes | str, qos: int = 0, retain: bool = False
    ) -> Any:
        return self.client.publish(topic_name, payload, qos=qos, retain=retain)

    def stop(self) -> None:
        self.client.disconnect()
        self.client.loop_stop()

    def kill(self) -> None:
        """Drop the socket without DISCONNECT: the broker sends the last will."""
        self.client.loop_stop()
        sock = self.client.socket()
        if sock is not None:
            sock.close()

    def _connected(self, client: mqtt.Client, _u: Any, _f: Any, reason: Any, _p: Any) -> None:
        if reason.is_failure:
            return
        for sub, qos in self._subs:
            client.subscribe(sub, qos)
        self.connects += 1
        if self._on_connect_cb is not None:
            self._on_connect_cb()  # before ``connected``: what it publishes goes out first
        self.connected.set()

    def _disconnected(self, *_args: Any) -> None:
        self.connected.clear()

    def _message(self, _c: mqtt.Client, _u: Any, msg: mqtt.MQTTMessage) -> None:
        try:
            self._handler(msg.topic, msg.payload, bool(msg.retain))
        except Exception:  # noqa: BLE001 (one bad message must not stop the network thread)
            logging.getLogger(__name__).exception("handling a message on %s", msg.topic)
