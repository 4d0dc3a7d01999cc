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
from agv_mission.json_values import json_default
from agv_mission.missions.load.resolved import LoadedMission
from agv_mission.missions.report.run_plot import plot_run
from agv_mission.missions.run.metrics import COVARIANCE_COLUMNS
from agv_mission.missions.run.people_record import write_people_csv
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
    for setup in loaded.robots:  # a fleet's robots, each with the one-robot result keys
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
