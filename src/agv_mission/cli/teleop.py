"""``teleop``: drive the simulated robot by keyboard and record room poses."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from agv_mission.cli.console import Overrides, Seed, failure, invalid, out
from agv_mission.missions.load.errors import MissionError


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
    set_: Overrides = [],  # noqa: B006
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
    seed: Seed = None,
) -> None:
    """Drive the simulated robot by keyboard and record room poses (r + label)."""
    from agv_mission.maps.recorder import RecorderFileError
    from agv_mission.teleop.session import (
        load_teleop_mission,
        open_session,
        run_teleop,
        session_report,
        write_teleop_outputs,
    )

    if output is not None and recorder is not None:
        raise failure("invalid input", "give --output or --recorder, not both")
    try:
        loaded = load_teleop_mission(mission, world, robot, set_, seed)
    except MissionError as exc:
        raise invalid(exc) from None
    try:
        run_dir, recs = open_session(loaded, output, recorder, append)
    except RecorderFileError as exc:
        raise failure("invalid input", str(exc)) from None
    result = run_teleop(loaded, recs, time_scale=time_scale)
    if run_dir is not None:
        write_teleop_outputs(run_dir, loaded, result)
    for line in session_report(result, recs, run_dir):
        out.print(line, highlight=False, markup=False)
    raise typer.Exit(result.exit_code)
