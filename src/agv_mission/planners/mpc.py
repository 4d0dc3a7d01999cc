"""Nonlinear MPC local planner (casadi + fatrop).

Model: unicycle with state (x, y, theta, v, w) and controls (a, alpha, slack), so the
velocity and acceleration limits are simple bounds. Every solve works in a frame
centred on the robot (x0 = (0, 0, 0, v, w)), which keeps the numbers small and
theta free of wrap-around.

The NLP is laid out the way fatrop's structure detection wants it:
variables x0, u0, x1, u1, ..., xN; constraints per stage [dynamics_k; path_k] with
the initial-state constraint right after dynamics_0; dynamics written
``x_{k+1} - F(x_k, u_k)``; every constraint touching one stage only. The obstacle
constraints ``|p_k - o_j|^2 + s_k >= R^2`` use one slack ``s_k >= 0`` per stage
(a control of that stage), penalised linearly and quadratically (exact penalty),
so the problem is always feasible.
"""

from __future__ import annotations

import math
import time

import casadi as ca
import numpy as np

from agv_mission.geometry import Pose2D, wrap_angle
from agv_mission.planners.base import VelocityCommand, VelocityLimits
from agv_mission.planners.configs import MpcConfig
from agv_mission.planners.path_tracking import (
    ProgressTracker,
    interpolate,
    prepare_path,
    speed_profile,
    unwrap_from,
)

_NX = 5  # x, y, theta, v, w
_NU = 3  # a, alpha, slack
_FAR = 50.0  # where unused obstacle slots are parked (robot frame, metres)


class _Problem:
    """The NLP built once: solver function, bounds and index helpers."""

    def __init__(self, cfg: MpcConfig, limits: VelocityLimits) -> None:
        n, k_obs, dt = cfg.horizon, max(cfg.max_obstacles, 0), cfg.dt
        wts = cfg.weights
        x = ca.SX.sym("x", _NX)
        u = ca.SX.sym("u", _NU)

        def f(s: ca.SX, c: ca.SX) -> ca.SX:
            return ca.vertcat(s[3] * ca.cos(s[2]), s[3] * ca.sin(s[2]), s[4], c[0], c[1])

        k1 = f(x, u)
        k2 = f(x + dt / 2 * k1, u)
        k3 = f(x + dt / 2 * k2, u)
        k4 = f(x + dt * k3, u)
        step = ca.Function("F", [x, u], [x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)])

        p_x0 = ca.SX.sym("x0", _NX)
        p_ref = ca.SX.sym("ref", 4, n + 1)  # x, y, theta, v per stage
        p_obs = ca.SX.sym("obs", 2, k_obs)
        p_r2 = ca.SX.sym("r2")
        p_wv = ca.SX.sym("speed_weight")  # scales the speed weight (turn-in-place: large)
        p_wh = ca.SX.sym("heading_weight")  # scales the heading weights (fades at the goal)
        p_wp = ca.SX.sym("position_weight")  # scales the position weights (grows at the goal)
        params = ca.vertcat(p_x0, ca.vec(p_ref), ca.vec(p_obs), p_r2, p_wv, p_wh, p_wp)

        xs = [ca.SX.sym(f"x{k}", _NX) for k in range(n + 1)]
        us = [ca.SX.sym(f"u{k}", _NU) for k in range(n)]
        w: list[ca.SX] = []
        g: list[ca.SX] = []
        equality: list[bool] = []
        cost = 0
        for k in range(n + 1):
            xk, r = xs[k], p_ref[:, k]
            e = xk[0:2] - r[0:2]
            if k == n:
                w.append(xk)
                cost += p_wp * wts.terminal_position * ca.sumsqr(e)
                cost += p_wh * wts.terminal_heading * (xk[2] - r[2]) ** 2
                cost += p_wv * wts.speed * (xk[3] - r[3]) ** 2
                break
            uk = us[k]
            w += [xk, uk]
            g.append(xs[k + 1] - step(xk, uk))
            equality += [True] * _NX
            if k == 0:
                g.append(xk - p_x0)
                equality += [True] * _NX
            elif k_obs > 0:
                d2 = (xk[0] - p_obs[0, :]) ** 2 + (xk[1] - p_obs[1, :]) ** 2
                g.append(d2.T + uk[2] - p_r2)
                equality += [False] * k_obs
            cost += p_wp * wts.position * ca.sumsqr(e) + p_wh * wts.heading * (xk[2] - r[2]) ** 2
            cost += p_wv * wts.speed * (xk[3] - r[3]) ** 2 + wts.angular_velocity * xk[4] ** 2
            cost += wts.acceleration * uk[0] ** 2 + wts.angular_acceleration * uk[1] ** 2
            cost += wts.slack_linear * uk[2] + wts.slack_quadratic * uk[2] ** 2

        nlp = {"x": ca.vertcat(*w), "f": cost, "g": ca.vertcat(*g), "p": params}
        so = cfg.solver_options
        if cfg.solver == "fatrop":
            opts = {
                "structure_detection": "auto",
                "equality": equality,
                "expand": True,
                "print_time": False,
                "fatrop": {
                    "print_level": 0,
                    "max_iter": so.max_iter,
                    "tol": so.tol,
                    "mu_init": so.mu_init,
                },
            }
        else:
            opts = {
                "expand": True,
                "print_time": False,
                "ipopt": {
                    "print_level": 0,
                    "sb": "yes",
                    "max_iter": so.max_iter,
                    "tol": so.tol,
                    "mu_init": so.mu_init,
                    "linear_solver": "mumps",
                },
            }
        self.solver = ca.nlpsol("mpc", cfg.solver, nlp, opts)

        self.n, self.k_obs = n, k_obs
        self.stride = _NX + _NU
        self.nw = n * self.stride + _NX
        lbx = np.empty(self.nw)
        ubx = np.empty(self.nw)
        for k in range(n + 1):
            i = k * self.stride
            lbx[i : i + _NX] = [-np.inf, -np.inf, -np.inf, limits.min_v, -limits.max_w]
            ubx[i : i + _NX] = [np.inf, np.inf, np.inf, limits.max_v, limits.max_w]
            if k < n:
                j = i + _NX
                lbx[j : j + _NU] = [-limits.max_acc_v, -limits.max_acc_w, 0.0]
                ubx[j : j + _NU] = [limits.max_acc_v, limits.max_acc_w, np.inf]
        self.lbx, self.ubx = lbx, ubx
        eq = np.array(equality, dtype=bool)
        self.lbg = np.zeros(len(eq))
        self.ubg = np.where(eq, 0.0, np.inf)

    def states(self, wopt: np.ndarray) -> np.ndarray:
        """(N+1, 5) states of a solution vector."""
        idx = np.arange(self.n + 1)[:, None] * self.stride + np.arange(_NX)[None, :]
        return wopt[idx]

    def controls(self, wopt: np.ndarray) -> np.ndarray:
        """(N, 3) controls of a solution vector."""
        idx = np.arange(self.n)[:, None] * self.stride + _NX + np.arange(_NU)[None, :]
        return wopt[idx]

    def pack(self, states: np.ndarray, controls: np.ndarray) -> np.ndarray:
        wv = np.empty(self.nw)
        idx_x = np.arange(self.n + 1)[:, None] * self.stride + np.arange(_NX)[None, :]
        idx_u = np.arange(self.n)[:, None] * self.stride + _NX + np.arange(_NU)[None, :]
        wv[idx_x] = states
        wv[idx_u] = controls
        return wv


def _to_local(points: np.ndarray, pose: Pose2D) -> np.ndarray:
    c, s = math.cos(pose.yaw), math.sin(pose.yaw)
    d = points - np.array([pose.x, pose.y])
    return np.column_stack((c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]))


def _to_map(points: np.ndarray, pose: Pose2D) -> np.ndarray:
    c, s = math.cos(pose.yaw), math.sin(pose.yaw)
    return np.column_stack(
        (pose.x + c * points[:, 0] - s * points[:, 1], pose.y + s * points[:, 0] + c * points[:, 1])
    )


def brake_command(
    velocity: tuple[float, float], limits: VelocityLimits, period: float
) -> tuple[float, float]:
    """One period of maximum deceleration towards (0, 0), within the limits."""
    v, w = velocity
    dv = limits.max_acc_v * period
    dw = limits.max_acc_w * period
    v_new = max(v - dv, 0.0) if v > 0 else min(v + dv, 0.0)
    w_new = max(w - dw, 0.0) if w > 0 else min(w + dw, 0.0)
    v_new = float(np.clip(v_new, limits.min_v, limits.max_v))
    w_new = float(np.clip(w_new, -limits.max_w, limits.max_w))
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
        self._problem = _Problem(config, limits)
        self.last_stats: dict = {}
        self.reset()

    def reset(self) -> None:
        """Forget the warm start and the path progress (a new goal)."""
        self._prev_w: np.ndarray | None = None
        self._prev_pose: Pose2D | None = None
        self._rotating = False
        self._final_turn_done = False
        self._tracker.reset()

    # -- helpers -----------------------------------------------------------------------

    def _select_obstacles(
        self, obstacles: np.ndarray, near_xy: np.ndarray, pose: Pose2D
    ) -> np.ndarray:
        """(K, 2) robot-frame points nearest to ``near_xy`` (robot frame: the reference and
        the warm-start trajectory); unused slots parked far away."""
        k = self._problem.k_obs
        out = np.tile([_FAR, _FAR], (k, 1)).astype(float)
        if k == 0 or obstacles is None or len(obstacles) == 0:
            return out
        pts = np.asarray(obstacles, dtype=float).reshape(-1, 2)
        # Cheap prefilter around the robot, then robot frame.
        reach = float(np.max(np.abs(near_xy))) + self.config.obstacle_range
        rel = pts - np.array([pose.x, pose.y])
        pts = _to_local(pts[np.einsum("ij,ij->i", rel, rel) < reach * reach], pose)
        # Thin out: one point per grid cell (the one nearest the robot), so that K points
        # spread over the surroundings instead of crowding on the nearest centimetres of wall.
        cell = self.config.obstacle_spacing
        if cell > 0 and len(pts) > k:
            pts = pts[np.argsort(np.einsum("ij,ij->i", pts, pts))]
            ij = np.floor(pts / cell).astype(np.int64)
            _, first = np.unique(ij[:, 0] * 1_000_003 + ij[:, 1], return_index=True)
            pts = pts[first]
        # Distance of each point to the robot, the reference and the previous prediction.
        samples = np.vstack(([0.0, 0.0], near_xy[::2], near_xy[-1:]))
        d2 = ((pts[:, None, :] - samples[None, :, :]) ** 2).sum(axis=2).min(axis=1)
        keep = d2 < self.config.obstacle_range**2
        pts, d2 = pts[keep], d2[keep]
        if len(pts) > k:
            idx = np.argpartition(d2, k - 1)[:k]
            pts = pts[idx]
        out[: len(pts)] = pts
        return out

    def _rollout(self, x0: np.ndarray, ref: np.ndarray) -> np.ndarray:
        """Cold-start guess: a simple tracker driven along the reference, within the limits."""
        pb, lim, dt = self._problem, self.limits, self.config.dt
        states = np.empty((pb.n + 1, _NX))
        controls = np.zeros((pb.n, _NU))
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
        path, cumlen, total = prepare_path(path, pose, goal)
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
            self.last_stats = {}
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
        ref_xy, ref_th = interpolate(path, cumlen, s_ref)
        # The heading error that decides turn-in-place: to the goal on the final approach,
        # else to a point ahead on the path (or its tangent there when that point is close).
        ahead, ahead_th = interpolate(path, cumlen, np.array([min(s0 + cfg.lookahead, total)]))
        to_ahead = ahead[0] - xy
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
        near = np.vstack((ref[0:2].T, guess_states[:, 0:2]))
        obs = self._select_obstacles(obstacles, near, pose)
        r = self.robot_radius + cfg.safety_margin
        # Slacks that make the guess feasible (a cold start inside the margin converges).
        if pb.k_obs > 0:
            d2 = ((guess_states[:-1, None, 0:2] - obs[None, :, :]) ** 2).sum(axis=2).min(axis=1)
            slack = np.maximum(r * r - d2, 0.0) * 1.1 + 1e-4
        else:
            slack = np.full(pb.n, 1e-4)
        slack[0] = 1e-4
        guess[np.arange(pb.n) * pb.stride + _NX + 2] = slack
        p = np.concatenate(
            (x0, ref.T.ravel(), obs.ravel(), [r * r, speed_weight, heading_weight, position_weight])
        )

        args = {
            "x0": guess,
            "p": p,
            "lbx": pb.lbx,
            "ubx": pb.ubx,
            "lbg": pb.lbg,
            "ubg": pb.ubg,
        }
        t_solve = time.perf_counter()
        try:
            sol = pb.solver(**args)
        except RuntimeError:
            return self._fail((v0, w0), t0)
        stats = pb.solver.stats()
        stats["t_wall_solver_call"] = time.perf_counter() - t_solve
        self.last_stats = stats
        if not stats.get("success", False):
            return self._fail((v0, w0), t0)
        wopt = np.asarray(sol["x"]).ravel()
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
