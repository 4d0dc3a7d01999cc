"""One mission in its own process: load, run with a stream observer and a pipe control.

The service talks to a worker over one duplex :class:`multiprocessing.connection.Connection`
(a pipe for local processes, a socket for Ray tasks). Worker -> service: ``("msg", type,
text, t)`` live-stream messages (JSON text, encoded once here), ``("status", status)``,
``("progress", dict)``, ``("reply", request_id, code, body)`` and finally ``("end", status,
reason, result)``. Service -> worker: ``("cancel", reason)``, ``("pause",)``,
``("resume",)``, ``("cmd_vel", v, w)``, ``("goal", x, y, yaw)``, ``("record", request_id,
label)``.

Commands are read between control steps without waiting; while paused the worker blocks
on the connection, so a resume or cancel acts at once (no polling period).
"""

from __future__ import annotations

import contextlib
import math
import signal
import threading
import time
import traceback
from collections import deque
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any, TextIO

from agv_mission.geometry import Pose2D
from agv_mission.missions.observe import RunStart, StepSample, TreeNode
from agv_mission.service import messages as msg

STREAM_FILE = "stream.jsonl"
REMOTE_TIMEOUT = 0.5  # wall seconds without cmd_vel before a teleop robot stops
LIVE_STATE_SPACING = 0.2  # sim seconds between live states: the contract's 5 per sim second
PROGRESS_PERIOD = 0.25  # wall seconds between progress reports
LIVE_SCAN_PERIOD = 0.2  # wall seconds between live scans (thinned; every scan is costly)
LIVE_HORIZON_PERIOD = 0.2
LIVE_PARTICLES_PERIOD = 0.5
FILE_THIN_PERIOD = 0.5  # sim seconds between scans/particles/horizons in stream.jsonl
MAP_PERIOD = 1.0  # wall seconds between map messages while SLAM grows the map


COALESCED = frozenset({"state", "scan", "particles", "horizon"})  # latest wins while queued


class ServiceGone(Exception):
    """The service's end of the connection closed."""


class Outbox:
    """Sends to the service from a thread of its own, so the mission never waits for it.

    When the service reads slowly (a busy event loop, a full socket buffer), a frequent
    message (state, scan, particles, horizon) still queued is replaced in place by the
    newer one of its kind; other messages keep their order and are all delivered.
    """

    def __init__(self, conn: Connection) -> None:
        self.conn = conn
        self.closed = False
        self._queue: deque[list[Any]] = deque()
        self._slots: dict[str, list[Any]] = {}  # kind -> its queued, unsent slot
        self._cond = threading.Condition()
        self._stop = False
        self.coalesced = 0
        self._thread = threading.Thread(target=self._pump, name="outbox", daemon=True)
        self._thread.start()

    def put(self, item: tuple[Any, ...]) -> None:
        with self._cond:
            if self.closed or self._stop:
                return
            kind = item[1] if item[0] == "msg" and item[1] in COALESCED else None
            slot = self._slots.get(kind) if kind is not None else None
            if slot is not None:
                slot[0] = item
                self.coalesced += 1
                return
            slot = [item]
            self._queue.append(slot)
            if kind is not None:
                self._slots[kind] = slot
            self._cond.notify()

    def _pump(self) -> None:
        while True:
            with self._cond:
                while not self._queue and not self._stop:
                    self._cond.wait()
                if not self._queue:
                    return
                slot = self._queue.popleft()
                item = slot[0]
                if item[0] == "msg" and self._slots.get(item[1]) is slot:
                    del self._slots[item[1]]
            try:
                self.conn.send(item)
            except (OSError, EOFError, BrokenPipeError, ValueError):
                with self._cond:
                    self.closed = True
                    self._queue.clear()
                    self._slots.clear()
                return

    def close(self, timeout: float = 30.0) -> None:
        """Deliver everything queued, then stop the thread."""
        with self._cond:
            self._stop = True
            self._cond.notify()
        self._thread.join(timeout)


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
        self.emit(msg.rooms_message(start.rooms))
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
        }

    def on_end(self, record: Any) -> None:
        self.sim_time = record.sim_time

    def close(self) -> None:
        if self.file is not None:
            self.file.close()
            self.file = None


class PipeControl:
    """Steers the run from the service's commands: pause, resume, cancel, remote driving,
    goals and room records. Paces simulated time at wall speed during a teleop task."""

    def __init__(self, conn: Connection, stream: StreamObserver) -> None:
        self.conn = conn
        self.stream = stream
        self.paused = False
        self.cmd: tuple[float, float] = (0.0, 0.0)
        self.cmd_wall = -math.inf
        self.pace_origin: tuple[float, float] | None = None  # (wall, sim) of pacing start
        self.run: Any = None
        self.cancel_reason: str | None = None

    def before_step(self, run: Any) -> None:
        self.run = run
        self._drain(0.0)
        while self.paused and self.cancel_reason is None:
            self._drain(1.0)
        if self.cancel_reason is not None:
            if run.rows:  # a run ends after at least one step: its record needs one
                run.cancel(self.cancel_reason)
            return
        self._teleop(run)

    def _drain(self, timeout: float) -> None:
        """Act on every command waiting, waiting at most ``timeout`` for the first one."""
        try:
            ready = self.conn.poll(timeout)
            while ready:
                self._act(self.conn.recv())
                ready = self.conn.poll(0.0)
        except (EOFError, OSError):
            self.stream.closed = True
            self.paused = False
            self.cancel_reason = self.cancel_reason or "the service went away"

    def _act(self, command: tuple[Any, ...]) -> None:
        kind, run = command[0], self.run
        if kind == "cancel":
            self.paused = False
            self.cancel_reason = str(command[1])
        elif kind == "pause" and not self.paused:
            self.paused = True
            run.sim.set_command(0.0, 0.0)
            self._set_status("paused")
        elif kind == "resume" and self.paused:
            self.paused = False
            self.pace_origin = None
            self._set_status("running")
        elif kind == "cmd_vel":
            self.cmd, self.cmd_wall = (float(command[1]), float(command[2])), time.monotonic()
        elif kind == "goal":
            run.handle.remote_goal = Pose2D(float(command[1]), float(command[2]), float(command[3]))
        elif kind == "record":
            self._record(str(command[1]), str(command[2]))

    def _set_status(self, status: str) -> None:
        self.stream.status = status
        self.stream.send(("status", status))

    def _record(self, request_id: str, label: str) -> None:
        handle = self.run.handle
        try:
            pose = handle.record(label)
        except (OSError, ValueError) as exc:
            self.stream.send(("reply", request_id, 500, {"detail": f"not recorded: {exc}"}))
            return
        handle.log_recorded(label, pose, source="service")
        body = {"confirmation": "Entry saved in file", "label": label, "pose": msg.pose(pose)}
        self.stream.send(("reply", request_id, 200, body))

    def _teleop(self, run: Any) -> None:
        """During a teleop task: the latest remote command (stale after 0.5 s wall) and
        simulated time paced at wall speed (except while it drives to a goal it was sent:
        nobody steers then, and the drive should not take longer than it must)."""
        handle = run.handle
        if self.stream.task is None or self.stream.task.get("type") != "teleop":
            self.pace_origin = None
            return
        now = time.monotonic()
        handle.remote_command = self.cmd if now - self.cmd_wall <= REMOTE_TIMEOUT else None
        if handle.remote_goal is not None:  # an autonomous goal drive runs at full speed
            self.pace_origin = None
            return
        if self.pace_origin is None:
            self.pace_origin = (now, run.sim.time)
            return
        wall0, sim0 = self.pace_origin
        wait = (run.sim.time - sim0) - (now - wall0)
        if wait > 0.5:  # far ahead (a goal drive was fast): re-anchor
            self.pace_origin = (now, run.sim.time)
        elif wait > 0:
            self._drain(wait)  # sleep, but answer commands at once


def worker_main(job: dict[str, Any], conn: Connection) -> None:
    """The entry point of a mission process (local process or Ray task)."""
    with contextlib.suppress(ValueError):  # not the main thread (some Ray workers)
        signal.signal(signal.SIGINT, signal.SIG_IGN)  # the service decides how a run ends
    try:
        _run(job, conn)
    except Exception as exc:  # never die silently: the service records the reason
        tb = traceback.format_exc(limit=5)
        with contextlib.suppress(OSError, EOFError):
            conn.send(("end", "error", f"worker: {type(exc).__name__}: {exc}", None))
        Path(job["run_dir"], "worker.log").write_text(tb, encoding="utf-8")
    finally:
        conn.close()


def _run(job: dict[str, Any], conn: Connection) -> None:
    from agv_mission.missions.errors import MissionError
    from agv_mission.missions.loader import load_mission
    from agv_mission.missions.outputs import write_mission, write_run
    from agv_mission.missions.runner import run_mission
    from agv_mission.service.sandbox import DataDirGuard

    data_dir, run_dir = Path(job["data_dir"]), Path(job["run_dir"])
    run_dir.mkdir(parents=True, exist_ok=True)
    try:
        loaded = load_mission(
            data_dir / "mission.yaml",
            job["sets"],
            job["seed"],
            text=job["mission"],
            path_guard=DataDirGuard(data_dir),
        )
    except MissionError as exc:
        conn.send(("end", "error", f"invalid mission: {exc}", None))
        return
    write_mission(run_dir, loaded)
    stream = StreamObserver(conn, run_dir)
    control = PipeControl(conn, stream)
    stream.send(("status", "running"))
    try:
        record = run_mission(loaded, run_dir, observers=[stream], control=control)
        stream.status = record.status
        result = write_run(run_dir, loaded, record)
        end = {"type": "end", "status": record.status, "reason": record.reason}
        stream.emit(end, live=False)
    finally:
        stream.close()
        stream.send(("progress", stream.progress()))
        stream.flush()
    conn.send(("end", record.status, record.reason, _jsonable(result)))


def _jsonable(result: dict[str, Any]) -> dict[str, Any]:
    return msg.finite(result)
