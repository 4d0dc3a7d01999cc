"""``run``, ``validate`` and ``schema``: one mission file, run, checked or described."""

from __future__ import annotations

import json
import math
import time
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.markup import escape

from agv_mission.cli.console import (
    EXIT_CODES,
    Overrides,
    Pace,
    PipeSafeStdout,
    Seed,
    err,
    failure,
    invalid,
    out,
    print_summary,
    progress_bar,
)
from agv_mission.cli.startup import quiet_until_started, started_as_program
from agv_mission.missions.load.errors import MissionError

REFRESH_PERIOD = 0.1  # s of wall time between redraws of the progress bar


def run(
    mission: Annotated[Path | None, typer.Argument(help="mission file; default: the demo")] = None,  # noqa: UP007
    set_: Overrides = [],  # noqa: B006
    output: Annotated[Path | None, typer.Option(help="root of run directories")] = None,  # noqa: UP007
    seed: Seed = None,
    no_bag: Annotated[
        bool, typer.Option("--no-bag", help="do not write bag/ (same as output.bag: false)")
    ] = False,
    pace: Pace = None,
) -> None:
    """Validate and run a mission in simulation; write a run directory."""
    if started_as_program():  # Ctrl-C during the imports below: exit 130, no traceback
        quiet_until_started()
    from agv_mission.missions.load.loader import load_demo_mission, load_mission
    from agv_mission.missions.run.errors import RunStopped
    from agv_mission.missions.run.signals import SignalStop

    stopper = SignalStop().install()
    try:
        if mission is None:
            loaded = load_demo_mission(set_, seed)
        else:
            loaded = load_mission(mission, set_, seed)
        # The run's own machinery, once the input is known good (bad input is told sooner).
        from agv_mission.bags.writer import BagWriter
        from agv_mission.missions.load.resolved import Layout
        from agv_mission.missions.report.directory import ResultNotWritten
        from agv_mission.missions.report.outputs import RunDirError
        from agv_mission.missions.run.pacing import PacedControl

        stopper.phase = "running"  # from here a signal ends the run, with a result
    except MissionError as exc:
        raise invalid(exc) from None
    except (KeyboardInterrupt, RunStopped):  # before anything was written
        err.print("stopped before the run started", highlight=False)
        raise typer.Exit(stopper.exit_code or 130) from None

    print_warnings(loaded)
    bag = loaded.mission.output.bag and not no_bag
    observers = [BagWriter().prepare()] if bag else []
    root = output if output is not None else Path(loaded.mission.output)
    if loaded.layout is Layout.FLEET:
        robots = ", ".join(f"{r.name} ({r.robot.name})" for r in loaded.robots)
        out.print(
            f"[bold]{loaded.name}[/]: {len(loaded.robots)} robots in {loaded.world.name}: "
            f"{robots}; {len(loaded.fleet_tasks)} fleet task(s), seed {loaded.mission.seed}"
        )
    else:
        out.print(
            f"[bold]{loaded.name}[/]: {mission_outline(loaded)} in "
            f"{loaded.world.name} with {loaded.robot.name}, seed {loaded.mission.seed}"
        )
    control = stopper if pace is None else PacedControl(stopper, pace)
    try:
        done = _run_with_progress(root, loaded, control, observers)
    except RunDirError as exc:
        where = "--output" if output is not None else f"{loaded.source}: output"
        raise failure("invalid input", f"{where} {exc}") from None
    except ResultNotWritten as exc:
        raise failure("internal error", str(exc), 3) from None
    result, record = done.result, done.record
    print_summary(result)
    for problem in result.get("output_errors", []):
        err.print(f"[yellow]warning[/]: not written: {problem}", highlight=False, markup=False)
    code = EXIT_CODES.get(record.status, 3)
    if record.status == "aborted" and stopper.exit_code:
        code = stopper.exit_code
    stopper.ignore()  # everything is written: a signal now must not turn the code into a kill
    raise typer.Exit(code)


def _run_with_progress(root: Path, loaded: Any, control: Any, observers: list[Any]) -> Any:
    """Run the mission in a new run directory under ``root`` with a progress bar of
    simulated seconds; the finished run."""
    from agv_mission.missions.report.directory import run_under

    with progress_bar("{task.completed:.1f}/{task.total:.0f} sim s", auto_refresh=False) as bar:
        job = bar.add_task("running", total=loaded.mission.limits.time)
        shown = [-math.inf]

        def progress(t: float, _total: float) -> None:
            bar.update(job, completed=t)
            now = time.monotonic()
            if now - shown[0] >= REFRESH_PERIOD:  # refreshed here: the bar runs no thread
                bar.refresh()
                shown[0] = now

        return run_under(root, loaded, progress=progress, control=control, observers=observers)


def mission_outline(loaded: Any) -> str:
    """A one-robot mission in a few words: its tasks, or its tree when it has none."""
    tree = loaded.tree
    if tree is None:
        return "no tasks"
    tasks = tree.task_types()
    if tasks:
        return f"{tree.count} tree node(s), {len(tasks)} task(s)"
    root = tree.root
    named = f" '{root.name}'" if getattr(root, "name", None) not in (None, root.type) else ""
    return f"a behaviour tree of {tree.count} node(s) (root: {root.type}{named})"


def validate(
    files_: Annotated[list[Path], typer.Argument(metavar="FILE...", help="mission files")],
    set_: Overrides = [],  # noqa: B006
    seed: Seed = None,
) -> None:
    """Validate mission files without running them (with the overrides ``run`` would take)."""
    from agv_mission.missions.load.loader import load_mission

    bad = 0
    for path in files_:
        try:
            print_warnings(load_mission(path, set_, seed))
            out.print(f"{path}: [green]valid[/]", highlight=False)
        except MissionError as exc:
            bad += 1
            invalid(exc)
    raise typer.Exit(2 if bad else 0)


def print_warnings(loaded: object) -> None:
    """What the loader took as near as it could (``file:line: field: ...``), on stderr."""
    for warning in getattr(loaded, "warnings", ()):
        err.print(f"[yellow]warning[/]: {escape(str(warning))}", highlight=False)


def schema(
    robot: Annotated[bool, typer.Option("--robot", help="the robot file's schema instead")] = False,
) -> None:
    """Print the JSON Schema of the mission file (or, with --robot, of a robot file)."""
    if robot:
        from agv_mission.robots.robot_files import robot_json_schema

        doc = robot_json_schema()
    else:
        from agv_mission.missions.load.schema import mission_json_schema

        doc = mission_json_schema()
    PipeSafeStdout().write(json.dumps(doc, indent=2) + "\n")
