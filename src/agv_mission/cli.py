"""The ``agv-mission`` command line: parse, call, print, set the exit code. Nothing else."""

from __future__ import annotations

import json
import os
import signal
import sys
import time
from pathlib import Path
from typing import Annotated, Optional


def _exit_quietly(signum: int, _frame: object) -> None:
    """Ctrl-C while the program is still starting: exit 130, no traceback."""
    os._exit(128 + signum)


# Run as the program (not imported by a test or a service): quiet until a command sets
# its own handlers. The imports below take a while.
if __name__ == "__main__" or Path(sys.argv[0]).name in ("agv-mission", "cli.py"):
    signal.signal(signal.SIGINT, _exit_quietly)

import typer  # noqa: E402
from rich.console import Console  # noqa: E402
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn  # noqa: E402
from rich.table import Table  # noqa: E402

from agv_mission.missions.errors import MissionError  # noqa: E402

app = typer.Typer(
    add_completion=False,
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    help="Run YAML missions on a simulated differential-drive robot.",
)


class _PipeSafeStdout:
    """``sys.stdout`` that survives a reader going away (``agv-mission run ... | head -1``):
    once the pipe is closed, output goes to /dev/null and the exit code stays the run's."""

    def write(self, text: str) -> int:
        try:
            return sys.stdout.write(text)
        except BrokenPipeError:
            _silence_stdout()
            return len(text)

    def flush(self) -> None:
        try:
            sys.stdout.flush()
        except BrokenPipeError:
            _silence_stdout()

    def isatty(self) -> bool:
        return sys.stdout.isatty()

    def fileno(self) -> int:
        return sys.stdout.fileno()

    @property
    def encoding(self) -> str:
        return getattr(sys.stdout, "encoding", None) or "utf-8"


def _silence_stdout() -> None:
    """Point file descriptor 1 at /dev/null, so the interpreter's last flush cannot fail."""
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError):
        pass
    finally:
        os.close(devnull)


@app.callback()
def _started() -> None:
    """Started: Ctrl-C is Python's KeyboardInterrupt again (each command handles it)."""
    if signal.getsignal(signal.SIGINT) is _exit_quietly:
        signal.signal(signal.SIGINT, signal.default_int_handler)


out = Console(file=_PipeSafeStdout(), soft_wrap=True)  # type: ignore[arg-type]
err = Console(stderr=True, soft_wrap=True)

EXIT_CODES = {"succeeded": 0, "failed": 1, "error": 3, "aborted": 130, "interrupted": 1}


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
    no_bag: Annotated[
        bool, typer.Option("--no-bag", help="do not write bag/ (same as output.bag: false)")
    ] = False,
) -> None:
    """Validate and run a mission in simulation; write a run directory."""
    from agv_mission.bags.writer import BagWriter
    from agv_mission.missions.loader import load_demo_mission, load_mission
    from agv_mission.missions.outputs import RunDirError, open_run_dir, write_run
    from agv_mission.missions.runner import RunStopped, run_mission
    from agv_mission.missions.signals import SignalStop

    stopper = SignalStop().install()
    try:
        if mission is None:
            loaded = load_demo_mission(set_, seed)
        else:
            loaded = load_mission(mission, set_, seed)
        stopper.phase = "running"  # from here a signal ends the run, with a result
    except MissionError as exc:
        _report_invalid(exc)
        raise typer.Exit(2) from None
    except (KeyboardInterrupt, RunStopped):  # before anything was written
        err.print("stopped before the run started", highlight=False)
        raise typer.Exit(stopper.exit_code or 130) from None

    bag = loaded.mission.output.bag and not no_bag
    observers = [BagWriter().prepare()] if bag else []
    root = output if output is not None else Path(loaded.mission.output)
    try:
        run_dir = open_run_dir(root, loaded)
    except RunDirError as exc:
        where = "--output" if output is not None else f"{loaded.source}: output"
        err.print(f"[bold red]invalid input[/]: {where} {exc}", highlight=False)
        raise typer.Exit(2) from None
    out.print(
        f"[bold]{loaded.name}[/]: {len(loaded.mission.tasks)} task(s) in "
        f"{loaded.world.name} with {loaded.robot.name}, seed {loaded.mission.seed}"
    )
    with _progress("{task.completed:.1f}/{task.total:.0f} sim s") as bar:
        job = bar.add_task("running", total=loaded.mission.limits.time)
        record = run_mission(
            loaded,
            run_dir,
            progress=lambda t, total: bar.update(job, completed=t),
            control=stopper,
            observers=observers,
        )
    stopper.phase = "writing"  # a signal now is too late to stop anything: outputs first
    try:
        result = write_run(run_dir, loaded, record)
    except Exception as exc:  # noqa: BLE001 (result.json itself could not be written)
        err.print(
            f"[bold red]internal error[/]: cannot write {run_dir / 'result.json'}: {exc}",
            highlight=False,
        )
        raise typer.Exit(3) from None
    _summary(result)
    for problem in result.get("output_errors", []):
        err.print(f"[yellow]warning[/]: not written: {problem}", highlight=False, markup=False)
    code = EXIT_CODES.get(record.status, 3)
    if record.status == "aborted" and stopper.exit_code:
        code = stopper.exit_code
    stopper.ignore()  # everything is written: a signal now must not turn the code into a kill
    raise typer.Exit(code)


def _progress(counter: str) -> Progress:
    """A progress bar on stderr, shown only on a terminal and gone when it ends."""
    return Progress(
        TextColumn("[progress.description]{task.description}"),
        BarColumn(),
        TextColumn(counter),
        TimeElapsedColumn(),
        console=err,
        transient=True,
        disable=not err.is_terminal,
    )


def _summary(result: dict) -> None:
    from agv_mission.missions.summary import metrics_line, task_rows

    ok = result["status"] == "succeeded"
    colour = "green" if ok else "red"
    out.print(
        f"[bold {colour}]{result['status']}[/]" + ("" if ok else f": {result['reason']}"),
        highlight=False,
    )
    table = Table(show_header=True, header_style="bold", box=None)
    for column in ("task", "status", "detail"):
        table.add_column(column)
    for row in task_rows(result):
        table.add_row(*row)
    out.print(table)
    out.print(metrics_line(result), highlight=False)
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
def schema(
    robot: Annotated[bool, typer.Option("--robot", help="the robot file's schema instead")] = False,
) -> None:
    """Print the JSON Schema of the mission file (or, with --robot, of a robot file)."""
    if robot:
        from agv_mission.robots.description import robot_json_schema

        doc = robot_json_schema()
    else:
        from agv_mission.missions.schema import mission_json_schema

        doc = mission_json_schema()
    _PipeSafeStdout().write(json.dumps(doc, indent=2) + "\n")


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
    from agv_mission.teleop.session import (
        load_teleop_mission,
        open_session,
        run_teleop,
        session_report,
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
        run_dir, recs = open_session(loaded, output, recorder, append)
    except RecorderFileError as exc:
        err.print(f"[bold red]invalid input[/]: {escape(str(exc))}", highlight=False)
        raise typer.Exit(2) from None
    result = run_teleop(loaded, recs, time_scale=time_scale)
    if run_dir is not None:
        write_teleop_outputs(run_dir, loaded, result)
    for line in session_report(result, recs, run_dir):
        out.print(line, highlight=False, markup=False)
    raise typer.Exit(result.exit_code)


@app.command("map")
def map_(
    bag: Annotated[Path, typer.Argument(help="ROS 1 .bag, ROS 2 bag directory or .mcap file")],
    save_map: Annotated[
        Path, typer.Option("--save-map", help="map_saver stem: writes PATH.pgm + PATH.yaml")
    ] = Path("map"),
    scan_topic: Annotated[
        Optional[str], typer.Option("--scan-topic", help="default: the LaserScan topic")  # noqa: UP007, UP045
    ] = None,
    odom_topic: Annotated[
        Optional[str],  # noqa: UP007, UP045
        typer.Option("--odom-topic", help="default: the nav_msgs/Odometry topic, else /tf"),
    ] = None,
    truth_topic: Annotated[
        Optional[str],  # noqa: UP007, UP045
        typer.Option("--truth-topic", help="ground truth for the report's RMSE"),
    ] = None,
    set_: Annotated[
        list[str], typer.Option("--set", help="SLAM KEY=VALUE (stack.slam.KEY or KEY)")
    ] = [],  # noqa: B006
) -> None:
    """Build an occupancy grid map from a recorded bag (map_saver format + a report)."""
    from rich.markup import escape

    from agv_mission.bags.offline import (
        MappingFailed,
        map_bag,
        report_lines,
        save_outputs,
        slam_config,
    )
    from agv_mission.bags.reader import BagError

    try:
        config = slam_config(set_)
        result = map_bag(bag, config, scan_topic, odom_topic, truth_topic)
    except MissionError as exc:
        _report_invalid(exc)
        raise typer.Exit(2) from None
    except BagError as exc:
        err.print(f"[bold red]invalid input[/]: {escape(str(exc))}", highlight=False)
        raise typer.Exit(2) from None
    except MappingFailed as exc:
        err.print(f"[bold red]mapping failed[/]: {escape(str(exc))}", highlight=False)
        raise typer.Exit(1) from None
    for line in report_lines(result, save_outputs(result, save_map)):
        out.print(line, highlight=False, markup=False)
    raise typer.Exit(0)


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
    out.print(report.plan_line(plan, seeds, backend, n_workers, address), highlight=False)
    started = time.perf_counter()
    with _progress("{task.completed:.0f}/{task.total:.0f} runs") as bar:
        job = bar.add_task("regress", total=len(plan.jobs))

        def progress(result: dict, done: int, total: int) -> None:
            mark = "[green]ok[/]" if result["passed"] else "[red]FAIL[/]"
            bar.console.print(
                f"{mark} {escape(report.run_label(result, len(plan.variants), seeds))}",
                highlight=False,
            )
            bar.update(job, completed=done)

        interrupted = False
        try:
            results = backends.run_jobs(plan.jobs, backend, n_workers, address, progress)
        except planning.RegressError as exc:
            err.print(f"[bold red]invalid input[/]: {escape(str(exc))}", highlight=False)
            raise typer.Exit(2) from None
        except backends.Interrupted as exc:  # Ctrl-C: report what ran
            results, interrupted = exc.results, True
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
    if interrupted:
        err.print(report.interrupted_line(results, plan), highlight=False)
        raise typer.Exit(130)
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
