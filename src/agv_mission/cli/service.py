"""``serve`` and ``submit``: missions as a service, and a client of one."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Annotated, Any, Optional

import typer

from agv_mission.cli.console import (
    EXIT_CODES,
    Overrides,
    Pace,
    Seed,
    failure,
    invalid,
    out,
    print_summary,
    progress_bar,
)
from agv_mission.missions.load.errors import MissionError

EXIT_UNAVAILABLE = 69  # sysexits' EX_UNAVAILABLE: the service could not be reached or refused


def run_observers(loaded: Any) -> list[Any]:
    """What ``run`` adds to a run, for each run of ``serve``: the bag (unless the mission
    says ``output.bag: false``). Module level, so a worker process receives it by name."""
    from agv_mission.bags.writer import BagWriter

    return [BagWriter().prepare()] if loaded.mission.output.bag else []


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
            observers=run_observers,
        )
    except ServeError as exc:
        raise failure("cannot serve", str(exc)) from None


def submit(
    mission: Annotated[Path, typer.Argument(help="mission file")],
    server: Annotated[
        str, typer.Option(help="service URL (default: serve's default address)")
    ] = "http://127.0.0.1:8080",
    set_: Overrides = [],  # noqa: B006
    seed: Seed = None,
    pace: Pace = None,
    follow: Annotated[bool, typer.Option("--follow", help="stream progress until it ends")] = False,
    token: Annotated[
        Optional[str],  # noqa: UP007, UP045
        typer.Option(envvar="AGV_MISSION_TOKEN", help="the service's bearer token"),
    ] = None,
) -> None:
    """Submit a mission to a running service, with the files it names (map, rooms,
    robot, recorder); print the run id, and with --follow what ``run`` prints.

    Exit codes: as ``run`` (0 succeeded, 1 failed, 2 invalid input, 3 error, 130
    aborted) once followed; 69 when the service cannot be reached or refuses."""
    from agv_mission.missions.report.summary import headline
    from agv_mission.service import client

    try:
        run = client.submit(mission, set_, seed, server, token, pace)
    except MissionError as exc:
        raise invalid(exc) from None
    except client.ClientError as exc:
        raise failure("service unavailable", str(exc), EXIT_UNAVAILABLE) from None
    out.print(run["id"], highlight=False)
    if not follow:
        raise typer.Exit(0)
    with progress_bar("{task.completed:.1f} sim s") as bar:
        job = bar.add_task(f"running {run['name']}", total=None)

        def show(message: dict[str, Any]) -> None:
            if message.get("type") == "state":
                bar.update(job, completed=float(message.get("t", 0.0)))

        try:
            final = client.follow(server, run["id"], token, show)
        except client.ClientError as exc:
            raise failure("service unavailable", str(exc), EXIT_UNAVAILABLE) from None
    result = final.get("result")
    if result and result.get("fleet") is not None:
        robots = result.get("robots") or {}
        names = ", ".join(f"{name} ({r.get('robot')})" for name, r in robots.items())
        out.print(
            f"[bold]{result['name']}[/]: {len(robots)} robots in {result.get('world')}: "
            f"{names}; seed {result.get('seed')}"
        )
        print_summary(result)
    elif result:
        out.print(
            f"[bold]{result['name']}[/]: {headline(result)} in "
            f"{result.get('world')} with {result.get('robot')}, seed {result.get('seed')}"
        )
        print_summary(result)
    else:
        failure(final["status"], str(final.get("reason")))
    raise typer.Exit(EXIT_CODES.get(final["status"], 1))
