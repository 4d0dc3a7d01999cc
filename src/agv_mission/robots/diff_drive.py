"""A differential-drive robot's body in a :class:`~agv_mission.world.simulation.SimulatedWorld`:
twist commands in, true state / encoder ticks / scans out."""

from __future__ import annotations

import mujoco
import numpy as np

from agv_mission.geometry import Pose2D
from agv_mission.maps.worlds import World
from agv_mission.robots.body import diff_drive_shape
from agv_mission.robots.description import RobotDescription
from agv_mission.robots.sensors import Imu, ImuSamples, Lidar, WheelEncoders
from agv_mission.robots.sim_config import SimConfig
from agv_mission.sensor_msgs import LaserScan
from agv_mission.world.body import diff_drive_world
from agv_mission.world.simulation import Body, SimulatedWorld


class DiffDriveBody:
    """One robot's body in the world, with its wheel encoders and lidar.

    Deterministic: the same robot, world, start, config and rng seed, with the same call
    sequence, give bit-identical trajectories and sensor readings.
    """

    @classmethod
    def alone(
        cls,
        robot: RobotDescription,
        world: World,
        start: Pose2D,
        config: SimConfig | None = None,
        rng: np.random.Generator | None = None,
    ) -> DiffDriveBody:
        """``robot`` alone in ``world`` at ``start``: a world with one robot."""
        config = config or SimConfig()
        sim = diff_drive_world(
            world, config.physics_dt, [("robot", diff_drive_shape(robot), start)]
        ).build()
        body = cls(sim, "robot", robot, config, rng)
        sim.start()
        return body

    def __init__(
        self,
        world: SimulatedWorld,
        name: str,
        robot: RobotDescription,
        config: SimConfig | None = None,
        rng: np.random.Generator | None = None,
        imu_rng: np.random.Generator | None = None,
    ) -> None:
        """Take hold of the body ``name`` of ``world``, standing where the world was built
        with it (call ``world.start()`` once every body has its sensors). The IMU draws
        from ``imu_rng`` (its own stream, so the lidar's and the encoders' draws do not
        depend on it)."""
        self.world = world
        self.name = name
        self.robot = robot
        self.config = config or SimConfig()
        self.rng = rng if rng is not None else np.random.default_rng(0)
        self.body: Body = world.bodies[name]
        m = world.model
        self._act = [
            mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_ACTUATOR, f"{name}/motor_{side}")
            for side in ("left", "right")
        ]
        self._command = (0.0, 0.0)
        cfg, lidar, enc = self.config, robot.lidar, robot.encoder
        self.lidar = Lidar(
            world,
            self.body,
            lidar,
            self.rng,
            site=f"{name}/lidar",
            noise_std=cfg.pick("lidar_noise", lidar.noise_std),
            # A constant lidar_noise given alone replaces the robot's whole noise model.
            noise_fraction=cfg.pick(
                "lidar_noise_fraction", 0.0 if cfg.lidar_noise is not None else lidar.noise_fraction
            ),
            dropout=cfg.pick("lidar_dropout", lidar.dropout),
        )
        self.encoders = WheelEncoders(
            m,
            world.data,
            robot.wheel_radius,
            enc.ticks_per_meter,
            self.rng,
            noise=cfg.pick("encoder_noise", enc.noise),
            slip=cfg.pick("wheel_slip", enc.slip),
            scale_error=cfg.pick("wheel_scale_error", enc.scale_error),
            joints=(f"{name}/wheel_left", f"{name}/wheel_right"),
        )
        self.imu: Imu | None = None
        if robot.imu is not None:
            if imu_rng is None:  # a stream of its own beside the body's
                seeds = getattr(self.rng.bit_generator, "seed_seq", None)
                seeds = seeds if isinstance(seeds, np.random.SeedSequence) else None
                imu_rng = np.random.default_rng((seeds or np.random.SeedSequence(0)).spawn(1)[0])
            self.imu = Imu(world, self.body, robot.imu, imu_rng, ideal=cfg.ideal)

    # ----------------------------------------------------------------- time and commands
    @property
    def time(self) -> float:
        """Simulated seconds since the start."""
        return self.world.time

    @property
    def dt(self) -> float:
        return self.world.dt

    @property
    def command(self) -> tuple[float, float]:
        """The last (clipped) twist command."""
        return self._command

    def set_command(self, v: float, w: float) -> None:
        """Body twist command (m/s, rad/s), clipped to the robot's limits, as wheel speeds."""
        v_max, w_max = self.robot.max_linear_velocity, self.robot.max_angular_velocity
        v = min(max(float(v), -v_max), v_max)
        w = min(max(float(w), -w_max), w_max)
        self._command = (v, w)
        half = self.robot.wheel_separation / 2.0
        r = self.robot.wheel_radius
        ctrl = self.world.data.ctrl
        ctrl[self._act[0]] = (v - w * half) / r
        ctrl[self._act[1]] = (v + w * half) / r

    def advance(self, duration: float) -> None:
        """Step the whole world ``round(duration / dt)`` physics steps (a robot alone)."""
        self.world.step(int(round(duration / self.dt)))

    # ----------------------------------------------------------------- ground truth
    def true_pose(self) -> Pose2D:
        return self.world.pose(self.body)

    def true_velocity(self) -> tuple[float, float]:
        """Body-frame forward speed (m/s) and yaw rate (rad/s) of the base frame."""
        return self.world.velocity(self.body)

    def teleport(self, pose: Pose2D) -> None:
        """Put the robot at ``pose`` at rest (kidnapping); encoders and IMU do not see the
        jump."""
        self.world.teleport(self.body, pose)
        if self.imu is not None:
            self.imu.rebase()

    # ----------------------------------------------------------------- sensors
    def encoder_ticks(self) -> tuple[int, int]:
        """Cumulative (left, right) encoder ticks; noise/slip applied per read."""
        return self.encoders.read()

    def imu_samples(self) -> ImuSamples | None:
        """The IMU's samples since the last read (None: the robot has no IMU)."""
        return self.imu.read() if self.imu is not None else None

    def scan(self) -> LaserScan:
        """A lidar scan at the current state (stamped with the simulation time)."""
        self.world.kinematics()
        return self.lidar.scan(self.time)

    def contacts(self) -> int:
        """Contact points between the robot and walls/pillars (floor excluded)."""
        return self.world.wall_contacts(self.body)

    def min_clearance(self) -> float:
        """Planar distance from the robot's footprint circle to the nearest wall/pillar
        (negative when overlapping; ``inf`` in an empty world)."""
        return self.world.wall_clearance(self.body)

    def clearances(self) -> tuple[float, float]:
        """(circle, footprint): :meth:`min_clearance`, and the distance from the footprint
        polygon (where the robot has one; else the same) to the nearest wall or pillar."""
        circle = self.world.wall_clearance(self.body)
        polygon = self.robot.polygon
        if polygon is None or circle > 0.5:  # far: the circle's figure is close enough
            return circle, circle
        p = self.world.pose(self.body)
        reach = polygon.circumscribed + 0.6
        exact = self.world.walls.polygon_distance(polygon.in_map(p.x, p.y, p.yaw), reach)
        return circle, max(circle, exact)
