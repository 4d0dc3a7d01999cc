"""Simulated sensors of a robot's body in the world (see :mod:`agv_mission.robots.body`)."""

from __future__ import annotations

import math

import mujoco
import numpy as np

from agv_mission.messages import LaserScan
from agv_mission.robots.description import LidarSpec
from agv_mission.world.simulation import Body, SimulatedWorld


class Lidar:
    """A planar scanner: all beams in one ray cast of the world, from its site (the
    description's mount).

    Beam ``i`` points at ``angle_min + i * angle_increment`` counter-clockwise from the
    scan frame's +x: a full turn from straight ahead by default (like the TurtleBot3 LDS),
    or ``angle_min`` to ``angle_max`` (a Hokuyo's 270 degrees). It sees the world's walls and every other
    body's outline (robots' hulls, people), never its own robot. Returns closer than
    ``range_min`` or beyond ``range_max`` read ``inf``; dropped beams (``dropout``) read
    ``nan``.
    """

    def __init__(
        self,
        world: SimulatedWorld,
        body: Body,
        spec: LidarSpec,
        rng: np.random.Generator,
        site: str = "lidar",
        noise_std: float | None = None,
        noise_fraction: float | None = None,
        dropout: float | None = None,
    ) -> None:
        self.world = world
        self.body = body
        self.spec = spec
        self.rng = rng
        self.noise_std = spec.noise_std if noise_std is None else float(noise_std)
        self.noise_fraction = spec.noise_fraction if noise_fraction is None else noise_fraction
        self.dropout = spec.dropout if dropout is None else float(dropout)
        self.site_id = mujoco.mj_name2id(world.model, mujoco.mjtObj.mjOBJ_SITE, site)
        if self.site_id < 0:
            raise ValueError(f"model has no site {site!r}")
        n = spec.beams
        self.angle_min, self.angle_increment = spec.beam_angles()
        angles = self.angle_min + self.angle_increment * np.arange(n)
        # Beam directions in the sensor frame, (n, 3); rotated to the world each scan.
        self._local = np.stack([np.cos(angles), np.sin(angles), np.zeros(n)], axis=1)
        self._vec = np.zeros(3 * n)
        self._dist = np.zeros(n)
        self._geomid = np.zeros(n, dtype=np.int32)
        # The ray cast culls by bounding volume; exact clamping is done afterwards.
        self._cutoff = spec.range_max + 1.0

    def cast(self) -> np.ndarray:
        """Noise-free hit distances (float64, -1 for no hit) from the current kinematics.

        Call ``world.kinematics()`` first so the site's pose is current.
        """
        d = self.world.data
        origin = d.site_xpos[self.site_id].copy()
        rot = d.site_xmat[self.site_id].reshape(3, 3)
        np.matmul(self._local, rot.T, out=self._vec.reshape(-1, 3))
        self.world.cast(origin, self._vec, self.body, self._geomid, self._dist, self._cutoff)
        return self._dist

    def scan(self, time: float) -> LaserScan:
        """One scan at the current state: Gaussian range noise of standard deviation
        ``max(noise_std, noise_fraction * range)`` and random dropouts, from the rng."""
        dist = self.cast().copy()
        hit = dist >= 0.0
        if self.noise_std > 0.0 or self.noise_fraction > 0.0:
            d = dist[hit]
            sigma = np.maximum(self.noise_std, self.noise_fraction * d)
            dist[hit] = d + sigma * self.rng.standard_normal(len(d))
        ok = hit & (dist >= self.spec.range_min) & (dist <= self.spec.range_max)
        ranges = np.where(ok, dist, np.inf).astype(np.float32)
        if self.dropout > 0.0:
            # A beam that got no echo back (a dark, glossy or grazing surface) is an invalid
            # reading (REP 117: nan), not "nothing in range" (inf): it clears no free space.
            ranges[self.rng.random(len(ranges)) < self.dropout] = np.nan
        return LaserScan(
            ranges=ranges,
            angle_min=self.angle_min,
            angle_increment=self.angle_increment,
            range_min=self.spec.range_min,
            range_max=self.spec.range_max,
            time=float(time),
        )


class WheelEncoders:
    """Incremental encoders on the two wheel hinges, read as cumulative integer ticks.

    Each :meth:`read` turns the wheel travel since the previous read (joint angle x radius x
    ticks per metre) into ticks, scaled per wheel by ``scale * (1 + N(0, noise) +
    U(-slip, slip))``, and accumulates them (sub-tick fractions are kept, so a noise-free
    encoder never drifts). ``scale`` is the wheel's systematic error, ``1 + N(0,
    scale_error)`` drawn once. Draws come from ``rng`` only when the errors are non-zero.
    """

    def __init__(
        self,
        model: mujoco.MjModel,
        data: mujoco.MjData,
        wheel_radius: float,
        ticks_per_meter: float,
        rng: np.random.Generator,
        noise: float = 0.0,
        slip: float = 0.0,
        scale_error: float = 0.0,
        joints: tuple[str, str] = ("wheel_left", "wheel_right"),
    ) -> None:
        self.data = data
        self.rng = rng
        self.noise = float(noise)
        self.slip = float(slip)
        self.ticks_per_rad = wheel_radius * ticks_per_meter
        self.scale = (1.0, 1.0)
        if scale_error > 0.0:
            a, b = (1.0 + rng.normal(0.0, scale_error, size=2)).tolist()
            self.scale = (a, b)
        self._qadr = np.array(
            [
                model.jnt_qposadr[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, j)]
                for j in joints
            ]
        )
        self._left, self._right = (int(a) for a in self._qadr)
        self._last_angle = self._angles()
        self._acc = (0.0, 0.0)  # float ticks

    def _angles(self) -> tuple[float, float]:
        qpos = self.data.qpos
        return float(qpos[self._left]), float(qpos[self._right])

    def read(self) -> tuple[int, int]:
        # Two wheels in plain floats: numpy's per-call overhead was most of the cost.
        (a0, a1), (b0, b1) = self._angles(), self._last_angle
        self._last_angle = (a0, a1)
        d0, d1 = (a0 - b0) * self.ticks_per_rad, (a1 - b1) * self.ticks_per_rad
        s0, s1 = self.scale
        if self.noise > 0.0:
            n0, n1 = self.rng.normal(0.0, self.noise, size=2).tolist()
            s0, s1 = s0 * (1.0 + n0), s1 * (1.0 + n1)
        if self.slip > 0.0:
            u0, u1 = self.rng.uniform(-self.slip, self.slip, size=2).tolist()
            s0, s1 = s0 + self.scale[0] * u0, s1 + self.scale[1] * u1
        self._acc = (self._acc[0] + d0 * s0, self._acc[1] + d1 * s1)
        return math.floor(self._acc[0]), math.floor(self._acc[1])

    def rebase(self) -> None:
        """Forget wheel motion since the last read (after a teleport rewrote the joints)."""
        self._last_angle = self._angles()
