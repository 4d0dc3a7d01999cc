"""The run directory: result, trajectory, resolved mission, tree and plot, written atomically."""

from __future__ import annotations

import contextlib
import io
import json
import re
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from agv_mission.atomic import atomic_write_bytes, atomic_write_text
from agv_mission.maps.worlds import World
from agv_mission.maps.zones import ZoneFilters
from agv_mission.messages import json_default
from agv_mission.missions.load.no_map import names_no_map
from agv_mission.missions.load.resolved import LoadedMission
from agv_mission.missions.report.palette import ROBOT_COLOURS
from agv_mission.missions.run.metrics import COVARIANCE_COLUMNS
from agv_mission.missions.run.people_record import plot_people, write_people_csv
from agv_mission.missions.run.record import TRAJECTORY_COLUMNS, RunRecord

#: The last column of trajectory.csv: the battery's level (0..1) at each step.
BATTERY_COLUMNS = ("battery",)


def make_run_dir(output_root: Path, name: str) -> Path:
    """``OUTPUT/<name>-<UTC timestamp>/``, unique even for runs started in the same second."""
    stamp = datetime.now(timezone.utc).strftime("%Y%m%dT%H%M%SZ")
    output_root.mkdir(parents=True, exist_ok=True)
    for n in range(1000):
        path = output_root / (f"{name}-{stamp}" + (f"-{n}" if n else ""))
        try:
            path.mkdir()
            return path
        except FileExistsError:
            continue
    raise RuntimeError(f"cannot create a run directory under {output_root}")


class RunDirError(Exception):
    """The run directory cannot be made; the message names the root and why."""


def open_run_dir(root: Path, loaded: LoadedMission, name: str | None = None) -> Path:
    """Make ``root/<name>-<UTC timestamp>/`` (name: the mission's) and write the resolved
    ``mission.yaml`` into it: from here on the directory must end with a result.json."""
    try:
        run_dir = make_run_dir(root, name or loaded.name)
        write_mission(run_dir, loaded)
    except (OSError, ValueError) as exc:
        reason = getattr(exc, "strerror", None) or exc
        raise RunDirError(f"{str(root)!r}: cannot create a run directory there: {reason}") from exc
    return run_dir


def result_document(loaded: LoadedMission, record: RunRecord, run_dir: Path) -> dict[str, Any]:
    robots = {}
    for setup in loaded.fleet:  # a fleet's robots, each with the one-robot result keys
        own = record.robots.get(setup.name)
        if own is not None:
            robots[setup.name] = {
                "status": own.status,
                "reason": own.reason,
                "robot": setup.robot.name,
                "tasks": own.tasks,
                "metrics": own.metrics,
                **{k: own.extras[k] for k in ("rooms_recorded", "maps") if k in own.extras},
            }
    return {
        "name": loaded.name,
        "status": record.status,
        "reason": record.reason,
        "sim_time": record.sim_time,
        "wall_time": record.wall_time,
        "seed": loaded.mission.seed,
        "world": loaded.world.name,
        **({"world_import": loaded.world.imported} if loaded.world.imported else {}),
        "robot": loaded.robot.name,
        "tasks": record.tasks,
        "metrics": record.metrics,
        "events": record.events,
        **record.extras,
        **({"robots": robots} if robots else {}),
        **({"warnings": [str(w) for w in loaded.warnings]} if loaded.warnings else {}),
        "run_dir": str(run_dir),
    }


def write_mission(run_dir: Path, loaded: LoadedMission) -> None:
    text = yaml.safe_dump(loaded.resolved(), sort_keys=False, default_flow_style=None)
    atomic_write_text(run_dir / "mission.yaml", text)


def write_run(run_dir: Path, loaded: LoadedMission, record: RunRecord) -> dict[str, Any]:
    """Write every output of a finished run; returns the result document.

    ``result.json`` comes first: whatever fails after it (a full disk, a plotting error)
    leaves the result in place, and is added to it under ``output_errors``.
    """
    result = result_document(loaded, record, run_dir)
    write_json(run_dir / "result.json", result)
    errors: list[str] = []
    for name, write in (
        ("trajectory.csv", lambda p: write_run_trajectory(p, record)),
        ("tree.txt", lambda p: atomic_write_text(p, strip_ansi(record.tree_text) + "\n")),
        ("run.png", lambda p: plot_run(p, loaded, record)),
        *_btlogs(record),
        *(
            [("people.csv", lambda p: write_people(p, record.people))]
            if record.people is not None
            else []
        ),
    ):
        try:
            write(run_dir / name)
        except Exception as exc:  # noqa: BLE001 (any failure of one output is reported)
            errors.append(f"{name}: {type(exc).__name__}: {exc}")
    if errors:
        result["output_errors"] = errors
        with contextlib.suppress(OSError):
            write_json(run_dir / "result.json", result)
    return result


def _btlogs(record: RunRecord) -> list[tuple[str, Any]]:
    """``tree.btlog`` (a fleet: ``tree.<robot>.btlog`` per robot), for Groot2."""
    logs = (
        {f"tree.{name}.btlog": r.btlog for name, r in record.robots.items()}
        if record.robots
        else {"tree.btlog": record.btlog}
    )
    return [
        (name, lambda p, data=data: atomic_write_bytes(p, data))
        for name, data in logs.items()
        if data is not None
    ]


_ANSI = re.compile(r"\x1b\[[0-9;?]*[A-Za-z]")


def strip_ansi(text: str) -> str:
    """``text`` without terminal colour codes (py_trees colours its tree on a terminal)."""
    return _ANSI.sub("", text)


def write_json(path: Path, doc: dict[str, Any]) -> None:
    atomic_write_text(path, json.dumps(doc, indent=2, allow_nan=False, default=json_default) + "\n")


def write_people(path: Path, track: Any) -> None:
    """``people.csv``: where each person present was at each control step."""
    write_people_csv(path, track.t, track.xy, track.ids)


def write_run_trajectory(path: Path, record: RunRecord) -> None:
    """``trajectory.csv`` of a run: a fleet's with a first column ``robot`` (fleet.md), one
    row per robot per control step, in time order."""
    if not record.robots:
        write_trajectory(path, record.trajectory, record.covariance, record.battery)
        return
    parts = []
    for name, own in record.robots.items():
        buf = io.StringIO()
        covariance = own.covariance
        if covariance is None:  # every robot's rows have the same columns
            covariance = np.full((len(own.trajectory), len(COVARIANCE_COLUMNS)), np.nan)
        write_trajectory(buf, own.trajectory, covariance, own.battery)
        header, *rows = buf.getvalue().splitlines()
        parts.append([(float(r.split(",", 1)[0]), k, f"{name},{r}") for k, r in enumerate(rows)])
    rows = sorted((row for part in parts for row in part), key=lambda r: (r[0], r[1]))
    text = "robot," + header + "\n" + "".join(r[2] + "\n" for r in rows)
    atomic_write_text(path, text)


def write_trajectory(
    path: Path | io.StringIO,
    trajectory: np.ndarray,
    covariance: np.ndarray | None = None,
    battery: np.ndarray | None = None,
) -> None:
    """The contract's nine columns, then the estimate's covariance when the localiser has
    one, then the battery's level (``battery``, nan for a robot without one)."""
    buf = io.StringIO()
    columns = TRAJECTORY_COLUMNS
    fmt = ["%.6f"] * len(TRAJECTORY_COLUMNS)
    if covariance is not None and len(covariance) == len(trajectory):
        columns = TRAJECTORY_COLUMNS + COVARIANCE_COLUMNS
        trajectory = np.hstack([trajectory, covariance])
        fmt += ["%.6g"] * len(COVARIANCE_COLUMNS)
    columns += BATTERY_COLUMNS
    if battery is None or len(battery) != len(trajectory):  # not modelled: nan
        battery = np.full(len(trajectory), np.nan)
    trajectory = np.hstack([trajectory, battery.reshape(-1, 1)])
    fmt += ["%.6f"]
    buf.write(",".join(columns) + "\n")
    if trajectory.size:
        np.savetxt(buf, trajectory, delimiter=",", fmt=fmt)
    if isinstance(path, io.StringIO):
        path.write(buf.getvalue())
    else:
        atomic_write_text(path, buf.getvalue())


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
    for i, o in enumerate(loaded.mission.obstacles):
        label = "unmapped obstacles" if i == 0 else None
        if o.type == "cylinder":
            ax.add_patch(Circle((o.x, o.y), o.radius, color="tab:red", alpha=0.6, label=label))
        else:
            c, s = np.cos(o.yaw), np.sin(o.yaw)
            corners = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]]) * [o.size_x / 2, o.size_y / 2]
            xy = corners @ np.array([[c, s], [-s, c]]) + [o.x, o.y]
            ax.add_patch(Polygon(xy, closed=True, color="tab:red", alpha=0.6, label=label))
    if record.people is not None:
        plot_people(ax, record.people.xy, record.people.radii)
    snapshots = record.particle_snapshots
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
    _plot_bodies(ax, loaded, record, Polygon)
    for e in record.events:
        if e["event"] == "goal_reached":
            ax.plot(e["x"], e["y"], "*", color="gold", markeredgecolor="k", ms=11)
        elif e["event"] == "goal_failed":
            ax.plot(e.get("x", np.nan), e.get("y", np.nan), "x", color="red", ms=10)
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
    buf = io.BytesIO()
    fig.savefig(buf, format="png", bbox_inches="tight")
    plt.close(fig)
    atomic_write_bytes(path, buf.getvalue())
