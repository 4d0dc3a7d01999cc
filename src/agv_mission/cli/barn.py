"""``barn``: BARN's worlds run by its protocol, in parallel (barn.md)."""

from __future__ import annotations

import os
import time
from datetime import datetime, timezone
from pathlib import Path
from typing import Annotated, Optional

import typer
from rich.console import Console
from rich.table import Table

from agv_mission.cli.console import Overrides, err, failure, invalid, out, progress_bar
from agv_mission.cli.service import run_observers
from agv_mission.missions.load.errors import MissionError


def barn(
    directory: Annotated[
        Path, typer.Argument(metavar="DIR", help="world_K.world files and path_files/path_K.npy")
    ],
    worlds: Annotated[
        Optional[str],  # noqa: UP007, UP045
        typer.Option("--worlds", help="e.g. 0-49,120,200-299; default: every world in DIR"),
    ] = None,
    set_: Overrides = [],  # noqa: B006
    seed: Annotated[int, typer.Option(min=0, help="every world's seed")] = 0,
    workers: Annotated[
        Optional[int],  # noqa: UP007, UP045
        typer.Option("--workers", "-j", min=1, help="parallel worlds; default: one per core"),
    ] = None,
    output: Annotated[
        Optional[Path],  # noqa: UP007, UP045
        typer.Option(help="root of the run directories; default: runs/barn-<UTC time>"),
    ] = None,
    json_: Annotated[
        Optional[Path],  # noqa: UP007, UP045
        typer.Option("--json", help="write the summary and every world's result here"),
    ] = None,
    backend: Annotated[str, typer.Option(help="local (process pool) or ray")] = "local",
    address: Annotated[
        Optional[str],  # noqa: UP007, UP045
        typer.Option(help="Ray cluster address (ray backend); default: a local Ray instance"),
    ] = None,
) -> None:
    """Run BARN's worlds (Jackal, no map, BARN's start, goal, clock and metric)."""
    from agv_mission.barn import suite
    from agv_mission.missions.report.outputs import write_json

    if backend not in ("local", "ray"):
        raise failure("invalid input", f"--backend {backend}: local or ray")
    n_workers = workers or os.cpu_count() or 1
    stamp = datetime.now(timezone.utc).strftime("%Y%m%dT%H%M%SZ")
    root = output if output is not None else Path("runs") / f"barn-{stamp}"
    jobs = _world_jobs(directory, worlds, list(set_), seed, root, backend, n_workers)
    out.print(
        f"BARN: {len(jobs)} world(s) from {directory} on {n_workers} worker(s) "
        f"({backend}); run directories under {root}",
        highlight=False,
        markup=False,
    )
    started = time.perf_counter()
    results, interrupted = _run_worlds(jobs, backend, n_workers, address)
    elapsed = time.perf_counter() - started
    summary = suite.summarise(results, elapsed, n_workers)
    tables = out if out.is_terminal else Console(soft_wrap=True, width=200)
    tables.print(_table(results))
    tables.print(_summary_table(summary))
    if json_ is not None:
        try:
            write_json(json_, suite.json_document(results, summary))
        except OSError as exc:
            raise failure("internal error", f"--json {json_}: {exc.strerror or exc}", 3) from None
        out.print(f"JSON: {json_}", highlight=False, markup=False)
    if interrupted:
        err.print(f"stopped after {len(results)} of {len(jobs)} world(s)", highlight=False)
        raise typer.Exit(130)
    broken = [r for r in results if r.get("error")]
    for r in broken[:5]:
        err.print(f"world_{r['world']}: {r['error'].strip()}", highlight=False, markup=False)
    if any(r.get("invalid") for r in broken):
        raise typer.Exit(2)
    raise typer.Exit(3 if broken else 0)


def _world_jobs(
    directory: Path,
    worlds: str | None,
    set_: list[str],
    seed: int,
    root: Path,
    backend: str,
    n_workers: int,
) -> list[dict]:
    """The jobs of the chosen worlds, the first world's mission checked and ``root``
    ready for their run directories; bad input exits 2."""
    from agv_mission.barn import suite
    from agv_mission.barn import workers as pool

    try:
        plan = suite.plan_worlds(directory, worlds)
        jobs = suite.world_jobs(plan, set_, seed, root, run_observers)
        pool.warm_up(backend, min(n_workers, len(jobs)))  # imports while we check
        suite.load_world_mission(jobs[0])  # --set and the first world checked here
        root.mkdir(parents=True, exist_ok=True)
        taken = [j["world"] for j in jobs if (root / f"world_{j['world']}").exists()]
        if taken:
            raise suite.BarnInputError(
                f"--output {root}: already holds world_{taken[0]}/ (choose a new folder)"
            )
    except suite.BarnInputError as exc:
        raise failure("invalid input", str(exc)) from None
    except MissionError as exc:
        raise invalid(exc) from None
    except OSError as exc:
        raise failure("invalid input", f"--output {root}: {exc.strerror or exc}") from None
    return jobs


def _run_worlds(
    jobs: list[dict], backend: str, n_workers: int, address: str | None
) -> tuple[list[dict], bool]:
    """Every world's result, a line each as it comes; and whether Ctrl-C stopped them."""
    from agv_mission.barn import suite
    from agv_mission.barn import workers as pool
    from agv_mission.job_pool import Interrupted

    interrupted = False
    with progress_bar("{task.completed:.0f}/{task.total:.0f} worlds") as bar:
        task = bar.add_task("barn", total=len(jobs))

        def progress(result: dict, done: int, _total: int) -> None:
            bar.console.print(_line(result), highlight=False, markup=False)
            bar.update(task, completed=done)

        try:
            results = pool.run_worlds(jobs, backend, n_workers, address, progress)
        except suite.BarnInputError as exc:
            raise failure("invalid input", str(exc)) from None
        except Interrupted as exc:
            results, interrupted = exc.results, True
    return results, interrupted


def _line(result: dict) -> str:
    metric = f"{result['metric']:.3f}"
    return f"world_{result['world']}: {result['status']} {result['time']:.2f} s metric {metric}"


def _table(results: list[dict]) -> Table:
    table = Table(show_header=True, header_style="bold", box=None)
    for column in ("world", "status", "time s", "metric"):
        table.add_column(column, justify="left" if column == "status" else "right")
    for r in results:
        table.add_row(str(r["world"]), r["status"], f"{r['time']:.2f}", f"{r['metric']:.4f}")
    return table


def _summary_table(summary: dict) -> Table:
    table = Table(show_header=True, header_style="bold", box=None, title="BARN summary")
    for column in ("worlds", "success", "collisions", "timeouts", "mean time s", "mean metric"):
        table.add_column(column, justify="right")

    def num(value: float | None, digits: int) -> str:
        return "-" if value is None else f"{value:.{digits}f}"

    table.add_row(
        str(summary["worlds"]),
        num(summary["success_rate"], 3),
        num(summary["collision_rate"], 3),
        num(summary["timeout_rate"], 3),
        num(summary["mean_time"], 2),
        num(summary["mean_metric"], 4),
    )
    return table
