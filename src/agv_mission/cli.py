"""The ``agv-mission`` command line: parse, call, print, set the exit code. Nothing else."""

from __future__ import annotations

import json
import sys
from importlib.resources import as_file, files
from pathlib import Path
from typing import Annotated, Optional

import typer
from rich.console import Console
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

from agv_mission.missions.errors import MissionError

app = typer.Typer(
    add_completion=False,
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    help="Run YAML missions on a simulated differential-drive robot.",
)
out = Console(soft_wrap=True)
err = Console(stderr=True, soft_wrap=True)

DEMO_MISSION = "visit_rooms.yaml"
EXIT_CODES = {"succeeded": 0, "failed": 1, "error": 1, "aborted": 130, "interrupted": 1}


def _report_invalid(exc: MissionError) -> None:
    err.print(
        f"[bold red]invalid input[/] ({len(exc.problems)} problem"
        f"{'s' if len(exc.problems) != 1 else ''}):",
        highlight=False,
    )
    for problem in exc.problems:
        err.print(f"  {problem}", highlight=False, markup=False)


@app.command()
def run(
    mission: Annotated[Path | None, typer.Argument(help="mission file; default: the demo")] = None,  # noqa: UP007
    set_: Annotated[list[str], typer.Option("--set", help="KEY=VALUE override (YAML value)")] = [],  # noqa: B006
    output: Annotated[Path | None, typer.Option(help="root of run directories")] = None,  # noqa: UP007
    seed: Annotated[int | None, typer.Option(help="override the mission's seed")] = None,  # noqa: UP007
) -> None:
    """Validate and run a mission in simulation; write a run directory."""
    from agv_mission.missions.loader import load_mission
    from agv_mission.missions.outputs import make_run_dir, write_mission, write_run
    from agv_mission.missions.runner import run_mission

    try:
        if mission is None:
            with as_file(files("agv_mission") / "data" / "missions" / DEMO_MISSION) as demo:
                loaded = load_mission(demo, set_, seed)
        else:
            loaded = load_mission(mission, set_, seed)
    except MissionError as exc:
        _report_invalid(exc)
        raise typer.Exit(2) from None

    root = output if output is not None else Path(loaded.mission.output)
    run_dir = make_run_dir(root, loaded.name)
    write_mission(run_dir, loaded)
    out.print(
        f"[bold]{loaded.name}[/]: {len(loaded.mission.tasks)} task(s) in "
        f"{loaded.world.name} with {loaded.robot.name}, seed {loaded.mission.seed}"
    )
    with Progress(
        TextColumn("[progress.description]{task.description}"),
        BarColumn(),
        TextColumn("{task.completed:.1f}/{task.total:.0f} sim s"),
        TimeElapsedColumn(),
        console=err,
        transient=True,
        disable=not err.is_terminal,
    ) as bar:
        job = bar.add_task("running", total=loaded.mission.limits.time)
        record = run_mission(
            loaded, run_dir, progress=lambda t, total: bar.update(job, completed=t)
        )
    result = write_run(run_dir, loaded, record)
    _summary(result)
    raise typer.Exit(EXIT_CODES.get(record.status, 1))


def _summary(result: dict) -> None:
    ok = result["status"] == "succeeded"
    colour = "green" if ok else "red"
    out.print(
        f"[bold {colour}]{result['status']}[/]" + ("" if ok else f": {result['reason']}"),
        highlight=False,
    )
    table = Table(show_header=True, header_style="bold", box=None)
    table.add_column("task")
    table.add_column("status")
    table.add_column("detail")
    for task in result["tasks"]:
        detail = task.get("reason") or ""
        if "waypoints" in task:
            reached = sum(w["status"] == "reached" for w in task["waypoints"])
            detail = f"{reached}/{len(task['waypoints'])} waypoints reached " + detail
        if "rooms" in task:
            reached = sum(r["status"] == "reached" for r in task["rooms"])
            recorded = sum(bool(r.get("recorded")) for r in task["rooms"])
            detail = f"{reached}/{len(task['rooms'])} rooms reached, {recorded} recorded " + detail
        table.add_row(f"{task['index']}. {task['type']}", task["status"], detail)
    out.print(table)
    m = result["metrics"]
    loc = m["localization"]
    out.print(
        f"sim {result['sim_time']:.1f} s in {result['wall_time']:.1f} s wall "
        f"({m['real_time_factor']}x real time), driven {m['distance_driven']:.2f} m, "
        f"collisions {m['collisions']}, min clearance {m['min_clearance']} m, "
        f"position RMSE {loc['position_rmse']:.3f} m",
        highlight=False,
    )
    out.print(f"run directory: {result['run_dir']}", highlight=False)


@app.command()
def validate(
    files_: Annotated[list[Path], typer.Argument(metavar="FILE...", help="mission files")],
) -> None:
    """Validate mission files without running them."""
    from agv_mission.missions.loader import load_mission

    bad = 0
    for path in files_:
        try:
            load_mission(path)
            out.print(f"{path}: [green]valid[/]", highlight=False)
        except MissionError as exc:
            bad += 1
            _report_invalid(exc)
    raise typer.Exit(2 if bad else 0)


@app.command()
def schema() -> None:
    """Print the JSON Schema of the mission file."""
    from agv_mission.missions.schema import Mission

    sys.stdout.write(json.dumps(Mission.model_json_schema(), indent=2) + "\n")


@app.command()
def teleop(
    mission: Annotated[
        Path | None,
        typer.Argument(help="mission file for world, robot, start and stack; default: small_house"),
    ] = None,  # noqa: UP007, UP045
    world: Annotated[
        str | None, typer.Option(help="world (built-in name, world file or ROS map YAML)")
    ] = None,  # noqa: UP007, UP045
    robot: Annotated[
        str | None, typer.Option(help="robot (burger, waffle, rosbots or a robot file)")
    ] = None,  # noqa: UP007, UP045
    set_: Annotated[list[str], typer.Option("--set", help="KEY=VALUE override (YAML value)")] = [],  # noqa: B006
    output: Annotated[
        Path | None, typer.Option(help="root of run directories (default: the mission's output)")
    ] = None,  # noqa: UP007, UP045
    recorder: Annotated[
        Path | None, typer.Option(help="record straight into this file (appends if it exists)")
    ] = None,  # noqa: UP007, UP045
    append: Annotated[
        Path | None, typer.Option(help="start from the entries of this recorder file")
    ] = None,  # noqa: UP007, UP045
    time_scale: Annotated[
        float, typer.Option(min=0.1, max=100.0, help="simulated seconds per wall second")
    ] = 1.0,
    seed: Annotated[Optional[int], typer.Option(help="override the mission's seed")] = None,  # noqa: UP007, UP045
) -> None:
    """Drive the simulated robot by keyboard and record room poses (r + label)."""
    from rich.markup import escape

    from agv_mission.maps.recorder import RecorderFileError
    from agv_mission.missions.outputs import make_run_dir
    from agv_mission.missions.stack import open_recorders
    from agv_mission.teleop.session import (
        check_recorder_file,
        load_teleop_mission,
        run_teleop,
        write_teleop_outputs,
    )

    if output is not None and recorder is not None:
        err.print(
            "[bold red]invalid input[/]: give --output or --recorder, not both", highlight=False
        )
        raise typer.Exit(2)
    try:
        loaded = load_teleop_mission(mission, world, robot, set_, seed)
    except MissionError as exc:
        _report_invalid(exc)
        raise typer.Exit(2) from None
    try:
        if recorder is not None:
            run_dir, recs = None, open_recorders(loaded, None, recorder, append)
        else:
            if append is not None:
                check_recorder_file(append)  # before making a directory
            root = output if output is not None else Path(loaded.mission.output)
            name = loaded.name if loaded.name == "teleop" else f"{loaded.name}-teleop"
            run_dir = make_run_dir(root, name)
            recs = open_recorders(loaded, run_dir, None, append)
    except RecorderFileError as exc:
        err.print(f"[bold red]invalid input[/]: {escape(str(exc))}", highlight=False)
        raise typer.Exit(2) from None
    result = run_teleop(loaded, recs, time_scale=time_scale)
    if run_dir is not None:
        write_teleop_outputs(run_dir, loaded, result)
    out.print(f"teleop ended ({result.reason}) after {result.sim_time:.1f} sim s", highlight=False)
    saved = [r for r in recs if len(r) and r.path.exists()]
    for rec in saved:
        n = len(rec)
        out.print(
            f"recorder file: {rec.path} ({n} entr{'y' if n == 1 else 'ies'}: {', '.join(rec.labels)})",
            highlight=False,
            markup=False,
        )
    if not saved:
        out.print("nothing recorded; no recorder file written", highlight=False)
    if run_dir is not None:
        out.print(f"run directory: {run_dir}", highlight=False, markup=False)
    raise typer.Exit(result.exit_code)


@app.command()
def regress(
    paths: Annotated[
        list[Path], typer.Argument(metavar="PATHS...", help="scenario files or directories")
    ],
    workers: Annotated[
        int | None,  # noqa: UP007, UP045
        typer.Option("--workers", "-j", min=1, help="parallel runs; default: the CPU count"),
    ] = None,
    junit: Annotated[Path | None, typer.Option(help="write JUnit XML here")] = None,  # noqa: UP007, UP045
    json_: Annotated[
        Path | None,  # noqa: UP007, UP045
        typer.Option("--json", help="write the JSON summary here"),
    ] = None,
    sweep: Annotated[
        list[str],
        typer.Option(help="KEY=V1,V2,... run every value (repeatable: cartesian product)"),
    ] = [],  # noqa: B006
    seeds: Annotated[
        int, typer.Option(min=1, help="run seeds S..S+N-1 (S: the mission's seed)")
    ] = 1,
    backend: Annotated[str, typer.Option(help="local (process pool) or ray")] = "local",
    address: Annotated[
        str | None,  # noqa: UP007, UP045
        typer.Option(help="Ray cluster address (ray backend); default: a local Ray instance"),
    ] = None,
    output: Annotated[
        Path | None,  # noqa: UP007, UP045
        typer.Option(help="root of the run directories; default: runs/regress-<UTC time>"),
    ] = None,
) -> None:
    """Run scenarios (missions with an expect: block) in parallel and check them."""
    import os
    import time

    from rich.markup import escape

    from agv_mission.regress import backends, report
    from agv_mission.regress import plan as planning

    if backend not in ("local", "ray"):
        err.print(f"[bold red]invalid input[/]: --backend {escape(backend)}: local or ray")
        raise typer.Exit(2)
    backends.warm_up(backend, workers)  # the pool's fork server imports while we plan
    try:
        plan = planning.plan_jobs(paths, sweep, seeds, output)
    except planning.RegressError as exc:
        err.print(f"[bold red]invalid input[/]: {escape(str(exc))}", highlight=False)
        raise typer.Exit(2) from None
    if plan.problems:
        _report_invalid(MissionError(plan.problems))
        report.write_reports([], plan, 0.0, backend, workers, junit, json_)
        raise typer.Exit(2)
    n_workers = workers or os.cpu_count() or 1
    out.print(
        f"{len(plan.jobs)} run(s): {len(plan.scenarios)} scenario(s) x {len(plan.variants)} "
        f"variant(s) x {seeds} seed(s) on {backend} "
        + (f"({n_workers} workers)" if backend == "local" else f"({address or 'local Ray'})"),
        highlight=False,
    )
    started = time.perf_counter()
    with Progress(
        TextColumn("[progress.description]{task.description}"),
        BarColumn(),
        TextColumn("{task.completed:.0f}/{task.total:.0f} runs"),
        TimeElapsedColumn(),
        console=err,
        transient=True,
        disable=not err.is_terminal,
    ) as bar:
        job = bar.add_task("regress", total=len(plan.jobs))

        def progress(result: dict, done: int, total: int) -> None:
            mark = "[green]ok[/]" if result["passed"] else "[red]FAIL[/]"
            bar.console.print(
                f"{mark} {escape(report.run_label(result, len(plan.variants), seeds))}",
                highlight=False,
            )
            bar.update(job, completed=done)

        try:
            results = backends.run_jobs(plan.jobs, backend, n_workers, address, progress)
        except planning.RegressError as exc:
            err.print(f"[bold red]invalid input[/]: {escape(str(exc))}", highlight=False)
            raise typer.Exit(2) from None
    elapsed = time.perf_counter() - started
    # Not a terminal (CI logs, pipes): do not squeeze the tables into 80 columns.
    tables = out if out.is_terminal else Console(soft_wrap=True, width=240)
    tables.print(report.results_table(results, len(plan.variants), seeds))
    if len(plan.variants) > 1 or seeds > 1:
        tables.print(report.comparison_table(report.compare(results)))
    report.write_reports(results, plan, elapsed, backend, n_workers, junit, json_)
    failed = [r for r in results if not r["passed"]]
    colour = "red" if failed else "green"
    out.print(
        f"[bold {colour}]{len(results) - len(failed)}/{len(results)} passed[/] in "
        f"{elapsed:.1f} s; run directories under {escape(str(plan.output_root))}",
        highlight=False,
    )
    for path, what in ((junit, "JUnit XML"), (json_, "JSON summary")):
        if path is not None:
            out.print(f"{what}: {escape(str(path))}", highlight=False)
    raise typer.Exit(1 if failed else 0)


@app.command()
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
    import os

    from rich.markup import escape

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
        err.print(f"[bold red]cannot serve[/]: {escape(str(exc))}", highlight=False)
        raise typer.Exit(2) from None


@app.command()
def submit(
    mission: Annotated[Path, typer.Argument(help="mission file")],
    server: Annotated[str, typer.Option(help="service URL, e.g. http://127.0.0.1:8080")],
    set_: Annotated[list[str], typer.Option("--set", help="KEY=VALUE override (YAML value)")] = [],  # noqa: B006
    seed: Annotated[Optional[int], typer.Option(help="override the mission's seed")] = None,  # noqa: UP007, UP045
    follow: Annotated[bool, typer.Option("--follow", help="stream progress until it ends")] = False,
    token: Annotated[
        Optional[str],  # noqa: UP007, UP045
        typer.Option(envvar="AGV_MISSION_TOKEN", help="the service's bearer token"),
    ] = None,
) -> None:
    """Submit a mission to a running service; print the run id (and follow it live)."""
    from rich.markup import escape

    from agv_mission.service import client

    try:
        run = client.submit(mission, set_, seed, server, token)
    except MissionError as exc:
        _report_invalid(exc)
        raise typer.Exit(2) from None
    except client.ClientError as exc:
        err.print(f"[bold red]error[/]: {escape(str(exc))}", highlight=False)
        raise typer.Exit(2) from None
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
        err.print(f"[bold red]error[/]: {escape(str(exc))}", highlight=False)
        raise typer.Exit(1) from None
    result = final.get("result")
    if result:
        _summary(result)
    else:
        out.print(f"{final['status']}: {final.get('reason')}", highlight=False)
    raise typer.Exit(EXIT_CODES.get(final["status"], 1))


def main() -> None:
    app()


if __name__ == "__main__":
    main()
