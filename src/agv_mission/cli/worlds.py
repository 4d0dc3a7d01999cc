"""``world``: a world's extent, spawn, rooms and map, to pick waypoints from."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer
from rich.table import Table

from agv_mission.cli.console import failure, out


def world(
    name: Annotated[str, typer.Argument(help="a built-in world (or a world file or ROS map YAML)")],
    save_map: Annotated[
        Optional[Path],  # noqa: UP007, UP045
        typer.Option("--save-map", help="map_saver stem: writes PATH.pgm + PATH.yaml"),
    ] = None,
    robot: Annotated[
        Optional[str],  # noqa: UP007, UP045
        typer.Option(help="a Gazebo world is cut at this robot's scan height (default 0.17 m)"),
    ] = None,
) -> None:
    """Describe a world (extent, spawn, rooms, docks) and optionally save its map."""
    from agv_mission.maps.ros_map import save_ros_map
    from agv_mission.maps.world_loader import DEFAULT_SCAN_HEIGHT, WorldError, load_world
    from agv_mission.maps.worlds import describe
    from agv_mission.robots.robot_files import RobotFileError, load_robot

    height = DEFAULT_SCAN_HEIGHT
    if robot is not None:
        try:
            height = load_robot(robot, Path.cwd()).lidar.height
        except FileNotFoundError:
            raise failure(
                "invalid input", f"--robot {robot}: no built-in robot or robot file"
            ) from None
        except (RobotFileError, OSError, ValueError) as exc:
            raise failure("invalid input", f"--robot {robot}: {exc}") from None
    try:
        loaded = load_world(name, Path.cwd(), height)
    except WorldError as exc:
        raise failure("invalid input", str(exc)) from None
    except (OSError, ValueError, RuntimeError) as exc:
        raise failure("invalid input", f"cannot read world {name!r}: {exc}") from None
    about = describe(loaded)
    xmin, xmax, ymin, ymax = about.extent
    grid = loaded.map
    out.print(
        f"[bold]{about.name}[/]: {xmax - xmin:.2f} x {ymax - ymin:.2f} m "
        f"(x {xmin:g}..{xmax:g}, y {ymin:g}..{ymax:g}); map {grid.width} x {grid.height} "
        f"cells at {grid.resolution:g} m",
        highlight=False,
    )
    s = about.spawn
    out.print(f"spawn: x {s.x:.2f}, y {s.y:.2f}, yaw {s.yaw:.2f}", highlight=False)
    if about.rooms:
        table = Table(show_header=True, header_style="bold", box=None)
        for column in ("room", "x", "y", "yaw", "point"):
            table.add_column(column, justify="left" if column in ("room", "point") else "right")
        for room in about.rooms:
            p = room.point
            table.add_row(room.label, f"{p.x:.2f}", f"{p.y:.2f}", f"{p.yaw:.2f}", room.kind)
        out.print(table)
    else:
        out.print("rooms: none (give the mission a rooms file)", highlight=False)
    if loaded.docks:
        for dock in loaded.docks.values():
            d = dock.pose
            out.print(
                f"dock {dock.name}: x {d.x:.2f}, y {d.y:.2f}, yaw {d.yaw:.2f}", highlight=False
            )
    else:
        out.print("docks: none", highlight=False)
    if save_map is not None:
        try:
            pgm, yaml_path = save_ros_map(grid, save_map)
        except OSError as exc:
            raise failure(
                "invalid input", f"--save-map {save_map}: {exc.strerror or exc}"
            ) from None
        out.print(f"map: {pgm} + {yaml_path}", highlight=False, markup=False)
    raise typer.Exit(0)
