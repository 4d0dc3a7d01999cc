"""A run's observations as live-stream messages: to the service (live, thinned to what a
client can use) and to ``stream.jsonl`` in the run directory (for replay)."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any, TextIO

from agv_mission.geometry import Pose2D
from agv_mission.missions.run.observe import RunStart
from agv_mission.missions.run.samples import StepSample, TreeNode
from agv_mission.service import stream_messages as msg
from agv_mission.service.links import Outbox

STREAM_FILE = "stream.jsonl"
LIVE_STATE_SPACING = 0.2  # sim seconds between live states: the contract's 5 per sim second
PROGRESS_PERIOD = 0.25  # wall seconds between progress reports
LIVE_SCAN_PERIOD = 0.2  # wall seconds between live scans (thinned; every scan is costly)
LIVE_HORIZON_PERIOD = 0.2
LIVE_PARTICLES_PERIOD = 0.5
LIVE_PEOPLE_PERIOD = 0.1  # wall seconds between live people (they walk: smoother than scans)
FILE_THIN_PERIOD = 0.5  # sim seconds between scans/particles/horizons in stream.jsonl
MAP_PERIOD = 1.0  # wall seconds between map messages while SLAM grows the map


@dataclass
class RobotView:
    """What the stream knows of one robot: its tree, task and goal, and when its thinned
    kinds are next due."""

    name: str
    nodes: list[TreeNode] | None = None
    task: dict[str, Any] | None = None
    goal: dict[str, float] | None = None
    last_live_state: float = -math.inf
    live_due: dict[str, float] = field(default_factory=dict)
    file_due: dict[str, float] = field(default_factory=dict)

    def progress(self) -> dict[str, Any]:
        task = self.task or {}
        return {
            "task_index": task.get("index"),
            "task_type": task.get("type"),
            "detail": msg.detail_of(self.nodes),
        }


class StreamObserver:
    """Turns run observations into stream messages: to the service (live) and to
    ``stream.jsonl`` in the run directory (for replay). Every robot's messages name it
    (``robot``); a fleet's robots are thinned each on its own."""

    def __init__(self, conn: Connection, run_dir: Path | None) -> None:
        self.conn = conn
        self.outbox = Outbox(conn)
        self.file: TextIO | None = (
            open(run_dir / STREAM_FILE, "w", encoding="utf-8")  # noqa: SIM115
            if run_dir is not None
            else None
        )
        self.status = "running"
        self.views: dict[str, RobotView] = {}
        self.recorded: dict[str, Pose2D] = {}
        self.last_progress = 0.0
        self._last_map = -math.inf
        self.sim_time = 0.0
        self.cpu0 = time.process_time()  # the worker's CPU seconds are reported from here
        self.closed = False

    def view(self, robot: str) -> RobotView:
        view = self.views.get(robot)
        if view is None:
            view = self.views[robot] = RobotView(robot)
        return view

    def task_of(self, robot: str) -> dict[str, Any] | None:
        """The robot's current task ``{index, type}`` (None: none running)."""
        view = self.views.get(robot)
        return None if view is None else view.task

    # ---------------------------------------------------------------- sending

    def emit(self, message: dict[str, Any], live: bool = True, to_file: bool = True) -> None:
        text = msg.dumps(message)
        if to_file and self.file is not None:
            self.file.write(text + "\n")
        if live:
            self.send(("msg", message["type"], text, message.get("t"), message.get("robot")))

    def send(self, item: tuple[Any, ...]) -> None:
        if self.closed or self.outbox.closed:
            return
        self.outbox.put(item)

    def flush(self) -> None:
        """Deliver what is queued and stop sending from the thread (the run is over)."""
        self.outbox.close()

    def _due(self, table: dict[str, float], key: str, now: float, period: float) -> bool:
        if now >= table.get(key, -math.inf):
            table[key] = now + period
            return True
        return False

    # ---------------------------------------------------------------- observer

    def on_start(self, start: RunStart) -> None:
        self.emit(msg.map_message(start.world_map))
        if start.keepout_mask is not None or start.speed_mask is not None:
            self.emit(msg.zones_message(start.keepout_mask, start.speed_mask))
        self.emit(msg.rooms_message(start.rooms, start.docks))
        self.emit(msg.recorded_message(self.recorded))
        self.emit(msg.robots_message(start))
        for r in start.robots:
            self.view(r.name).nodes = r.tree_nodes
            self.emit(msg.tree_message(r.tree_nodes, r.name))

    def on_step(self, s: StepSample) -> None:
        wall = time.monotonic()
        self.sim_time = s.t
        view = self.view(s.robot)
        if s.tree_nodes is not None:
            view.nodes = s.tree_nodes
            self.emit(msg.tree_message(s.tree_nodes, s.robot))
        view.task = None if s.task_index is None else {"index": s.task_index, "type": s.task_type}
        for event in s.events:
            self.emit({"type": "event", "robot": s.robot, **event})
            if event.get("event") == "room_recorded":
                self.recorded[str(event.get("room"))] = Pose2D(
                    float(event.get("x", 0.0)),
                    float(event.get("y", 0.0)),
                    float(event.get("yaw", 0.0)),
                )
                self.emit(msg.recorded_message(self.recorded))
        if s.grid is not None and wall - self._last_map >= MAP_PERIOD:
            self._last_map = wall
            self.emit(msg.map_message(s.grid))
        t = round(s.t, 3)
        if s.plan is not None:
            self.emit({"type": "plan", "robot": s.robot, "t": t, "path": msg.xy_list(s.plan)})
        goal = msg.pose(s.goal)
        if goal != view.goal:
            view.goal = goal
            self.emit({"type": "goal", "robot": s.robot, "t": t, "pose": goal})
        self._thinned(s, view, wall)
        live = s.t >= view.last_live_state + LIVE_STATE_SPACING - 1e-6
        if live:
            view.last_live_state = s.t
        self.emit(self.state(s), live=live)
        if wall - self.last_progress >= PROGRESS_PERIOD:
            self.last_progress = wall
            self.send(("progress", self.progress()))

    def _thinned(self, s: StepSample, view: RobotView, wall: float) -> None:
        """Scans, particles and horizons: every one is costly to encode, so at most a few
        per wall second live and a few per sim second in the file, per robot."""
        parts = (
            ("scan", s.scan, LIVE_SCAN_PERIOD),
            ("particles", s.particles, LIVE_PARTICLES_PERIOD),
            ("horizon", s.horizon, LIVE_HORIZON_PERIOD),
            ("people", s.people, LIVE_PEOPLE_PERIOD),
        )
        for kind, data, live_period in parts:
            if data is None:
                continue
            live = self._due(view.live_due, kind, wall, live_period)
            to_file = self._due(view.file_due, kind, s.t - 1e-9, FILE_THIN_PERIOD)
            if not (live or to_file):
                continue
            message: dict[str, Any] = {"type": kind, "robot": s.robot, "t": round(s.t, 3)}
            if kind == "scan":
                message["points"] = msg.xy_list(data.points(s.estimate))
            elif kind == "particles":
                message["particles"] = msg.particles_list(data)
            elif kind == "people":  # the world's, not the robot's: no robot key
                message = msg.people_message(s.t, *data)
            else:
                message["path"] = msg.xy_list(data)
            self.emit(message, live=live, to_file=to_file)

    def progress(self) -> dict[str, Any]:
        """Simulated time, CPU, the first robot's task and detail, and every robot's."""
        robots = {name: view.progress() for name, view in self.views.items()}
        lead = next(iter(robots.values()), {"task_index": None, "task_type": None, "detail": ""})
        detail = lead["detail"]
        if len(robots) > 1:
            detail = " · ".join(f"{name}: {p['task_type'] or 'idle'}" for name, p in robots.items())
        return {
            "sim_time": round(self.sim_time, 3),
            "task_index": lead["task_index"],
            "task_type": lead["task_type"],
            "detail": detail,
            "robots": robots,
            "cpu_time": round(time.process_time() - self.cpu0, 3),
        }

    def state(self, s: StepSample) -> dict[str, Any]:
        view = self.view(s.robot)
        return {
            "type": "state",
            "robot": s.robot,
            "t": round(s.t, 3),
            "pose": msg.pose(s.truth),
            "estimate": msg.pose(s.estimate),
            "covariance": msg.covariance_list(s.covariance),
            "v": round(s.v, 4),
            "w": round(s.w, 4),
            "status": self.status,
            "task": view.task,
            "progress": {"sim_time": round(s.t, 3), **view.progress()},
            "battery": None if s.battery is None else round(s.battery, 5),
            "charging": s.charging,
            "docked": s.docked,
        }

    def on_end(self, record: Any) -> None:
        self.sim_time = record.sim_time
        self.status = record.status

    def close(self) -> None:
        if self.file is not None:
            self.file.close()
            self.file = None
