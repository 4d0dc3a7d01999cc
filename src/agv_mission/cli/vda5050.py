"""``vda5050 vehicles`` and ``vda5050 dispatch``: VDA 5050 over MQTT, vehicle and master."""

from __future__ import annotations

import signal
import threading
import time
from pathlib import Path
from typing import Annotated, Any, Optional

import typer
from rich.markup import escape

from agv_mission.cli.console import EXIT_CODES, Overrides, Seed, failure, invalid, out
from agv_mission.missions.load.errors import MissionError

app = typer.Typer(
    no_args_is_help=True,
    help="VDA 5050 2.1 over MQTT: simulated vehicles, and missions as a master control.",
)

Broker = Annotated[
    Optional[str],  # noqa: UP045
    typer.Option(help="mqtt://HOST:PORT of a broker; default: start one on 127.0.0.1:1883"),
]
Manufacturer = Annotated[str, typer.Option(help="the topics' manufacturer level")]
Username = Annotated[Optional[str], typer.Option(help="broker user (or MQTT_USERNAME)")]  # noqa: UP045
Password = Annotated[Optional[str], typer.Option(help="broker password (or MQTT_PASSWORD)")]  # noqa: UP045
EmbeddedPort = Annotated[int, typer.Option(min=1, max=65535, help="port of the embedded broker")]


def _broker(
    url: str | None, username: str | None, password: str | None, port: int
) -> tuple[Any, Any]:
    """(the broker's URL, the embedded broker or None); exit 2 on a bad URL or a busy port."""
    from agv_mission.vda5050.transport import BrokerUrl, BrokerUrlError, EmbeddedBroker

    if url is not None:
        try:
            return BrokerUrl.parse(url, username, password), None
        except BrokerUrlError as exc:
            raise failure("invalid input", str(exc)) from None
    embedded = EmbeddedBroker(port=port)
    try:
        found = embedded.start()
    except (OSError, RuntimeError) as exc:
        raise failure("broker", f"{exc} (is a broker running already? give --broker)", 3) from None
    out.print(f"broker: {found} (embedded)", highlight=False)
    return found, embedded


def _stop_on_signals(stop: threading.Event) -> None:
    def handler(signum: int, _frame: object) -> None:
        stop.set()

    signal.signal(signal.SIGTERM, handler)
    signal.signal(signal.SIGINT, handler)


@app.command()
def vehicles(
    mission: Annotated[
        Path, typer.Argument(help="mission or fleet mission file (its tasks are ignored)")
    ],
    broker: Broker = None,
    manufacturer: Manufacturer = "agv-mission",
    time_scale: Annotated[
        float, typer.Option(min=0.01, max=100.0, help="simulated seconds per wall second")
    ] = 1.0,
    username: Username = None,
    password: Password = None,
    embedded_port: EmbeddedPort = 1883,
    duration: Annotated[
        Optional[float],  # noqa: UP045
        typer.Option(min=0.0, help="stop after this many wall seconds (default: until Ctrl-C)"),
    ] = None,
    set_: Overrides = [],  # noqa: B006
    seed: Seed = None,
) -> None:
    """Every robot of MISSION as a VDA 5050 vehicle, until Ctrl-C or SIGTERM."""
    from agv_mission.vda5050.vehicle_set import VehicleSet, load_vehicles

    try:
        fleet_mission = load_vehicles(mission, set_, seed)
    except MissionError as exc:
        raise invalid(exc) from None
    url, embedded = _broker(broker, username, password, embedded_port)
    stop = threading.Event()
    _stop_on_signals(stop)
    fleet = VehicleSet(fleet_mission, url, manufacturer, time_scale)
    try:
        fleet.start()
    except (RuntimeError, ConnectionError) as exc:
        fleet.stop()
        if embedded is not None:
            embedded.stop()
        raise failure("vehicles", str(exc), 3) from None
    world = fleet_mission.loaded.world.name
    for spec in fleet_mission.vehicles:
        out.print(
            f"{spec.serial}: uagv/v2/{manufacturer}/{spec.serial}/# ({spec.description.name} in "
            f"{world}, time scale {time_scale:g})",
            highlight=False,
            markup=False,
        )
    code = 0
    end = None if duration is None else time.monotonic() + duration
    try:
        while not stop.is_set():
            problem = fleet.failed()
            if problem:  # a simulation that stopped must not go on answering as a vehicle
                out.print(problem, highlight=False, markup=False)
                code = 3
                break
            left = 1.0 if end is None else min(1.0, end - time.monotonic())
            if left <= 0:
                break
            stop.wait(left)
    finally:
        fleet.stop()
        if embedded is not None:
            embedded.stop()
    raise typer.Exit(code)


@app.command()
def dispatch(
    mission: Annotated[Path, typer.Argument(help="mission file whose tasks become orders")],
    broker: Broker = None,
    manufacturer: Manufacturer = "agv-mission",
    robot: Annotated[
        list[str],
        typer.Option(help="serial number of a vehicle to drive (one-robot missions; default agv1)"),
    ] = [],  # noqa: B006
    reassign_timeout: Annotated[
        float, typer.Option(min=0.0, help="seconds a vehicle may be away before its tasks move")
    ] = 10.0,
    lookahead: Annotated[
        int, typer.Option(min=1, help="nodes released past the vehicle's last node")
    ] = 2,
    username: Username = None,
    password: Password = None,
    embedded_port: EmbeddedPort = 1883,
    output: Annotated[Optional[Path], typer.Option(help="root of run directories")] = None,  # noqa: UP045
    set_: Overrides = [],  # noqa: B006
    seed: Seed = None,
) -> None:
    """The master: MISSION's tasks as orders to VDA 5050 vehicles, to the mission's result."""
    from agv_mission.vda5050.master import Master, load_plan, new_run_dir, write_outputs

    try:
        plan = load_plan(mission, set_, seed, robot or None)
    except MissionError as exc:
        raise invalid(exc) from None
    url, embedded = _broker(broker, username, password, embedded_port)
    stop = threading.Event()
    _stop_on_signals(stop)
    run_dir = new_run_dir(plan, output)
    master = Master(plan, url, manufacturer, reassign_timeout, lookahead, run_dir)
    out.print(
        f"[bold]{plan.name}[/]: {len(plan.tasks)} task(s) for {', '.join(plan.robots)} on {url}",
        highlight=False,
    )
    try:
        result = master.run(stop)
    except ConnectionError as exc:
        result = master._result("error", str(exc))
    finally:
        if embedded is not None:
            embedded.stop()
    write_outputs(run_dir, master, result)
    colour = "green" if result["status"] == "succeeded" else "red"
    reason = f": {escape(result['reason'])}" if result["reason"] else ""
    out.print(f"[bold {colour}]{result['status']}[/]{reason}", highlight=False)
    for task in result["tasks"]:
        out.print(
            f"  task {task['task']} {task['type']} on {task['robot']}: {task['status']}"
            + (f" ({task['reason']})" if task["reason"] else ""),
            highlight=False,
            markup=False,
        )
    out.print(f"run directory: {run_dir}", highlight=False)
    raise typer.Exit(EXIT_CODES.get(result["status"], 3))


@app.command()
def watch(
    broker: Broker = None,
    manufacturer: Annotated[
        str, typer.Option(help="the topics' manufacturer level to watch (+: every one)")
    ] = "+",
    world: Annotated[
        list[str],
        typer.Option(help="a world (built-in name or file) for vehicles on a map of its name"),
    ] = [],  # noqa: B006
    host: Annotated[str, typer.Option(help="address the page is served on")] = "127.0.0.1",
    port: Annotated[int, typer.Option(min=0, max=65535, help="port of the page (0: any)")] = 8050,
    username: Username = None,
    password: Password = None,
    embedded_port: EmbeddedPort = 1883,
    duration: Annotated[
        Optional[float],  # noqa: UP045
        typer.Option(min=0.0, help="stop after this many wall seconds (default: until Ctrl-C)"),
    ] = None,
) -> None:
    """A web page showing every VDA 5050 vehicle on a broker on its map, with its state."""
    from agv_mission.maps.world_loader import WorldError, load_world
    from agv_mission.vda5050.watch import FleetWatch, WatchServer

    try:
        worlds = [load_world(spec) for spec in world]
    except WorldError as exc:
        raise failure("invalid input", str(exc)) from None
    url, embedded = _broker(broker, username, password, embedded_port)
    stop = threading.Event()
    _stop_on_signals(stop)
    fleet = FleetWatch(url, manufacturer, worlds)
    try:
        server = WatchServer(fleet, host, port)
    except OSError as exc:
        if embedded is not None:
            embedded.stop()
        raise failure("watch", f"cannot serve on {host}:{port}: {exc}", 3) from None
    try:
        fleet.start()
    except (RuntimeError, ConnectionError) as exc:
        server.server_close()
        if embedded is not None:
            embedded.stop()
        raise failure("watch", str(exc), 3) from None
    threading.Thread(target=server.serve_forever, name="vda5050-watch", daemon=True).start()
    shown = f"http://{host}:{server.server_address[1]}/"
    out.print(
        f"watching uagv/v2/{manufacturer}/+/ on {url}: {shown}", highlight=False, markup=False
    )
    end = None if duration is None else time.monotonic() + duration
    try:
        while not stop.is_set():
            left = 1.0 if end is None else min(1.0, end - time.monotonic())
            if left <= 0:
                break
            stop.wait(left)
    finally:
        server.shutdown()
        server.server_close()
        fleet.stop()
        if embedded is not None:
            embedded.stop()
