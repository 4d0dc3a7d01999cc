"""One mission in its own process: load, run with a stream observer and a pipe control.

The worker's end of the link (:mod:`agv_mission.service.links`) is a plain
:class:`multiprocessing.connection.Connection`. Commands are read between control steps
without waiting; while paused the worker blocks on the connection, so a resume or cancel
acts at once (no polling period).
"""

from __future__ import annotations

import contextlib
import math
import signal
import time
import traceback
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

import numpy as np

from agv_mission.geometry import Pose2D
from agv_mission.json_values import finite
from agv_mission.missions.run.pacing import Pacer
from agv_mission.service import stream_messages as msg
from agv_mission.service.stream import StreamObserver

REMOTE_TIMEOUT = 0.5  # wall seconds without cmd_vel before a teleop robot stops


class PipeControl:
    """Steers the run from the service's commands: pause, resume, pace, cancel, remote
    driving, goals and room records, each for the robot it names. Holds simulated time to
    the run's pace (none: flat out), and to wall speed while any robot's current task is
    teleop."""

    def __init__(self, conn: Connection, stream: StreamObserver, pace: float | None = None) -> None:
        self.conn = conn
        self.stream = stream
        self.paused = False
        self.cmds: dict[str, tuple[tuple[float, float], float]] = {}  # robot -> (v, w), wall
        self.pacer = Pacer(pace)
        self.run: Any = None
        self.cancel_reason: str | None = None

    def before_step(self, run: Any) -> None:
        self.run = run
        self._drain(0.0)
        self._pace(run)
        while self.paused and self.cancel_reason is None:
            self._drain(1.0)
        if self.cancel_reason is not None:
            if run.lead.rows:  # a run ends after at least one step: its record needs one
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
            for robot in run.robots:
                robot.sim.set_command(0.0, 0.0)
            self._set_status("paused")
        elif kind == "resume" and self.paused:
            self.paused = False
            self.pacer.restart()
            self._set_status("running")
        elif kind == "pace":
            with contextlib.suppress(ValueError):  # the service checked it
                self.pacer.set(command[1])
        elif kind == "cmd_vel":
            self.cmds[str(command[1])] = (float(command[2]), float(command[3])), time.monotonic()
        elif kind == "goal":
            self._goal(str(command[1]), str(command[2]), Pose2D(*map(float, command[3:6])))
        elif kind == "record":
            self._record(str(command[1]), str(command[2]), str(command[3]))

    def _set_status(self, status: str) -> None:
        self.stream.status = status
        self.stream.send(("status", status))

    def _robot(self, request_id: str, name: str) -> Any:
        """The named robot of the run (the service checked the name; None answers 422)."""
        robot = self.run.by_name.get(name)
        if robot is None:
            self.stream.send(("reply", request_id, 422, {"detail": f"no robot {name!r}"}))
        return robot

    def _record(self, request_id: str, name: str, label: str) -> None:
        robot = self._robot(request_id, name)
        if robot is None:
            return
        handle = robot.handle
        try:
            pose = handle.record(label)
        except (OSError, ValueError) as exc:
            self.stream.send(("reply", request_id, 500, {"detail": f"not recorded: {exc}"}))
            return
        handle.log_recorded(label, pose, source="service")
        body = {
            "confirmation": "Entry saved in file",
            "label": label,
            "pose": msg.pose(pose),
            "robot": name,
        }
        self.stream.send(("reply", request_id, 200, body))

    def _goal(self, request_id: str, name: str, goal: Pose2D) -> None:
        """Drive the robot to ``goal`` if a path reaches it (202); say why not otherwise
        (422)."""
        robot = self._robot(request_id, name)
        if robot is None:
            return
        handle = robot.handle
        why = unreachable(handle.navigator, handle.state.estimate, goal)
        if why is not None:
            self.stream.send(("reply", request_id, 422, {"detail": why}))
            return
        handle.remote_goal = goal
        self.stream.send(("reply", request_id, 202, {}))

    def _driven(self, run: Any) -> list[Any]:
        """The robots whose current task is teleop."""
        return [
            robot
            for robot in run.robots
            if (self.stream.task_of(robot.name) or {}).get("type") == "teleop"
        ]

    def _pace(self, run: Any) -> None:
        """Wait until the next step is due: the run's pace, or wall speed while a robot is
        driven remotely (also while it drives to a goal it was sent: the dashboard shows
        the drive as it happens). Commands are answered meanwhile."""
        wait = self.pacer.delay(run.world.time, 1.0 if self._driven(run) else None)
        if wait > 0 and not self.paused:
            self._drain(wait)

    def _teleop(self, run: Any) -> None:
        """Each teleop robot's latest remote command (stale after 0.5 s wall)."""
        now = time.monotonic()
        for robot in self._driven(run):
            cmd, at = self.cmds.get(robot.name, ((0.0, 0.0), -math.inf))
            robot.handle.remote_command = cmd if now - at <= REMOTE_TIMEOUT else None


def unreachable(navigator: Any, start: Pose2D, goal: Pose2D) -> str | None:
    """Why no path reaches ``goal`` from ``start`` on the navigator's costmap (outside the
    map, in or too near an obstacle, cut off), with the global planner's margin; None when
    free space joins them (or the robot itself stands where nothing is free: the
    navigator's own escape and failure reports answer that)."""
    from agv_mission.maps.rooms import reachable_cells

    costmap = navigator.costmap
    margin = getattr(navigator.global_planner, "clearance", 0.0)
    where = f"goal ({goal.x:.2f}, {goal.y:.2f})"
    xy = np.array([goal.x, goal.y])
    rows, cols = costmap.grid.world_to_cell(xy)
    if not costmap.grid.in_bounds(rows, cols):
        return f"{where} is outside the map"
    if not bool(costmap.is_free(xy, margin)):
        return f"{where} is in an obstacle or closer to one than the robot can go"
    cells = reachable_cells(costmap, start, margin)
    if cells.any() and not bool(cells[int(rows), int(cols)]):
        return (
            f"{where} is unreachable: no free corridor leads there from "
            f"({start.x:.2f}, {start.y:.2f})"
        )
    return None


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
    from agv_mission.missions.load.errors import MissionError
    from agv_mission.missions.load.loader import load_mission
    from agv_mission.missions.report.directory import run_in
    from agv_mission.service.sandbox import DataDirGuard

    data_dir, run_dir = Path(job["data_dir"]), Path(job["run_dir"])
    run_dir.mkdir(parents=True, exist_ok=True)
    # a mission sent with its files reads them from its run directory (inputs/)
    mission_path = job.get("mission_path")
    source = run_dir / mission_path if mission_path else data_dir / "mission.yaml"
    try:
        loaded = load_mission(
            source,
            job["sets"],
            job["seed"],
            text=job["mission"],
            path_guard=DataDirGuard(data_dir),
        )
    except MissionError as exc:
        conn.send(("end", "error", f"invalid mission: {exc}", None))
        return
    stream = StreamObserver(conn, run_dir)
    control = PipeControl(conn, stream, job.get("pace"))
    stream.send(("status", "running"))
    limits = {
        r.name: (r.robot.max_linear_velocity, r.robot.max_angular_velocity) for r in loaded.robots
    }
    stream.send(("robots", limits))
    observers = [stream, *(job["observers"](loaded) if job.get("observers") else [])]
    try:
        done = run_in(run_dir, loaded, observers=observers, control=control)
        record, result = done.record, done.result
        end = {"type": "end", "status": record.status, "reason": record.reason}
        stream.emit(end, live=False)
    finally:
        stream.close()
        stream.send(("progress", stream.progress()))
        stream.flush()
    conn.send(("end", record.status, record.reason, finite(result)))


def ray_entry(job: dict[str, Any], address: Any, authkey: bytes) -> None:
    """A Ray task: connect back to the service, then run like a local worker."""
    from multiprocessing.connection import Client

    conn = Client(address, authkey=authkey)
    conn.send(("hello", job["run_id"]))
    worker_main(job, conn)
