"""The simulated world: one MuJoCo model, every body in it, physics stepped once for all.

The world owns the model and its data; robots are attached to it as bodies (see
:mod:`agv_mission.world.body`) and read and command them through a :class:`Body`. It
answers what only the world can: ray casts (every lidar sees walls and every other
body), contacts between bodies and with walls, and clearances.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco
import numpy as np

from agv_mission.geometry import Pose2D, wrap_angle, yaw_from_quaternion
from agv_mission.maps.worlds import World
from agv_mission.world.model import (
    BODY_BIT,
    PARKED_Z,
    PERSON_HEIGHT,
    PERSON_PREFIX,
    PILLAR_SLOTS,
    SEEN_GROUP,
    WALL_GROUP,
    uses_wall_slots,
    world_spec,
)
from agv_mission.world.planar_cast import PlanarWalls
from agv_mission.world.walls import Walls, WallWindow

WINDOW_CHECK_PERIOD = 0.1  # s of simulated motion between wall-window checks

WALL = -1  # owner of a wall or pillar geom
FLOOR = -2  # owner of the floor and anything else static
PERSON = -3  # owner of person i's geom: PERSON - i
# m beyond a body's footprint and a person's radius within which people collide with it,
# looked at every ARM_EVERY moves of the people (control periods): that long's walk (1.5
# m/s) and a body's drive (2 m/s) with room to spare
PERSON_REACH = 1.0
ARM_EVERY = 2


@dataclass(frozen=True)
class Body:
    """A moving body of the world on a free joint: a robot's base."""

    name: str
    index: int  # position among the world's bodies
    body_id: int  # MuJoCo body id of the base
    qadr: int  # free joint's qpos address
    vadr: int  # free joint's qvel address
    spawn_z: float
    radius: float  # planar footprint radius, for clearances
    dofs: tuple[int, ...] = ()  # every degree of freedom of the body and its parts


class WorldBuilder:
    """Collects the world's walls and its bodies in one :class:`mujoco.MjSpec`, then
    compiles them into a :class:`SimulatedWorld`."""

    def __init__(
        self, world: World, timestep: float, bodies: int = 1, fastest_mode: float = math.inf
    ) -> None:
        self.world = world
        self.spec = world_spec(world, timestep, bodies, fastest_mode)
        self.windows = bodies
        self._bodies: list[tuple[str, str, float, float]] = []
        self._starts: list[Pose2D] = []

    def attach(self, name: str, base: str, radius: float, sight: float, start: Pose2D) -> None:
        """Register the body ``base`` (already added to :attr:`spec`) as ``name``, with
        its planar footprint ``radius``, the range ``sight`` its sensors see and the pose
        it stands at when the world is built."""
        if any(n == name for n, *_ in self._bodies):
            raise ValueError(f"the world already has a body named {name!r}")
        self._bodies.append((name, base, radius, sight))
        self._starts.append(start)

    def build(self) -> SimulatedWorld:
        """The world, every body standing at its start (call :meth:`SimulatedWorld.start`
        once the bodies' sensors are made)."""
        sim = SimulatedWorld(self.world, self.spec.compile(), self._bodies, self.windows)
        for body, start in zip(sim.bodies.values(), self._starts, strict=True):
            sim.place(body, start)
        return sim


class SimulatedWorld:
    """Physics, contacts, clearances and ray casts of one world and every body in it.

    Deterministic: the same world, bodies, commands and call sequence give bit-identical
    states.
    """

    def __init__(
        self,
        world: World,
        model: mujoco.MjModel,
        bodies: list[tuple[str, str, float, float]],
        windows: int = 1,
    ) -> None:
        self.world = world
        self.model = m = model
        self.data = mujoco.MjData(model)
        self.bodies: dict[str, Body] = {}
        owner = np.full(m.ngeom, FLOOR, dtype=np.int64)
        people: dict[int, int] = {}
        for i in range(m.ngeom):
            name = m.geom(i).name
            if name.startswith(("wall", "pillar")):
                owner[i] = WALL
            elif name.startswith(PERSON_PREFIX):
                k = int(name[len(PERSON_PREFIX) :])
                owner[i] = PERSON - k
                people[k] = i
        self._person_geoms = np.array([people[k] for k in sorted(people)], dtype=np.int64)
        self._people_body = -1
        self._person_leaves = self._people_tree()
        self._people_xy = np.zeros((len(self._person_geoms), 3))  # each one's geom's place
        self._people_armed = len(self._person_geoms) > 0  # someone may touch a body
        self._moves = 0
        self._all_present = False
        geoms = self._person_geoms  # a slice when in a row (they are: one body's)
        in_row = len(geoms) and (np.diff(geoms) == 1).all()
        self._person_slots = slice(int(geoms[0]), int(geoms[-1]) + 1) if in_row else geoms
        self._geom_pos, self._bvh_aabb = m.geom_pos, m.bvh_aabb  # views, kept
        for k, (name, base, radius, _) in enumerate(bodies):
            body_id = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, base)
            joint = int(m.body_jntadr[body_id])
            # the base and every body below it (wheels) belong to it
            tree = {body_id} | {b for b in range(m.nbody) if self._descends(b, body_id)}
            self.bodies[name] = Body(
                name=name,
                index=k,
                body_id=body_id,
                qadr=int(m.jnt_qposadr[joint]),
                vadr=int(m.jnt_dofadr[joint]),
                spawn_z=float(m.body_pos[body_id][2]),
                radius=radius,
                dofs=tuple(int(d) for d in np.flatnonzero(np.isin(m.dof_bodyid, list(tree)))),
            )
            owner[np.isin(m.geom_bodyid, list(tree))] = k
        self._owner = owner  # geom id -> WALL, FLOOR or a body's index
        self._order = list(self.bodies.values())
        radii = m.geom_size[self._person_geoms, 0]  # each body's squared reach for people
        self._person_reach2 = [(radii + b.radius + PERSON_REACH) ** 2 for b in self._order]
        self.walls = Walls(world)
        self.window: WallWindow | None = None
        if uses_wall_slots(world, windows):
            sight = max((s for *_, s in bodies), default=0.0)
            self.window = WallWindow(m, self.walls, world.wall_height, radius=sight + 0.5)
        self._kinematics_at = -math.inf
        self._mirrored: np.ndarray | None = None  # a mirror's touching geom pairs
        self._rays = np.zeros(6, dtype=np.uint8)
        self._rays[[WALL_GROUP, SEEN_GROUP]] = 1
        # A world of many pillars (BARN's) casts its walls in the plane, MuJoCo the bodies.
        self.planar: PlanarWalls | None = None
        if self.window is None and len(world.cylinders) > PILLAR_SLOTS:
            self.planar = PlanarWalls(
                self.walls,
                self._geom_ids("wall_", world.boxes),
                self._geom_ids("pillar_", world.cylinders),
            )
            self._rays[WALL_GROUP] = 0

    def _geom_ids(self, prefix: str, items: list) -> np.ndarray:
        ids = [
            mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_GEOM, f"{prefix}{i}")
            for i in range(len(items))
        ]
        return np.array(ids, dtype=np.int32)

    def _people_tree(self) -> np.ndarray:
        """The people body's bounding-volume tree leaf of each person's geom. MuJoCo keeps
        the tree it compiled and culls contacts with it: its inner boxes are made to cover
        everything once, the leaves follow the people (:meth:`move_people`)."""
        m = self.model
        if not len(self._person_geoms):
            return np.zeros(0, dtype=np.int64)
        body = self._people_body = int(m.geom_bodyid[self._person_geoms[0]])
        if m.body_ipos[body].any() or not np.array_equal(m.body_iquat[body], (1, 0, 0, 0)):
            raise ValueError("the people's body must have the world's frame as its own")
        adr, num = int(m.body_bvhadr[body]), int(m.body_bvhnum[body])
        nodes = np.arange(adr, adr + num)
        geom = m.bvh_nodeid[adr : adr + num]
        m.bvh_aabb[nodes[geom < 0]] = (0.0, 0.0, 0.0, 1e9, 1e9, 1e9)
        leaf = {int(g): int(n) for g, n in zip(geom, nodes, strict=True) if g >= 0}
        return np.array([leaf[int(g)] for g in self._person_geoms], dtype=np.int64)

    def _descends(self, body: int, root: int) -> bool:
        while body > 0:
            if body == root:
                return True
            body = int(self.model.body_parentid[body])
        return False

    # ----------------------------------------------------------------- time
    @property
    def time(self) -> float:
        """Simulated seconds since the start."""
        return float(self.data.time)

    @property
    def dt(self) -> float:
        return float(self.model.opt.timestep)

    def start(self) -> None:
        """Compute the state of the placed bodies (call once every body stands at its start)."""
        self._mirrored = None  # the contacts are this model's own again
        self.follow_window()
        mujoco.mj_forward(self.model, self.data)
        self._kinematics_at = self.time

    def step(self, n: int) -> None:
        """Step the physics ``n`` times (with a wall window, re-centred at least every
        :data:`WINDOW_CHECK_PERIOD` of motion)."""
        chunk = n if self.window is None else max(1, int(WINDOW_CHECK_PERIOD / self.dt))
        while n > 0:
            self.follow_window()
            mujoco.mj_step(self.model, self.data, min(chunk, n))
            n -= chunk

    # ----------------------------------------------------------------- mirroring
    _STATE = int(mujoco.mjtState.mjSTATE_PHYSICS | mujoco.mjtState.mjSTATE_TIME)

    def snapshot(self) -> tuple[np.ndarray, np.ndarray]:
        """What a mirror of this world needs to be it now: the physics state (time,
        positions, velocities) and the geom pairs in contact."""
        state = np.empty(mujoco.mj_stateSize(self.model, self._STATE))
        mujoco.mj_getState(self.model, self.data, state, self._STATE)
        return state, self._touching().copy()

    def mirror(self, snapshot: tuple[np.ndarray, np.ndarray]) -> None:
        """Be the world a :meth:`snapshot` was taken of (another process steps the
        physics; this one senses in it): its state, and its contacts until this world
        computes its own (:meth:`start`)."""
        state, touching = snapshot
        mujoco.mj_setState(self.model, self.data, state, self._STATE)
        self._mirrored = touching
        self._kinematics_at = -math.inf

    def _touching(self) -> np.ndarray:
        """(n, 2) geom ids of the contacts now."""
        if self._mirrored is not None:
            return self._mirrored
        return self.data.contact.geom[: self.data.ncon]

    def follow_window(self) -> None:
        """Re-centre the wall window on the bodies that moved (large worlds)."""
        if self.window is not None and self._order:
            q = self.data.qpos
            centres = np.array([[q[b.qadr], q[b.qadr + 1]] for b in self._order])
            self.window.update(centres)

    # ----------------------------------------------------------------- bodies
    def pose(self, body: Body) -> Pose2D:
        a = body.qadr
        px, py, _, w, x, y, z = self.data.qpos[a : a + 7].tolist()
        return Pose2D(px, py, yaw_from_quaternion(x, y, z, w))

    def velocity(self, body: Body) -> tuple[float, float]:
        """Body-frame forward speed (m/s) and yaw rate (rad/s) of the base frame."""
        qv = self.data.qvel[body.vadr : body.vadr + 6]
        yaw = self.pose(body).yaw
        # Free joint: linear velocity in the world frame, angular velocity in the body frame.
        return float(math.cos(yaw) * qv[0] + math.sin(yaw) * qv[1]), float(qv[5])

    def place(self, body: Body, pose: Pose2D) -> None:
        """Write ``body``'s free joint at ``pose`` (on the floor), at rest."""
        a = body.qadr
        self.data.qpos[a : a + 3] = (pose.x, pose.y, body.spawn_z)
        yaw = wrap_angle(pose.yaw)
        self.data.qpos[a + 3 : a + 7] = (math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2))

    def teleport(self, body: Body, pose: Pose2D) -> None:
        """Put ``body`` at ``pose`` at rest (kidnapping), the rest of the world as it was."""
        self.place(body, pose)
        self.data.qvel[list(body.dofs)] = 0.0
        self.data.qacc_warmstart[:] = 0.0
        self._arm_people()
        self.start()

    # ----------------------------------------------------------------- sensing
    def cast(
        self,
        origin: np.ndarray,
        directions: np.ndarray,
        exclude: Body,
        geomid: np.ndarray,
        dist: np.ndarray,
        cutoff: float,
    ) -> None:
        """Cast ``len(dist)`` rays from ``origin`` along ``directions`` (flat, 3n) into
        ``dist`` (-1: no hit) and ``geomid``, seeing walls and every body but ``exclude``
        (in a world of many pillars, MuJoCo casts only when there are other bodies)."""
        if self.planar is not None and len(self.bodies) == 1 and not len(self._person_geoms):
            dist.fill(-1.0)
            geomid.fill(-1)
        else:
            mujoco.mj_multiRay(
                self.model,
                self.data,
                origin,
                directions,
                self._rays,
                1,  # flg_static: walls live in the world body
                exclude.body_id,
                geomid,
                dist,
                None,  # normal (new in MuJoCo 4.0)
                len(dist),
                cutoff,
            )
        if self.planar is not None:
            self.planar.cast(origin, directions, dist, geomid, cutoff)

    def kinematics(self) -> None:
        """Bring sites and geoms to the current state (once per simulated instant)."""
        if self._kinematics_at != self.time:
            self.follow_window()
            mujoco.mj_kinematics(self.model, self.data)
            self._kinematics_at = self.time

    # ----------------------------------------------------------------- safety
    def contacts(self) -> list[tuple[int, int]]:
        """Every contact between a body and a wall (``(index, WALL)``) or another body
        (``(i, j)``, ``i < j``), the floor and people left out (:meth:`person_contacts`)."""
        touching = self._touching()
        if not len(touching):
            return []
        owner = self._owner[touching]
        found = []
        for a, b in owner.tolist():
            if a < WALL or b < WALL or a == b:  # the floor, a person
                continue
            if a == WALL or b == WALL:
                found.append((max(a, b), WALL))
            else:
                found.append((min(a, b), max(a, b)))
        return found

    def person_contacts(self) -> set[tuple[int, int]]:
        """Every (body index, person index) pair touching now."""
        if not self._people_armed:  # nobody near a body: no contact to look for
            return set()
        touching = self._touching()
        if not len(touching):
            return set()
        found = set()
        for a, b in self._owner[touching].tolist():
            if a >= 0 and b <= PERSON:
                found.add((a, PERSON - b))
            elif b >= 0 and a <= PERSON:
                found.add((b, PERSON - a))
        return found

    # ----------------------------------------------------------------- people
    @property
    def people(self) -> int:
        """How many people bodies the model holds."""
        return len(self._person_geoms)

    def move_people(self, xy: np.ndarray, present: np.ndarray) -> None:
        """Put the people where the crowd says (standing on the floor), those not present
        under it, out of every ray's and chassis' way."""
        if not len(self._person_geoms):
            return
        pos = self._people_xy
        pos[:, 0:2] = xy
        if not self._all_present:  # once everyone is in, they all stand on the floor
            pos[:, 2] = np.where(present, PERSON_HEIGHT / 2, PARKED_Z)
            self._all_present = bool(present.all())
        self._geom_pos[self._person_slots] = pos
        # a cylinder's box is centred on it, in the body's inertial frame (the world's)
        self._bvh_aabb[self._person_leaves, 0:3] = pos
        self._kinematics_at = -math.inf  # the geoms moved: rays need them where they are
        self._moves += 1
        if self._moves % ARM_EVERY == 0 or self._moves == 1:
            self._arm_people()

    def _arm_people(self) -> None:
        """Let only the people near a body collide (the rest could not touch one within a
        control period): with nobody near, the contact search skips the people's body."""
        if not self._moves or not self._order:
            return
        m, q = self.model, self.data.qpos
        xy = self._people_xy
        near = np.zeros(len(xy), dtype=bool)
        for b, reach2 in zip(self._order, self._person_reach2, strict=True):
            dx, dy = xy[:, 0] - q[b.qadr], xy[:, 1] - q[b.qadr + 1]
            near |= dx * dx + dy * dy <= reach2
        near &= xy[:, 2] > 0.0
        m.geom_contype[self._person_geoms] = np.where(near, BODY_BIT, 0)
        self._people_armed = bool(near.any())
        m.body_contype[self._people_body] = BODY_BIT if self._people_armed else 0

    def wall_contacts(self, body: Body) -> int:
        """Contact points between ``body`` and walls/pillars."""
        return sum(1 for k, other in self.contacts() if k == body.index and other == WALL)

    def wall_clearance(self, body: Body) -> float:
        """Planar distance from ``body``'s footprint circle to the nearest wall or pillar
        (negative when overlapping; ``inf`` in an empty world)."""
        p = self.pose(body)
        best = None
        if self.window is not None:
            best = self.window.min_distance(p.x, p.y)
        if best is None:
            best = math.inf
            if len(self.walls.box_c):
                best = min(best, float(self.walls.box_distance(p.x, p.y).min()))
            if len(self.walls.cyl):
                best = min(best, float(self.walls.cyl_distance(p.x, p.y).min()))
        return best - body.radius

    def position(self, index: int) -> tuple[float, float]:
        """The planar position of the body at ``index`` (as :meth:`contacts` numbers them)."""
        q, a = self.data.qpos, self._order[index].qadr
        return float(q[a]), float(q[a + 1])

    def body_gaps(self) -> np.ndarray:
        """(n, n) planar gaps between the bodies' footprint circles (inf on the diagonal)."""
        q = self.data.qpos
        xy = np.array([[q[b.qadr], q[b.qadr + 1]] for b in self._order]).reshape(-1, 2)
        r = np.array([b.radius for b in self._order])
        gaps = np.hypot(*(xy[:, None, :] - xy[None, :, :]).transpose(2, 0, 1)) - r[:, None]
        gaps -= r[None, :]
        np.fill_diagonal(gaps, math.inf)
        return gaps
