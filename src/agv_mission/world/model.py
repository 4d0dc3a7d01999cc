"""The world's MuJoCo model, built with :class:`mujoco.MjSpec`: floor, walls, and the bodies
attached to it (robots, by :mod:`agv_mission.world.body`; people).

Layout (the names and groups are the contract between the world and what it holds):

* ``floor``: a plane in geom group :data:`FLOOR_GROUP`.
* ``wall_<i>`` / ``pillar_<i>``: static boxes / cylinders in the world body, geom group
  :data:`WALL_GROUP`. Lidars see :data:`WALL_GROUP` and :data:`SEEN_GROUP` (walls need
  ``flg_static=1``).
* every moving body's outline a lidar can see (a robot's hull, a person) is in
  :data:`SEEN_GROUP`; the parts it cannot (wheels, casters, the chassis under the hull) in
  :data:`PARTS_GROUP`. A lidar excludes its own body by id.

Collision bits keep the contact search small even with hundreds of wall boxes: walls and
floor never test against each other (same body, disjoint bits), wheels and casters only
touch the floor, chassis touch walls, other chassis and people.

Large worlds (more static shapes than :data:`WALL_SLOTS`): MuJoCo updates every geom each
step and the lidar's rays test every geom, so a map with a thousand wall blocks costs several
times a small one. The model then holds ``wall_slot_<i>`` box and ``pillar_slot_<i>``
cylinder slots instead, parked (group :data:`PARKED_GROUP`, no collisions) until the
world's :class:`~agv_mission.world.walls.WallWindow` moves the walls near its bodies into
them (a rolling window, like a local costmap). MuJoCo precomputes the world body's
bounding-volume tree from the compiled geoms, so every slot is compiled covering the whole
world: the tree stays conservative whatever wall a slot later takes.
"""

from __future__ import annotations

import math

import mujoco

from agv_mission.maps.worlds import World

FLOOR_GROUP = 0
WALL_GROUP = 1
PARTS_GROUP = 2  # robot parts no lidar sees: wheels, casters, the chassis under its hull
PARKED_GROUP = 3  # wall slots not in use: neither the lidar nor the contact search sees them
SEEN_GROUP = 4  # moving bodies' outlines the lidars see: robot hulls, people

WALL_SLOTS = 192  # box slots of one rolling window in large worlds
PILLAR_SLOTS = 32

# contype / conaffinity bits
FLOOR_BIT = 1
WALL_BIT = 2
BODY_BIT = 4  # chassis against chassis and people

PERSON_HEIGHT = 1.7  # m: a standing adult, as the bag's /people markers draw them
PERSON_PREFIX = "person_"
PEOPLE_BODY = "people"
PARKED_Z = -5.0  # m: where a person not yet in the world waits, under the floor

GRAVITY = 9.81
FLOOR_FRICTION = 1.0
WALL_FRICTION = (0.5, 0.005, 0.0001)
WALL_RGBA = (0.7, 0.7, 0.75, 1.0)


def integrator(timestep: float, fastest_mode: float) -> mujoco.mjtIntegrator:
    """``Euler`` when the bodies' fastest servo (time constant ``fastest_mode``, s) is
    stable under it, else ``implicitfast``.

    Explicit Euler is stable for a wheel servo's damping while ``timestep < 2 tau`` (the
    time constant of a lifted wheel, :data:`agv_mission.world.body.LIFTED_WHEEL_TAU`). There it is the more
    accurate of the two: ``implicitfast`` linearises the velocity servo as a damper while
    its force is clamped by ``forcerange`` and the contact forces were solved without that
    correction, so the wheels creep against the floor by an amount that grows with the time
    step (replaying a patrol's commands, the odometry's final yaw error was 2.8 deg at
    2 ms and 6.1 deg at 4 ms with ``implicitfast``, 0.9-1.0 deg with Euler from 2 to 10 ms,
    as RK4 at 1 ms). Above the limit (15 ms) ``implicitfast`` keeps a lifted wheel from
    oscillating.
    """
    if timestep < 2.0 * fastest_mode:
        return mujoco.mjtIntegrator.mjINT_EULER
    return mujoco.mjtIntegrator.mjINT_IMPLICITFAST


#: Up to this many walls a world with several bodies compiles every wall in place: the
#: windows' slots, compiled to cover the whole world, defeat MuJoCo's bounding-volume
#: culling, and for several bodies that costs more than the walls themselves (10 robots
#: in a 753-wall warehouse: 3.7 ms of physics and lidar per robot per simulated second
#: with slots, 2.6 ms with every wall; one robot: 2.0 ms with slots, 2.5 ms without).
FLEET_STATIC_WALLS = 2000
#: Cylinders alone are compiled in place up to this many per body: BARN's worlds hold
#: 181-365 pillars, and with all 209 of world_0 in place a 15 s run took 2.5 s of wall time
#: against 3.3 s through :data:`PILLAR_SLOTS` slots (which also showed the lidar only the
#: nearest 32).
CYLINDERS_IN_PLACE = 1000


def uses_wall_slots(world: World, bodies: int = 1) -> bool:
    """Whether ``world`` has more boxes than the rolling windows of ``bodies`` moving
    bodies would hold (or more than :data:`CYLINDERS_IN_PLACE` cylinders a body), and
    (for several bodies) more walls than :data:`FLEET_STATIC_WALLS`; else every wall is
    compiled in place."""
    walls = len(world.boxes) + len(world.cylinders)
    if bodies > 1 and walls <= FLEET_STATIC_WALLS:
        return False
    return (
        len(world.boxes) > WALL_SLOTS * bodies or len(world.cylinders) > CYLINDERS_IN_PLACE * bodies
    )


def sig6(*xs: float) -> list[float]:
    """Numbers at 6 significant digits, as the model's MJCF text carried them: runs
    reproduce those of earlier versions bit for bit."""
    return [float(f"{x:.6g}") for x in xs]


def _yaw_quat(yaw: float) -> list[float]:
    return sig6(math.cos(yaw / 2.0), 0.0, 0.0, math.sin(yaw / 2.0))


def world_bounds(world: World) -> tuple[float, float, float, float]:
    """(xmin, xmax, ymin, ymax) holding the map and every wall, with a margin."""
    x0, x1, y0, y1 = world.map.extent
    for b in world.boxes:
        r = math.hypot(b.half_x, b.half_y)
        x0, x1, y0, y1 = min(x0, b.x - r), max(x1, b.x + r), min(y0, b.y - r), max(y1, b.y + r)
    for c in world.cylinders:
        x0, x1 = min(x0, c.x - c.radius), max(x1, c.x + c.radius)
        y0, y1 = min(y0, c.y - c.radius), max(y1, c.y + c.radius)
    return x0 - 1.0, x1 + 1.0, y0 - 1.0, y1 + 1.0


def world_spec(
    world: World, timestep: float, bodies: int = 1, fastest_mode: float = math.inf
) -> mujoco.MjSpec:
    """The spec of ``world``'s floor and walls (or, in a world with more walls than
    the windows of ``bodies`` moving bodies hold, parked wall slots: :data:`WALL_SLOTS` box
    and :data:`PILLAR_SLOTS` cylinder slots per body), before any body is
    attached; ``fastest_mode`` is the time constant of the stiffest servo
    of the bodies to come (:func:`integrator`).

    Constraint islands are off for one body (finding the one island costs ~5 % of a step,
    results are bit-identical) and on for several, so each body's contacts are solved on
    their own.
    """
    spec = mujoco.MjSpec()
    spec.modelname = world.name
    spec.compiler.degree = False
    spec.compiler.autolimits = True
    opt = spec.option
    opt.timestep = sig6(timestep)[0]
    opt.integrator = integrator(timestep, fastest_mode)
    opt.gravity = [0.0, 0.0, -GRAVITY]
    if bodies <= 1:
        opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_ISLAND
    spec.visual.global_.offwidth = 800
    spec.visual.global_.offheight = 600
    wb = spec.worldbody
    wb.add_geom(
        name="floor",
        type=mujoco.mjtGeom.mjGEOM_PLANE,
        size=[0.0, 0.0, 0.1],
        group=FLOOR_GROUP,
        contype=FLOOR_BIT,
        conaffinity=FLOOR_BIT,
        friction=[FLOOR_FRICTION, 0.005, 0.0001],
        rgba=[0.9, 0.9, 0.9, 1.0],
    )
    h = world.wall_height
    wall = {
        "group": WALL_GROUP,
        "contype": WALL_BIT,
        "conaffinity": WALL_BIT,
        "friction": list(WALL_FRICTION),
        "rgba": list(WALL_RGBA),
    }
    if uses_wall_slots(world, bodies):
        x0, x1, y0, y1 = world_bounds(world)
        cx, cy, hx, hy = (x0 + x1) / 2, (y0 + y1) / 2, (x1 - x0) / 2, (y1 - y0) / 2
        parked = {**wall, "group": PARKED_GROUP, "contype": 0}
        for i in range(WALL_SLOTS * bodies):
            wb.add_geom(
                name=f"wall_slot_{i}",
                type=mujoco.mjtGeom.mjGEOM_BOX,
                pos=sig6(cx, cy, h / 2),
                size=sig6(hx, hy, h / 2),
                **parked,
            )
        for i in range(PILLAR_SLOTS * bodies):
            wb.add_geom(
                name=f"pillar_slot_{i}",
                type=mujoco.mjtGeom.mjGEOM_CYLINDER,
                pos=sig6(cx, cy, h / 2),
                size=sig6(math.hypot(hx, hy), h / 2, 0.0),
                **parked,
            )
        return spec
    for i, b in enumerate(world.boxes):
        wb.add_geom(
            name=f"wall_{i}",
            type=mujoco.mjtGeom.mjGEOM_BOX,
            pos=sig6(b.x, b.y, h / 2),
            size=sig6(b.half_x, b.half_y, h / 2),
            quat=_yaw_quat(b.yaw),
            **wall,
        )
    for i, c in enumerate(world.cylinders):
        wb.add_geom(
            name=f"pillar_{i}",
            type=mujoco.mjtGeom.mjGEOM_CYLINDER,
            pos=sig6(c.x, c.y, h / 2),
            size=sig6(c.radius, h / 2, 0.0),
            **wall,
        )
    return spec


def add_people(spec: mujoco.MjSpec, radii: list[float]) -> None:
    """People: one mocap body (``people``) holding a cylinder per person (``person_<i>``,
    moved by the crowd every control step: :meth:`SimulatedWorld.move_people`), in
    :data:`SEEN_GROUP` the lidars see, colliding with chassis only (people do not collide
    with each other or with walls: the pedestrian model keeps them apart), parked under the
    floor until the person enters. One body and not one each: MuJoCo's step and its ray
    casts cost per body, whatever its groups (measured: 50 bodies added 4.3 us to a 5.6 us
    step and 114 us to a 360-beam cast of 58 us; 50 geoms of one body 1.4 and 17 us)."""
    if not radii:
        return
    body = spec.worldbody.add_body(name=PEOPLE_BODY, mocap=True)
    # its frame the world's, inertial frame included (the frame of its bounding-volume tree)
    body.explicitinertial = True
    body.mass, body.inertia = 1.0, [1.0, 1.0, 1.0]
    body.ipos, body.iquat = [0.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0]
    for i, r in enumerate(radii):
        body.add_geom(
            name=f"{PERSON_PREFIX}{i}",
            type=mujoco.mjtGeom.mjGEOM_CYLINDER,
            pos=[0.0, 0.0, PARKED_Z],
            size=sig6(r, PERSON_HEIGHT / 2, 0.0),
            group=SEEN_GROUP,
            contype=BODY_BIT,
            conaffinity=0,
            rgba=[1.0, 0.55, 0.1, 1.0],
        )
