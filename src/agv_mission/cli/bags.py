"""``map``: an occupancy grid map from a recorded bag."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer

from agv_mission.cli.console import failure, invalid, out
from agv_mission.missions.load.errors import MissionError


def map_(
    bag: Annotated[
        Path,
        typer.Argument(
            help="ROS 1 .bag, ROS 2 bag directory, .mcap file or CARMEN log (.log, .log.gz)"
        ),
    ],
    save_map: Annotated[
        Path, typer.Option("--save-map", help="map_saver stem: writes PATH.pgm + PATH.yaml")
    ] = Path("map"),
    scan_topic: Annotated[
        Optional[str], typer.Option("--scan-topic", help="default: the LaserScan topic")  # noqa: UP007, UP045
    ] = None,
    odom_topic: Annotated[
        Optional[str],  # noqa: UP007, UP045
        typer.Option(
            "--odom-topic",
            help="default: the nav_msgs/Odometry topic, else /tf (CARMEN: the scans' own "
            "odometry; ODOM: the ODOM lines)",
        ),
    ] = None,
    truth_topic: Annotated[
        Optional[str],  # noqa: UP007, UP045
        typer.Option(
            "--truth-topic",
            help="ground truth for the report's RMSE and relative pose error (CARMEN: "
            "FLASER / ROBOTLASER1 / ODOM, the poses those lines carry: a corrected log's)",
        ),
    ] = None,
    robot: Annotated[
        Optional[str],  # noqa: UP007, UP045
        typer.Option(
            "--robot",
            help="whose topics, in a bag of several robots (a fleet run's: /NAME/scan, "
            "/NAME/odom); default: the only one",
        ),
    ] = None,
    set_: Annotated[
        list[str], typer.Option("--set", help="SLAM KEY=VALUE (stack.slam.KEY or KEY)")
    ] = [],  # noqa: B006
) -> None:
    """Build an occupancy grid map from a recorded bag or CARMEN log (map_saver format,
    cropped to what was seen, + a report)."""
    from agv_mission.bags.offline import (
        MappingFailed,
        default_slam,
        map_bag,
        report_lines,
        save_outputs,
    )
    from agv_mission.bags.reader import BagError

    try:
        config = default_slam(set_)
        result = map_bag(bag, config, scan_topic, odom_topic, truth_topic, robot=robot)
    except MissionError as exc:
        raise invalid(exc) from None
    except BagError as exc:
        raise failure("invalid input", str(exc)) from None
    except MappingFailed as exc:
        raise failure("mapping failed", str(exc), 1) from None
    for line in report_lines(result, save_outputs(result, save_map)):
        out.print(line, highlight=False, markup=False)
    raise typer.Exit(0)
