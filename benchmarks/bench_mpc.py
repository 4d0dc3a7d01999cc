"""Local-planner timing: MPC solve time and success rate, pure-pursuit compute time.

``solve_ms`` is wall time of a whole ``compute`` call (reference, obstacle selection and
solve), ``solve_cpu_ms`` the same call's thread CPU time (steadier on a shared machine);
the fatrop NLP runs in the same process for a side-by-side ratio.

Closed loop with an exact unicycle integration at 0.1 s in an L-shaped corridor whose
walls are given as lidar points (1 cm apart, 3.5 m range) plus a small round obstacle
next to the path, so the MPC works with its full set of obstacle constraints
(16 points by default). Tracking: ``tracking_rmse_m`` is the RMS distance of the robot to
the path it follows, ``goal_error_m`` where it stopped, ``clearance_m`` the closest point. ``run()`` returns flat ``{"mpc.solve_ms.p50": ...}`` metrics.
"""

from __future__ import annotations

import math
import time

import numpy as np

from agv_mission.geometry import Pose2D
from agv_mission.planners.base import VelocityLimits
from agv_mission.planners.mpc import MpcConfig, MpcController
from agv_mission.planners.path_tracking import closest_point
from agv_mission.planners.pure_pursuit import PurePursuitConfig, PurePursuitController

PERIOD = 0.1
LIMITS = VelocityLimits(max_v=0.26, max_w=1.82, max_acc_v=1.0, max_acc_w=3.0)
RADIUS = 0.22
LIDAR_RANGE = 3.5


def _segment(a, b, step=0.01) -> np.ndarray:
    a, b = np.asarray(a, float), np.asarray(b, float)
    n = max(1, int(np.linalg.norm(b - a) / step))
    return a + (b - a) * np.linspace(0.0, 1.0, n + 1)[:, None]


def _world() -> tuple[list[np.ndarray], np.ndarray]:
    """Paths (there and back) in an L corridor 0.9 m wide; wall and obstacle points."""
    walls = np.vstack(
        (
            _segment((-0.6, -0.45), (3.45, -0.45)),
            _segment((3.45, -0.45), (3.45, 3.2)),
            _segment((-0.6, 0.45), (2.55, 0.45)),
            _segment((2.55, 0.45), (2.55, 3.2)),
            _segment((-0.6, -0.45), (-0.6, 0.45)),
        )
    )
    angles = np.linspace(0.0, 2.0 * np.pi, 24, endpoint=False)
    post = np.column_stack((1.5 + 0.06 * np.cos(angles), 0.32 + 0.06 * np.sin(angles)))
    there = np.array([[0.0, 0.0], [3.0, 0.0], [3.0, 2.8]])
    return [there, there[::-1].copy()], np.vstack((walls, post))


def _drive(controller, paths, points, max_steps=600) -> dict[str, list]:
    out: dict[str, list] = {
        "ms": [],
        "cpu_ms": [],
        "ok": [],
        "iters": [],
        "solver_ms": [],
        "goal_err": [],
        "clear": [],
        "track": [],
    }
    pose = Pose2D(0.0, 0.0, 0.0)
    for path in paths:
        goal = Pose2D(float(path[-1][0]), float(path[-1][1]))
        controller.reset()
        vel = (0.0, 0.0)
        for _ in range(max_steps):
            visible = points[np.hypot(*(points - [pose.x, pose.y]).T) < LIDAR_RANGE]
            t0, c0 = time.perf_counter(), time.thread_time()
            cmd = controller.compute(pose, vel, path, goal, visible)
            out["cpu_ms"].append((time.thread_time() - c0) * 1e3)
            out["ms"].append((time.perf_counter() - t0) * 1e3)
            out["ok"].append(cmd.ok)
            stats = getattr(controller, "last_stats", {})
            if "iter_count" in stats:
                out["iters"].append(stats["iter_count"])
                out["solver_ms"].append(stats.get("t_wall_solver_call", 0.0) * 1e3)
            pose = pose.driven(cmd.v, cmd.w, PERIOD)
            vel = (cmd.v, cmd.w)
            out["clear"].append(float(np.min(np.hypot(*(points - [pose.x, pose.y]).T))))
            out["track"].append(closest_point(path, (pose.x, pose.y)).distance)
            if pose.distance_to(goal) < 0.05 and cmd.v == 0.0 and cmd.w == 0.0:
                break
        out["goal_err"].append(pose.distance_to(goal))
        pose = Pose2D(pose.x, pose.y, pose.yaw + math.pi)  # the navigator turns it around
    return out


def _rms(values: list[float]) -> float:
    return float(np.sqrt(np.mean(np.square(values))))


def run() -> dict[str, float]:
    paths, points = _world()
    t0 = time.perf_counter()
    mpc = MpcController(MpcConfig(), LIMITS, RADIUS, PERIOD)
    build_s = time.perf_counter() - t0
    m = _drive(mpc, paths, points)
    # The NLP solved to tolerance every step (fatrop, the solver before the RTI), same run.
    f = _drive(MpcController(MpcConfig(solver="fatrop"), LIMITS, RADIUS, PERIOD), paths, points)
    p = _drive(PurePursuitController(PurePursuitConfig(), LIMITS, RADIUS, PERIOD), paths, points)
    ms, pms = np.array(m["ms"]), np.array(p["ms"])
    cpu, fcpu = np.array(m["cpu_ms"]), np.array(f["cpu_ms"])
    return {
        "mpc.solve_cpu_ms.p50": float(np.percentile(cpu, 50)),
        "mpc.solve_cpu_ms.p99": float(np.percentile(cpu, 99)),
        "mpc.fatrop.solve_cpu_ms.p50": float(np.percentile(fcpu, 50)),
        "mpc.fatrop.solve_cpu_ms.p99": float(np.percentile(fcpu, 99)),
        # The same run's ratio: steady when the machine's speed changes between runs.
        "mpc.cpu_p50_over_fatrop": float(np.percentile(cpu, 50) / np.percentile(fcpu, 50)),
        "mpc.fatrop.goal_error_m.max": float(max(f["goal_err"])),
        "mpc.fatrop.clearance_m.min": float(min(f["clear"])),
        "mpc.solve_ms.p50": float(np.percentile(ms, 50)),
        "mpc.solve_ms.p99": float(np.percentile(ms, 99)),
        "mpc.solve_ms.max": float(ms.max()),
        "mpc.success_rate": float(np.mean(m["ok"])),
        "mpc.solver_call_ms.p50": float(np.percentile(m["solver_ms"], 50)),
        "mpc.iterations.mean": float(np.mean(m["iters"])),
        "mpc.iterations.max": float(np.max(m["iters"])),
        "mpc.steps": float(len(ms)),
        "mpc.goal_error_m.max": float(max(m["goal_err"])),
        "mpc.clearance_m.min": float(min(m["clear"])),
        "mpc.tracking_rmse_m": _rms(m["track"]),
        "mpc.fatrop.tracking_rmse_m": _rms(f["track"]),
        "mpc.build_s": build_s,
        "pure_pursuit.compute_ms.p50": float(np.percentile(pms, 50)),
        "pure_pursuit.compute_ms.p99": float(np.percentile(pms, 99)),
        "pure_pursuit.goal_error_m.max": float(max(p["goal_err"])),
    }


if __name__ == "__main__":
    for key, value in run().items():
        print(f"{key:32s} {value:10.4f}")
