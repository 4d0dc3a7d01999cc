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

DEMO_MISSION = "patrol.yaml"


def _report_invalid(exc: MissionError) -> None:
    err.print(f"[bold red]invalid input[/] ({len(exc.problems)} problem"
              f"{'s' if len(exc.problems) != 1 else ''}):", highlight=False)
    for problem in exc.problems:
        err.print(f"  {problem}", highlight=False, markup=False)


@app.command()
def run(
    mission: Annotated[Optional[Path], typer.Argument(help="mission file; default: the demo")] = None,  # noqa: UP007
    set_: Annotated[list[str], typer.Option("--set", help="KEY=VALUE override (YAML value)")] = [],  # noqa: B006
    output: Annotated[Optional[Path], typer.Option(help="root of run directories")] = None,  # noqa: UP007
    seed: Annotated[Optional[int], typer.Option(help="override the mission's seed")] = None,  # noqa: UP007
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
    out.print(f"[bold]{loaded.name}[/]: {len(loaded.mission.tasks)} task(s) in "
              f"{loaded.world.name} with {loaded.robot.name}, seed {loaded.mission.seed}")
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
        record = run_mission(loaded, progress=lambda t, total: bar.update(job, completed=t))
    result = write_run(run_dir, loaded, record)
    _summary(result)
    raise typer.Exit(0 if record.status == "succeeded" else 1)


def _summary(result: dict) -> None:
    ok = result["status"] == "succeeded"
    colour = "green" if ok else "red"
    out.print(f"[bold {colour}]{result['status']}[/]"
              + ("" if ok else f": {result['reason']}"), highlight=False)
    table = Table(show_header=True, header_style="bold", box=None)
    table.add_column("task")
    table.add_column("status")
    table.add_column("detail")
    for task in result["tasks"]:
        detail = task.get("reason") or ""
        if "waypoints" in task:
            reached = sum(w["status"] == "reached" for w in task["waypoints"])
            detail = f"{reached}/{len(task['waypoints'])} waypoints reached " + detail
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


def main() -> None:
    app()


if __name__ == "__main__":
    main()
