"""``serve`` and ``submit``: missions as a service, and a client of one."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Annotated, Optional

import typer

from agv_mission.cli.console import (
    EXIT_CODES,
    Overrides,
    Seed,
    err,
    failure,
    invalid,
    out,
    print_summary,
)
from agv_mission.missions.errors import MissionError


def serve(
    host: Annotated[
        str, typer.Option(help="address to bind (loopback unless --token)")
    ] = "127.0.0.1",
    port: Annotated[int, typer.Option(min=0, max=65535, help="0 picks a free port")] = 8080,
    data: Annotated[Path, typer.Option(help="run registry and run directories")] = Path("agv-data"),
    workers: Annotated[
        Optional[int], typer.Option(min=1, help="missions at once; default: the CPU count")  # noqa: UP007, UP045
    ] = None,
    queue_size: Annotated[int, typer.Option(min=1, help="queued runs before 429")] = 1000,
    backend: Annotated[str, typer.Option(help="local (processes) or ray")] = "local",
    address: Annotated[
        Optional[str], typer.Option(help="Ray cluster address (ray backend)")  # noqa: UP007, UP045
    ] = None,
    token: Annotated[
        Optional[str],  # noqa: UP007, UP045
        typer.Option(envvar="AGV_MISSION_TOKEN", help="bearer token every /api request needs"),
    ] = None,
) -> None:
    """Run missions as a service: HTTP API, run registry, workers, live stream."""
    from agv_mission.service.server import ServeError
    from agv_mission.service.server import serve as run_server

    try:
        run_server(
            host,
            port,
            data,
            workers or os.cpu_count() or 1,
            queue_size,
            backend,
            address,
            token,
        )
    except ServeError as exc:
        raise failure("cannot serve", str(exc)) from None


def submit(
    mission: Annotated[Path, typer.Argument(help="mission file")],
    server: Annotated[str, typer.Option(help="service URL, e.g. http://127.0.0.1:8080")],
    set_: Overrides = [],  # noqa: B006
    seed: Seed = None,
    follow: Annotated[bool, typer.Option("--follow", help="stream progress until it ends")] = False,
    token: Annotated[
        Optional[str],  # noqa: UP007, UP045
        typer.Option(envvar="AGV_MISSION_TOKEN", help="the service's bearer token"),
    ] = None,
) -> None:
    """Submit a mission to a running service; print the run id (and follow it live)."""
    from agv_mission.service import client

    try:
        run = client.submit(mission, set_, seed, server, token)
    except MissionError as exc:
        raise invalid(exc) from None
    except client.ClientError as exc:
        raise failure("error", str(exc)) from None
    out.print(run["id"], highlight=False)
    if not follow:
        raise typer.Exit(0)
    shown = {"t": -1e9}

    def show(message: dict) -> None:
        kind = message.get("type")
        if kind == "event":
            details = {k: v for k, v in message.items() if k not in ("type", "t", "event")}
            err.print(
                f"  t={message.get('t', 0):.1f} {message.get('event')} {details}",
                highlight=False,
                markup=False,
            )
        elif kind == "state" and message["t"] - shown["t"] >= 5.0:
            shown["t"] = message["t"]
            p = message.get("progress") or {}
            err.print(
                f"  t={message['t']:.1f} {message.get('status')} {p.get('detail', '')}",
                highlight=False,
                markup=False,
            )

    try:
        final = client.follow(server, run["id"], token, show)
    except client.ClientError as exc:
        raise failure("error", str(exc), 1) from None
    result = final.get("result")
    if result:
        print_summary(result)
    else:
        out.print(f"{final['status']}: {final.get('reason')}", highlight=False)
    raise typer.Exit(EXIT_CODES.get(final["status"], 1))
