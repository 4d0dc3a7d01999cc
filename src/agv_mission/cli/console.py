"""Where the commands print: ``out`` (results, pipe-safe) and ``err`` (problems, progress),
and the printing every command shares."""

from __future__ import annotations

import os
import sys
from typing import Annotated, Optional

import typer
from rich.console import Console
from rich.markup import escape
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

from agv_mission.missions.load.errors import MissionError
from agv_mission.missions.run.pacing import PACE_RANGE

EXIT_CODES = {"succeeded": 0, "failed": 1, "error": 3, "aborted": 130, "interrupted": 1}

# Options several commands share.
Overrides = Annotated[list[str], typer.Option("--set", help="KEY=VALUE override (YAML value)")]
Seed = Annotated[Optional[int], typer.Option(help="override the mission's seed")]  # noqa: UP007, UP045
Pace = Annotated[
    Optional[float],  # noqa: UP007, UP045
    typer.Option(
        min=PACE_RANGE[0],
        max=PACE_RANGE[1],
        help="simulated seconds per wall second, to watch the run (1.0: real time); "
        "default: as fast as it goes",
    ),
]


class PipeSafeStdout:
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


out = Console(file=PipeSafeStdout(), soft_wrap=True)  # type: ignore[arg-type]
err = Console(stderr=True, soft_wrap=True)


def invalid(exc: MissionError) -> typer.Exit:
    """Print every problem of bad input (file, line, field); the exit (2) to raise."""
    err.print(
        f"[bold red]invalid input[/] ({len(exc.problems)} problem"
        f"{'s' if len(exc.problems) != 1 else ''}):",
        highlight=False,
    )
    for problem in exc.problems:
        err.print(f"  {problem}", highlight=False, markup=False)
    return typer.Exit(2)


def failure(title: str, message: str, code: int = 2) -> typer.Exit:
    """Print ``title: message`` on stderr (the message as plain text); the exit to raise."""
    err.print(f"[bold red]{title}[/]: {escape(message)}", highlight=False)
    return typer.Exit(code)


def progress_bar(counter: str, auto_refresh: bool = True) -> Progress:
    """A progress bar on stderr, shown only on a terminal and gone when it ends. Without
    ``auto_refresh`` it runs no thread of its own (the caller refreshes it): a run whose
    robots decide in forked processes forks only from a process with no other thread."""
    return Progress(
        TextColumn("[progress.description]{task.description}"),
        BarColumn(),
        TextColumn(counter),
        TimeElapsedColumn(),
        console=err,
        transient=True,
        disable=not err.is_terminal,
        auto_refresh=auto_refresh,
    )


def print_summary(result: dict) -> None:
    """A run's result document as a status line, a task table and the metrics."""
    from agv_mission.missions.report.summary import (
        LEG_COLUMNS,
        leg_rows,
        metrics_line,
        task_rows,
        tree_rows,
    )

    ok = result["status"] == "succeeded"
    colour = "green" if ok else "red"
    out.print(
        f"[bold {colour}]{result['status']}[/]" + ("" if ok else f": {result['reason']}"),
        highlight=False,
    )
    rows = task_rows(result)
    by_tree = not rows and bool(result.get("tree") or result.get("robots"))
    if by_tree:  # a tree mission: its tree says what it did
        rows = tree_rows(result)
    table = Table(show_header=True, header_style="bold", box=None)
    for column in ("tree node" if by_tree else "task", "status", "detail"):
        table.add_column(column)
    for row in rows:
        table.add_row(*row)
    if rows:
        out.print(table)
    legs = leg_rows(result)
    if legs:
        table = Table(
            show_header=True, header_style="bold", box=None, collapse_padding=True, pad_edge=False
        )
        for i, column in enumerate(LEG_COLUMNS):
            table.add_column(column, justify="left" if i in (1, 2) else "right", no_wrap=True)
        for row in legs:
            table.add_row(*row)
        out.print(table)
    out.print(metrics_line(result), highlight=False)
    out.print(f"run directory: {result['run_dir']}", highlight=False)
