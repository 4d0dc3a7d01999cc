"""Nonlinear MPC local planner (casadi; real-time iteration by default, or fatrop / ipopt).

:mod:`agv_mission.planners.mpc_problem` builds the optimisation problem once per
configuration and limits; this controller fills its parameter vector in place each
control step (the reference along the path at the speed profile, the lidar points nearest
each predicted stage, the warm start shifted from the previous solution) and turns its
first control into a velocity command. Everything a path allows is computed once per
path (:class:`ReferenceProfile`), so a step costs a few small numpy operations around
one buffered casadi call.
"""

from __future__ import annotations

import math
import time

import numpy as np

from agv_mission.geometry import Footprint, Pose2D, wrap_angle
from agv_mission.planners.base import VelocityCommand, VelocityLimits
from agv_mission.planners.configs import MpcConfig
from agv_mission.planners.free_corridor import free_distance
from agv_mission.planners.mpc_problem import NU, NX, MpcProblem, RtiStep, mpc_problem
from agv_mission.planners.path_follower import PathFollower, PathStep
from agv_mission.planners.path_tracking import ReferenceProfile

_FAR = 50.0  # where unused obstacle slots are parked (robot frame, metres)

__all__ = ["MpcConfig", "MpcController", "MpcProblem", "brake_command"]


def _to_map(points: np.ndarray, pose: Pose2D) -> np.ndarray:
    c, s = math.cos(pose.yaw), math.sin(pose.yaw)
    out = np.empty_like(points)
    out[:, 0] = c * points[:, 0] - s * points[:, 1] + pose.x
    out[:, 1] = s * points[:, 0] + c * points[:, 1] + pose.y
    return out


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


class MpcController(PathFollower):
    """Tracks the path with a nonlinear MPC and stops at its end; avoids lidar points."""

    Config = MpcConfig
    predicts_moving = True  # takes tracked people as moving obstacles (``compute(moving=)``)

    def __init__(
        self,
        config: MpcConfig,
        limits: VelocityLimits,
        robot_radius: float,
        control_period: float,
        footprint: Footprint | None = None,
    ) -> None:
        super().__init__(limits, control_period)
        self.config = config
        self.robot_radius = robot_radius
        # the body as discs along its axis: one of robot_radius, or a polygon's cover
        self.discs, self.disc_radius = (
            footprint.discs() if footprint is not None else ((0.0,), robot_radius)
        )
        self._problem = pb = mpc_problem(config.model_dump_json(), limits, self.discs)
        # a robot that cannot stop within its safety margin watches the way ahead
        margin = config.safety_margin
        self._fast = limits.max_v**2 > 2.0 * limits.max_acc_v * margin
        self._half_width = footprint.half_width if footprint is not None else robot_radius
        self._front = footprint.front if footprint is not None else robot_radius
        self._rti = RtiStep(pb.rti_fn) if pb.kind == "rti" else None
        # The parameter vector, filled in place (the RTI's own argument buffer) through
        # views of its reference (N+1, 4) and obstacle (N-1, m, 2) parts.
        self._p = self._rti.p if self._rti is not None else np.zeros(pb.n_params)
        self._ref = self._p[pb.p_ref].reshape(pb.n + 1, 4)
        # one row of m slots per stage and disc (stage-major)
        self._obs = self._p[pb.p_obs].reshape(max(pb.n - 1, 0) * pb.nd, pb.m, 2)
        self._rows = np.arange(max(pb.n - 1, 0) * pb.nd)
        self._stats: dict | None = {}
        self._solve_info: dict = {}
        self._t_solver_call = 0.0
        self.reset()

    def reset(self) -> None:
        """Forget the warm start and the path progress (a new goal)."""
        super().reset()
        self._prev: tuple[Pose2D, np.ndarray, np.ndarray] | None = None  # pose, states, controls
        self._rotating = False
        self._final_turn_done = False

    # -- helpers -----------------------------------------------------------------------

    def _seen_free(self, step: PathStep, profile: ReferenceProfile) -> float:
        """The arclength the robot's origin must stop at: where the corridor its body
        sweeps along the path is on an obstacle point or hidden behind one, less its
        front and the safety margin (inf: free as far as it could need)."""
        cfg, lim = self.config, self.limits
        dec = cfg.decel_fraction * lim.max_acc_v
        reach = lim.max_v**2 / (2.0 * dec) + self._front + cfg.safety_margin + 0.3
        spacing = 0.1
        n = int(min(reach, step.total - step.s) / spacing)
        if n < 1 or step.obstacles is None or not len(step.obstacles):
            return math.inf
        samples = np.array([profile.point(step.s + spacing * (k + 1))[0:2] for k in range(n)])
        pose = step.pose
        free = free_distance(
            samples, spacing, (pose.x, pose.y), step.obstacles, self._half_width + cfg.safety_margin
        )
        if free >= n * spacing:
            return math.inf
        return step.s + free - self._front - cfg.safety_margin

    def _disc_centres(self, states: np.ndarray) -> np.ndarray:
        """The discs' centres at the guessed ``states`` (rows x, y, theta, ...): one row
        per state and disc, stage-major."""
        if len(self.discs) == 1 and self.discs[0] == 0.0:
            return states[:, 0:2]
        off = np.asarray(self.discs)
        cx = states[:, 0, None] + off[None, :] * np.cos(states[:, 2, None])
        cy = states[:, 1, None] + off[None, :] * np.sin(states[:, 2, None])
        return np.column_stack([cx.ravel(), cy.ravel()])

    def _stage_obstacles(
        self,
        obstacles: np.ndarray,
        stage_xy: np.ndarray,
        pose: Pose2D,
        moving: np.ndarray | None = None,
    ) -> np.ndarray:
        """Fill the obstacle parameters: for each stage 1..N-1 and each disc the ``m``
        points nearest its guessed centre, a row of ``stage_xy`` (robot frame, stage-major;
        the constraints that can bind there):
        lidar points, and each tracked person where it will be at that stage's time
        (constant velocity), as the point of its body (grown by ``people_margin``) nearest
        the stage. Slots with no point within ``obstacle_range`` are parked far away.
        Returns each row's smallest squared distance to its points (inf: none)."""
        out, cfg = self._obs, self.config
        reach2 = cfg.obstacle_range**2
        pts = np.asarray(obstacles, dtype=float).reshape(-1, 2)
        dx, dy = pts[:, 0] - pose.x, pts[:, 1] - pose.y
        # Only points within obstacle_range of some stage can count: those within that
        # of the farthest stage's distance from the robot (at most max_obstacles, the
        # nearest).
        ring = math.sqrt(float((stage_xy * stage_xy).sum(axis=1).max())) + cfg.obstacle_range
        d2_robot = dx * dx + dy * dy
        near = np.flatnonzero(d2_robot <= ring * ring)
        if len(near) > cfg.max_obstacles:
            near = near[np.argpartition(d2_robot[near], cfg.max_obstacles - 1)]
            near = near[: cfg.max_obstacles]
        c, s = math.cos(pose.yaw), math.sin(pose.yaw)
        lx = np.broadcast_to(c * dx[near] + s * dy[near], (len(stage_xy), len(near)))
        ly = np.broadcast_to(c * dy[near] - s * dx[near], (len(stage_xy), len(near)))
        people = self._people_points(moving, stage_xy, pose, ring, c, s)
        if people is not None:
            lx = np.hstack([lx, people[0]])
            ly = np.hstack([ly, people[1]])
        if lx.shape[1] == 0:
            out[:] = _FAR
            return np.full(len(stage_xy), np.inf)
        ex = stage_xy[:, 0, None] - lx
        ey = stage_xy[:, 1, None] - ly
        d2 = ex * ex + ey * ey
        rows = self._rows
        nearest = np.full(len(stage_xy), np.inf)
        k = min(self._problem.m, lx.shape[1])
        # The k nearest of each stage by repeated argmin: for a few slots far cheaper
        # than a row-wise argpartition.
        for j in range(k):
            i = d2.argmin(axis=1)
            dj = d2[rows, i]
            far = dj > reach2
            out[:, j, 0] = np.where(far, _FAR, lx[rows, i])
            out[:, j, 1] = np.where(far, _FAR, ly[rows, i])
            if j == 0:
                nearest = np.where(far, np.inf, dj)
            d2[rows, i] = np.inf
        out[:, k:] = _FAR
        return nearest

    def _people_points(
        self,
        moving: np.ndarray | None,
        stage_xy: np.ndarray,
        pose: Pose2D,
        ring: float,
        c: float,
        s: float,
    ) -> tuple[np.ndarray, np.ndarray] | None:
        """(x, y) per stage and person (robot frame): the person's predicted centre at the
        stage's time moved towards the stage by its radius and ``people_margin``. People
        whose predicted walk never comes within ``ring`` of the robot (their closest
        approach over the horizon; every stage lies within it) are left out: walking away
        or past, they cannot bind (of 6 people near a patrolling burger among 50, 1 is
        kept on average, where a bound on the distance alone kept 2.5)."""
        if moving is None or not len(moving):
            return None
        rows = np.asarray(moving, dtype=float)  # x, y, radius, vx, vy, ...
        cfg = self.config
        # points as complex numbers: half the array operations of x and y apart
        z = rows[:, 0] - pose.x + 1j * (rows[:, 1] - pose.y)
        vel = rows[:, 3] + 1j * rows[:, 4]
        nd = self._problem.nd
        n = len(stage_xy) // nd
        grow = rows[:, 2] + cfg.people_margin
        # the time of closest approach within the stages' times, and the distance then
        when = -(z * vel.conjugate()).real / np.maximum((vel * vel.conjugate()).real, 1e-12)
        keep = np.abs(z + vel * np.clip(when, cfg.dt, n * cfg.dt)) <= ring + grow
        if not keep.any():
            return None
        turn = complex(c, -s)  # map frame to the robot's
        z, vel, grow = z[keep] * turn, vel[keep] * turn, grow[keep]
        stage = np.arange(len(stage_xy)) // nd + 1.0  # each row's stage, 1..N-1
        centre = z + vel * (stage[:, None] * cfg.dt)
        gap = (stage_xy[:, 0] + 1j * stage_xy[:, 1])[:, None] - centre
        dist = np.maximum(np.abs(gap), 1e-6)
        # a stage guessed inside the grown body: a point between it and the centre, so the
        # constraint still pushes the stage out
        point = centre + gap * (np.where(dist > grow, grow, 0.5 * dist) / dist)
        return point.real, point.imag

    @property
    def last_stats(self) -> dict:
        """The solver's statistics of the last solve (fetched on demand: costs ~0.1 ms)."""
        if self._stats is None:
            pb = self._problem
            self._stats = dict(self._solve_info or pb.solver.stats())
            self._stats["t_wall_solver_call"] = self._t_solver_call
        return self._stats

    def _rollout(self, x0: np.ndarray, ref: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Cold-start guess (states, controls): a simple tracker driven along the
        reference ``ref`` (N+1, 4), within the limits."""
        pb, lim, dt = self._problem, self.limits, self.config.dt
        states = np.empty((pb.n + 1, NX))
        controls = np.zeros((pb.n, NU))
        x, y, th, v, w = (float(c) for c in x0)
        states[0] = x0
        for k in range(pb.n):
            dx, dy = ref[k + 1, 0] - x, ref[k + 1, 1] - y
            target = math.atan2(dy, dx) if dx * dx + dy * dy > 1e-4 else ref[k + 1, 2]
            err = wrap_angle(target - th)
            w_des = min(max(2.0 * err, -lim.max_w), lim.max_w)
            v_des = ref[k + 1, 3] if abs(err) < 1.0 else 0.0
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
        return states, controls

    def _warm_start(
        self, pose: Pose2D, x0: np.ndarray, ref: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """The previous solution moved into this robot frame and shifted by one step."""
        if self._prev is None:
            return self._rollout(x0, ref)
        prev_pose, prev_states, prev_controls = self._prev
        states = np.empty_like(prev_states)
        states[:-1] = prev_states[1:]
        states[-1] = prev_states[-1]
        controls = np.empty_like(prev_controls)
        controls[:-1] = prev_controls[1:]
        controls[-1] = prev_controls[-1]
        # Previous robot frame -> current robot frame: a rotation and a translation.
        turn = prev_pose.yaw - pose.yaw
        c, s = math.cos(turn), math.sin(turn)
        cy, sy = math.cos(pose.yaw), math.sin(pose.yaw)
        tx, ty = prev_pose.x - pose.x, prev_pose.y - pose.y
        px, py = states[:, 0].copy(), states[:, 1]
        states[:, 0] = c * px - s * py + (cy * tx + sy * ty)
        states[:, 1] = s * px + c * py + (cy * ty - sy * tx)
        states[:, 2] += wrap_angle(turn)
        states[0] = x0
        return states, controls

    def _fail(self, velocity: tuple[float, float]) -> VelocityCommand:
        self._prev = None
        v, w = brake_command(velocity, self.limits, self.control_period)
        return VelocityCommand(v, w, ok=False)

    # -- the plugin API ----------------------------------------------------------------

    def stop(self, velocity: tuple[float, float]) -> tuple[float, float]:
        lim = self.limits
        v0 = min(max(float(velocity[0]), lim.min_v), lim.max_v)
        w0 = min(max(float(velocity[1]), -lim.max_w), lim.max_w)
        self._prev = None
        self._stats = {}
        return brake_command((v0, w0), lim, self.control_period)

    def follow(self, step: PathStep) -> VelocityCommand:
        cfg, lim, pb, pose = self.config, self.limits, self._problem, step.pose
        v0 = min(max(float(step.velocity[0]), lim.min_v), lim.max_v)
        w0 = min(max(float(step.velocity[1]), -lim.max_w), lim.max_w)
        dec = cfg.decel_fraction * lim.max_acc_v
        profile = self.reference(step, lim.max_v, dec, cfg.turn_fraction)
        s0, dist_goal, (gx, gy) = step.s, step.dist_goal, step.to_goal

        # The point ahead whose heading decides turn-in-place: to the goal on the final
        # approach, else to a point ahead on the path (or its tangent there when that point
        # is close).
        # (at speed further ahead: half a second's travel)
        lookahead = max(cfg.lookahead, 0.5 * v0)
        ax, ay, ahead_th = profile.point(min(s0 + lookahead, step.total))
        ax, ay = ax - pose.x, ay - pose.y
        threshold = cfg.rotate_threshold
        final = dist_goal < cfg.final_approach
        if final:
            # One turn towards a goal beside the robot; after that only a goal behind calls
            # for turning in place (no limit cycle when the goal is blocked).
            heading_err = wrap_angle(math.atan2(gy, gx) - pose.yaw)
            if self._final_turn_done:
                threshold = max(threshold, cfg.final_rotate_threshold)
        elif math.hypot(ax, ay) > 0.5 * lookahead:
            heading_err = wrap_angle(math.atan2(ay, ax) - pose.yaw)
        else:
            heading_err = wrap_angle(ahead_th - pose.yaw)
        if abs(heading_err) > threshold:
            self._rotating = True
        elif abs(heading_err) < cfg.rotate_exit:
            if self._rotating and final:
                self._final_turn_done = True
            self._rotating = False

        ref = self._ref  # (N+1, 4): x, y, theta, v per stage, a view of the parameters
        if self._rotating:
            # Hold the position, turn to the path; the speed is braked outside the solver.
            ref[:, 0:2] = 0.0
            ref[:, 2] = heading_err
            ref[:, 3] = 0.0
            speed_weight, heading_weight, position_weight = cfg.rotate_speed_weight, 1.0, 1.0
        else:
            # Arclengths at the speed profile, in the robot frame; a fast robot stops
            # within the stretch of path its lidar has seen free.
            stop_at = self._seen_free(step, profile) if self._fast else math.inf
            s_ref, v_ref = profile.sample(s0, v0, pb.n, cfg.dt, stop_at)
            self._p[pb.p_ref] = profile.in_frame(s_ref, v_ref, pose)
            # Path heading and speed stop mattering at the goal (the navigator turns in
            # place there): fading them lets the position terms remove a last offset.
            # The position weight grows as 1/d^2 so that the last centimetres still count
            # against the effort terms.
            fade = min(1.0, dist_goal / cfg.final_approach)
            speed_weight, heading_weight = fade, fade
            position_weight = min(1.0 / (fade * fade), cfg.final_position_gain)
        x0 = np.array((0.0, 0.0, 0.0, v0, w0))
        states, controls = self._warm_start(pose, x0, ref)
        r = self.disc_radius + cfg.safety_margin
        p = self._p
        p[0:NX] = x0
        p[-4:] = (r * r, speed_weight, heading_weight, position_weight)
        controls[:, 2] = 1e-4
        moving = step.moving
        has_people = moving is not None and len(moving) > 0
        if pb.m > 0 and (has_people or (step.obstacles is not None and len(step.obstacles))):
            obstacles = step.obstacles if step.obstacles is not None else np.zeros((0, 2))
            d2 = self._stage_obstacles(obstacles, self._disc_centres(states[1:-1]), pose, moving)
            if pb.nd > 1:
                d2 = d2.reshape(-1, pb.nd).min(axis=1)
            # Slacks that make the guess feasible (a cold start inside the margin converges).
            controls[1:, 2] += np.maximum(r * r - d2, 0.0) * 1.1
        elif pb.m > 0:
            self._obs[:] = _FAR

        self._stats = None
        t_solve = time.perf_counter()
        try:
            states, controls, self._solve_info = pb.solve(
                states, controls, p, cold=self._prev is None, rti=self._rti
            )
        except RuntimeError:
            return self._fail((v0, w0))
        self._t_solver_call = time.perf_counter() - t_solve
        if not (np.isfinite(states).all() and np.isfinite(controls).all()):
            return self._fail((v0, w0))
        self._prev = (pose, states, controls)

        v = min(max(v0 + float(controls[0, 0]) * self.control_period, lim.min_v), lim.max_v)
        if self._rotating and v0 * v0 <= 2.0 * lim.max_acc_v * cfg.safety_margin:
            # stops within its margin: braked outside the solver; a faster robot is braked
            # by the solver, which steers the body round what it would coast into
            v = brake_command((v0, w0), lim, self.control_period)[0]
        w = min(max(w0 + float(controls[0, 1]) * self.control_period, -lim.max_w), lim.max_w)
        return VelocityCommand(v, w, ok=True, predicted=_to_map(states[:, 0:2], pose))
