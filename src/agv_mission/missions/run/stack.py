"""The one place that builds a mission's robots on their bodies in the world: sensors,
localiser, navigator, recorders.

Every front door (``run``, ``regress``, ``teleop``, the service) starts from a
:class:`RobotStack` per robot, so a mission's seed gives the same random streams, the same
plugins and the same control period whichever way it came in.
"""

from __future__ import annotations

import inspect
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from agv_mission.geometry import Bounds, Pose2D
from agv_mission.localization.base import Localizer
from agv_mission.mapping.base import Slam
from agv_mission.maps.costmap import ObstacleLayerConfig
from agv_mission.maps.grid import OccupancyGrid
from agv_mission.maps.obstacle_layer import ObstacleLayer
from agv_mission.missions.load.resolved import LoadedMission, RobotSetup
from agv_mission.navigation.config import NavigationConfig
from agv_mission.navigation.navigator import Navigator
from agv_mission.planners.base import VelocityLimits
from agv_mission.registry import PluginConfig, registry
from agv_mission.robots.description import RobotDescription
from agv_mission.robots.drive_base import DriveBase, robots_world
from agv_mission.robots.sensors import ImuSamples
from agv_mission.sensor_msgs import LaserScan
from agv_mission.world.crowd import Crowd
from agv_mission.world.model import add_people
from agv_mission.world.simulation import SimulatedWorld

CONTROL_PERIOD = 0.1
PEOPLE_STREAM = 0x9E0_91E  # the people's random stream: the seed's, apart from the robots'
#: amcl's refinement's heading noise when the odometry fuses a MEMS gyro: rad sd after a
#: radian turned and after a metre driven. The MPU-9250's angle random walk and residual
#: bias (see robots.description) give ~2e-4 rad per radian turned at 1 rad/s and ~5e-4
#: rad per metre at 0.2 m/s; these are four to ten times that (the wheels': 0.02, 0.01).
#: amcl's refinement on a map that is not the world's own: the covariance floor from the
#: fit's residuals, no scan pinning x or y tighter than 1 cm (AmclConfig's defaults pin a
#: surveyed map's pose to millimetres).
MADE_MAP_FLOOR = {"refine_split_scale": 0.0, "refine_floor_xy": 0.01}
GYRO_HEADING_NOISE = {"refine_noise_turn": 0.002, "refine_noise_yaw_per_m": 0.002}
#: SLAM's odometry prior when the odometry fuses a MEMS gyro (the wheels' are
#: GridSlamConfig's defaults: 0.1 rad per radian turned, 0.2 rad per metre, 1 mrad a
#: scan). The MPU-9250's angle random walk (1.75e-4 rad/sqrt(s)) and residual bias
#: (4.8e-5 rad/s) give ~2.6e-4 rad per radian turned at the explorer's 0.8 rad/s, ~6e-4
#: rad per metre at 0.2 m/s and ~1e-4 rad over a 5 Hz scan's 0.2 s; these are ten, five
#: and one times that. With the wheels' prior the matcher, not the gyro, set the heading:
#: map_area of the AWS house drifted 4.7 degrees where the odometry stayed within 1.4.
#: A scan point's std in SLAM's matcher over the lidar's range noise at its farthest
#: return. The matcher counts a scan's points as independent, but one wall's points share
#: the error of the map's anchors they are paired with, so a scan knows less than they
#: add up to. Measured on map_area of the AWS house (waffle, seeds 1 and 2, estimate RMSE
#: after 10 s): 1.0 (6 cm) 0.108 / 0.061 m, 1.6 (10 cm) 0.045 / 0.054 m; 2.5 (15 cm, the
#: runs' scans replayed) no better than 1.6. The runs are chaotic: 9.8 cm instead of 10
#: took seed 1 elsewhere (0.07 m on seed 2), hence whole centimetres.
SCAN_POINT_FACTOR = 1.6
#: The share of its lidar's beams a scan must return for SLAM to match it (fewer: the
#: odometry alone). Measured on map_area of the depot (burger, LDS-01's 360 beams, seed
#: 1): scans of fewer than 80 returns (a column or two, a wall's end 3 m off) turned the
#: estimate's heading by 1.7 degrees in all over the run, where the gyro drifted 0.6;
#: those of more, by -0.1. Of the house's scans 2 % have fewer than 90, of the tb3
#: arena's none.
MIN_SCAN_SHARE = 0.25
GYRO_SLAM_NOISE = {
    "odom_rotation_noise": 0.003,
    "odom_rotation_per_metre": 0.003,
    "odom_rotation_floor": 1e-4,
}


class VelocitySmoother:
    """Limits command changes to the robot's accelerations, like a cmd_vel smoother."""

    def __init__(self, limits: VelocityLimits, period: float) -> None:
        self.limits, self.period = limits, period
        self.v = self.w = 0.0

    def __call__(self, v: float, w: float) -> tuple[float, float]:
        lim, dt = self.limits, self.period
        v = _clip(float(v), -lim.max_v, lim.max_v)
        w = _clip(float(w), -lim.max_w, lim.max_w)
        self.v = _clip(v, self.v - lim.max_acc_v * dt, self.v + lim.max_acc_v * dt)
        self.w = _clip(w, self.w - lim.max_acc_w * dt, self.w + lim.max_acc_w * dt)
        return self.v, self.w


def _clip(x: float, lo: float, hi: float) -> float:
    """``np.clip`` of one float (the same value, without numpy's ~8 us per call)."""
    return min(max(x, lo), hi)


def velocity_limits(robot: RobotDescription) -> VelocityLimits:
    """The bounds a robot description puts on commands."""
    return VelocityLimits(
        max_v=robot.max_linear_velocity,
        max_w=robot.max_angular_velocity,
        max_acc_v=robot.max_linear_acceleration,
        max_acc_w=robot.max_angular_acceleration,
    )


@dataclass
class Sensing:
    """What one control step reads: odometry, the lidar scan when one is due, the truth;
    and, from a lidar faster than the control loop, the scans taken within the control
    period before it (``earlier``, oldest first), each with the odometry and the truth at
    its own time."""

    time: float
    odom: Pose2D
    scan: LaserScan | None
    truth: Pose2D
    earlier: tuple[Sensing, ...] = ()
    imu: ImuSamples | None = None  # the IMU's samples since the sensing before

    @property
    def imu_samples(self) -> tuple[ImuSamples, ...]:
        """Every IMU sample this step brings, in batches, oldest first."""
        found = [s.imu for s in self.earlier] + [self.imu]
        return tuple(batch for batch in found if batch is not None and len(batch))

    @property
    def scans(self) -> tuple[LaserScan, ...]:
        """Every scan this step brings, oldest first."""
        found = [s.scan for s in self.earlier] + [self.scan]
        return tuple(scan for scan in found if scan is not None)


ScanFilter = Callable[[float, LaserScan], LaserScan | None]


class RobotStack:
    """One robot: its body in the world with its encoders, lidar, odometry and localiser.

    Random streams: the mission's seed spawns four per robot (simulation, localisation,
    planning, faults), always in this order and robot after robot, so every front door
    draws the same numbers (a one-robot mission's are those of the first robot).
    """

    def __init__(
        self,
        loaded: LoadedMission,
        setup: RobotSetup,
        world: SimulatedWorld,
        seeds: list[np.random.SeedSequence],
    ) -> None:
        self.loaded, self.setup = loaded, setup
        self.name = setup.name
        robot = setup.robot
        self.loc_rng, self.planner_rng, self.fault_rng = (
            np.random.default_rng(s) for s in seeds[1:]
        )
        self.limits = velocity_limits(robot)
        self.smoother = VelocitySmoother(self.limits, CONTROL_PERIOD)
        self.scan_period = 1.0 / robot.lidar.rate
        self.next_scan = 0.0
        self._between: list[Sensing] = []  # scans taken within the last control period
        # the odometry fuses the gyro (robot_localization) when the robot has an IMU and
        # the stack's odometry takes it: the localiser's and SLAM's heading noise follow
        self.fuses_gyro = robot.imu is not None and setup.stack.odometry.imu
        localization = self.localization_config(loaded.map)
        self.base = DriveBase.build(
            world,
            setup.name,
            robot,
            loaded.mission.simulation,
            seeds[0],
            use_imu=self.fuses_gyro,
        )
        self.sim, self.odometry = self.base.body, self.base.odometry
        self.odom, _ = self.base.read()
        self.odom_start = self.odom
        self.localizer: Localizer = registry.create(
            "localization", localization, grid=loaded.map, rng=self.loc_rng
        )
        self.localizer.reset(setup.start, self.odom)

    def localization_config(self, grid: OccupancyGrid) -> PluginConfig:
        """The robot's localisation plugin's config on ``grid``.

        On a map that is not the world's own (a mission's ``map:``, a map a map_area task
        just made) amcl's refinement takes its covariance floor from the fit's residuals
        (MADE_MAP_FLOOR) unless the mission sets it: such a map may be drawn
        off by centimetres as a whole, which no scan can see (see AmclConfig). With the
        gyro in the odometry its heading noise is the gyro's (GYRO_HEADING_NOISE), not the
        wheels'."""
        config = self.setup.stack.localization
        update: dict[str, float] = {}
        if grid is not self.loaded.world.map:
            update.update(MADE_MAP_FLOOR)
        if self.fuses_gyro:
            update.update(GYRO_HEADING_NOISE)
        fields, given = type(config).model_fields, config.model_fields_set
        update = {k: v for k, v in update.items() if k in fields and k not in given}
        if update:
            config = config.model_copy(update=update)
        return config

    def new_localizer(self, grid: OccupancyGrid) -> Localizer:
        """The robot's localisation plugin on ``grid`` (not yet reset)."""
        return registry.create(
            "localization", self.localization_config(grid), grid=grid, rng=self.loc_rng
        )

    def new_slam(self, bounds: Bounds) -> Slam:
        """The robot's SLAM plugin over ``bounds`` (not yet reset), its odometry prior
        and scan weight from the robot's sensors (:meth:`_slam_sensors`) unless the
        mission sets them."""
        config = self.setup.stack.slam
        fields, given = type(config).model_fields, config.model_fields_set
        update = {
            k: v for k, v in self._slam_sensors(config).items() if k in fields and k not in given
        }
        if update:
            config = config.model_copy(update=update)
        return registry.create("slam", config, bounds=bounds, rng=self.loc_rng)

    def _slam_sensors(self, config: PluginConfig) -> dict[str, float]:
        """SLAM's odometry prior and scan weight from this robot's own sensors: the
        prior's translation noise twice a wheel's relative travel error (as
        :func:`new_odometry` reckons it; 1 % a metre at least), the gyro's heading noise
        (GYRO_SLAM_NOISE) when the odometry fuses one, and a scan point's std no less than
        SCAN_POINT_FACTOR times the lidar's range noise at its farthest return, rounded up
        to a whole centimetre (an LDS-01's 1.75 % of 3.5 m: 6 cm, so 10 cm). Points are weighed alike and the far
        ones fix the heading: weighed as the near ones' 3 cm they made the matcher
        overrule the odometry. A scan with fewer returns than MIN_SCAN_SHARE of the
        lidar's beams is not matched: in an open hall such a scan sees a column or a
        wall's end, too little to set the heading the gyro keeps better."""
        sim, robot = self.sim, self.setup.robot
        enc = sim.encoders
        scale = sim.config.pick("wheel_scale_error", robot.encoder.scale_error)
        wheel = math.sqrt(enc.noise**2 + enc.slip**2 / 3.0 + scale**2)
        lidar = sim.lidar
        far = max(lidar.noise_std, lidar.noise_fraction * lidar.spec.range_max)
        far = math.ceil(100.0 * SCAN_POINT_FACTOR * far - 1e-9) / 100.0  # whole cm
        out = {
            "odom_translation_noise": max(2.0 * wheel, 0.01),
            "point_sigma": max(float(getattr(config, "point_sigma", 0.0)), far),
            "min_points": max(
                int(getattr(config, "min_points", 0)), round(MIN_SCAN_SHARE * lidar.spec.beams)
            ),
        }
        if self.fuses_gyro:
            out.update(GYRO_SLAM_NOISE)
        return out

    def build_navigator(self) -> Navigator:
        """The robot's global and local planners behind a navigator on the known map."""
        stack, robot = self.setup.stack, self.setup.robot
        # a polygon footprint goes to the local planners that take one (the MPC)
        cls = registry.get("local_planner", stack.local_planner.type)
        takes = "footprint" in inspect.signature(cls).parameters
        local_planner = registry.create(
            "local_planner",
            stack.local_planner,
            limits=self.limits,
            robot_radius=robot.inscribed_radius,
            control_period=CONTROL_PERIOD,
            **({"footprint": robot.polygon} if takes and robot.polygon is not None else {}),
        )
        navigation, obstacles = tuned_for_speed(robot, stack.navigation, stack.costmap.obstacles)
        return Navigator(
            ObstacleLayer(self.setup.costmap, obstacles),
            registry.create("global_planner", stack.global_planner),
            local_planner,
            self.limits,
            navigation,
            CONTROL_PERIOD,
            seed=int(self.planner_rng.integers(0, 2**31 - 1)),
            zones=self.setup.zones,
        )

    def sense(self, scan_filter: ScanFilter | None = None) -> Sensing:
        """Read the encoders into odometry and, when one is due, a lidar scan; with the
        scans taken within the last control period (:meth:`scan_steps`)."""
        sim = self.sim
        now = sim.time
        self.odom, imu = self.base.read()
        scan = None
        if now >= self.next_scan - 1e-9:
            self.next_scan += self.scan_period
            scan = sim.scan()
            if scan_filter is not None:
                scan = scan_filter(now, scan)
        earlier, self._between = tuple(self._between), []
        return Sensing(now, self.odom, scan, sim.true_pose(), earlier, imu)

    def has_moved(self) -> bool:
        """Whether odometry saw the robot move since the start."""
        moved = self.odom.relative_to(self.odom_start)
        return not (math.hypot(moved.x, moved.y) < 1e-3 and abs(moved.yaw) < 1e-3)

    def drive(self, v: float, w: float) -> tuple[float, float]:
        """Smooth (v, w) within the robot's limits and send it; returns what was sent."""
        v, w = self.smoother(v, w)
        self.sim.set_command(v, w)
        return v, w

    def scan_steps(self, t0: float, steps: int, dt: float) -> list[int]:
        """The physics steps (1..steps-1) after ``t0`` at which a lidar faster than the
        control loop scans within the coming control period; scans due at the period's
        ends are :meth:`sense`'s, so a lidar at 10 Hz or slower has none."""
        out: list[int] = []
        due = self.next_scan
        while due < t0 + CONTROL_PERIOD - 1e-9:
            k = max(1, int(round((due - t0) / dt)))
            if k >= steps:  # within half a physics step of the end: sense() takes it
                break
            if out and k <= out[-1]:
                k = out[-1]
            out.append(k)
            due += self.scan_period
        return out

    def take_scan(self, scan_filter: ScanFilter | None = None) -> None:
        """A scan at the world's current time, with the odometry and the truth then, for
        the next :meth:`sense`."""
        sim = self.sim
        self.next_scan += self.scan_period
        odom, imu = self.base.read()
        scan = sim.scan()
        if scan_filter is not None:
            scan = scan_filter(sim.time, scan)
        self._between.append(Sensing(sim.time, odom, scan, sim.true_pose(), (), imu))


def build_world(loaded: LoadedMission) -> tuple[SimulatedWorld, list[RobotStack], Crowd | None]:
    """The mission's world with every robot's body and its people in it, each robot's
    stack, and the crowd walking there (None: the mission has no people)."""
    setups = loaded.robots
    builder = robots_world(
        loaded.world, [(s.name, s.robot, s.start) for s in setups], loaded.mission.simulation
    )
    if loaded.people:
        add_people(builder.spec, [g.radius for g in loaded.people for _ in range(g.count)])
    world = builder.build()
    crowd = None
    if loaded.people:  # clear of the robots, standing where the world was built with them
        people_seed = np.random.SeedSequence([loaded.mission.seed, PEOPLE_STREAM])
        crowd = Crowd.in_world(loaded.people, world, np.random.default_rng(people_seed))
    root = np.random.SeedSequence(loaded.mission.seed)
    stacks = []
    for setup in setups:
        stacks.append(RobotStack(loaded, setup, world, root.spawn(4)))
    world.start()
    return world, stacks, crowd


def tuned_for_speed(
    robot: RobotDescription, navigation: NavigationConfig, obstacles: ObstacleLayerConfig
) -> tuple[NavigationConfig, ObstacleLayerConfig]:
    """The navigator's and the obstacle layer's reach for a fast robot, where the mission
    leaves them unset: a robot that needs ``d`` metres to stop from full speed (braking at
    half its deceleration, as the MPC's reference does) checks its path for new obstacles
    ``2 d`` ahead, marks what its lidar sees up to ``2 d + 1`` m (within its range) and
    hands the controller the points within ``d + 1`` m. A TurtleBot3 (d < 3 cm) keeps the
    defaults; a Jackal at 2 m/s (d = 2 m) replans 4 m ahead on 5 m of marks."""
    d = robot.max_linear_velocity**2 / robot.max_linear_acceleration
    nav: dict[str, float] = {}
    if "blocked_lookahead" not in navigation.model_fields_set:
        nav["blocked_lookahead"] = max(navigation.blocked_lookahead, 2.0 * d)
    if "obstacle_range" not in navigation.model_fields_set:
        nav["obstacle_range"] = max(navigation.obstacle_range, d + 1.0)
    layer: dict[str, float] = {}
    if "max_range" not in obstacles.model_fields_set:
        layer["max_range"] = max(obstacles.max_range, min(robot.lidar.range_max, 2.0 * d + 1.0))
    if "raytrace_range" not in obstacles.model_fields_set:
        reach = layer.get("max_range", obstacles.max_range) + 0.5
        layer["raytrace_range"] = max(obstacles.raytrace_range, reach)
    changed = {k: v for k, v in nav.items() if v != getattr(navigation, k)}
    changed_layer = {k: v for k, v in layer.items() if v != getattr(obstacles, k)}
    return (
        navigation.model_copy(update=changed) if changed else navigation,
        obstacles.model_copy(update=changed_layer) if changed_layer else obstacles,
    )
