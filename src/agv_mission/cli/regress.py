"""``regress``: scenario suites run in parallel and checked against their ``expect:``."""

from __future__ import annotations

import os
import time
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer
from rich.console import Console
from rich.markup import escape

from agv_mission.cli.console import err, failure, invalid, out, progress_bar
from agv_mission.missions.load.errors import MissionError

if TYPE_CHECKING:
    from agv_mission.regress.plan import Plan


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
    from agv_mission.regress import backends, report
    from agv_mission.regress import plan as planning

    if backend not in ("local", "ray"):
        raise failure("invalid input", f"--backend {backend}: local or ray")
    backends.warm_up(backend, workers)  # the pool's fork server imports while we plan
    try:
        plan = planning.plan_jobs(paths, sweep, seeds, output)
    except planning.RegressError as exc:
        raise failure("invalid input", str(exc)) from None
    for line in report.skipped_lines(plan):
        err.print(f"[yellow]{escape(line)}[/]", highlight=False)
    if plan.problems:
        invalid(MissionError(plan.problems))
        report.write_reports([], plan, 0.0, backend, workers, junit, json_)
        raise typer.Exit(2)
    n_workers = workers or os.cpu_count() or 1
    out.print(report.plan_line(plan, seeds, backend, n_workers, address), highlight=False)
    started = time.perf_counter()
    results, interrupted = _run_scenarios(plan, seeds, backend, n_workers, address)
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


def _run_scenarios(
    plan: Plan, seeds: int, backend: str, n_workers: int, address: str | None
) -> tuple[list[dict], bool]:
    """Every run's result, marked ok or FAIL as it comes; and whether Ctrl-C stopped them."""
    from agv_mission.job_pool import Interrupted
    from agv_mission.regress import backends, report
    from agv_mission.regress import plan as planning

    with progress_bar("{task.completed:.0f}/{task.total:.0f} runs") as bar:
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
            raise failure("invalid input", str(exc)) from None
        except Interrupted as exc:  # Ctrl-C: report what ran
            results, interrupted = exc.results, True
    return results, interrupted
