"""A run's picture (``run.png``): the map with its rooms, zones and docks, the planned
paths, the driven and estimated trajectories, particles, people and goals."""

from __future__ import annotations

import io
from pathlib import Path
from typing import Any

import numpy as np

from agv_mission.atomic import atomic_write_bytes
from agv_mission.maps.grid import OccupancyGrid
from agv_mission.maps.worlds import World
from agv_mission.maps.zones import ZoneFilters
from agv_mission.missions.load.layout import names_no_map
from agv_mission.missions.load.resolved import LoadedMission
from agv_mission.missions.report.palette import ROBOT_COLOURS
from agv_mission.missions.run.people_record import plot_people
from agv_mission.missions.run.record import RunRecord


def _plot_world(ax: Any, world: World) -> None:
    """The world's bodies, for a robot given no map (its map is blank)."""
    from matplotlib.collections import PatchCollection
    from matplotlib.patches import Circle, Polygon

    patches: list[Any] = [Circle((c.x, c.y), c.radius) for c in world.cylinders]
    for b in world.boxes:
        c, s = np.cos(b.yaw), np.sin(b.yaw)
        corners = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]]) * [b.half_x, b.half_y]
        patches.append(Polygon(corners @ np.array([[c, s], [-s, c]]) + [b.x, b.y], closed=True))
    if patches:
        ax.add_collection(PatchCollection(patches, color="0.35", lw=0))
        ax.fill([], [], color="0.35", label="the world (no map given)")


def _plot_zones(ax: Any, zones: ZoneFilters) -> None:
    """Keepout zones in red, speed zones in blue (darker: slower), as their rasters."""
    xmin, xmax, ymin, ymax = zones.grid.extent
    extent = (xmin, xmax, ymin, ymax)
    if zones.keepout.any():
        rgba = np.zeros((*zones.keepout.shape, 4))
        rgba[zones.keepout] = (0.85, 0.1, 0.1, 0.35)
        ax.imshow(rgba, origin="lower", extent=extent, interpolation="nearest")
        ax.fill([], [], color=(0.85, 0.1, 0.1, 0.35), label="keepout zones")
    if zones.levels:
        limited = np.isfinite(zones.speed)
        rgba = np.zeros((*zones.speed.shape, 4))
        slow = 1.0 - np.where(limited, zones.speed, zones.max_speed) / zones.max_speed
        rgba[limited] = np.column_stack(
            [np.full(limited.sum(), 0.1), np.full(limited.sum(), 0.3), np.ones(limited.sum()),
             0.15 + 0.35 * slow[limited]]
        )  # fmt: skip
        ax.imshow(rgba, origin="lower", extent=extent, interpolation="nearest")
        ax.fill([], [], color=(0.1, 0.3, 1.0, 0.35), label="speed zones")
        for level, (r, c) in _zone_labels(zones):
            x, y = zones.grid.cell_to_world(np.array(r), np.array(c))
            ax.text(x, y, f"{level:.2g} m/s", color="navy", fontsize=7, ha="center")


def _zone_labels(zones: ZoneFilters) -> list[tuple[float, tuple[int, int]]]:
    """A cell in the middle of each speed level's cells, to print its limit at."""
    out = []
    for level in zones.levels:
        rows, cols = np.nonzero(zones.speed == np.float32(level))
        k = len(rows) // 2
        out.append((level, (int(rows[k]), int(cols[k]))))
    return out


def _plot_bodies(ax: Any, loaded: LoadedMission, record: RunRecord, patch: Any) -> None:
    """Each robot's footprint (its polygon, or its circle) where it started and ended."""
    own = record.robots or ({loaded.robots[0].name: record} if loaded.robots else {})
    outlines = {r.name: r.robot.outline for r in loaded.robots}
    for k, (name, rec) in enumerate(own.items()):
        t, outline = rec.trajectory, outlines.get(name)
        if outline is None or not t.size:
            continue
        colour = ROBOT_COLOURS[k % len(ROBOT_COLOURS)]
        for row in (t[0], t[-1]):
            xy = outline.in_map(float(row[1]), float(row[2]), float(row[3]))
            ax.add_patch(patch(xy, closed=True, fill=False, lw=0.8, ec=colour, alpha=0.8))


def plot_run(path: Path, loaded: LoadedMission, record: RunRecord) -> None:
    """The map with rooms, planned paths, the driven and estimated trajectory, and goals."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Circle, Polygon

    grid = record.built_map if record.built_map is not None else loaded.map
    xmin, xmax, ymin, ymax = grid.extent
    image = np.full(grid.data.shape, 0.75)
    image[grid.data == 0] = 1.0
    image[grid.data == 100] = 0.0
    fig, ax = plt.subplots(figsize=(8, 8 * (ymax - ymin) / max(xmax - xmin, 1e-6) + 0.6), dpi=110)
    ax.imshow(
        image,
        cmap="gray",
        vmin=0,
        vmax=1,
        origin="lower",
        extent=(xmin, xmax, ymin, ymax),
        interpolation="nearest",
    )
    _plot_places(ax, loaded)
    for i, p in enumerate(record.paths):
        ax.plot(
            p[:, 0],
            p[:, 1],
            "-",
            lw=0.8,
            color="tab:orange",
            alpha=0.6,
            label="planned paths" if i == 0 else None,
        )
    _plot_obstacles(ax, loaded, Circle, Polygon)
    if record.people is not None:
        plot_people(ax, record.people.xy, record.people.radii)
    _plot_particles(ax, record.particle_snapshots)
    _plot_trajectories(ax, record)
    _plot_bodies(ax, loaded, record, Polygon)
    for e in record.events:
        if e["event"] == "goal_reached":
            ax.plot(e["x"], e["y"], "*", color="gold", markeredgecolor="k", ms=11)
        elif e["event"] == "goal_failed":
            ax.plot(e.get("x", np.nan), e.get("y", np.nan), "x", color="red", ms=10)
    _frame(ax, grid, loaded, record)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", bbox_inches="tight")
    plt.close(fig)
    atomic_write_bytes(path, buf.getvalue())


def _plot_places(ax: Any, loaded: LoadedMission) -> None:
    """Zones, the world's walls (a run without a map), rooms and docks."""
    if loaded.zones is not None:
        _plot_zones(ax, loaded.zones)
    if names_no_map(loaded.mission.map):
        _plot_world(ax, loaded.world)
    for room in loaded.rooms.values():
        poly = np.asarray(room.polygon + (room.polygon[0],))
        ax.plot(poly[:, 0], poly[:, 1], "--", lw=0.8, color="tab:purple", alpha=0.7)
        cx, cy = room.inside_point()
        ax.text(cx, cy, room.label, color="tab:purple", ha="center", fontsize=8, alpha=0.8)
    for i, dock in enumerate(loaded.docks.values()):
        d = dock.pose
        ax.plot(d.x, d.y, "s", color="goldenrod", ms=6, label="docks" if i == 0 else None)
        ax.annotate(dock.name, (d.x, d.y), fontsize=7, color="goldenrod")


def _plot_obstacles(ax: Any, loaded: LoadedMission, circle: Any, polygon: Any) -> None:
    """The mission's unmapped obstacles (cylinders and boxes)."""
    for i, o in enumerate(loaded.mission.obstacles):
        label = "unmapped obstacles" if i == 0 else None
        if o.type == "cylinder":
            ax.add_patch(circle((o.x, o.y), o.radius, color="tab:red", alpha=0.6, label=label))
        else:
            c, s = np.cos(o.yaw), np.sin(o.yaw)
            corners = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]]) * [o.size_x / 2, o.size_y / 2]
            xy = corners @ np.array([[c, s], [-s, c]]) + [o.x, o.y]
            ax.add_patch(polygon(xy, closed=True, color="tab:red", alpha=0.6, label=label))


def _plot_particles(ax: Any, snapshots: list[tuple[float, np.ndarray]]) -> None:
    """Up to six of the particle filter's snapshots, each with its time."""
    if snapshots:
        picks = sorted(
            {round(i) for i in np.linspace(0, len(snapshots) - 1, min(6, len(snapshots)))}
        )
        for k, i in enumerate(picks):
            t, particles = snapshots[i]
            ax.scatter(
                particles[:, 0],
                particles[:, 1],
                s=1.0,
                alpha=0.35,
                color="tab:red",
                linewidths=0,
                label="particles" if k == 0 else None,
            )
            ax.annotate(
                f"t={t:.0f}s",
                (float(np.mean(particles[:, 0])), float(np.mean(particles[:, 1]))),
                fontsize=6,
                color="tab:red",
                alpha=0.8,
            )


def _plot_trajectories(ax: Any, record: RunRecord) -> None:
    """The driven and estimated trajectory; a fleet's, a colour a robot."""
    traj = record.trajectory
    if traj.size:
        ax.plot(traj[:, 1], traj[:, 2], "-", lw=1.4, color=ROBOT_COLOURS[0], label="driven (true)")
        ax.plot(traj[:, 4], traj[:, 5], ":", lw=1.0, color="tab:green", label="estimated")
        ax.plot(traj[0, 1], traj[0, 2], "o", color=ROBOT_COLOURS[0], label="start")
    for k, (name, own) in enumerate(record.robots.items()):  # a fleet: a colour a robot
        t = own.trajectory
        if not t.size:
            continue
        colour = ROBOT_COLOURS[k % len(ROBOT_COLOURS)]
        ax.plot(t[:, 1], t[:, 2], "-", lw=1.4, color=colour, label=name)
        ax.plot(t[:, 4], t[:, 5], ":", lw=0.8, color=colour, alpha=0.7)
        ax.plot(t[0, 1], t[0, 2], "o", color=colour)
        ax.plot(t[-1, 1], t[-1, 2], "s", color=colour)


def _frame(ax: Any, grid: OccupancyGrid, loaded: LoadedMission, record: RunRecord) -> None:
    """The view (the map's free space), axes, title and legend."""
    occupied = np.argwhere(grid.data == 0)
    if occupied.size:
        pts = grid.cell_to_world(occupied[:, 0], occupied[:, 1])
        pad = 1.0
        ax.set_xlim(pts[:, 0].min() - pad, pts[:, 0].max() + pad)
        ax.set_ylim(pts[:, 1].min() - pad, pts[:, 1].max() + pad)
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    title = f"{loaded.name}: {record.status}  (sim {record.sim_time:.1f} s)"
    battery = record.metrics.get("battery")
    if battery:
        title += f"  battery {battery['start']:.0%} -> {battery['end']:.0%}"
        title += f" (min {battery['minimum']:.0%})"
    ax.set_title(title)
    if ax.get_legend_handles_labels()[0]:  # a run that ended before its first row has none
        ax.legend(loc="upper right", fontsize=7)
