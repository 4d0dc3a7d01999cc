"""Simulated sensors of a robot's body in the world (see :mod:`agv_mission.world.body`)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco
import numpy as np

from agv_mission.geometry import wrap_angle
from agv_mission.robots.description import ImuSpec, LidarSpec
from agv_mission.sensor_msgs import LaserScan
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


@dataclass(frozen=True)
class ImuSamples:
    """The IMU's samples since its previous read: stamps (n,), the gyro's z rate (n,,
    rad/s) and the accelerometer's x, y (n, 2, m/s^2), in the robot's frame."""

    times: np.ndarray
    gyro: np.ndarray
    accel: np.ndarray
    period: float  # s between samples

    @property
    def turn(self) -> float:
        """The heading change the gyro measured over these samples, rad."""
        return float(self.gyro.sum()) * self.period

    def __len__(self) -> int:
        return len(self.times)


class Imu:
    """A MEMS gyro (z) and accelerometer (x, y) on the robot's base, sampled at its rate.

    Each sample is the true mean rate over its sample period plus the gyro's bias (drawn
    once per run: what is left after the start-up calibration, ``gyro_bias_instability``)
    and white noise of ``noise_density * sqrt(rate)``, so integrated over any stretch the
    heading's error is a random walk of ``gyro_noise_density * sqrt(t)`` plus ``bias * t``.
    The truth is read once per :meth:`read` (the physics runs at 100 Hz, a TurtleBot3's
    IMU at 200 Hz): between reads the heading follows the cubic that matches the headings
    and the yaw rates at both ends, and the speed a straight line, so the samples add up
    to the true heading change exactly. ``ideal``: no noise and no bias.
    """

    def __init__(
        self,
        world: SimulatedWorld,
        body: Body,
        spec: ImuSpec,
        rng: np.random.Generator,
        ideal: bool = False,
    ) -> None:
        self.world, self.body, self.spec, self.rng = world, body, spec, rng
        self.period = 1.0 / spec.rate
        root_rate = math.sqrt(spec.rate)
        self.gyro_sd = 0.0 if ideal else spec.gyro_noise_density * root_rate
        self.accel_sd = 0.0 if ideal else spec.accel_noise_density * root_rate
        b = spec.gyro_bias_instability
        self.bias = 0.0 if ideal or b == 0.0 else float(rng.normal(0.0, b))
        self._theta = 0.0  # the true heading turned since the start, unwrapped
        self._start_reads()

    def _start_reads(self) -> None:
        world = self.world
        self._t = world.time
        self._yaw = world.pose(self.body).yaw
        self._v, self._w = world.velocity(self.body)
        self._next = math.floor(self._t / self.period + 1e-9) + 1  # index of the next sample
        self._theta_sample, self._v_sample = self._theta, self._v

    def rebase(self) -> None:
        """Forget the motion since the last read (a teleport is not a turn)."""
        self._start_reads()

    def read(self) -> ImuSamples:
        """The samples due since the last read, up to the world's current time."""
        world = self.world
        now = world.time
        yaw = world.pose(self.body).yaw
        v1, w1 = world.velocity(self.body)
        t0, v0, w0, h = self._t, self._v, self._w, now - self._t
        turned = wrap_angle(yaw - self._yaw)
        k0, k1 = self._next, math.floor(now / self.period + 1e-9)
        theta0 = self._theta
        self._t, self._yaw, self._v, self._w = now, yaw, v1, w1
        self._theta = theta0 + turned
        if k1 < k0 or h <= 0.0:
            empty = np.zeros(0)
            return ImuSamples(empty, empty, np.zeros((0, 2)), self.period)
        self._next = k1 + 1
        # A read brings ~20 samples: plain floats, in the same operations and order as
        # array arithmetic would do them (the same bits), without ~40 numpy calls.
        period, bias = self.period, self.bias
        a, b, c = w0 * h, turned, w1 * h
        dv = v1 - v0
        prev_theta, prev_v = self._theta_sample, self._v_sample
        times: list[float] = []
        gyro: list[float] = []
        accel: list[tuple[float, float]] = []
        for k in range(k0, k1 + 1):
            t = k * period
            s = (t - t0) / h
            s2 = s * s
            s3 = s2 * s
            theta = theta0 + (s3 - 2.0 * s2 + s) * a + (3.0 * s2 - 2.0 * s3) * b
            theta += (s3 - s2) * c
            speed = v0 + s * dv
            rate = (theta - prev_theta) / period
            times.append(t)
            gyro.append(rate + bias)
            accel.append(((speed - prev_v) / period, speed * rate))
            prev_theta, prev_v = theta, speed
        self._theta_sample, self._v_sample = prev_theta, prev_v
        gyro_arr, accel_arr = np.array(gyro), np.array(accel)
        if self.gyro_sd > 0.0 or self.accel_sd > 0.0:
            noise = self.rng.standard_normal((len(times), 3))
            gyro_arr += self.gyro_sd * noise[:, 0]
            accel_arr += self.accel_sd * noise[:, 1:]
        return ImuSamples(np.array(times), gyro_arr, accel_arr, self.period)
