"""A fleet run's record: each robot's own record and the fleet layer's summary
(dispatch, waits, deadlocks, robot-robot contacts, makespan), as fleet.md writes it."""

from __future__ import annotations

import math
from typing import Any

from agv_mission.missions.run.record import RunRecord


def fleet_record(
    by_name: dict[str, RunRecord],
    log: dict[str, Any],
    sim_time: float,
    wall_time: float,
    outcome: tuple[str, str | None],
    processes: int,
) -> RunRecord:
    """A fleet run's record: every robot's own record (``by_name``, in robot order) under
    ``robots`` and the fleet's summary from its ``log`` (fleet.md); ``outcome`` is the
    run's status and reason."""
    records = list(by_name.values())
    tasks = [{**task, "robot": name} for name, record in by_name.items() for task in record.tasks]
    gap = log["robot_robot_min_distance"]
    collisions = sum(r.metrics["collisions"] for r in records)
    clearances = [
        r.metrics["min_clearance"] for r in records if r.metrics["min_clearance"] is not None
    ]
    fleet = {
        "dispatch": log["dispatch"],
        "makespan": log["makespan"],
        "robot_robot_collisions": len(log["robot_robot_collisions"]),
        "robot_robot_min_distance": round(gap, 4) if math.isfinite(gap) else None,
        "waits": {"count": log["waits"]["count"], "time": round(log["waits"]["time"], 3)},
        "deadlocks": log["deadlocks"],
    }
    metrics = {
        "sim_time": round(sim_time, 3),
        "wall_time": round(wall_time, 3),
        "real_time_factor": round(sim_time / wall_time, 2) if wall_time > 0 else None,
        "robots": len(records),
        "processes": processes,
        "distance_driven": round(sum(r.metrics["distance_driven"] for r in records), 4),
        "collisions": collisions + fleet["robot_robot_collisions"],
        "min_clearance": min(clearances) if clearances else None,
    }
    events = sorted(
        ({**e, "robot": name} for name, record in by_name.items() for e in record.events),
        key=lambda e: e.get("t", 0.0),
    )
    return RunRecord(
        status=outcome[0],
        reason=outcome[1],
        sim_time=round(sim_time, 6),
        wall_time=round(wall_time, 3),
        tasks=tasks,
        metrics=metrics,
        trajectory=records[0].trajectory[:0],
        paths=[p for record in records for p in record.paths],
        events=events,
        tree_text="\n".join(f"[{name}]\n{record.tree_text}" for name, record in by_name.items()),
        extras={"fleet": fleet, "collisions": log["robot_robot_collisions"], **_gathered(by_name)},
        robots=by_name,
    )


def _gathered(by_name: dict[str, RunRecord]) -> dict[str, Any]:
    """The robots' recorded rooms (one table, in robot order: a label recorded twice keeps
    the later robot's) and built maps (each naming its robot), as a one-robot result has
    them."""
    rooms: dict[str, Any] = {}
    maps: list[dict[str, Any]] = []
    for name, record in by_name.items():
        rooms.update(record.extras.get("rooms_recorded", {}))
        maps += [{"robot": name, **m} for m in record.extras.get("maps", [])]
    return {**({"rooms_recorded": rooms} if rooms else {}), **({"maps": maps} if maps else {})}
