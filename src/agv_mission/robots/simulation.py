"""A MuJoCo differential-drive robot in a :class:`~agv_mission.maps.worlds.World`."""

from __future__ import annotations

import math

import mujoco
import numpy as np

from agv_mission.geometry import Pose2D, wrap_angle, yaw_from_quaternion
from agv_mission.maps.worlds import World
from agv_mission.messages import LaserScan
from agv_mission.robots.description import RobotDescription
from agv_mission.robots.mjcf import WALL_GROUP, build_mjcf
from agv_mission.robots.sensors import Lidar, WheelEncoders
from agv_mission.robots.sim_config import SimConfig


class DiffDriveSim:
    """The simulated robot: twist commands in, true state / encoder ticks / scans out.

    Deterministic: the same robot, world, start, config and rng seed, with the same call
    sequence, give bit-identical trajectories and sensor readings.
    """

    def __init__(
        self,
        robot: RobotDescription,
        world: World,
        start: Pose2D,
        config: SimConfig | None = None,
        rng: np.random.Generator | None = None,
    ) -> None:
        self.robot = robot
        self.world = world
        self.config = config or SimConfig()
        self.rng = rng if rng is not None else np.random.default_rng(0)
        self.xml = build_mjcf(robot, world, timestep=self.config.physics_dt)
        self.model = mujoco.MjModel.from_xml_string(self.xml)
        self.data = mujoco.MjData(self.model)
        m = self.model
        self._free_qadr = int(
            m.jnt_qposadr[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, "base_free")]
        )
        self._free_vadr = int(
            m.jnt_dofadr[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, "base_free")]
        )
        self._spawn_z = float(m.body_pos[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "base")][2])
        self._act = [
            mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_ACTUATOR, n)
            for n in ("motor_left", "motor_right")
        ]
        base_id = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "base")
        robot_bodies = {
            base_id,
            mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "wheel_left"),
            mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "wheel_right"),
        }
        self._is_robot_geom = np.isin(m.geom_bodyid, list(robot_bodies))
        self._is_wall_geom = m.geom_group == WALL_GROUP
        self._command = (0.0, 0.0)

        # 2D obstacle arrays for min_clearance().
        boxes = world.boxes
        self._box_c = np.array([[b.x, b.y] for b in boxes], dtype=float).reshape(-1, 2)
        self._box_h = np.array([[b.half_x, b.half_y] for b in boxes], dtype=float).reshape(-1, 2)
        yaws = np.array([b.yaw for b in boxes], dtype=float)
        self._box_cs = np.stack([np.cos(yaws), np.sin(yaws)], axis=1).reshape(-1, 2)
        cyl = world.cylinders
        self._cyl = np.array([[c.x, c.y, c.radius] for c in cyl], dtype=float).reshape(-1, 3)

        self._write_pose(start)
        mujoco.mj_forward(self.model, self.data)
        self.lidar = Lidar(
            self.model, self.data, robot.lidar, self.rng, noise_std=self.config.lidar_noise
        )
        self.encoders = WheelEncoders(
            self.model,
            self.data,
            robot.wheel_radius,
            robot.encoder.ticks_per_meter,
            self.rng,
            noise=self.config.encoder_noise,
            slip=self.config.wheel_slip,
        )

    # ----------------------------------------------------------------- time and commands
    @property
    def time(self) -> float:
        """Simulated seconds since the start."""
        return float(self.data.time)

    @property
    def dt(self) -> float:
        return float(self.model.opt.timestep)

    @property
    def command(self) -> tuple[float, float]:
        """The last (clipped) twist command."""
        return self._command

    def set_command(self, v: float, w: float) -> None:
        """Body twist command (m/s, rad/s), clipped to the robot's limits, as wheel speeds."""
        v = float(np.clip(v, -self.robot.max_linear_velocity, self.robot.max_linear_velocity))
        w = float(np.clip(w, -self.robot.max_angular_velocity, self.robot.max_angular_velocity))
        self._command = (v, w)
        half = self.robot.wheel_separation / 2.0
        r = self.robot.wheel_radius
        self.data.ctrl[self._act[0]] = (v - w * half) / r
        self.data.ctrl[self._act[1]] = (v + w * half) / r

    def advance(self, duration: float) -> None:
        """Step the physics for ``round(duration / dt)`` steps (at least 0)."""
        n = int(round(duration / self.dt))
        if n > 0:
            mujoco.mj_step(self.model, self.data, n)

    # ----------------------------------------------------------------- ground truth
    def true_pose(self) -> Pose2D:
        q = self.data.qpos[self._free_qadr : self._free_qadr + 7]
        w, x, y, z = q[3], q[4], q[5], q[6]
        return Pose2D(float(q[0]), float(q[1]), yaw_from_quaternion(x, y, z, w))

    def true_velocity(self) -> tuple[float, float]:
        """Body-frame forward speed (m/s) and yaw rate (rad/s) of the base frame."""
        qv = self.data.qvel[self._free_vadr : self._free_vadr + 6]
        yaw = self.true_pose().yaw
        # Free joint: linear velocity in the world frame, angular velocity in the body frame.
        v = math.cos(yaw) * qv[0] + math.sin(yaw) * qv[1]
        return float(v), float(qv[5])

    def teleport(self, pose: Pose2D) -> None:
        """Put the robot at ``pose`` at rest (kidnapping); encoders do not see the jump."""
        self._write_pose(pose)
        self.data.qvel[:] = 0.0
        self.data.qacc_warmstart[:] = 0.0
        mujoco.mj_forward(self.model, self.data)

    def _write_pose(self, pose: Pose2D) -> None:
        a = self._free_qadr
        self.data.qpos[a : a + 3] = (pose.x, pose.y, self._spawn_z)
        yaw = wrap_angle(pose.yaw)
        self.data.qpos[a + 3 : a + 7] = (math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2))

    # ----------------------------------------------------------------- sensors
    def encoder_ticks(self) -> tuple[int, int]:
        """Cumulative (left, right) encoder ticks; noise/slip applied per read."""
        return self.encoders.read()

    def scan(self) -> LaserScan:
        """A lidar scan at the current state (stamped with the simulation time)."""
        mujoco.mj_kinematics(self.model, self.data)
        return self.lidar.scan(self.time)

    def contacts(self) -> int:
        """Number of contact points between the robot and walls/pillars (floor excluded)."""
        n = self.data.ncon
        if n == 0:
            return 0
        g = self.data.contact.geom[:n]
        robot = self._is_robot_geom[g]
        wall = self._is_wall_geom[g]
        hit = (robot[:, 0] & wall[:, 1]) | (robot[:, 1] & wall[:, 0])
        return int(np.count_nonzero(hit))

    def min_clearance(self) -> float:
        """Planar distance from the robot's footprint circle to the nearest wall/pillar
        (negative when overlapping; ``inf`` in an empty world)."""
        p = self.true_pose()
        best = math.inf
        if len(self._box_c):
            d = np.array([p.x, p.y]) - self._box_c
            c, s = self._box_cs[:, 0], self._box_cs[:, 1]
            local = np.abs(np.stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]], 1))
            q = local - self._box_h
            outside = np.linalg.norm(np.maximum(q, 0.0), axis=1)
            inside = np.minimum(q.max(axis=1), 0.0)
            best = min(best, float((outside + inside).min()))
        if len(self._cyl):
            dc = np.hypot(self._cyl[:, 0] - p.x, self._cyl[:, 1] - p.y) - self._cyl[:, 2]
            best = min(best, float(dc.min()))
        return best - self.robot.footprint_radius
