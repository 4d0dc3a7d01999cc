"""``WS /api/runs/{run_id}/live``: a run's live stream to one client, thinned to what the
client can take, and the client's own messages (``ping``, ``cmd_vel``)."""

from __future__ import annotations

import asyncio
import contextlib
import json
import math

from fastapi import APIRouter, WebSocket, WebSocketDisconnect

from agv_mission.service.access import authorised, same_origin
from agv_mission.service.context import Service
from agv_mission.service.hub import KIND_BUDGET, Client
from agv_mission.service.runs import RunManager, UnknownRobot

MAX_WS_MESSAGE = 4096  # bytes of a client message on the live stream
SEND_PERIOD = 0.05  # seconds between two sends to one live client (20 batches a second)


def live_router(service: Service) -> APIRouter:
    """The live stream of one service's runs."""
    router = APIRouter()
    manager, registry, token = service.manager, service.registry, service.settings.token

    @router.websocket("/api/runs/{run_id}/live")
    async def live(websocket: WebSocket, run_id: str) -> None:
        if not authorised(
            token, websocket.headers.get("authorization"), websocket.query_params.get("token")
        ):
            await websocket.close(code=4401, reason="missing or wrong token")
            return
        if not same_origin(websocket.headers.get("origin"), websocket.headers.get("host")):
            await websocket.close(code=4403, reason="cross-origin")
            return
        run = await registry.aget(run_id)
        if run is None:
            await websocket.close(code=4404, reason="no such run")
            return
        await websocket.accept()
        hub = await manager.live.hub_for(run_id, run)
        client = hub.subscribe(_rate(websocket.query_params.get("rate")))
        sender = asyncio.create_task(_send_loop(websocket, client))
        try:
            while True:
                text = await websocket.receive_text()
                if len(text) > MAX_WS_MESSAGE:
                    _tell(client, "error", message=f"a message is at most {MAX_WS_MESSAGE} bytes")
                    continue
                _client_message(manager, run_id, client, text)
        except (WebSocketDisconnect, RuntimeError):
            pass
        finally:
            hub.unsubscribe(client)
            sender.cancel()
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await sender

    return router


async def _send_loop(websocket: WebSocket, client: Client) -> None:
    """Drain one client's queue, at most every :data:`SEND_PERIOD` seconds (a status
    change or the end at once): a message wakes no client by itself (that would be one
    task switch per client per worker step); what arrived meanwhile goes out together,
    thinned. The hub never waits for this."""
    loop = asyncio.get_running_loop()
    while True:
        await client.ready.wait()
        client.ready.clear()
        client.urgent.clear()
        started = loop.time()
        items, due = client.take(started)
        for kind, text in items:
            await websocket.send_text(text)
            if kind == "end":
                await websocket.close(code=1000)
                return
        if client.dropped:
            await websocket.close(code=1013, reason="too slow")
            return
        if due is not None:  # a held message falls due then
            loop.call_at(max(due, started + SEND_PERIOD), client.ready.set)
        rest = started + SEND_PERIOD - loop.time()
        if rest > 0 and not client.urgent.is_set():
            wake = loop.call_later(rest, client.urgent.set)
            await client.urgent.wait()
            wake.cancel()


def _rate(given: str | None) -> float:
    """``?rate=N``: at most N messages of each frequent kind (state, scan, particles,
    horizon) per wall second for this client (1 to the hub's budget; default: the budget)."""
    try:
        rate = float(given) if given is not None else KIND_BUDGET
    except ValueError:
        rate = KIND_BUDGET
    return min(max(rate, 1.0), KIND_BUDGET) if math.isfinite(rate) else KIND_BUDGET


def _client_message(manager: RunManager, run_id: str, client: Client, text: str) -> None:
    """Act on one client message; a frame that is no valid command answers an ``error``
    message, a ``cmd_vel`` beyond the robot's limits a ``clamped`` one."""
    try:
        message = json.loads(text)
    except ValueError as exc:
        _tell(client, "error", message=f"not JSON: {exc}")
        return
    if not isinstance(message, dict):
        _tell(client, "error", message='a message is a JSON object with a "type"')
        return
    kind = message.get("type")
    if kind == "ping":
        client.put("pong", '{"type":"pong"}')
    elif kind == "cmd_vel":
        v, w, robot = message.get("v", 0.0), message.get("w", 0.0), message.get("robot")
        if not all(_finite_number(x) for x in (v, w)):
            _tell(client, "error", message="cmd_vel needs finite numbers v (m/s) and w (rad/s)")
            return
        if robot is not None and not isinstance(robot, str):
            _tell(client, "error", message="cmd_vel's robot is a robot's name (a string)")
            return
        try:
            sent = manager.cmd_vel(run_id, robot, float(v), float(w))
        except UnknownRobot as exc:
            _tell(client, "error", message=f"cmd_vel: {exc}", robot=robot)
            return
        if sent is None:
            _tell(client, "error", message="the run is not active: nothing to drive")
        elif sent[1:] != (float(v), float(w)):
            name = sent[0]
            v_max, w_max = manager.limits(run_id, name) or (math.inf, math.inf)
            _tell(
                client,
                "clamped",
                robot=name,
                v=sent[1],
                w=sent[2],
                requested={"v": v, "w": w},
                limits={"v": v_max, "w": w_max},
                message=f"cmd_vel clamped to the robot's limits: |v| <= {v_max} m/s, "
                f"|w| <= {w_max} rad/s",
            )
    else:
        _tell(client, "error", message=f"unknown message type {kind!r}: send ping or cmd_vel")


def _finite_number(x: object) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)


def _tell(client: Client, kind: str, **fields: object) -> None:
    """A message to this client alone."""
    client.put(kind, json.dumps({"type": kind, **fields}), urgent=True)


LIVE_DOC = """
## The live stream

`WS /api/runs/{id}/live` (with `?token=TOKEN` when a token is set; `?rate=N` thins the
frequent kinds to N a second) sends JSON text messages, each with a `type`: `state`
(`t`, `pose`, `estimate`, `v`, `w`, `status`, `task`), `scan` (`t`, `points`), `plan`
(`t`, `path`), `tree` (`nodes`), `event` (an event of `result.json`) and, once, `end`
(`status`, `reason`). At the start, `robots` lists every robot (`name`, `type`, `colour`,
`radius`, `start`, `tree`; schema `StreamRobots`), and every per-robot message names its
robot in `robot`. A client sends `{"type": "cmd_vel", "v": 0.1, "w": 0.0, "robot": "agv1"}`
to drive a robot whose current task is `teleop` (`robot` may be left out when the run has
one robot; an unknown one, or none in a fleet run, is answered `error`), or
`{"type": "ping"}` (answered `pong`). A command beyond
the robot's limits is clamped and answered `clamped` (`v`, `w` sent, `requested`, `limits`);
a frame that is no valid command is answered `error` (`message`).
"""
