r"""The part of ``compute`` every path-following local planner shares: the path prepared
once while the navigator passes the same one, the robot's progress along it, and stopping
at the goal or just past it. The MPC and pure pursuit are both :class:`PathFollower`\ s."""

from __future__ import annotations

import bisect
import math
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from agv_mission.geometry import Pose2D
from agv_mission.planners.base import VelocityCommand, VelocityLimits
from agv_mission.planners.path_tracking import (
    ReferenceProfile,
    Segments,
    clean_path,
    closest_point,
    cumulative_length,
)


class ProgressTracker:
    """The robot's arclength on the path, kept monotone-ish from call to call.

    While the path is unchanged, the projection is searched in a window around the
    previous progress, so a path that passes near itself (out and back along a corridor)
    is followed in order; a new path (any change) is searched whole.
    """

    def __init__(self, window_back: float = 0.3, window_ahead: float = 0.5) -> None:
        self.window_back = window_back
        self.window_ahead = window_ahead
        self.reset()

    def reset(self) -> None:
        self.progress: float | None = None
        self._key: int | None = None
        self._segments: Segments | None = None
        self._cum: list[float] = []
        self._rows: list[tuple[float, ...]] = []

    def update(
        self, path: np.ndarray, cumlen: np.ndarray, xy: np.ndarray, key: int | None = None
    ) -> float:
        """The progress at ``xy``; ``key`` identifies the path (default: a hash of it)."""
        if key is None:
            key = hash(path.tobytes())
        if self.progress is not None and key == self._key and self._segments is not None:
            s = self._in_window(
                float(xy[0]),
                float(xy[1]),
                self.progress - self.window_back,
                self.progress + self.window_ahead,
            )
            if s is None:  # the window misses the path: search it whole
                s = closest_point(path, xy, cumlen, segments=self._segments).s
            s = max(s, self.progress - 0.05)
        else:
            self._segments = seg = Segments.of(path, cumlen) if len(path) >= 2 else None
            if seg is not None:
                self._cum = cumlen.tolist()
                self._rows = list(
                    zip(
                        *seg.start.T.tolist(),
                        *seg.delta.T.tolist(),
                        seg.length2.tolist(),
                        seg.length.tolist(),
                        self._cum,
                        strict=False,
                    )
                )
            s = closest_point(path, xy, cumlen, segments=seg).s
        self.progress, self._key = s, key
        return s

    def _in_window(self, x: float, y: float, s_min: float, s_max: float) -> float | None:
        """:func:`closest_point` on the arclength window [s_min, s_max] (None: the window
        misses the path), on the few segments that overlap it: plain floats, no arrays."""
        first = max(bisect.bisect_left(self._cum, s_min) - 1, 0)
        last = bisect.bisect_right(self._cum, s_max)
        best, s_best = math.inf, None
        for ax, ay, dx, dy, len2, length, c in self._rows[first:last]:
            t = ((x - ax) * dx + (y - ay) * dy) / max(len2, 1e-18)
            inv = 1.0 / max(length, 1e-18)
            lo, hi = max((s_min - c) * inv, 0.0), min((s_max - c) * inv, 1.0)
            if lo > hi:
                continue
            t = min(max(t, lo), hi)
            ex, ey = ax + t * dx - x, ay + t * dy - y
            d2 = ex * ex + ey * ey
            if d2 < best:
                best, s_best = d2, c + t * length
        return s_best


def prepare_path(
    path: np.ndarray, pose: Pose2D, goal: Pose2D
) -> tuple[np.ndarray, np.ndarray, float]:
    """A usable polyline of at least two points (the goal alone becomes pose -> goal),
    with its cumulative length and total length."""
    path = clean_path(path)
    if len(path) == 0:
        path = np.array([[goal.x, goal.y]])
    if len(path) == 1:
        path = np.vstack(([pose.x, pose.y], path))
    cumlen = cumulative_length(path)
    return path, cumlen, float(cumlen[-1])


@dataclass(frozen=True, slots=True)
class PathStep:
    """One control step of a path follower: its inputs and where the robot is on the
    path (map frame)."""

    pose: Pose2D
    velocity: tuple[float, float]  # the current (v, w)
    obstacles: np.ndarray  # (K, 2) lidar points near the robot
    path: np.ndarray  # (N, 2) the prepared polyline (at least two points)
    cumlen: np.ndarray  # (N,) arclength at every vertex
    total: float  # its length
    s: float  # the robot's arclength on it
    to_goal: tuple[float, float]  # from the robot to the path's end
    dist_goal: float
    goal_ahead: float  # the end's distance ahead along the robot's heading
    # tracked moving obstacles (people), rows (x, y, radius, vx, vy) in the map frame
    moving: np.ndarray | None = None


class PathFollower:
    """The part of ``compute`` every path-following local planner shares: the path
    prepared once while the navigator passes the same one, the progress along it, and
    stopping at the goal or just past it (not turning back). A subclass gives
    :meth:`follow` (the command away from the goal) and :meth:`stop`; its ``config`` has
    ``goal_tolerance`` and ``overshoot_tolerance``."""

    config: Any

    def __init__(self, limits: VelocityLimits, control_period: float) -> None:
        self.limits = limits
        self.control_period = control_period
        self._tracker = ProgressTracker(window_ahead=limits.max_v * control_period * 3.0 + 0.3)
        self._path_key: int | None = None
        self._prepared: tuple[np.ndarray, np.ndarray, float] = (np.zeros((0, 2)), np.zeros(0), 0.0)
        self._profile: tuple[np.ndarray, tuple, ReferenceProfile] | None = None

    def reset(self) -> None:
        """Forget the path progress (a new goal)."""
        self._path_key = None
        self._tracker.reset()

    def diagnostics(self) -> dict[str, float]:
        return {}

    def reference(
        self, step: PathStep, max_v: float, dec: float, turn_fraction: float
    ) -> ReferenceProfile:
        """The path's :class:`ReferenceProfile` (up to ``max_v``, braking at ``dec``), kept
        while the path is."""
        args = (max_v, dec, turn_fraction)
        if self._profile is not None and self._profile[0] is step.path and self._profile[1] == args:
            return self._profile[2]
        lim = self.limits
        profile = ReferenceProfile(
            step.path,
            step.cumlen,
            max_v,
            lim.max_w,
            lim.max_acc_v,
            dec,
            turn_fraction=turn_fraction,
            min_v=lim.min_v,
        )
        self._profile = (step.path, args, profile)
        return profile

    def follow(self, step: PathStep) -> VelocityCommand:
        """The command for this step while the goal is not reached."""
        raise NotImplementedError

    def stop(self, velocity: tuple[float, float]) -> tuple[float, float]:
        """The command at the goal (braking within the limits)."""
        raise NotImplementedError

    def compute(
        self,
        pose: Pose2D,
        velocity: tuple[float, float],
        path: np.ndarray,
        goal: Pose2D,
        obstacles: np.ndarray,
        moving: np.ndarray | None = None,
    ) -> VelocityCommand:
        t0 = time.perf_counter()
        raw = np.asarray(path, dtype=float)
        key: int | None = hash(raw.tobytes())
        if key == self._path_key:
            path, cumlen, total = self._prepared
        else:
            path, cumlen, total = prepare_path(raw, pose, goal)
            # A path of fewer than two distinct points is completed from the pose: not kept.
            if len(raw) >= 2 and len(path) == len(clean_path(raw)):
                self._path_key, self._prepared = key, (path, cumlen, total)
            else:
                key = None
        s0 = self._tracker.update(path, cumlen, np.array((pose.x, pose.y)), key)
        dx, dy = float(path[-1, 0]) - pose.x, float(path[-1, 1]) - pose.y
        dist_goal = math.hypot(dx, dy)
        goal_ahead = math.cos(pose.yaw) * dx + math.sin(pose.yaw) * dy
        cfg = self.config
        if dist_goal < cfg.goal_tolerance or (
            goal_ahead <= 0.0 and dist_goal < cfg.overshoot_tolerance
        ):
            cmd = VelocityCommand(*self.stop(velocity))
        else:
            step = PathStep(
                pose,
                velocity,
                obstacles,
                path,
                cumlen,
                total,
                s0,
                (dx, dy),
                dist_goal,
                goal_ahead,
                moving,
            )
            cmd = self.follow(step)
        cmd.solve_time = time.perf_counter() - t0
        return cmd
