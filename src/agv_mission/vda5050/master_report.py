"""What a master's dispatch leaves behind: ``result.json`` (each task, each vehicle, the
fleet's dispatch and events), ``trajectory.csv`` from the vehicles' states, ``mission.yaml``."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any, Protocol

import yaml

from agv_mission.atomic import atomic_write_text
from agv_mission.missions.report.outputs import make_run_dir, write_json
from agv_mission.vda5050.routes import MasterPlan


class DispatchRecord(Protocol):
    """What a master's report reads (:class:`~agv_mission.vda5050.master.Master` is one):
    the plan, each vehicle as it saw it, what it dispatched and when, and the trajectory
    rows of the vehicles' states."""

    plan: MasterPlan
    peers: Mapping[str, Any]
    url: Any
    manufacturer: str
    dispatch: list[dict[str, Any]]
    events: list[dict[str, Any]]
    rows: list[tuple[Any, ...]]

    def now(self) -> float: ...


def master_result(master: DispatchRecord, status: str, reason: str | None) -> dict[str, Any]:
    """The dispatch's ``result.json``: the mission's status, each task, each vehicle."""
    robots = {}
    for name, peer in master.peers.items():
        mine = [t for t in master.plan.tasks if t.assigned == name]
        bad = [t for t in mine if t.status == "failed"]
        robots[name] = {
            "status": "failed"
            if bad
            else (
                "succeeded"
                if all(t.status in ("succeeded", "skipped") for t in mine)
                else "not_run"
                if not mine
                else "incomplete"
            ),
            "reason": bad[0].reason if bad else None,
            "connection": peer.connection,
            "tasks": [
                {"task": t.number, "type": t.type, "status": t.status, "reason": t.reason}
                for t in mine
            ],
            "metrics": {
                "orders": peer.orders,
                "order_updates": peer.updates,
                "distance": round(peer.distance, 3),
            },
        }
    return {
        "name": master.plan.name,
        "status": status,
        "reason": reason,
        "broker": str(master.url),
        "manufacturer": master.manufacturer,
        "wall_time": round(master.now(), 3),
        "tasks": [
            {
                "task": t.number,
                "type": t.type,
                "robot": t.assigned,
                "status": t.status,
                "reason": t.reason,
                "nodes": [n.node_id for n in t.nodes],
                "actions": list(t.actions.values()),
            }
            for t in master.plan.tasks
        ],
        "robots": robots,
        "fleet": {
            "dispatch": master.dispatch,
            "events": master.events,
            "makespan": round(master.now(), 3),
        },
    }


TRAJECTORY_HEADER = "robot,t,x,y,theta,vx,omega"


def write_outputs(run_dir: Path, master: DispatchRecord, result: dict[str, Any]) -> None:
    """``mission.yaml``, ``trajectory.csv`` (from the vehicles' state and visualization)
    and, last, ``result.json``."""
    atomic_write_text(
        run_dir / "mission.yaml", yaml.safe_dump(master.plan.resolved, sort_keys=False)
    )
    lines = [TRAJECTORY_HEADER] + [
        f"{r[0]},{r[1]:.3f},{r[2]:.6f},{r[3]:.6f},{r[4]:.6f},{float(r[5]):.6f},{float(r[6]):.6f}"
        for r in master.rows
    ]
    atomic_write_text(run_dir / "trajectory.csv", "\n".join(lines) + "\n")
    write_json(run_dir / "result.json", {**result, "run_dir": str(run_dir)})


def new_run_dir(plan: MasterPlan, output: Path | None) -> Path:
    return make_run_dir(output if output is not None else plan.output, f"{plan.name}-vda5050")
