"""BARN's protocol for its static worlds 0-299, as ``run.py`` of
``Daffan/the-barn-challenge`` runs it (barn.md).

The Jackal starts at (-2.25, 3.0) heading +y and is sent to (-2.25, 13.0), 10 m ahead,
with no map. The clock starts when its true position is first 0.1 m from the start; the
run succeeds when its true position comes within 1 m of the goal, is ``collided`` at the
first contact with an obstacle and ``timeout`` 100 s after the clock started. ``run.py``
polls the pose every 0.1 s of simulated time; :class:`BarnReferee` reads the true pose our
control loop records every step (10 Hz), the rows ``trajectory.csv`` holds, so the time and
the metric can be recomputed from that file.

The metric of a world: ``success * OT / clip(AT, 2 OT, 8 OT)``, AT the time taken and OT
the optimal time, the length of BARN's reference path (``path_files/path_K.npy``, grid
cells of 0.15 m, from the start through every cell's centre to the goal) at 2 m/s.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from py_trees.common import Status

START = (-2.25, 3.0, math.pi / 2.0)  # x, y, yaw: run.py's INIT_POSITION (yaw 1.57)
GOAL = (-2.25, 13.0)  # INIT_POSITION + GOAL_POSITION (0, 10)
MOVED = 0.1  # m from the start: the clock starts
ARRIVED = 1.0  # m from the goal: the run succeeded
TIME_LIMIT = 100.0  # s after the clock started
OPTIMAL_SPEED = 2.0  # m/s: the Jackal's top speed, OT = path length / 2
CELL = 0.15  # m: a BARN grid cell (two cylinder radii, 0.075 m)
CELL_OFFSET = (-4.575, 5.075)  # run.py's path_coord_to_gazebo_coord: -r - 30 * 2r, r + 5
ROBOT = "jackal"
#: The mission's own time limit: the referee ends every run first (100 s after the clock;
#: a robot that never moves 0.1 m is a timeout at 100 s), this is a backstop.
MISSION_TIME = 2.0 * TIME_LIMIT

STATUSES = ("succeeded", "collided", "timeout", "failed")
STAND = "stand"  # the mission tree's node that holds the robot once navigation ended
REST_ROWS = 5  # control steps (0.5 s) ...
REST_STEP = 1e-4  # ... in which the true pose moved less than this (m, rad) a step


class PathFileError(ValueError):
    """A path file that cannot be read as BARN's (n, 2) array of grid cells."""


def path_points(path_file: Path) -> np.ndarray:
    """The reference path in the world frame: start, each cell of ``path_file``, goal."""
    try:
        cells = np.load(path_file, allow_pickle=False)
    except (OSError, ValueError, EOFError) as exc:
        raise PathFileError(f"{path_file}: not a numpy .npy array: {exc}") from None
    if cells.ndim != 2 or cells.shape[1] != 2 or not len(cells):
        raise PathFileError(f"{path_file}: expected an (n, 2) array of cells, got {cells.shape}")
    if not np.issubdtype(cells.dtype, np.number) or not np.all(np.isfinite(cells)):
        raise PathFileError(f"{path_file}: expected finite numbers, got dtype {cells.dtype}")
    world = cells.astype(float) * CELL + np.array(CELL_OFFSET)
    return np.vstack([START[:2], world, GOAL])


def path_length(path_file: Path) -> float:
    """The length of BARN's reference path of a world (m)."""
    points = path_points(path_file)
    return float(np.sum(np.hypot(*np.diff(points, axis=0).T)))


def metric(success: bool, time: float, length: float) -> float:
    """BARN's navigation metric: ``success * OT / clip(AT, 2 OT, 8 OT)``."""
    optimal = length / OPTIMAL_SPEED
    return float(success) * optimal / float(np.clip(time, 2.0 * optimal, 8.0 * optimal))


@dataclass
class BarnOutcome:
    """A world's result as barn.md's ``--json`` has it."""

    status: str  # succeeded | collided | timeout | failed
    time: float  # s from the clock's start to the end
    metric: float
    path_length: float
    reason: str | None = None

    @property
    def success(self) -> bool:
        return self.status == "succeeded"


class BarnReferee:
    """The run control that applies BARN's protocol: reads the true pose of the latest
    control step (a row of ``trajectory.csv``) before the next one and ends the run when
    the robot arrived or the time is up. A collision ends the run by itself (the mission
    allows none).

    A robot whose navigation has ended (its tree stands in :data:`STAND`) short of the
    goal, and that has come to rest, can do nothing more in a static world: the run ends
    there as the timeout BARN's clock would give it (time: the full limit), instead of
    simulating it standing until then."""

    only_cancels = True  # it never commands the robot (robot processes stay possible)

    def __init__(self, stop: Any = None, time_limit: float = TIME_LIMIT) -> None:
        self.time_limit = time_limit  # s after the clock started
        self.clock: float | None = None  # t of the first row 0.1 m from the start
        self.verdict: str | None = None  # succeeded | timeout, when the referee ended it
        self.stop = stop  # another control asked first (Ctrl-C)
        self._stand: Any = None  # the tree's STAND node, once found

    def before_step(self, run: Any) -> None:
        if self.stop is not None:
            self.stop.before_step(run)
        rows = run.lead.rows
        if not rows or run.status is not None:
            return
        t, x, y = rows[-1][:3]
        if self.clock is None and math.hypot(x - START[0], y - START[1]) >= MOVED:
            self.clock = t
        since = t - (self.clock if self.clock is not None else 0.0)
        if math.hypot(x - GOAL[0], y - GOAL[1]) <= ARRIVED:
            self.verdict = "succeeded"
            run.end("succeeded", f"BARN: within {ARRIVED:g} m of the goal at t={t:.1f} s")
        elif since >= self.time_limit - 1e-9:
            self.verdict = "timeout"
            after = "the clock started" if self.clock is not None else "the start (never moved)"
            run.end("failed", f"BARN: timeout, {self.time_limit:g} s after {after}")
        elif self._standing(run, rows):
            self.verdict = "timeout"
            gap = math.hypot(x - GOAL[0], y - GOAL[1])
            run.end(
                "failed",
                f"BARN: timeout: navigation ended at t={t:.1f} s with the robot {gap:.2f} m "
                "from the goal, and it stands",
            )

    def _standing(self, run: Any, rows: list[Any]) -> bool:
        """Navigation has ended (the tree's :data:`STAND` runs) and the robot rests."""
        if self._stand is None:
            self._stand = next((n for n in run.lead.tree.root.iterate() if n.name == STAND), False)
        if not self._stand or self._stand.status is not Status.RUNNING or len(rows) < REST_ROWS:
            return False
        recent = np.asarray([r[:4] for r in rows[-REST_ROWS:]], dtype=float)
        moved = np.hypot(*(recent[1:, 1:3] - recent[:-1, 1:3]).T).max()
        turned = np.abs(np.diff(np.unwrap(recent[:, 3]))).max()
        return bool(moved < REST_STEP and turned < REST_STEP)

    def outcome(
        self,
        status: str,
        reason: str | None,
        trajectory: np.ndarray,
        collisions: int,
        length: float,
    ) -> BarnOutcome:
        """The world's outcome: the run's ``status``, ``reason`` and ``collisions``, and its
        ``trajectory`` (``trajectory.csv``'s rows: t, x, y, ...) for the time."""
        if collisions:
            barn = "collided"
        elif self.verdict is not None:
            barn = self.verdict
        else:  # the run did not reach the protocol's end: an error, or it was stopped
            barn = "failed"
        end = float(trajectory[-1, 0]) if len(trajectory) else 0.0
        elapsed = max(end - (self.clock if self.clock is not None else 0.0), 0.0)
        if barn == "timeout":
            elapsed = self.time_limit  # BARN's clock ran out (or would have: see above)
        return BarnOutcome(
            status=barn,
            time=round(elapsed, 6),
            metric=metric(barn == "succeeded", elapsed, length),
            path_length=length,
            reason=reason,
        )


def mission_text(world_file: Path, seed: int, output: Path) -> str:
    """A BARN world as a mission (YAML): the protocol's start, goal, robot and no map.

    The robot is sent to the goal once, as ``run.py`` sends move_base its goal; whatever
    navigation reports (arrived by its odometry, or gave up), the robot then stands and
    the referee's clock decides, as BARN's does (a robot that stopped short is a
    timeout)."""
    yaw = repr(START[2])
    goal = f"{{x: {GOAL[0]!r}, y: {GOAL[1]!r}, yaw: {yaw}}}"
    return (
        f"name: barn_{world_file.stem}\n"
        f"world: {_quoted(world_file)}\n"
        "map: none\n"
        f"robot: {ROBOT}\n"
        f"start: {{x: {START[0]!r}, y: {START[1]!r}, yaw: {yaw}}}\n"
        f"seed: {int(seed)}\n"
        "stack:\n"
        "  localization: {type: odometry}\n"
        "tree:\n"
        "  type: sequence\n"
        "  name: barn\n"
        "  children:\n"
        f"    - {{type: force_success, child: {{type: go_to, pose: {goal}}}}}\n"
        f"    - {{type: wait, name: {STAND}, seconds: {MISSION_TIME!r}}}\n"
        f"limits: {{time: {MISSION_TIME!r}, collisions: 0}}\n"
        f"output: {_quoted(output)}\n"
    )


def _quoted(path: Path) -> str:
    import json

    return json.dumps(str(path))  # a JSON string is a YAML string
