"""What a run produced (:class:`RunRecord`), before the run directory is written."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from agv_mission.maps.grid import OccupancyGrid
from agv_mission.missions.load.resolved import LoadedMission
from agv_mission.missions.run.metrics import run_metrics

TRAJECTORY_COLUMNS = ("t", "x", "y", "yaw", "est_x", "est_y", "est_yaw", "v", "w")


@dataclass
class RunRecord:
    """Everything a run produced, before it is written out."""

    status: str
    reason: str | None
    sim_time: float
    wall_time: float
    tasks: list[dict[str, Any]]
    metrics: dict[str, Any]
    trajectory: np.ndarray  # (steps, len(TRAJECTORY_COLUMNS))
    paths: list[np.ndarray]
    events: list[dict[str, Any]]
    tree_text: str
    extras: dict[str, Any] = field(default_factory=dict)  # more keys for result.json
    particle_snapshots: list[tuple[float, np.ndarray]] = field(default_factory=list)
    built_map: OccupancyGrid | None = None  # the last map a map_area task saved
    covariance: np.ndarray | None = None  # (steps, len(COVARIANCE_COLUMNS)), NaN: none
    battery: np.ndarray | None = None  # (steps,) the level 0..1; None: not modelled
    robots: dict[str, RunRecord] = field(default_factory=dict)  # a fleet's, by robot name
    people: Any = None  # the run's PeopleTrack (people.csv, run.png); None: nobody walked
    btlog: bytes | None = None  # tree.btlog (Groot2's FileLogger2 format); None: no tree ran


def bare_record(
    loaded: LoadedMission, status: str, reason: str, wall_time: float, sim_time: float = 0.0
) -> RunRecord:
    """The record of a run that ended before (or without) its loop: every task not run,
    no trajectory, the metrics' keys with nothing measured."""
    types = loaded.tree.task_types() if loaded.tree is not None else []
    tasks = [
        {"index": i + 1, "type": task_type, "status": "not_run", "reason": None}
        for i, task_type in enumerate(types)
    ]
    trajectory = np.zeros((0, len(TRAJECTORY_COLUMNS)))
    metrics = run_metrics(trajectory, None, 0, math.inf, sim_time, wall_time)
    metrics["navigation"]["recoveries"] = {}
    metrics["battery"] = None
    return RunRecord(
        status=status,
        reason=reason,
        sim_time=round(sim_time, 6),
        wall_time=round(wall_time, 3),
        tasks=tasks,
        metrics=metrics,
        trajectory=trajectory,
        paths=[],
        events=[],
        tree_text="",
        extras={"collisions": [], "faults": []},
    )
