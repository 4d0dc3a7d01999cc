"""What a run reports of its navigation: the legs (one goal pursued each) with their
planned, shortest and driven lengths, and the navigator's counters and timings."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from agv_mission.geometry import Pose2D


@dataclass
class Leg:
    """One goal pursued: what was planned, what was shortest, when it began and ended.

    ``planned`` is the length of the leg's first plan; ``shortest`` the length of the
    shortest path at the planner's clearance between the same points, on the same costmap
    (no inflation cost, no fillets); ``shortest_free`` the shortest free path's (any-angle,
    in the robot's configuration space: no margin beyond its radius, as the field
    measures planners; :mod:`agv_mission.planners.shortest_free`). The driven distance
    comes from the trajectory.
    """

    goal: Pose2D
    t_start: float
    start: Pose2D
    planned: float | None = None
    shortest: float | None = None
    shortest_free: float | None = None
    t_end: float | None = None
    status: str = "running"
    replans: int = 0


@dataclass
class NavigationStats:
    """Counters and timings a run reports."""

    plans: int = 0
    replans: int = 0
    planning_times: list[float] = field(default_factory=list)
    solve_times: list[float] = field(default_factory=list)
    solver_failures: int = 0
    legs: list[Leg] = field(default_factory=list)


RATIOS = (
    "driven_vs_planned",
    "driven_vs_shortest",
    "planned_vs_shortest",
    "driven_vs_shortest_free",
    "planned_vs_shortest_free",
)
MOVING, STOPPED = 0.05, 0.01  # m/s: a stop is moving -> stopped -> moving within one leg


def leg_report(
    legs: list[Leg], t: np.ndarray, xy: np.ndarray, v: np.ndarray, end_time: float
) -> dict[str, Any]:
    """Per-leg path quality from the true trajectory (times ``t``, positions ``xy``,
    commanded speeds ``v``): planned and shortest length, distance driven, their ratios
    and the stops on the way; plus the worst ratio over the legs that succeeded."""
    rows: list[dict[str, Any]] = []
    for leg in legs:
        t1 = leg.t_end if leg.t_end is not None else end_time
        # [t_start, t_end): the row at t_end is the next leg's first
        inside = (t >= leg.t_start - 1e-9) & ((t < t1 - 1e-9) | (t1 >= end_time))
        path = xy[inside]
        driven = float(np.sum(np.linalg.norm(np.diff(path, axis=0), axis=1))) if len(path) else 0.0
        row: dict[str, Any] = {
            "goal": [round(leg.goal.x, 3), round(leg.goal.y, 3)],
            "status": leg.status if leg.t_end is not None else "running",
            "t_start": round(leg.t_start, 3),
            "t_end": round(t1, 3),
            "planned": _r(leg.planned),
            "shortest": _r(leg.shortest),
            "shortest_free": _r(leg.shortest_free),
            "driven": round(driven, 4),
            "replans": leg.replans,
            "stops": _stops(v[inside]),
        }
        for key, num, den in (
            ("driven_vs_planned", driven, leg.planned),
            ("driven_vs_shortest", driven, leg.shortest),
            ("planned_vs_shortest", leg.planned, leg.shortest),
            ("driven_vs_shortest_free", driven, leg.shortest_free),
            ("planned_vs_shortest_free", leg.planned, leg.shortest_free),
        ):
            row[key] = round(num / den, 4) if num is not None and den and den > 0.2 else None
        rows.append(row)
    done = [r for r in rows if r["status"] == "succeeded"]
    report: dict[str, Any] = {"legs": rows}
    for key in RATIOS:
        values = [r[key] for r in done if r[key] is not None]
        report[f"{key}_max"] = max(values) if values else None
    report["stops"] = sum(r["stops"] for r in done)
    # Totals over the legs that have each length: what was planned (first plans) and
    # what was shortest; the distance driven is ``metrics.distance_driven``.
    report["planned_length"] = _r(sum(leg.planned for leg in legs if leg.planned is not None))
    report["shortest_length"] = _r(sum(leg.shortest for leg in legs if leg.shortest is not None))
    report["shortest_free_length"] = _r(
        sum(leg.shortest_free for leg in legs if leg.shortest_free is not None)
    )
    return report


def _stops(v: np.ndarray) -> int:
    """Times the speed fell from moving to standing and rose again (stop-and-go)."""
    stops, moving, pending = 0, False, False
    for speed in np.abs(v):
        if speed >= MOVING:
            if pending:
                stops += 1
                pending = False
            moving = True
        elif speed < STOPPED and moving:
            moving, pending = False, True
    return stops


def _r(value: float | None) -> float | None:
    return None if value is None else round(value, 4)
