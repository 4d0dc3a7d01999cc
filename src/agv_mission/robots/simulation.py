"""A MuJoCo differential-drive robot in a :class:`~agv_mission.maps.worlds.World`."""

from __future__ import annotations

import math

import mujoco
import numpy as np

from agv_mission.geometry import Pose2D, wrap_angle, yaw_from_quaternion
from agv_mission.maps.worlds import World
from agv_mission.messages import LaserScan
from agv_mission.robots.description import RobotDescription
from agv_mission.robots.mjcf import (
    PARKED_GROUP,
    WALL_BIT,
    WALL_GROUP,
    build_mjcf,
    uses_wall_slots,
)
from agv_mission.robots.sensors import Lidar, WheelEncoders
from agv_mission.robots.sim_config import SimConfig

WINDOW_CHECK_PERIOD = 0.1  # s of simulated motion between wall-window checks


class _Walls:
    """The world's static boxes and cylinders as arrays, for planar distance queries."""

    def __init__(self, world: World) -> None:
        boxes = world.boxes
        self.box_c = np.array([[b.x, b.y] for b in boxes], dtype=float).reshape(-1, 2)
        self.box_h = np.array([[b.half_x, b.half_y] for b in boxes], dtype=float).reshape(-1, 2)
        self.box_yaw = np.array([b.yaw for b in boxes], dtype=float)
        self.box_cs = np.stack([np.cos(self.box_yaw), np.sin(self.box_yaw)], axis=1).reshape(-1, 2)
        # Rows cx, cy, cos, sin, half_x, half_y: one array for the per-step distance query.
        self._box = np.vstack((self.box_c.T, self.box_cs.T, self.box_h.T))
        cyl = world.cylinders
        self.cyl = np.array([[c.x, c.y, c.radius] for c in cyl], dtype=float).reshape(-1, 3)

    def box_distance(self, x: float, y: float, idx: np.ndarray | slice = slice(None)) -> np.ndarray:
        """Planar distance from (x, y) to each box (negative inside)."""
        b = self._box if isinstance(idx, slice) and idx == slice(None) else self._box[:, idx]
        cx, cy, c, s, hx, hy = b
        dx, dy = x - cx, y - cy
        qx = np.abs(c * dx + s * dy) - hx
        qy = np.abs(-s * dx + c * dy) - hy
        ox, oy = np.maximum(qx, 0.0), np.maximum(qy, 0.0)
        return np.sqrt(ox * ox + oy * oy) + np.minimum(np.maximum(qx, qy), 0.0)

    def cyl_distance(self, x: float, y: float, idx: np.ndarray | slice = slice(None)) -> np.ndarray:
        cyl = self.cyl[idx]
        return np.hypot(cyl[:, 0] - x, cyl[:, 1] - y) - cyl[:, 2]


class WallWindow:
    """The rolling window of a large world: the walls near the robot, moved into the
    model's wall slots (see :mod:`agv_mission.robots.mjcf`) whenever the robot has moved
    ``refresh`` metres from where the window was last centred.

    Every wall within ``radius`` (the lidar's range plus the refresh distance) of the
    centre gets a slot, nearest first, so the lidar and the contact search see exactly the
    walls they could touch; the cost per step no longer grows with the size of the map.
    """

    def __init__(
        self,
        model: mujoco.MjModel,
        walls: _Walls,
        height: float,
        radius: float,
        refresh: float = 0.25,
    ) -> None:
        self.model, self.walls = model, walls
        self.height, self.radius, self.refresh = height, radius, refresh

        def ids(prefix: str) -> np.ndarray:
            out = []
            while (
                i := mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, f"{prefix}{len(out)}")
            ) >= 0:
                out.append(i)
            return np.array(out, dtype=np.int64)

        self.box_slots = ids("wall_slot_")
        self.cyl_slots = ids("pillar_slot_")
        # The world body's bounding-volume tree, refitted bottom-up after every move.
        adr, num = int(model.body_bvhadr[0]), int(model.body_bvhnum[0])
        nodes = np.arange(adr, adr + num)
        geom = model.bvh_nodeid[adr : adr + num]
        children = model.bvh_child[adr : adr + num] + adr
        depth = model.bvh_depth[adr : adr + num]
        is_slot = np.isin(geom, np.concatenate((self.box_slots, self.cyl_slots)))
        self._slot_leaves, self._slot_leaf_geoms = nodes[is_slot], geom[is_slot]
        inner = geom < 0
        self._levels = [
            (nodes[inner & (depth == d)], children[inner & (depth == d)])
            for d in range(int(depth.max(initial=0)), -1, -1)
            if np.any(inner & (depth == d))
        ]
        self.centre: tuple[float, float] | None = None
        self.active_boxes = np.zeros(0, dtype=np.int64)
        self.active_cylinders = np.zeros(0, dtype=np.int64)
        self.overflow = False  # more walls within the radius than slots (nearest kept)

    def update(self, x: float, y: float) -> bool:
        """Re-centre when the robot has moved far enough; True when the slots changed."""
        if self.centre is not None and math.hypot(x - self.centre[0], y - self.centre[1]) < (
            self.refresh
        ):
            return False
        self.centre = (x, y)
        w, m, h = self.walls, self.model, self.height
        self.active_boxes = self._nearest(w.box_distance(x, y), len(self.box_slots))
        self.active_cylinders = self._nearest(w.cyl_distance(x, y), len(self.cyl_slots))

        used, idx = self.box_slots[: len(self.active_boxes)], self.active_boxes
        half = w.box_h[idx]
        yaw = w.box_yaw[idx]
        m.geom_pos[used] = np.column_stack((w.box_c[idx], np.full(len(idx), h / 2)))
        m.geom_quat[used] = np.column_stack(
            (np.cos(yaw / 2), np.zeros(len(idx)), np.zeros(len(idx)), np.sin(yaw / 2))
        )
        m.geom_size[used] = np.column_stack((half, np.full(len(idx), h / 2)))
        m.geom_aabb[used] = np.column_stack((np.zeros((len(idx), 3)), m.geom_size[used]))
        m.geom_rbound[used] = np.linalg.norm(m.geom_size[used], axis=1)
        self._enable(used, self.box_slots[len(idx) :])

        used, idx = self.cyl_slots[: len(self.active_cylinders)], self.active_cylinders
        cyl = w.cyl[idx]
        m.geom_pos[used] = np.column_stack((cyl[:, 0:2], np.full(len(idx), h / 2)))
        m.geom_size[used] = np.column_stack(
            (cyl[:, 2], np.full(len(idx), h / 2), np.zeros(len(idx)))
        )
        m.geom_aabb[used] = np.column_stack(
            (np.zeros((len(idx), 3)), cyl[:, 2], cyl[:, 2], np.full(len(idx), h / 2))
        )
        m.geom_rbound[used] = np.hypot(cyl[:, 2], h / 2)
        self._enable(used, self.cyl_slots[len(idx) :])
        self._refit()
        return True

    def _refit(self) -> None:
        """World-frame boxes of the slot leaves, then every inner node as the union of its
        children, deepest level first (MuJoCo keeps the tree it compiled; its boxes must
        follow the slots)."""
        m = self.model
        aabb = m.bvh_aabb
        g = self._slot_leaf_geoms
        q = m.geom_quat[g]  # yaw only: (cos, 0, 0, sin) of yaw / 2
        c = np.abs(1.0 - 2.0 * q[:, 3] ** 2)
        s = np.abs(2.0 * q[:, 0] * q[:, 3])
        size = m.geom_size[g]
        box = m.geom_type[g] == mujoco.mjtGeom.mjGEOM_BOX
        hx = size[:, 0]
        hy = np.where(box, size[:, 1], size[:, 0])
        hz = np.where(box, size[:, 2], size[:, 1])
        aabb[self._slot_leaves, 0:3] = m.geom_pos[g]
        aabb[self._slot_leaves, 3:6] = np.column_stack((c * hx + s * hy, s * hx + c * hy, hz))
        for nodes, children in self._levels:
            a, b = aabb[children[:, 0]], aabb[children[:, 1]]
            lo = np.minimum(a[:, 0:3] - a[:, 3:6], b[:, 0:3] - b[:, 3:6])
            hi = np.maximum(a[:, 0:3] + a[:, 3:6], b[:, 0:3] + b[:, 3:6])
            aabb[nodes, 0:3] = (lo + hi) / 2
            aabb[nodes, 3:6] = (hi - lo) / 2

    def _nearest(self, distance: np.ndarray, slots: int) -> np.ndarray:
        idx = np.flatnonzero(distance < self.radius)
        if len(idx) > slots:
            self.overflow = True
            idx = idx[np.argsort(distance[idx])[:slots]]
        return idx

    def _enable(self, used: np.ndarray, parked: np.ndarray) -> None:
        m = self.model
        m.geom_group[used] = WALL_GROUP
        m.geom_conaffinity[used] = WALL_BIT  # no contype: slots never test each other
        m.geom_group[parked] = PARKED_GROUP
        m.geom_conaffinity[parked] = 0
        m.geom_pos[parked] = (0.0, 0.0, -10.0)

    def min_distance(self, x: float, y: float) -> float | None:
        """Distance to the nearest wall when the window decides it (else ``None``)."""
        best = math.inf
        if len(self.active_boxes):
            best = float(self.walls.box_distance(x, y, self.active_boxes).min())
        if len(self.active_cylinders):
            best = min(best, float(self.walls.cyl_distance(x, y, self.active_cylinders).min()))
        # Walls outside the window are farther than radius - refresh from the robot.
        if best < self.radius - self.refresh and not self.overflow:
            return best
        return None


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
        # Geom ids of the robot and of the walls (slots included), for counting contacts.
        self._robot_geoms = frozenset(
            i for i in range(m.ngeom) if int(m.geom_bodyid[i]) in robot_bodies
        )
        self._command = (0.0, 0.0)

        self._walls = _Walls(world)
        self.wall_window: WallWindow | None = None
        if uses_wall_slots(world):
            self.wall_window = WallWindow(
                m, self._walls, world.wall_height, radius=robot.lidar.range_max + 0.5
            )
            self.wall_window.update(start.x, start.y)
        self._wall_geoms = frozenset(
            i for i in range(m.ngeom) if m.geom(i).name.startswith(("wall", "pillar"))
        )

        self._write_pose(start)
        mujoco.mj_forward(self.model, self.data)
        cfg, lidar, enc = self.config, robot.lidar, robot.encoder
        self.lidar = Lidar(
            self.model,
            self.data,
            lidar,
            self.rng,
            noise_std=cfg.pick("lidar_noise", lidar.noise_std),
            # A constant lidar_noise given alone replaces the robot's whole noise model.
            noise_fraction=cfg.pick(
                "lidar_noise_fraction", 0.0 if cfg.lidar_noise is not None else lidar.noise_fraction
            ),
            dropout=cfg.pick("lidar_dropout", lidar.dropout),
        )
        self.encoders = WheelEncoders(
            self.model,
            self.data,
            robot.wheel_radius,
            enc.ticks_per_meter,
            self.rng,
            noise=cfg.pick("encoder_noise", enc.noise),
            slip=cfg.pick("wheel_slip", enc.slip),
            scale_error=cfg.pick("wheel_scale_error", enc.scale_error),
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
        v_max, w_max = self.robot.max_linear_velocity, self.robot.max_angular_velocity
        v = min(max(float(v), -v_max), v_max)
        w = min(max(float(w), -w_max), w_max)
        self._command = (v, w)
        half = self.robot.wheel_separation / 2.0
        r = self.robot.wheel_radius
        self.data.ctrl[self._act[0]] = (v - w * half) / r
        self.data.ctrl[self._act[1]] = (v + w * half) / r

    def advance(self, duration: float) -> None:
        """Step the physics for ``round(duration / dt)`` steps (at least 0)."""
        n = int(round(duration / self.dt))
        # With a wall window, re-centre it at least every WINDOW_CHECK_PERIOD of motion.
        chunk = n if self.wall_window is None else max(1, int(WINDOW_CHECK_PERIOD / self.dt))
        while n > 0:
            self._follow_window()
            mujoco.mj_step(self.model, self.data, min(chunk, n))
            n -= chunk

    def _follow_window(self) -> None:
        """Re-centre the wall window on the robot when it has moved (large worlds)."""
        if self.wall_window is not None:
            a = self._free_qadr
            self.wall_window.update(float(self.data.qpos[a]), float(self.data.qpos[a + 1]))

    # ----------------------------------------------------------------- ground truth
    def true_pose(self) -> Pose2D:
        a = self._free_qadr
        px, py, _, w, x, y, z = self.data.qpos[a : a + 7].tolist()
        return Pose2D(px, py, yaw_from_quaternion(x, y, z, w))

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
        self._follow_window()
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
        self._follow_window()
        mujoco.mj_kinematics(self.model, self.data)
        return self.lidar.scan(self.time)

    def contacts(self) -> int:
        """Number of contact points between the robot and walls/pillars (floor excluded)."""
        n = self.data.ncon
        if n == 0:
            return 0
        robot, wall = self._robot_geoms, self._wall_geoms
        return sum(
            (a in robot and b in wall) or (b in robot and a in wall)
            for a, b in self.data.contact.geom[:n].tolist()
        )

    def min_clearance(self) -> float:
        """Planar distance from the robot's footprint circle to the nearest wall/pillar
        (negative when overlapping; ``inf`` in an empty world)."""
        p = self.true_pose()
        best = None
        if self.wall_window is not None:
            best = self.wall_window.min_distance(p.x, p.y)
        if best is None:
            best = math.inf
            if len(self._walls.box_c):
                best = min(best, float(self._walls.box_distance(p.x, p.y).min()))
            if len(self._walls.cyl):
                best = min(best, float(self._walls.cyl_distance(p.x, p.y).min()))
        return best - self.robot.footprint_radius
