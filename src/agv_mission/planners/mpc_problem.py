"""The MPC's optimisation problem, built once per configuration and limits (casadi).

Model: unicycle with state (x, y, theta, v, w) and controls (a, alpha, slack), so the
velocity and acceleration limits are simple bounds; every solve works in a frame centred
on the robot (x0 = (0, 0, 0, v, w)). Obstacle constraints: the body is a row of discs
along its x axis (one, at the origin, for a round robot; a cover of a polygon footprint,
:meth:`agv_mission.geometry.Footprint.discs`), and each disc of each model step gets the
few lidar points nearest its predicted centre (``m`` slots per disc and stage).

The default ``rti`` solver takes one Gauss-Newton SQP step per control step from the
shifted previous solution (see :func:`rti_function`): about a third of the CPU time of
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
from pathlib import Path

import casadi as ca
import numpy as np

from agv_mission.planners.base import VelocityLimits
from agv_mission.planners.configs import MpcConfig

NX = 5  # x, y, theta, v, w
NU = 3  # a, alpha, slack


class MpcProblem:
    """The NLP built once per configuration and limits: solver function, bounds, indices.

    Obstacle constraints are per stage: stage k (1..N-1) has ``m`` obstacle slots of its
    own, filled with the candidate points nearest that stage's predicted position.
    """

    def __init__(
        self, cfg: MpcConfig, limits: VelocityLimits, discs: tuple[float, ...] = (0.0,)
    ) -> None:
        n, dt = cfg.horizon, cfg.dt
        m = cfg.obstacles_per_stage if cfg.max_obstacles > 0 else 0
        nd = len(discs)
        self.discs = discs
        wts = cfg.weights
        x = ca.SX.sym("x", NX)
        u = ca.SX.sym("u", NU)

        def f(s: ca.SX, c: ca.SX) -> ca.SX:
            return ca.vertcat(s[3] * ca.cos(s[2]), s[3] * ca.sin(s[2]), s[4], c[0], c[1])

        k1 = f(x, u)
        k2 = f(x + dt / 2 * k1, u)
        k3 = f(x + dt / 2 * k2, u)
        k4 = f(x + dt * k3, u)
        step = ca.Function("F", [x, u], [x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)])

        p_x0 = ca.SX.sym("x0", NX)
        p_ref = ca.SX.sym("ref", 4, n + 1)  # x, y, theta, v per stage
        p_obs = ca.SX.sym("obs", 2, m * nd * (n - 1))  # m slots per disc, stages 1..N-1
        p_r2 = ca.SX.sym("r2")
        p_wv = ca.SX.sym("speed_weight")  # scales the speed weight (turn-in-place: large)
        p_wh = ca.SX.sym("heading_weight")  # scales the heading weights (fades at the goal)
        p_wp = ca.SX.sym("position_weight")  # scales the position weights (grows at the goal)
        params = ca.vertcat(p_x0, ca.vec(p_ref), ca.vec(p_obs), p_r2, p_wv, p_wh, p_wp)

        xs = [ca.SX.sym(f"x{k}", NX) for k in range(n + 1)]
        us = [ca.SX.sym(f"u{k}", NU) for k in range(n)]
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
            equality += [True] * NX
            if k == 0:
                g.append(xk - p_x0)
                equality += [True] * NX
            elif m > 0:
                for j, c in enumerate(discs):
                    o = p_obs[:, ((k - 1) * nd + j) * m : ((k - 1) * nd + j + 1) * m]
                    g.append(disc_clearance(xk, c, o).T + uk[2] - p_r2)
                    equality += [False] * m
            cost += p_wp * wts.position * ca.sumsqr(e) + p_wh * wts.heading * (xk[2] - r[2]) ** 2
            cost += p_wv * wts.speed * (xk[3] - r[3]) ** 2 + wts.angular_velocity * xk[4] ** 2
            cost += wts.acceleration * uk[0] ** 2 + wts.angular_acceleration * uk[1] ** 2
            cost += wts.slack_linear * uk[2] + wts.slack_quadratic * uk[2] ** 2

        self.n, self.m, self.nd = n, m, nd
        self.stride = NX + NU
        self.nw = n * self.stride + NX
        self.idx_x = np.arange(n + 1)[:, None] * self.stride + np.arange(NX)[None, :]
        self.idx_u = np.arange(n)[:, None] * self.stride + NX + np.arange(NU)[None, :]
        self.idx_slack = np.arange(n) * self.stride + NX + 2
        # Parameter vector layout, filled in place every solve.
        self.n_params = params.shape[0]
        self.p_ref = slice(NX, NX + 4 * (n + 1))
        self.p_obs = slice(self.p_ref.stop, self.p_ref.stop + 2 * m * nd * (n - 1))
        self.kind = cfg.solver
        self.cold_iterations = cfg.rti_cold_iterations
        if cfg.solver == "rti":
            cached = _load_cached(cfg, limits, discs)
            if cached is None:
                cached = rti_function(
                    cfg, limits, step, params, p_x0, p_ref, p_obs, p_r2, p_wv, p_wh, p_wp, discs
                )
                _save_cached(cfg, limits, discs, cached)
            self.rti_fn = cached
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
            lbx[i : i + NX] = [-np.inf, -np.inf, -np.inf, limits.min_v, -limits.max_w]
            ubx[i : i + NX] = [np.inf, np.inf, np.inf, limits.max_v, limits.max_w]
            if k < n:
                j = i + NX
                lbx[j : j + NU] = [-limits.max_acc_v, -limits.max_acc_w, 0.0]
                ubx[j : j + NU] = [limits.max_acc_v, limits.max_acc_w, np.inf]
        eq = np.array(equality, dtype=bool)
        self.lbx, self.ubx = ca.DM(lbx), ca.DM(ubx)
        self.lbg, self.ubg = ca.DM(np.zeros(len(eq))), ca.DM(np.where(eq, 0.0, np.inf))

    def solve(
        self,
        states: np.ndarray,
        controls: np.ndarray,
        p: np.ndarray,
        cold: bool,
        rti: RtiStep | None = None,
    ) -> tuple[np.ndarray, np.ndarray, dict]:
        """The solution's states (N+1, 5) and controls (N, 3) from the guess ``states`` and
        ``controls``; raises RuntimeError when the solver fails."""
        if self.kind == "rti":
            iterations = self.cold_iterations if cold else 1
            assert rti is not None, "an rti problem needs the controller's RtiStep"
            states, u = rti.step(controls, p, iterations)
            out = np.empty((self.n, NU))
            out[:, 0:2] = u[:-1].reshape(self.n, 2)
            out[:, 2] = u[-1]
            return states, out, {"success": True, "iter_count": iterations}
        guess = self.pack(states, controls)
        sol = self.solver(x0=guess, p=p, lbx=self.lbx, ubx=self.ubx, lbg=self.lbg, ubg=self.ubg)
        wopt = sol["x"].full().ravel()
        return wopt[self.idx_x], wopt[self.idx_u], {}

    def pack(self, states: np.ndarray, controls: np.ndarray) -> np.ndarray:
        wv = np.empty(self.nw)
        wv[self.idx_x] = states
        wv[self.idx_u] = controls
        return wv


def rti_function(
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
    discs: tuple[float, ...] = (0.0,),
) -> ca.Function:
    """The function of one real-time-iteration step: (controls, params) -> new controls.

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
    nd = len(discs)
    n, m, wts = cfg.horizon, (p_obs.shape[1] // max((cfg.horizon - 1) * nd, 1)), cfg.weights
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
            for j, c in enumerate(discs):
                o = p_obs[:, ((k - 1) * nd + j) * m : ((k - 1) * nd + j + 1) * m]
                obstacles.append(disc_clearance(xs[k], c, o).T + slack - p_r2)
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
    cons_jac = ca.jacobian(cons, u)
    qp_data = ca.Function(
        "mpc_qp_data",
        [u, params],
        [
            jac,  # sparse: a stage's residuals depend only on the controls before it
            residual,
            ca.gradient(linear, u),
            cons_jac,  # sparse: DAQP densifies it itself, cheaper than SX zeros
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
            "a": cons_jac.sparsity(),
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
    return ca.Function("mpc_rti", [u_mx, p_mx], [u_new, rollout(u_new, p_mx)])


class RtiStep:
    """The real-time iteration (see :func:`rti_function`), called through casadi's buffer
    API: the arguments and results are numpy arrays bound once, so a call allocates
    nothing and converts nothing (``Function.__call__`` costs about 0.1 ms more). One per
    controller: the buffers are its own, the function is shared."""

    def __init__(self, step_fn: ca.Function) -> None:
        self.step_fn = step_fn  # (u, p) -> controls after one Gauss-Newton SQP step, states
        n = step_fn.size2_out(1) - 1
        self.u = np.zeros(step_fn.numel_in(0))
        self.p = np.zeros(step_fn.numel_in(1))
        self.u_new = np.zeros(step_fn.numel_out(0))
        self.states = np.zeros((n + 1, NX))  # casadi's column-major (5, N+1) = row-major
        self._buffer, self._eval = step_fn.buffer()
        for i, arg in enumerate((self.u, self.p)):
            self._buffer.set_arg(i, memoryview(arg))
        for i, res in enumerate((self.u_new, self.states)):
            self._buffer.set_res(i, memoryview(res))

    def step(
        self, controls: np.ndarray, p: np.ndarray, iterations: int
    ) -> tuple[np.ndarray, np.ndarray]:
        """``iterations`` Gauss-Newton SQP steps from ``controls`` (N, 3; the slack is their
        largest): the states (N+1, 5) and controls ``[a_0, alpha_0, ..., slack]`` reached."""
        n = len(controls)
        self.u[: 2 * n] = controls[:, 0:2].ravel()
        self.u[2 * n] = controls[:, 2].max()
        if p is not self.p:
            self.p[:] = p
        for i in range(iterations):
            if i:
                self.u[:] = self.u_new
            self._eval()
        return self.states.copy(), self.u_new.copy()


def _cache_dir() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "agv-mission" / "mpc"


def disc_clearance(xk: ca.SX, offset: float, o: ca.SX) -> ca.SX:
    """Squared distances from the disc ``offset`` m ahead of the state's position along its
    heading to the obstacle points ``o`` (2, m)."""
    px, py = xk[0], xk[1]
    if offset != 0.0:
        px, py = px + offset * ca.cos(xk[2]), py + offset * ca.sin(xk[2])
    return (px - o[0, :]) ** 2 + (py - o[1, :]) ** 2


def _cache_key(cfg: MpcConfig, limits: VelocityLimits, discs: tuple[float, ...]) -> str:
    """Changes with the configuration, the limits, the discs, casadi and this module's
    source."""
    digest = hashlib.sha256()
    for part in (cfg.model_dump_json(), repr(limits), repr(discs), ca.__version__):
        digest.update(part.encode())
    digest.update(Path(__file__).read_bytes())
    return digest.hexdigest()[:24]


def _load_cached(
    cfg: MpcConfig, limits: VelocityLimits, discs: tuple[float, ...]
) -> ca.Function | None:
    """The RTI functions serialised by an earlier process (loading takes ~0.07 s, building
    with common-subexpression elimination ~0.6 s), or None."""
    try:
        stem = _cache_dir() / _cache_key(cfg, limits, discs)
        return ca.Function.load(str(stem) + ".casadi")
    except (OSError, RuntimeError):
        return None


def _save_cached(
    cfg: MpcConfig, limits: VelocityLimits, discs: tuple[float, ...], rti: ca.Function
) -> None:
    """Serialise the RTI functions for later processes; a cache that cannot be written
    only costs the next process the build time."""
    try:
        stem = _cache_dir() / _cache_key(cfg, limits, discs)
        stem.parent.mkdir(parents=True, exist_ok=True)
        tmp = stem.parent / f".{stem.name}.{os.getpid()}.tmp"
        rti.save(str(tmp))
        os.replace(tmp, str(stem) + ".casadi")
    except (OSError, RuntimeError):
        return


@functools.lru_cache(maxsize=16)
def mpc_problem(
    cfg_json: str, limits: VelocityLimits, discs: tuple[float, ...] = (0.0,)
) -> MpcProblem:
    """One solver per configuration, limits and body discs, shared by every controller of
    the process (regression suites and the service create many controllers for the same
    robot)."""
    return MpcProblem(MpcConfig.model_validate_json(cfg_json), limits, discs)
