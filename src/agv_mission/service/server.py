"""``agv-mission serve``: bind, print the URL, run uvicorn until SIGINT/SIGTERM."""

from __future__ import annotations

import ipaddress
import signal
import socket
import sys
from pathlib import Path
from typing import Any

LOOPBACK_NAMES = {"localhost", "ip6-localhost"}


class ServeError(Exception):
    """The service cannot start as asked (exit code 2)."""


def is_loopback(host: str) -> bool:
    if host.lower() in LOOPBACK_NAMES:
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False


def check_exposure(host: str, token: str | None) -> None:
    if not is_loopback(host) and not token:
        raise ServeError(
            f"refusing to serve on {host} without a token: anyone who can reach it could "
            "run missions. Give --token (or AGV_MISSION_TOKEN), or bind 127.0.0.1"
        )


def bind(host: str, port: int) -> socket.socket:
    family = socket.AF_INET6 if ":" in host.strip("[]") else socket.AF_INET
    sock = socket.socket(family, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    # accepted connections inherit it: h11 writes a response's head and body apart, and
    # Nagle's algorithm would hold the body for the client's delayed ACK (40 ms a request)
    sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    try:
        sock.bind((host.strip("[]"), port))
    except OSError as exc:
        sock.close()
        raise ServeError(f"cannot listen on {host}:{port}: {exc.strerror or exc}") from None
    sock.listen(128)
    sock.set_inheritable(True)
    return sock


def serve(
    host: str,
    port: int,
    data_dir: Path,
    workers: int,
    queue_size: int,
    backend: str,
    address: str | None,
    token: str | None,
    observers: Any = None,
) -> None:
    """Run the service in this process until it is told to stop. ``observers``: see
    :attr:`~agv_mission.service.context.Settings.observers`."""
    check_exposure(host, token)  # before the app's imports: a refusal is said at once
    if backend not in ("local", "ray"):
        raise ServeError(f"--backend {backend!r}: local or ray")
    import uvicorn

    from agv_mission.service.app import Settings, create_app

    try:
        data_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ServeError(f"cannot create --data {data_dir}: {exc.strerror or exc}") from None
    sock = bind(host, port)
    app = create_app(Settings(data_dir, workers, queue_size, backend, address, token, observers))
    config = uvicorn.Config(
        app,
        log_level="warning",
        lifespan="on",
        timeout_graceful_shutdown=3,
        ws_max_size=1 << 16,
        # compression would deflate every message once per client (its own zlib context):
        # the fan-out's largest cost, for bytes that mostly stay on one machine or LAN
        ws_per_message_deflate=False,
        server_header=False,
    )
    server = uvicorn.Server(config)
    bound_host, bound_port = sock.getsockname()[:2]
    shown = f"[{bound_host}]" if ":" in bound_host else bound_host
    sys.stdout.write(f"serving on http://{shown}:{bound_port}\n")
    sys.stdout.flush()
    # uvicorn re-raises the stop signal once it has shut down; a clean stop exits 0
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: None)
    server.run(sockets=[sock])
