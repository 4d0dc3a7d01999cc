"""MJCF generation: one MuJoCo model holding a world's walls and a differential-drive robot.

Layout of the generated model (names are part of the contract used by
:mod:`agv_mission.robots.simulation` and :mod:`agv_mission.robots.sensors`):

* ``floor``: a plane in geom group :data:`FLOOR_GROUP`.
* ``wall_<i>`` / ``pillar_<i>``: static boxes / cylinders in the world body, geom group
  :data:`WALL_GROUP` (the only group the lidar sees; rays need ``flg_static=1``).
* body ``base`` on free joint ``base_free``: origin at the wheel axle midpoint (ROS
  ``base_link``) at axle height; chassis cylinder ``chassis`` of radius ``footprint_radius``;
  wheel bodies ``wheel_left`` / ``wheel_right`` on hinge joints of the same name with velocity
  actuators ``motor_left`` / ``motor_right``; frictionless casters ``caster_front`` /
  ``caster_back``; site ``lidar``. All robot geoms are in group :data:`ROBOT_GROUP`.

Collision bits keep the contact search tiny even with hundreds of wall boxes: walls and
floor never test against each other (same body, disjoint bits), wheels and casters only
touch the floor, and only the chassis tests against walls. Constraint islands are off:
the robot is the only moving body, so there is one island and finding it costs ~5 % of a
step (results are bit-identical).

Large worlds (more static shapes than ``wall_slots``): MuJoCo updates every geom each step
and the lidar's rays test every geom, so a map with a thousand wall blocks costs several
times a small one. The model then holds ``wall_slots`` box slots ``wall_slot_<i>`` and
``pillar_slots`` cylinder slots ``pillar_slot_<i>`` instead, parked (group
:data:`PARKED_GROUP`, no collisions) until :class:`agv_mission.robots.simulation.DiffDriveSim`
moves the walls near the robot into them (a rolling window, like a local costmap).
MuJoCo precomputes the world body's bounding-volume tree from the compiled geoms, so every
slot is compiled as a box (cylinder) covering the whole world: the tree stays conservative
whatever wall a slot later takes (compiled at its real size, a moved slot would be culled
from the contact search).
"""

from __future__ import annotations

import math

from agv_mission.maps.worlds import World
from agv_mission.robots.description import RobotDescription

FLOOR_GROUP = 0
WALL_GROUP = 1
ROBOT_GROUP = 2
PARKED_GROUP = 3  # wall slots not in use: neither the lidar nor the contact search sees them

WALL_SLOTS = 192  # box slots of the rolling window in large worlds
PILLAR_SLOTS = 32

# contype / conaffinity bits
_FLOOR_BIT = 1
_WALL_BIT = 2
WALL_BIT = _WALL_BIT

GRAVITY = 9.81
WHEEL_FRICTION = 1.0
WHEEL_MASS_SHARE = 0.08  # of the robot's mass, each wheel
# Wheel rotor armature (a geared motor's rotor, reflected), in mass x wheel radius^2: it
# keeps a lifted wheel's servo slow enough (LIFTED_WHEEL_TAU) for Euler at the 10 ms step.
ARMATURE_SHARE = 0.35


def _f(x: float) -> str:
    return f"{x:.6g}"


def _vec(*xs: float) -> str:
    return " ".join(_f(x) for x in xs)


def _yaw_quat(yaw: float) -> str:
    return _vec(math.cos(yaw / 2.0), 0.0, 0.0, math.sin(yaw / 2.0))


def wheel_torque_limit(robot: RobotDescription) -> float:
    """Per-wheel motor torque limit (N m).

    The torque that would give the robot's mass about three times its nominal linear
    acceleration (the rotors' armature takes its share: about 1.7 times in effect), capped
    well below what the wheel's traction (about a quarter of the weight per wheel,
    friction 1) can carry, so step commands neither spin the wheels nor lift the chassis.
    """
    accel = min(3.0 * robot.max_linear_acceleration, 0.4 * WHEEL_FRICTION * GRAVITY)
    return 0.5 * robot.mass * accel * robot.wheel_radius


def wheel_kv(robot: RobotDescription) -> float:
    """Velocity-actuator gain (N m s / rad): 10 ms time constant on the robot's reflected
    inertia alone (with the wheels and rotors, ~18 ms on the floor)."""
    reflected_inertia = 0.5 * robot.mass * robot.wheel_radius**2
    return reflected_inertia / 0.01


#: Time constant (s) of a wheel servo spinning its wheel alone (a lifted wheel): the
#: wheel's inertia plus the armature over :func:`wheel_kv`. Both scale with mass x wheel
#: radius^2, so it is the same for every robot: 7.6 ms.
LIFTED_WHEEL_TAU = (0.4 * WHEEL_MASS_SHARE + ARMATURE_SHARE) * 0.01 / 0.5


def integrator(timestep: float) -> str:
    """``Euler`` when the wheel servos are stable under it, else ``implicitfast``.

    Explicit Euler is stable for the servo's damping while ``timestep < 2 tau``
    (:data:`LIFTED_WHEEL_TAU`, also with a wheel in the air). There it is the more
    accurate of the two: ``implicitfast`` linearises the velocity servo as a damper while
    its force is clamped by ``forcerange`` and the contact forces were solved without that
    correction, so the wheels creep against the floor by an amount that grows with the time
    step (replaying a patrol's commands, the odometry's final yaw error was 2.8 deg at
    2 ms and 6.1 deg at 4 ms with ``implicitfast``, 0.9-1.0 deg with Euler from 2 to 10 ms,
    as RK4 at 1 ms). Above the limit (15 ms) ``implicitfast`` keeps a lifted wheel from
    oscillating.
    """
    return "Euler" if timestep < 2.0 * LIFTED_WHEEL_TAU else "implicitfast"


def uses_wall_slots(world: World) -> bool:
    """Whether ``world`` is large enough for the rolling window of wall slots."""
    return len(world.boxes) > WALL_SLOTS or len(world.cylinders) > PILLAR_SLOTS


def _world_bounds(world: World) -> tuple[float, float, float, float]:
    """(xmin, xmax, ymin, ymax) holding the map and every wall, with a margin."""
    x0, x1, y0, y1 = world.map.extent
    for b in world.boxes:
        r = math.hypot(b.half_x, b.half_y)
        x0, x1, y0, y1 = min(x0, b.x - r), max(x1, b.x + r), min(y0, b.y - r), max(y1, b.y + r)
    for c in world.cylinders:
        x0, x1 = min(x0, c.x - c.radius), max(x1, c.x + c.radius)
        y0, y1 = min(y0, c.y - c.radius), max(y1, c.y + c.radius)
    return x0 - 1.0, x1 + 1.0, y0 - 1.0, y1 + 1.0


def build_mjcf(robot: RobotDescription, world: World, timestep: float) -> str:
    """The MJCF XML of ``world``'s walls (or, in a large world, parked wall slots) plus
    ``robot`` (spawned at the origin; place it by writing the free joint's ``qpos``)."""
    r = robot.wheel_radius
    rf = robot.footprint_radius
    half_sep = robot.wheel_separation / 2.0
    m = robot.mass
    h_wall = world.wall_height

    # Vertical layout in the base frame (origin at axle height, z = 0 is the axle).
    floor_z = -r
    clearance = 0.4 * r
    chassis_top = max(robot.lidar.height - 0.01, clearance + 0.05) + floor_z
    chassis_bottom = floor_z + clearance
    chassis_half = (chassis_top - chassis_bottom) / 2.0
    chassis_z = (chassis_top + chassis_bottom) / 2.0
    caster_r = 0.5 * r
    caster_x = max(rf - caster_r - 0.01, 0.5 * rf)

    m_chassis, m_wheel, m_caster = 0.8 * m, WHEEL_MASS_SHARE * m, 0.02 * m
    armature = ARMATURE_SHARE * m * r * r
    kv = wheel_kv(robot)
    tau = wheel_torque_limit(robot)

    walls = []
    slots = uses_wall_slots(world)
    if slots:
        x0, x1, y0, y1 = _world_bounds(world)
        cx, cy, hx, hy = (x0 + x1) / 2, (y0 + y1) / 2, (x1 - x0) / 2, (y1 - y0) / 2
        parked = f'class="wall" group="{PARKED_GROUP}" contype="0"'
        walls += [
            f'    <geom name="wall_slot_{i}" type="box" pos="{_vec(cx, cy, h_wall / 2)}" '
            f'size="{_vec(hx, hy, h_wall / 2)}" {parked}/>'
            for i in range(WALL_SLOTS)
        ]
        walls += [
            f'    <geom name="pillar_slot_{i}" type="cylinder" pos="{_vec(cx, cy, h_wall / 2)}" '
            f'size="{_vec(math.hypot(hx, hy), h_wall / 2)}" {parked}/>'
            for i in range(PILLAR_SLOTS)
        ]
    for i, b in enumerate([] if slots else world.boxes):
        walls.append(
            f'    <geom name="wall_{i}" type="box" pos="{_vec(b.x, b.y, h_wall / 2)}" '
            f'size="{_vec(b.half_x, b.half_y, h_wall / 2)}" quat="{_yaw_quat(b.yaw)}" '
            f'class="wall"/>'
        )
    for i, c in enumerate([] if slots else world.cylinders):
        walls.append(
            f'    <geom name="pillar_{i}" type="cylinder" pos="{_vec(c.x, c.y, h_wall / 2)}" '
            f'size="{_vec(c.radius, h_wall / 2)}" class="wall"/>'
        )
    walls_xml = "\n".join(walls)

    return f"""<mujoco model="{robot.name}_in_{world.name}">
  <compiler angle="radian" autolimits="true"/>
  <option timestep="{_f(timestep)}" integrator="{integrator(timestep)}" gravity="0 0 {_f(-GRAVITY)}">
    <flag island="disable"/>
  </option>
  <visual><global offwidth="800" offheight="600"/></visual>
  <default>
    <default class="wall">
      <geom group="{WALL_GROUP}" contype="{_WALL_BIT}" conaffinity="{_WALL_BIT}"
            friction="0.5 0.005 0.0001" rgba="0.7 0.7 0.75 1"/>
    </default>
    <default class="robot">
      <geom group="{ROBOT_GROUP}" contype="{_FLOOR_BIT}" conaffinity="{_FLOOR_BIT}"/>
    </default>
  </default>
  <worldbody>
    <geom name="floor" type="plane" size="0 0 0.1" group="{FLOOR_GROUP}"
          contype="{_FLOOR_BIT}" conaffinity="{_FLOOR_BIT}" friction="{_f(WHEEL_FRICTION)} 0.005 0.0001"
          rgba="0.9 0.9 0.9 1"/>
{walls_xml}
    <body name="base" pos="0 0 {_f(r)}">
      <freejoint name="base_free"/>
      <geom name="chassis" class="robot" type="cylinder" size="{_vec(rf, chassis_half)}"
            pos="0 0 {_f(chassis_z)}" mass="{_f(m_chassis)}"
            contype="{_FLOOR_BIT | _WALL_BIT}" conaffinity="{_FLOOR_BIT | _WALL_BIT}"
            friction="0.5 0.005 0.0001" rgba="0.2 0.2 0.25 1"/>
      <geom name="caster_front" class="robot" type="sphere" size="{_f(caster_r)}"
            pos="{_vec(caster_x, 0, floor_z + caster_r)}" mass="{_f(m_caster)}"
            condim="1" priority="1" friction="0 0 0"/>
      <geom name="caster_back" class="robot" type="sphere" size="{_f(caster_r)}"
            pos="{_vec(-caster_x, 0, floor_z + caster_r)}" mass="{_f(m_caster)}"
            condim="1" priority="1" friction="0 0 0"/>
      <site name="lidar" pos="0 0 {_f(robot.lidar.height + floor_z)}" size="0.01"/>
      <body name="wheel_left" pos="0 {_f(half_sep)} 0">
        <joint name="wheel_left" type="hinge" axis="0 1 0" armature="{_f(armature)}"/>
        <geom name="wheel_left" class="robot" type="sphere" size="{_f(r)}" mass="{_f(m_wheel)}"
              condim="3" friction="{_f(WHEEL_FRICTION)} 0.005 0.0001" rgba="0.1 0.1 0.1 1"/>
      </body>
      <body name="wheel_right" pos="0 {_f(-half_sep)} 0">
        <joint name="wheel_right" type="hinge" axis="0 1 0" armature="{_f(armature)}"/>
        <geom name="wheel_right" class="robot" type="sphere" size="{_f(r)}" mass="{_f(m_wheel)}"
              condim="3" friction="{_f(WHEEL_FRICTION)} 0.005 0.0001" rgba="0.1 0.1 0.1 1"/>
      </body>
    </body>
  </worldbody>
  <actuator>
    <velocity name="motor_left" joint="wheel_left" kv="{_f(kv)}" forcerange="{_vec(-tau, tau)}"/>
    <velocity name="motor_right" joint="wheel_right" kv="{_f(kv)}" forcerange="{_vec(-tau, tau)}"/>
  </actuator>
</mujoco>
"""
