"""Pure-pursuit local planner: the baseline the MPC is compared with.

Steers towards the path point one lookahead ahead of the robot's projection, turns in
place when that point is far off the heading, follows the same braking speed profile
as the MPC reference (stop at the end of the path, slow for curvature) and ramps every
command within the acceleration limits. It ignores obstacles.
"""

from __future__ import annotations

import math

import numpy as np

from agv_mission.geometry import wrap_angle
from agv_mission.planners.base import VelocityCommand, VelocityLimits
from agv_mission.planners.configs import PurePursuitConfig
from agv_mission.planners.path_follower import PathFollower, PathStep
from agv_mission.planners.path_tracking import interpolate


def _ramp(target: float, current: float, max_step: float) -> float:
    return min(max(target, current - max_step), current + max_step)


class PurePursuitController(PathFollower):
    """Geometric path follower with a braking speed profile."""

    Config = PurePursuitConfig

    def __init__(
        self,
        config: PurePursuitConfig,
        limits: VelocityLimits,
        robot_radius: float,
        control_period: float,
    ) -> None:
        super().__init__(limits, control_period)
        self.config = config
        self.robot_radius = robot_radius
        self.reset()

    def reset(self) -> None:
        super().reset()
        self._rotating = False

    def _command(
        self, v_target: float, w_target: float, velocity: tuple[float, float]
    ) -> tuple[float, float]:
        lim, dt = self.limits, self.control_period
        v = _ramp(v_target, velocity[0], lim.max_acc_v * dt)
        w = _ramp(w_target, velocity[1], lim.max_acc_w * dt)
        v = float(np.clip(v, max(lim.min_v, 0.0), lim.max_v))
        w = float(np.clip(w, -lim.max_w, lim.max_w))
        return v, w

    def stop(self, velocity: tuple[float, float]) -> tuple[float, float]:
        return self._command(0.0, 0.0, velocity)

    def follow(self, step: PathStep) -> VelocityCommand:
        cfg, lim, dt = self.config, self.limits, self.control_period
        pose, velocity, goal_ahead = step.pose, step.velocity, step.goal_ahead
        path, cumlen, total, s0 = step.path, step.cumlen, step.total, step.s
        xy = np.array([pose.x, pose.y])

        # Lookahead point; at the end of the path, the goal itself.
        s_look = min(s0 + cfg.lookahead, total)
        look, _ = interpolate(path, cumlen, np.array([s_look]))
        target = path[-1] if s_look >= total else look[0]
        d = target - xy
        alpha = wrap_angle(math.atan2(d[1], d[0]) - pose.yaw)
        if abs(alpha) > cfg.rotate_threshold:
            self._rotating = True
        elif abs(alpha) < cfg.rotate_exit:
            self._rotating = False
        if self._rotating:
            # Turn in place, braking so the heading error is not overshot.
            w_brake = math.sqrt(2.0 * 0.5 * lim.max_acc_w * abs(alpha))
            w_t = math.copysign(min(cfg.rotate_gain * abs(alpha), w_brake, lim.max_w), alpha)
            return VelocityCommand(*self._command(0.0, w_t, velocity))

        # Speed: braking/curvature profile, goal slow-down, never more than the distance left.
        cruise = min(cfg.speed or lim.max_v, lim.max_v)
        profile = self.reference(
            step, cruise, cfg.decel_fraction * lim.max_acc_v, cfg.turn_fraction
        )
        _, v_prof = profile.sample(s0, velocity[0], 1, dt)
        remaining = max(total - s0, goal_ahead) if s_look >= total else total - s0
        v_t = float(v_prof[1])
        if cfg.goal_slowdown_distance > 0:
            v_t = min(v_t, cruise * remaining / cfg.goal_slowdown_distance)
        v_t = max(v_t, min(cfg.min_speed, cruise))
        v_t = min(v_t, max(remaining, 0.0) / dt)
        if s_look >= total:
            v_t = min(v_t, max(goal_ahead, 0.0) / dt)
        # Pure pursuit curvature; slow down if the turn rate would exceed max_w.
        ld2 = float(d @ d)
        kappa = 2.0 * math.sin(alpha) / math.sqrt(ld2) if ld2 > 1e-12 else 0.0
        if abs(kappa) * v_t > lim.max_w:
            v_t = lim.max_w / abs(kappa)
        v, _ = self._command(v_t, 0.0, velocity)
        w_t = float(np.clip(kappa * v, -lim.max_w, lim.max_w))
        return VelocityCommand(*self._command(v_t, w_t, velocity))
