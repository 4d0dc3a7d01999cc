"""Nonlinear MPC local planner (casadi; real-time iteration by default, or fatrop / ipopt).

Model: unicycle with state (x, y, theta, v, w) and controls (a, alpha, slack), so the
velocity and acceleration limits are simple bounds. Every solve works in a frame
centred on the robot (x0 = (0, 0, 0, v, w)), which keeps the numbers small and
theta free of wrap-around. Obstacle constraints: each model step gets the few lidar
points nearest its predicted position.

The default ``rti`` solver takes one Gauss-Newton SQP step per control step from the
shifted previous solution (see :func:`_rti_function`): about a third of the CPU time of
solving the NLP to tolerance, with the same tracking. The functions are built once per
configuration and limits, kept for the process and serialised to a user cache directory.

For fatrop, the NLP is laid out the way its structure detection wants it:
variables x0, u0, x1, u1, ..., xN; constraints per stage [dynamics_k; path_k] with
the initial-state constraint right after dynamics_0; dynamics written
``x_{k+1} - F(x_k, u_k)``; every constraint touching one stage only. The obstacle
constraints ``|p_k - o_j|^2 + s_k >= R^2`` use one slack ``s_k >= 0`` per stage
(a control of that stage), penalised linearly and quadratically (exact penalty),
so the problem is always feasible.
"""

from __future__ import annotations

import functools
import hashlib
import math
import os
import time
from dataclasses import dataclass
from pathlib import Path

import casadi as ca
import numpy as np

from agv_mission.geometry import Pose2D, wrap_angle
from agv_mission.planners.base import VelocityCommand, VelocityLimits
from agv_mission.planners.configs import MpcConfig
from agv_mission.planners.path_tracking import (
    ProgressTracker,
    clean_path,
    interpolate,
    prepare_path,
    speed_profile,
    unwrap_from,
)

_NX = 5  # x, y, theta, v, w
_NU = 3  # a, alpha, slack
_FAR = 50.0  # where unused obstacle slots are parked (robot frame, metres)


class _Problem:
    """The NLP built once per configuration and limits: solver function, bounds, indices.

    Obstacle constraints are per stage: stage k (1..N-1) has ``m`` obstacle slots of its
    own, filled with the candidate points nearest that stage's predicted position.
    """

    def __init__(self, cfg: MpcConfig, limits: VelocityLimits) -> None:
        n, dt = cfg.horizon, cfg.dt
        m = cfg.obstacles_per_stage if cfg.max_obstacles > 0 else 0
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
        p_obs = ca.SX.sym("obs", 2, m * (n - 1))  # m slots for each stage 1..N-1
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
            elif m > 0:
                o = p_obs[:, (k - 1) * m : k * m]
                d2 = (xk[0] - o[0, :]) ** 2 + (xk[1] - o[1, :]) ** 2
                g.append(d2.T + uk[2] - p_r2)
                equality += [False] * m
            cost += p_wp * wts.position * ca.sumsqr(e) + p_wh * wts.heading * (xk[2] - r[2]) ** 2
            cost += p_wv * wts.speed * (xk[3] - r[3]) ** 2 + wts.angular_velocity * xk[4] ** 2
            cost += wts.acceleration * uk[0] ** 2 + wts.angular_acceleration * uk[1] ** 2
            cost += wts.slack_linear * uk[2] + wts.slack_quadratic * uk[2] ** 2

        self.n, self.m = n, m
        self.stride = _NX + _NU
        self.nw = n * self.stride + _NX
        self.idx_x = np.arange(n + 1)[:, None] * self.stride + np.arange(_NX)[None, :]
        self.idx_u = np.arange(n)[:, None] * self.stride + _NX + np.arange(_NU)[None, :]
        self.idx_slack = np.arange(n) * self.stride + _NX + 2
        # Parameter vector layout, filled in place every solve.
        self.n_params = params.shape[0]
        self.p_ref = slice(_NX, _NX + 4 * (n + 1))
        self.p_obs = slice(self.p_ref.stop, self.p_ref.stop + 2 * m * (n - 1))
        self.kind = cfg.solver
        self.cold_iterations = cfg.rti_cold_iterations
        if cfg.solver == "rti":
            cached = _load_cached(cfg, limits)
            if cached is None:
                cached = _rti_function(
                    cfg, limits, step, params, p_x0, p_ref, p_obs, p_r2, p_wv, p_wh, p_wp
                )
                _save_cached(cfg, limits, cached)
            self.rti = cached
            return

        nlp = {"x": ca.vertcat(*w), "f": cost, "g": ca.vertcat(*g), "p": params}
        so = cfg.solver_options
        # error_on_fail: a failed solve raises (caught by the controller), so the hot path
        # needs no stats() call (about 0.1 ms) to learn whether it worked.
        if cfg.solver == "fatrop":
            opts = {
                "structure_detection": "auto",
                "equality": equality,
                "expand": True,
                "print_time": False,
                "error_on_fail": True,
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
                "error_on_fail": True,
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
        eq = np.array(equality, dtype=bool)
        self.lbx, self.ubx = ca.DM(lbx), ca.DM(ubx)
        self.lbg, self.ubg = ca.DM(np.zeros(len(eq))), ca.DM(np.where(eq, 0.0, np.inf))

    def solve(self, guess: np.ndarray, p: np.ndarray, cold: bool) -> tuple[np.ndarray, dict]:
        """The solution vector from ``guess``; raises RuntimeError when the solver fails."""
        if self.kind == "rti":
            controls = guess[self.idx_u]
            u = np.append(controls[:, 0:2].ravel(), controls[:, 2].max())
            for _ in range(self.cold_iterations if cold else 1):
                u, states = self.rti.step(u, p)
            wopt = np.empty(self.nw)
            wopt[self.idx_u[:, 0:2]] = u[:-1].reshape(self.n, 2)
            wopt[self.idx_u[:, 2]] = u[-1]
            wopt[self.idx_x] = states
            return wopt, {"success": True, "iter_count": self.cold_iterations if cold else 1}
        sol = self.solver(x0=guess, p=p, lbx=self.lbx, ubx=self.ubx, lbg=self.lbg, ubg=self.ubg)
        return sol["x"].full().ravel(), {}

    def states(self, wopt: np.ndarray) -> np.ndarray:
        """(N+1, 5) states of a solution vector."""
        return wopt[self.idx_x]

    def controls(self, wopt: np.ndarray) -> np.ndarray:
        """(N, 3) controls of a solution vector."""
        return wopt[self.idx_u]

    def pack(self, states: np.ndarray, controls: np.ndarray) -> np.ndarray:
        wv = np.empty(self.nw)
        wv[self.idx_x] = states
        wv[self.idx_u] = controls
        return wv


def _rti_function(
    cfg: MpcConfig,
    limits: VelocityLimits,
    step: ca.Function,
    params: ca.SX,
    p_x0: ca.SX,
    p_ref: ca.SX,
    p_obs: ca.SX,
    p_r2: ca.SX,
    p_wv: ca.SX,
    p_wh: ca.SX,
    p_wp: ca.SX,
) -> _Rti:
    """The functions of one real-time-iteration step: (controls, params) -> new controls.

    Single shooting: the states are the model's rollout of the controls from x0, so the
    QP has only the controls: (a, alpha) per step and one slack shared by every obstacle
    constraint (``u = [a_0, alpha_0, ..., a_N-1, alpha_N-1, slack]``; one slack instead
    of one per step halves the active bounds the QP solver works through). The cost is a
    sum of squared residuals, so its Gauss-Newton Hessian J'J is positive definite and the
    QP convex; the speed and turn rate bounds are linear in the accelerations (exact), the
    obstacle constraints are linearised at the guess (the slack keeps the QP feasible; it
    is penalised as if every step had used it). DAQP (a dual active-set method for small
    dense QPs) solves the QP; the step is taken in full and the states rolled out again.
    """
    n, m, wts = cfg.horizon, (p_obs.shape[1] // max(cfg.horizon - 1, 1)), cfg.weights
    u = ca.SX.sym("u", 2 * n + 1)
    slack = u[2 * n]
    xs = [p_x0]
    for k in range(n):
        xs.append(step(xs[-1], ca.vertcat(u[2 * k : 2 * k + 2], 0.0)))
    sp, sh, sv = ca.sqrt(p_wp), ca.sqrt(p_wh), ca.sqrt(p_wv)
    res: list[ca.SX] = []
    linear = 0
    speed: list[ca.SX] = []
    turn: list[ca.SX] = []
    obstacles: list[ca.SX] = []
    for k in range(1, n + 1):
        xk, r = xs[k], p_ref[:, k]
        terminal = k == n
        res.append(
            sp * math.sqrt(wts.terminal_position if terminal else wts.position) * (xk[0:2] - r[0:2])
        )
        res.append(
            sh * math.sqrt(wts.terminal_heading if terminal else wts.heading) * (xk[2] - r[2])
        )
        res.append(sv * math.sqrt(wts.speed) * (xk[3] - r[3]))
        if not terminal:
            res.append(math.sqrt(wts.angular_velocity) * xk[4])
        speed.append(xk[3])
        turn.append(xk[4])
    for k in range(n):
        res.append(math.sqrt(wts.acceleration) * u[2 * k])
        res.append(math.sqrt(wts.angular_acceleration) * u[2 * k + 1])
        if k >= 1 and m > 0:
            o, xk = p_obs[:, (k - 1) * m : k * m], xs[k]
            obstacles.append(((xk[0] - o[0, :]) ** 2 + (xk[1] - o[1, :]) ** 2).T + slack - p_r2)
    res.append(math.sqrt(wts.slack_quadratic * (n - 1)) * slack)
    linear = wts.slack_linear * (n - 1) * slack
    residual = ca.vertcat(*res)
    cons = ca.vertcat(*speed, *turn, *obstacles)
    big = 1e6  # finite bounds for the QP solver
    lbc = np.concatenate(
        (np.full(n, limits.min_v), np.full(n, -limits.max_w), np.zeros(len(obstacles) * m))
    )
    ubc = np.concatenate(
        (np.full(n, limits.max_v), np.full(n, limits.max_w), np.full(len(obstacles) * m, big))
    )
    # J'J from the sparse residual Jacobian (a stage's residuals depend only on the
    # controls before it): far fewer scalar operations than a dense product.
    jac = ca.jacobian(residual, u)
    qp_data = ca.Function(
        "mpc_qp_data",
        [u, params],
        [
            jac,  # sparse: a stage's residuals depend only on the controls before it
            residual,
            ca.gradient(linear, u),
            ca.densify(ca.jacobian(cons, u)),
            lbc - cons,
            ubc - cons,
        ],
        {"cse": True},
    )
    rollout = ca.Function("mpc_rollout", [u, params], [ca.horzcat(*xs)])
    qp = ca.conic(
        "mpc_qp",
        "daqp",
        {
            "h": ca.Sparsity.dense(2 * n + 1, 2 * n + 1),
            "a": ca.Sparsity.dense(cons.shape[0], 2 * n + 1),
        },
        {"error_on_fail": True},
    )
    lbu = np.append(np.tile([-limits.max_acc_v, -limits.max_acc_w], n), 0.0)
    ubu = np.append(np.tile([limits.max_acc_v, limits.max_acc_w], n), big)
    # The QP data and the solve in one function: no matrix crosses into Python (casadi's
    # dense conversions cost more than the solve). J'J is a sparse MX product (compiled
    # loops; as SX scalar instructions it costs several times more).
    u_mx = ca.MX.sym("u", 2 * n + 1)
    p_mx = ca.MX.sym("p", params.shape[0])
    jac_mx, res_mx, lin_mx, a, lba, uba = qp_data(u_mx, p_mx)
    sol = qp(
        h=ca.densify(2.0 * ca.mtimes(jac_mx.T, jac_mx)),
        g=2.0 * ca.mtimes(jac_mx.T, res_mx) + lin_mx,
        a=a,
        lba=lba,
        uba=uba,
        lbx=ca.DM(lbu) - u_mx,
        ubx=ca.DM(ubu) - u_mx,
    )
    u_new = u_mx + sol["x"]
    return _Rti(ca.Function("mpc_rti", [u_mx, p_mx], [u_new, rollout(u_new, p_mx)]))


@dataclass(frozen=True)
class _Rti:
    """The functions of the real-time iteration (see :func:`_rti_function`)."""

    step_fn: ca.Function  # (u, p) -> controls after one Gauss-Newton SQP step, their states

    def step(self, u: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """One Gauss-Newton SQP step from the controls ``u``: the new controls (2N + 1,)
        and the states they give (N+1, 5)."""
        u_new, states = self.step_fn(u, p)
        return u_new.full().ravel(), states.full().T


def _cache_dir() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "agv-mission" / "mpc"


def _cache_key(cfg: MpcConfig, limits: VelocityLimits) -> str:
    """Changes with the configuration, the limits, casadi and this module's source."""
    digest = hashlib.sha256()
    for part in (cfg.model_dump_json(), repr(limits), ca.__version__):
        digest.update(part.encode())
    digest.update(Path(__file__).read_bytes())
    return digest.hexdigest()[:24]


def _load_cached(cfg: MpcConfig, limits: VelocityLimits) -> _Rti | None:
    """The RTI functions serialised by an earlier process (loading takes ~0.07 s, building
    with common-subexpression elimination ~0.6 s), or None."""
    try:
        stem = _cache_dir() / _cache_key(cfg, limits)
        return _Rti(ca.Function.load(str(stem) + ".casadi"))
    except (OSError, RuntimeError):
        return None


def _save_cached(cfg: MpcConfig, limits: VelocityLimits, rti: _Rti) -> None:
    """Serialise the RTI functions for later processes; a cache that cannot be written
    only costs the next process the build time."""
    try:
        stem = _cache_dir() / _cache_key(cfg, limits)
        stem.parent.mkdir(parents=True, exist_ok=True)
        tmp = stem.parent / f".{stem.name}.{os.getpid()}.tmp"
        rti.step_fn.save(str(tmp))
        os.replace(tmp, str(stem) + ".casadi")
    except (OSError, RuntimeError):
        return


@functools.lru_cache(maxsize=16)
def _problem(cfg_json: str, limits: VelocityLimits) -> _Problem:
    """One solver per configuration and limits, shared by every controller of the process
    (regression suites and the service create many controllers for the same robot)."""
    return _Problem(MpcConfig.model_validate_json(cfg_json), limits)


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
        self._problem = _problem(config.model_dump_json(), limits)
        self._p = np.empty(self._problem.n_params)  # parameter vector, filled in place
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
        far = np.take_along_axis(d2, idx, axis=1) > cfg.obstacle_range**2
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
        r = self.robot_radius + cfg.safety_margin
        p = self._p
        p[0:_NX] = x0
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
