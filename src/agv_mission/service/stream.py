"""A run's observations as live-stream messages: to the service (live, thinned to what a
client can use) and to ``stream.jsonl`` in the run directory (for replay)."""

from __future__ import annotations

import math
import time
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any, TextIO

from agv_mission.geometry import Pose2D
from agv_mission.missions.observe import RunStart, StepSample, TreeNode
from agv_mission.service import messages as msg
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


class StreamObserver:
    """Turns run observations into stream messages: to the service (live) and to
    ``stream.jsonl`` in the run directory (for replay)."""

    def __init__(self, conn: Connection, run_dir: Path | None) -> None:
        self.conn = conn
        self.outbox = Outbox(conn)
        self.file: TextIO | None = (
            open(run_dir / STREAM_FILE, "w", encoding="utf-8")  # noqa: SIM115
            if run_dir is not None
            else None
        )
        self.status = "running"
        self.nodes: list[TreeNode] | None = None
        self.task: dict[str, Any] | None = None
        self.recorded: dict[str, Pose2D] = {}
        self.last_progress = 0.0
        self._live_due: dict[str, float] = {}
        self._file_due: dict[str, float] = {}
        self._last_map = -math.inf
        self._goal: dict[str, float] | None = None
        self._last_live_state = -math.inf
        self.sim_time = 0.0
        self.cpu0 = time.process_time()  # the worker's CPU seconds are reported from here
        self.closed = False

    # ---------------------------------------------------------------- sending

    def emit(self, message: dict[str, Any], live: bool = True, to_file: bool = True) -> None:
        text = msg.dumps(message)
        if to_file and self.file is not None:
            self.file.write(text + "\n")
        if live:
            self.send(("msg", message["type"], text, message.get("t")))

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
        self.nodes = start.tree_nodes
        self.emit(msg.tree_message(start.tree_nodes))

    def on_step(self, s: StepSample) -> None:
        wall = time.monotonic()
        self.sim_time = s.t
        if s.tree_nodes is not None:
            self.nodes = s.tree_nodes
            self.emit(msg.tree_message(s.tree_nodes))
        self.task = None if s.task_index is None else {"index": s.task_index, "type": s.task_type}
        for event in s.events:
            self.emit({"type": "event", **event})
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
        if s.plan is not None:
            self.emit({"type": "plan", "t": round(s.t, 3), "path": msg.xy_list(s.plan)})
        goal = msg.pose(s.goal)
        if goal != self._goal:
            self._goal = goal
            self.emit({"type": "goal", "t": round(s.t, 3), "pose": goal})
        self._thinned(s, wall)
        live = s.t >= self._last_live_state + LIVE_STATE_SPACING - 1e-6
        if live:
            self._last_live_state = s.t
        self.emit(self.state(s), live=live)
        if wall - self.last_progress >= PROGRESS_PERIOD:
            self.last_progress = wall
            self.send(("progress", self.progress()))

    def _thinned(self, s: StepSample, wall: float) -> None:
        """Scans, particles and horizons: every one is costly to encode, so at most a few
        per wall second live and a few per sim second in the file."""
        parts = (
            ("scan", s.scan, LIVE_SCAN_PERIOD),
            ("particles", s.particles, LIVE_PARTICLES_PERIOD),
            ("horizon", s.horizon, LIVE_HORIZON_PERIOD),
            ("people", s.people, LIVE_PEOPLE_PERIOD),
        )
        for kind, data, live_period in parts:
            if data is None:
                continue
            live = self._due(self._live_due, kind, wall, live_period)
            to_file = self._due(self._file_due, kind, s.t - 1e-9, FILE_THIN_PERIOD)
            if not (live or to_file):
                continue
            if kind == "scan":
                message = {
                    "type": "scan",
                    "t": round(s.t, 3),
                    "points": msg.xy_list(data.points(s.estimate)),
                }
            elif kind == "particles":
                message = {
                    "type": "particles",
                    "t": round(s.t, 3),
                    "particles": msg.particles_list(data),
                }
            elif kind == "people":
                message = msg.people_message(s.t, *data)
            else:
                message = {"type": "horizon", "t": round(s.t, 3), "path": msg.xy_list(data)}
            self.emit(message, live=live, to_file=to_file)

    def progress(self) -> dict[str, Any]:
        task = self.task or {}
        return {
            "sim_time": round(self.sim_time, 3),
            "task_index": task.get("index"),
            "task_type": task.get("type"),
            "detail": msg.detail_of(self.nodes),
            "cpu_time": round(time.process_time() - self.cpu0, 3),
        }

    def state(self, s: StepSample) -> dict[str, Any]:
        return {
            "type": "state",
            "t": round(s.t, 3),
            "pose": msg.pose(s.truth),
            "estimate": msg.pose(s.estimate),
            "covariance": msg.covariance_list(s.covariance),
            "v": round(s.v, 4),
            "w": round(s.w, 4),
            "status": self.status,
            "task": self.task,
            "progress": self.progress(),
            "battery": None if s.battery is None else round(s.battery, 5),
            "charging": s.charging,
            "docked": s.docked,
        }

    def on_end(self, record: Any) -> None:
        self.sim_time = record.sim_time

    def close(self) -> None:
        if self.file is not None:
            self.file.close()
            self.file = None
