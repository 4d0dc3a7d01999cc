"""A differential-drive body in the world's MuJoCo spec, built from its shape (what
:func:`agv_mission.robots.body.diff_drive_shape` takes of a robot description).

Names are the body's prefix (``agv1/``) and: body ``base`` on free joint ``base_free``
(origin at the wheel axle midpoint, ROS ``base_link``, at axle height); chassis cylinder
``chassis`` of radius ``footprint_radius``, or a box of the footprint polygon's bounds; ``hull``, the outline other robots' lidars see
(up to the scan height of the tallest lidar in the world: the mast or bumper a fleet's
robots carry to be seen); wheel bodies ``wheel_left`` / ``wheel_right`` on hinge joints of
the same name with velocity actuators ``motor_left`` / ``motor_right``; frictionless
casters ``caster_front`` / ``caster_back``; site ``lidar``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco

from agv_mission.geometry import Footprint, Pose2D
from agv_mission.maps.worlds import World
from agv_mission.world.model import (
    BODY_BIT,
    FLOOR_BIT,
    FLOOR_FRICTION,
    GRAVITY,
    PARTS_GROUP,
    SEEN_GROUP,
    WALL_BIT,
    sig6,
)
from agv_mission.world.simulation import WorldBuilder


@dataclass(frozen=True)
class DiffDriveShape:
    """What the world builds a differential-drive body from: its wheels, outline, mass,
    how hard it accelerates (its motors' torque) and its lidar's place and range."""

    wheel_radius: float
    wheel_separation: float
    footprint_radius: float
    outline: Footprint
    mass: float
    max_linear_acceleration: float
    lidar_height: float  # the scan plane, m above the floor
    lidar_mount: Pose2D  # the scanner on the base (x, y, yaw)
    lidar_range: float  # m: how far its sensors see


WHEEL_FRICTION = FLOOR_FRICTION
WHEEL_MASS_SHARE = 0.08  # of the robot's mass, each wheel
# Wheel rotor armature (a geared motor's rotor, reflected), in mass x wheel radius^2: it
# keeps a lifted wheel's servo slow enough (LIFTED_WHEEL_TAU) for Euler at the 10 ms step.
ARMATURE_SHARE = 0.35

#: Time constant (s) of a wheel servo spinning its wheel alone (a lifted wheel): the
#: wheel's inertia plus the armature over :func:`wheel_kv`. Both scale with mass x wheel
#: radius^2, so it is the same for every robot (the world's integrator choice uses it).
LIFTED_WHEEL_TAU = (0.4 * WHEEL_MASS_SHARE + ARMATURE_SHARE) * 0.01 / 0.5


def wheel_torque_limit(robot: DiffDriveShape) -> float:
    """Per-wheel motor torque limit (N m).

    The torque that would give the robot's mass about three times its nominal linear
    acceleration (the rotors' armature takes its share: about 1.7 times in effect), capped
    well below what the wheel's traction (about a quarter of the weight per wheel,
    friction 1) can carry, so step commands neither spin the wheels nor lift the chassis.
    """
    accel = min(3.0 * robot.max_linear_acceleration, 0.4 * WHEEL_FRICTION * GRAVITY)
    return 0.5 * robot.mass * accel * robot.wheel_radius


def wheel_kv(robot: DiffDriveShape) -> float:
    """Velocity-actuator gain (N m s / rad): 10 ms time constant on the robot's reflected
    inertia alone (with the wheels and rotors, ~18 ms on the floor)."""
    reflected_inertia = 0.5 * robot.mass * robot.wheel_radius**2
    return reflected_inertia / 0.01


def hull_top(robot: DiffDriveShape) -> float:
    """Height (m above the floor) a lidar's scan plane must be under to see this robot
    alone: its scan height plus the scanner's housing."""
    return robot.lidar_height + 0.03


def add_diff_drive_body(
    spec: mujoco.MjSpec, robot: DiffDriveShape, prefix: str, seen_up_to: float
) -> str:
    """Add ``robot``'s body to ``spec`` at the origin (place it by writing the free joint's
    ``qpos``), its names starting with ``prefix``; its hull reaches ``seen_up_to`` metres.
    Returns the base body's name."""
    r = robot.wheel_radius
    rf = robot.footprint_radius
    outline = robot.outline
    half_sep = robot.wheel_separation / 2.0
    m = robot.mass

    # Vertical layout in the base frame (origin at axle height, z = 0 is the axle).
    floor_z = -r
    clearance = 0.4 * r
    chassis_top = max(robot.lidar_height - 0.01, clearance + 0.05) + floor_z
    chassis_bottom = floor_z + clearance
    chassis_half = (chassis_top - chassis_bottom) / 2.0
    chassis_z = (chassis_top + chassis_bottom) / 2.0
    caster_r = 0.5 * r
    reach = min(outline.front, outline.back) if not outline.round else rf
    caster_x = max(reach - caster_r - 0.01, 0.5 * reach)
    hull_half = max(seen_up_to, hull_top(robot)) / 2.0

    m_chassis, m_wheel, m_caster = 0.8 * m, WHEEL_MASS_SHARE * m, 0.02 * m
    armature = ARMATURE_SHARE * m * r * r
    kv = wheel_kv(robot)
    tau = wheel_torque_limit(robot)
    part = {"group": PARTS_GROUP, "contype": FLOOR_BIT, "conaffinity": FLOOR_BIT}
    sphere, cylinder = mujoco.mjtGeom.mjGEOM_SPHERE, mujoco.mjtGeom.mjGEOM_CYLINDER
    # A polygon's body: the box of its bounds (exact for the rectangles robots are).
    if outline.round:
        shape, size, centre = cylinder, (rf, chassis_half, 0.0), (0.0, 0.0)
    else:
        (x0, y0), (x1, y1) = outline.polygon.min(axis=0), outline.polygon.max(axis=0)
        box = mujoco.mjtGeom.mjGEOM_BOX
        shape, size = box, ((x1 - x0) / 2.0, (y1 - y0) / 2.0, chassis_half)
        centre = ((x0 + x1) / 2.0, (y0 + y1) / 2.0)
    wheel_friction = sig6(WHEEL_FRICTION, 0.005, 0.0001)

    base = spec.worldbody.add_body(name=f"{prefix}base", pos=sig6(0.0, 0.0, r))
    base.add_freejoint(name=f"{prefix}base_free")
    touches = FLOOR_BIT | WALL_BIT | BODY_BIT
    base.add_geom(
        name=f"{prefix}chassis",
        type=shape,
        size=sig6(*size),
        pos=sig6(*centre, chassis_z),
        mass=sig6(m_chassis)[0],
        group=PARTS_GROUP,
        contype=touches,
        conaffinity=touches,
        friction=[0.5, 0.005, 0.0001],
        rgba=[0.2, 0.2, 0.25, 1.0],
    )
    for name, x in (("caster_front", caster_x), ("caster_back", -caster_x)):
        base.add_geom(
            name=f"{prefix}{name}",
            type=sphere,
            size=sig6(caster_r, 0.0, 0.0),
            pos=sig6(x, 0.0, floor_z + caster_r),
            mass=sig6(m_caster)[0],
            condim=1,
            priority=1,
            friction=[0.0, 0.0, 0.0],
            **part,
        )
    base.add_geom(  # seen by lidars, touches nothing, weighs nothing
        name=f"{prefix}hull",
        type=shape,
        size=sig6(*size[:2], hull_half) if not outline.round else sig6(rf, hull_half, 0.0),
        pos=sig6(*centre, floor_z + hull_half),
        mass=0.0,
        group=SEEN_GROUP,
        contype=0,
        conaffinity=0,
        rgba=[0.2, 0.2, 0.25, 0.3],
    )
    mount = robot.lidar_mount
    base.add_site(
        name=f"{prefix}lidar",
        pos=sig6(mount.x, mount.y, robot.lidar_height + floor_z),
        quat=[math.cos(mount.yaw / 2.0), 0.0, 0.0, math.sin(mount.yaw / 2.0)],
        size=[0.01, 0, 0],
    )
    for side, y in (("left", half_sep), ("right", -half_sep)):
        wheel = base.add_body(name=f"{prefix}wheel_{side}", pos=sig6(0.0, y, 0.0))
        wheel.add_joint(
            name=f"{prefix}wheel_{side}",
            type=mujoco.mjtJoint.mjJNT_HINGE,
            axis=[0.0, 1.0, 0.0],
            armature=sig6(armature)[0],
        )
        wheel.add_geom(
            name=f"{prefix}wheel_{side}",
            type=sphere,
            size=sig6(r, 0.0, 0.0),
            mass=sig6(m_wheel)[0],
            condim=3,
            friction=wheel_friction,
            rgba=[0.1, 0.1, 0.1, 1.0],
            **part,
        )
    for side in ("left", "right"):
        act = spec.add_actuator(
            name=f"{prefix}motor_{side}",
            target=f"{prefix}wheel_{side}",
            trntype=mujoco.mjtTrn.mjTRN_JOINT,
            forcelimited=True,
            forcerange=sig6(-tau, tau),
        )
        act.set_to_velocity(kv=sig6(kv)[0])
    return f"{prefix}base"


def diff_drive_world(
    world: World, timestep: float, bodies: list[tuple[str, DiffDriveShape, Pose2D]]
) -> WorldBuilder:
    """A builder of ``world`` with these bodies in it (name, shape, start), each lidar
    seeing over the tallest hull."""
    builder = WorldBuilder(world, timestep, len(bodies), fastest_mode=LIFTED_WHEEL_TAU)
    seen = max(hull_top(shape) for _, shape, _ in bodies)
    for name, shape, start in bodies:
        base = add_diff_drive_body(builder.spec, shape, f"{name}/", seen)
        builder.attach(name, base, shape.footprint_radius, shape.lidar_range, start)
    return builder
