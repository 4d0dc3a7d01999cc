"""Nonlinear MPC local planner (casadi; real-time iteration by default, or fatrop / ipopt).

:mod:`agv_mission.planners.mpc_problem` builds the optimisation problem once per
configuration and limits; this controller fills its parameters each control step (the
reference along the path at the speed profile, the lidar points nearest each predicted
stage, the warm start shifted from the previous solution) and turns its first control
into a velocity command.
"""

from __future__ import annotations

import math
import time

import numpy as np

from agv_mission.geometry import Pose2D, wrap_angle
from agv_mission.planners.base import VelocityCommand, VelocityLimits
from agv_mission.planners.configs import MpcConfig
from agv_mission.planners.mpc_problem import NU, NX, MpcProblem, mpc_problem
from agv_mission.planners.path_tracking import (
    ProgressTracker,
    clean_path,
    interpolate,
    prepare_path,
    speed_profile,
    unwrap_from,
)

_FAR = 50.0  # where unused obstacle slots are parked (robot frame, metres)

__all__ = ["MpcConfig", "MpcController", "MpcProblem", "brake_command"]


def _to_local(points: np.ndarray, pose: Pose2D) -> np.ndarray:
    c, s = math.cos(pose.yaw), math.sin(pose.yaw)
    return (points - (pose.x, pose.y)) @ np.array([[c, -s], [s, c]])


def _to_map(points: np.ndarray, pose: Pose2D) -> np.ndarray:
    c, s = math.cos(pose.yaw), math.sin(pose.yaw)
    return points @ np.array([[c, s], [-s, c]]) + (pose.x, pose.y)


def brake_command(
    velocity: tuple[float, float], limits: VelocityLimits, period: float
) -> tuple[float, float]:
    """One period of maximum deceleration towards (0, 0), within the limits."""
    v, w = velocity
    dv = limits.max_acc_v * period
    dw = limits.max_acc_w * period
    v_new = max(v - dv, 0.0) if v > 0 else min(v + dv, 0.0)
    w_new = max(w - dw, 0.0) if w > 0 else min(w + dw, 0.0)
    v_new = float(min(max(v_new, limits.min_v), limits.max_v))
    w_new = float(min(max(w_new, -limits.max_w), limits.max_w))
    return v_new, w_new


class MpcController:
    """Tracks the path with a nonlinear MPC and stops at its end; avoids lidar points."""

    Config = MpcConfig

    def __init__(
        self,
        config: MpcConfig,
        limits: VelocityLimits,
        robot_radius: float,
        control_period: float,
    ) -> None:
        self.config = config
        self.limits = limits
        self.robot_radius = robot_radius
        self.control_period = control_period
        self._tracker = ProgressTracker(window_ahead=limits.max_v * control_period * 3.0 + 0.3)
        self._problem = mpc_problem(config.model_dump_json(), limits)
        self._p = np.empty(self._problem.n_params)  # parameter vector, filled in place
        self._rows = np.arange(self._problem.n)[:, None]  # row index of per-stage arrays
        self._stats: dict | None = {}
        self._solve_info: dict = {}
        self._t_solver_call = 0.0
        self.reset()

    def reset(self) -> None:
        """Forget the warm start and the path progress (a new goal)."""
        self._path_key: int | None = None
        self._prepared: tuple[np.ndarray, np.ndarray, float] = (np.zeros((0, 2)), np.zeros(0), 0.0)
        self._prev_w: np.ndarray | None = None
        self._prev_pose: Pose2D | None = None
        self._rotating = False
        self._final_turn_done = False
        self._tracker.reset()

    # -- helpers -----------------------------------------------------------------------

    def _stage_obstacles(
        self, obstacles: np.ndarray, guess_xy: np.ndarray, pose: Pose2D
    ) -> np.ndarray:
        """(N-1, m, 2) robot-frame points: for each stage 1..N-1 the ``m`` lidar points
        nearest its guessed position (the constraints that can bind there); slots with no
        point within ``obstacle_range`` are parked far away."""
        m, cfg = self._problem.m, self.config
        out = np.full((len(guess_xy) - 2, m, 2), _FAR)
        if obstacles is None or len(obstacles) == 0:
            return out
        pts = np.asarray(obstacles, dtype=float).reshape(-1, 2)
        if len(pts) > cfg.max_obstacles:
            rel = pts - (pose.x, pose.y)
            d2_robot = np.einsum("ij,ij->i", rel, rel)
            pts = pts[np.argpartition(d2_robot, cfg.max_obstacles - 1)[: cfg.max_obstacles]]
        # Distances in the map frame (N-1 stage positions moved, not the points).
        stages = _to_map(guess_xy[1:-1], pose)
        dx = stages[:, 0, None] - pts[None, :, 0]
        dy = stages[:, 1, None] - pts[None, :, 1]
        d2 = dx * dx + dy * dy
        k = min(m, len(pts))
        if k < len(pts):
            idx = np.argpartition(d2, k - 1, axis=1)[:, :k]
        else:
            idx = np.broadcast_to(np.arange(k), (len(stages), k))
        chosen = _to_local(pts[idx.ravel()], pose).reshape(len(stages), k, 2)
        far = d2[self._rows[: len(stages)], idx] > cfg.obstacle_range**2
        chosen[far] = _FAR
        out[:, :k] = chosen
        return out

    @property
    def last_stats(self) -> dict:
        """The solver's statistics of the last solve (fetched on demand: costs ~0.1 ms)."""
        if self._stats is None:
            pb = self._problem
            self._stats = dict(self._solve_info or pb.solver.stats())
            self._stats["t_wall_solver_call"] = self._t_solver_call
        return self._stats

    def _rollout(self, x0: np.ndarray, ref: np.ndarray) -> np.ndarray:
        """Cold-start guess: a simple tracker driven along the reference, within the limits."""
        pb, lim, dt = self._problem, self.limits, self.config.dt
        states = np.empty((pb.n + 1, NX))
        controls = np.zeros((pb.n, NU))
        x, y, th, v, w = (float(c) for c in x0)
        states[0] = x0
        for k in range(pb.n):
            dx, dy = ref[0, k + 1] - x, ref[1, k + 1] - y
            target = math.atan2(dy, dx) if dx * dx + dy * dy > 1e-4 else ref[2, k + 1]
            err = wrap_angle(target - th)
            w_des = min(max(2.0 * err, -lim.max_w), lim.max_w)
            v_des = ref[3, k + 1] if abs(err) < 1.0 else 0.0
            a = min(max((v_des - v) / dt, -lim.max_acc_v), lim.max_acc_v)
            alpha = min(max((w_des - w) / dt, -lim.max_acc_w), lim.max_acc_w)
            v_new = min(max(v + a * dt, lim.min_v), lim.max_v)
            w_new = min(max(w + alpha * dt, -lim.max_w), lim.max_w)
            v_mid, th_mid = 0.5 * (v + v_new), th + 0.5 * (w + w_new) * dt
            x += v_mid * dt * math.cos(th_mid)
            y += v_mid * dt * math.sin(th_mid)
            th += 0.5 * (w + w_new) * dt
            v, w = v_new, w_new
            states[k + 1] = (x, y, th, v, w)
            controls[k, 0:2] = (a, alpha)
        return pb.pack(states, controls)

    def _warm_start(self, pose: Pose2D, x0: np.ndarray, ref: np.ndarray) -> np.ndarray:
        pb = self._problem
        if self._prev_w is None or self._prev_pose is None:
            return self._rollout(x0, ref)
        states = pb.states(self._prev_w)
        controls = pb.controls(self._prev_w)
        # Previous robot frame -> map -> current robot frame, shifted by one step.
        xy = _to_local(_to_map(states[:, 0:2], self._prev_pose), pose)
        th = states[:, 2] + wrap_angle(self._prev_pose.yaw - pose.yaw)
        states = np.column_stack((xy, th, states[:, 3:]))
        states = np.vstack((states[1:], states[-1:]))
        controls = np.vstack((controls[1:], controls[-1:]))
        states[0] = x0
        return pb.pack(states, controls)

    def _prepare(
        self, path: np.ndarray, pose: Pose2D, goal: Pose2D
    ) -> tuple[np.ndarray, np.ndarray, float]:
        """:func:`prepare_path`, kept while the navigator passes the same path."""
        path = np.asarray(path, dtype=float)
        key = hash(path.tobytes())
        if key == self._path_key:
            return self._prepared
        prepared = prepare_path(path, pose, goal)
        # A path of fewer than two distinct points is completed from the pose: not kept.
        if len(path) >= 2 and len(prepared[0]) == len(clean_path(path)):
            self._path_key, self._prepared = key, prepared
        return prepared

    def _fail(self, velocity: tuple[float, float], t0: float) -> VelocityCommand:
        self._prev_w = None
        v, w = brake_command(velocity, self.limits, self.control_period)
        return VelocityCommand(v, w, ok=False, solve_time=time.perf_counter() - t0)

    # -- the plugin API ----------------------------------------------------------------

    def diagnostics(self) -> dict[str, float]:
        return {}

    def compute(
        self,
        pose: Pose2D,
        velocity: tuple[float, float],
        path: np.ndarray,
        goal: Pose2D,
        obstacles: np.ndarray,
    ) -> VelocityCommand:
        t0 = time.perf_counter()
        cfg, lim, pb = self.config, self.limits, self._problem
        path, cumlen, total = self._prepare(path, pose, goal)
        xy = np.array([pose.x, pose.y])
        v0 = min(max(float(velocity[0]), lim.min_v), lim.max_v)
        w0 = min(max(float(velocity[1]), -lim.max_w), lim.max_w)
        s0 = self._tracker.update(path, cumlen, xy)
        to_goal = path[-1] - xy
        dist_goal = float(np.hypot(*to_goal))
        goal_ahead = math.cos(pose.yaw) * to_goal[0] + math.sin(pose.yaw) * to_goal[1]

        # At the goal, or just past it: brake, don't turn back.
        if dist_goal < cfg.goal_tolerance or (
            goal_ahead <= 0.0 and dist_goal < cfg.overshoot_tolerance
        ):
            v, w = brake_command((v0, w0), lim, self.control_period)
            self._prev_w = None
            self._stats = {}
            return VelocityCommand(v, w, ok=True, solve_time=time.perf_counter() - t0)

        # Reference: arclengths at the speed profile, in the robot frame.
        s_ref, v_ref = speed_profile(
            path,
            cumlen,
            s0,
            v0,
            pb.n,
            cfg.dt,
            lim.max_v,
            lim.max_w,
            lim.max_acc_v,
            cfg.decel_fraction * lim.max_acc_v,
            turn_fraction=cfg.turn_fraction,
            min_v=max(lim.min_v, 0.0),
        )
        # The reference and, last, the point ahead whose heading decides turn-in-place: to
        # the goal on the final approach, else to a point ahead on the path (or its tangent
        # there when that point is close).
        pts, ths = interpolate(path, cumlen, np.append(s_ref, min(s0 + cfg.lookahead, total)))
        ref_xy, ref_th, ahead_th = pts[:-1], ths[:-1], ths[-1:]
        to_ahead = pts[-1] - xy
        threshold = cfg.rotate_threshold
        final = dist_goal < cfg.final_approach
        if final:
            # One turn towards a goal beside the robot; after that only a goal behind calls
            # for turning in place (no limit cycle when the goal is blocked).
            heading_err = wrap_angle(math.atan2(to_goal[1], to_goal[0]) - pose.yaw)
            if self._final_turn_done:
                threshold = max(threshold, cfg.final_rotate_threshold)
        elif np.hypot(*to_ahead) > 0.5 * cfg.lookahead:
            heading_err = wrap_angle(math.atan2(to_ahead[1], to_ahead[0]) - pose.yaw)
        else:
            heading_err = wrap_angle(float(ahead_th[0]) - pose.yaw)
        if abs(heading_err) > threshold:
            self._rotating = True
        elif abs(heading_err) < cfg.rotate_exit:
            if self._rotating and final:
                self._final_turn_done = True
            self._rotating = False

        ref = np.empty((4, pb.n + 1))
        if self._rotating:
            # Hold the position, turn to the path; the speed is braked outside the solver.
            ref[0:2] = 0.0
            ref[2] = heading_err
            ref[3] = 0.0
            speed_weight, heading_weight, position_weight = cfg.rotate_speed_weight, 1.0, 1.0
        else:
            ref[0:2] = _to_local(ref_xy, pose).T
            ref[2] = unwrap_from(ref_th - pose.yaw, 0.0)
            ref[3] = v_ref
            # Path heading and speed stop mattering at the goal (the navigator turns in
            # place there): fading them lets the position terms remove a last offset.
            # The position weight grows as 1/d^2 so that the last centimetres still count
            # against the effort terms.
            fade = min(1.0, dist_goal / cfg.final_approach)
            speed_weight, heading_weight = fade, fade
            position_weight = min(1.0 / (fade * fade), cfg.final_position_gain)
        x0 = np.array([0.0, 0.0, 0.0, v0, w0])
        guess = self._warm_start(pose, x0, ref)
        guess_states = pb.states(guess)
        r = self.robot_radius + cfg.safety_margin
        p = self._p
        p[0:NX] = x0
        p[pb.p_ref] = ref.T.ravel()
        p[-4:] = (r * r, speed_weight, heading_weight, position_weight)
        slack = np.full(pb.n, 1e-4)
        if pb.m > 0:
            stage_obs = self._stage_obstacles(obstacles, guess_states[:, 0:2], pose)
            p[pb.p_obs] = stage_obs.ravel()
            # Slacks that make the guess feasible (a cold start inside the margin converges).
            d2 = ((guess_states[1:-1, None, 0:2] - stage_obs) ** 2).sum(axis=2).min(axis=1)
            slack[1:] += np.maximum(r * r - d2, 0.0) * 1.1
        guess[pb.idx_slack] = slack

        self._stats = None
        t_solve = time.perf_counter()
        try:
            wopt, self._solve_info = pb.solve(guess, p, cold=self._prev_w is None)
        except RuntimeError:
            return self._fail((v0, w0), t0)
        self._t_solver_call = time.perf_counter() - t_solve
        if not np.all(np.isfinite(wopt)):
            return self._fail((v0, w0), t0)
        self._prev_w = wopt
        self._prev_pose = pose

        u0 = pb.controls(wopt)[0]
        v = min(max(v0 + float(u0[0]) * self.control_period, lim.min_v), lim.max_v)
        if self._rotating:
            v = brake_command((v0, w0), lim, self.control_period)[0]
        w = min(max(w0 + float(u0[1]) * self.control_period, -lim.max_w), lim.max_w)
        predicted = _to_map(pb.states(wopt)[:, 0:2], pose)
        return VelocityCommand(
            v, w, ok=True, solve_time=time.perf_counter() - t0, predicted=predicted
        )
