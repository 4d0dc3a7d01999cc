"""People walking in the world: ORCA (RVO2, through ``pyrvo``) moves them around each other,
the robots and the walls; a route on the map's free space tells each where to go.

The pedestrian model is the operational level of the pedestrian-dynamics literature
(van den Berg et al., "Reciprocal n-body collision avoidance", 2011): each step, every
person takes the velocity closest to its preferred one that stays collision-free with its
neighbours and the walls for ``TIME_HORIZON`` seconds. Robots enter as agents whose pose
and velocity the world sets every step. The strategic level (where to go) is ours: wander
goals drawn from the seed inside an area, or a looping route; the way to a goal is the
shortest path on a coarse grid of the free space (:mod:`~agv_mission.world.walking_routes`),
pulled taut where the walls allow; the walls are the map's walkable space's outline
(:mod:`~agv_mission.world.walkable`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np
import pyrvo

from agv_mission.maps.grid import OccupancyGrid
from agv_mission.world.people_groups import ROBOT_MARGIN, PeopleGroup, clear_of_robots, place_people
from agv_mission.world.walkable import clearance, wall_obstacles
from agv_mission.world.walking_routes import route_grid

if TYPE_CHECKING:
    from agv_mission.world.simulation import SimulatedWorld

# ORCA's parameters for walking people: RVO2's examples use 1.5-2 s horizons and about 10
# neighbours; a person notices others a few metres away. Measured (50 people, warehouse):
# a 3 m neighbourhood, 8 neighbours and a 0.5 s wall horizon step about 20 % cheaper
# than 4 m / 10 / 1 s.
NEIGHBOR_DIST = 3.0  # m
MAX_NEIGHBORS = 8
TIME_HORIZON = 2.0  # s, people
TIME_HORIZON_OBST = 0.5  # s, walls
SPEED_HEADROOM = 1.2  # a person may briefly walk this much faster than preferred to avoid
WALL_SLACK = 0.05  # m a person's body may lean into a wall (a map cell: the outline's own error)


REACHED = 0.5  # m: a waypoint on the way counts as passed
ARRIVED = 0.3  # m: a goal counts as reached
REPLAN_PERIOD = 2.0
# s between a person's decisions (an ORCA step): they walk the decided velocity in between.
# RVO2's own examples step 0.25 s; 0.2 s halves the crowd's cost against 0.1 s (the control
# period), its step being most of what people cost a run.
DECISION_PERIOD = 0.2
MAX_WAYS = 10_000  # ways between goals kept (24 goals a group: 576 a group)
PERTURBATION = (
    0.01  # m/s (standard deviation) of random push on each preferred velocity (RVO2's examples)
)
STALL_SPEED = 0.2  # of the preferred speed: below it a person is held up...
STALL_TIME = 1.0  # s ... and after this long bears right
SIDESTEP = np.pi / 4  # rad a held-up person turns their way to the right
_BEAR_RIGHT = complex(np.cos(-SIDESTEP), np.sin(-SIDESTEP))


class Crowd:
    """The people of a run: built from resolved ``PeopleGroup``\\ s, the map's walkable
    space and the run's random generator; ``step`` moves them one control period.
    ``robots``: rows (x, y, radius) of the robots' footprints at the start, kept clear of
    everyone's start."""

    def __init__(
        self,
        groups: Sequence[PeopleGroup],
        grid: OccupancyGrid,
        rng: np.random.Generator,
        time_step: float = 0.1,
        decision_period: float = DECISION_PERIOD,
        robots: np.ndarray | None = None,
    ):
        self.rng = rng
        # the robots' footprints (x, y, radius): at the start, then as last decided among
        self._robot_discs = np.zeros((0, 3)) if robots is None else np.asarray(robots, float)
        self.time = 0.0
        specs = [g for g in groups for _ in range(g.count)]
        n = len(specs)
        self.ids = np.arange(n, dtype=np.int64)
        self.radii = np.array([s.radius for s in specs], dtype=float)
        self.speeds = np.array([s.speed for s in specs], dtype=float)
        self.start_times = np.array([s.start_time for s in specs], dtype=float)
        self.positions = np.zeros((n, 2))
        self.velocities = np.zeros((n, 2))
        # Points and velocities of the plane as complex numbers too (views of the same
        # memory): a decision's arithmetic in half the array operations (the crowd's step
        # measured 3 % cheaper; the same walks to 1e-14 m).
        self._p, self._v = _plane(self.positions), _plane(self.velocities)
        self.active = np.zeros(n, dtype=bool)
        self._grid = grid
        # the clearance with a border of -inf: a lookup needs no bounds check (off the map)
        self._room = np.pad(clearance(grid), 1, constant_values=-np.inf)
        self._stall = STALL_SPEED * self.speeds  # each person's held-up speed
        self._wall_room = self.radii - WALL_SLACK  # a step ending nearer a wall is refused
        self._dt = time_step
        self.decision_period = decision_period
        self._to = np.zeros((n, 2))  # where everyone will be at the next decision...
        self._t = _plane(self._to)
        self._walk = np.zeros(n, dtype=complex)  # ... and how far they walk a step there
        self._steps_left = 0  # steps of the decided walk still to walk
        self.decisions = 0  # ORCA steps so far (the velocities change with each)
        routers = {r: route_grid(grid, r) for r in sorted({g.radius for g in groups})}
        self._routers = [routers[s.radius] for s in specs]  # each person's (by its size)
        self._sim = pyrvo.RVOSimulator(
            time_step, NEIGHBOR_DIST, MAX_NEIGHBORS, TIME_HORIZON, TIME_HORIZON_OBST, 0.25, 1.5
        )
        for vertices in wall_obstacles(grid):
            self._sim.add_obstacle(vertices)
        self._sim.process_obstacles()
        self._agent = np.full(n, -1, dtype=np.int64)  # RVO2 index once a person is in
        self._robot_agents: list[int] = []
        self._goals: list[list[int]] = []  # each person's goal cells (route: in order)
        self._goal_index = np.zeros(n, dtype=np.int64)
        self._waypoints: list[np.ndarray] = [np.zeros((0, 2))] * n
        self._waypoint = np.zeros(n, dtype=np.int64)
        self._target = np.zeros((n, 2))  # each person's current waypoint
        self._g = _plane(self._target)
        self._final = np.zeros(n, dtype=bool)  # ... is its goal
        self._reach = np.full(n, REACHED)  # ... counts as reached this near
        self._next_check = np.zeros(n)
        self._ways: dict[tuple[int, int | None, int], np.ndarray] = {}  # goal to goal, kept
        self._slow_since = np.full(n, np.inf)  # since when each walks slower than it wants
        self._exact: dict[int, np.ndarray] = {}  # goal cells that stand for a given point
        self._on_route = np.array([s.behaviour == "route" for s in specs], dtype=bool)
        self._inattentive = np.array([not s.attentive for s in specs], dtype=bool)
        self._blind = bool(self._inattentive.any())
        self._agents: list[int] = []  # RVO2 indices of the people in, in order (cached)
        plan = place_people(groups, self._routers, rng, self._robot_discs, self._room_at)
        self.positions[:] = plan.positions
        self._goals = plan.goals
        self._goal_index[:] = plan.goal_index
        self._exact.update(plan.exact)
        for i in np.flatnonzero(self.start_times <= 0.0):  # in the world from the start
            self._enter(int(i))

    @classmethod
    def in_world(
        cls, groups: Sequence[PeopleGroup], world: SimulatedWorld, rng: np.random.Generator
    ) -> Crowd:
        """The crowd of ``world``'s map, everyone's start kept clear of the world's robots
        where they stand, its people standing in the world from the start."""
        robots = np.array(
            [(*world.pose(b).xy, b.radius) for b in world.bodies.values()], dtype=float
        ).reshape(-1, 3)
        crowd = cls(groups, world.world.map, rng, robots=robots)
        world.move_people(crowd.positions, crowd.active)
        return crowd

    @property
    def deciding(self) -> bool:
        """Whether the next step decides (ORCA): only then does it look at the robots."""
        return self._steps_left <= 0

    @property
    def everyone(self) -> bool:
        """Whether everyone has entered the world."""
        return len(self._agents) == len(self.active)

    # -- set up ------------------------------------------------------------------------

    # -- walking -----------------------------------------------------------------------

    def _next_goal(self, i: int) -> None:
        """The person's next goal: the next route point, or a fresh wander goal."""
        goals = self._goals[i]
        if not goals:
            self._waypoints[i] = self.positions[i : i + 1].copy()
            self._set_waypoint(i, 0)
            return
        reached = goals[int(self._goal_index[i])]
        if self._on_route[i]:
            self._goal_index[i] = (self._goal_index[i] + 1) % len(goals)
        else:
            self._goal_index[i] = int(self.rng.integers(len(goals)))
        self._route_to(i, goals[int(self._goal_index[i])], reached)

    def _route_to(self, i: int, goal: int, reached: int | None = None) -> None:
        """Waypoints from the person's position to ``goal``, pulled taut; the way from a
        goal just ``reached`` to the next (wanderers, routes) is worked out once and kept."""
        router = self._routers[i]
        start = reached if reached is not None else router.node(self.positions[i])
        key = (id(router), start, goal)
        known = self._ways.get(key)
        if known is not None:
            self._waypoints[i] = known
            self._set_waypoint(i, 0)
            return
        radius = float(self.radii[i])
        end = self._exact.get(goal)
        if end is None:
            end = router.points[goal]
        if self._sim.query_visibility(self.positions[i].tolist(), end.tolist(), radius):
            self._waypoints[i] = end[None, :].copy()  # in sight: straight there
        else:
            path = None if start is None else router.path(start, goal)
            if path is None:  # cut off (a door shut by a robot's body is not a wall): stand
                path = self.positions[i : i + 1].copy()
            else:
                path[-1] = end
            self._waypoints[i] = self._taut(self.positions[i], path, radius)
        self._set_waypoint(i, 0)
        if reached is not None and len(self._ways) < MAX_WAYS:
            self._ways[key] = self._waypoints[i]

    def _taut(self, start: np.ndarray, path: np.ndarray, radius: float) -> np.ndarray:
        """The path's corners only: from each kept point, the farthest point in sight."""
        visible = self._sim.query_visibility
        points = path.tolist()
        kept = []
        here = start.tolist()
        i = 0
        last = len(points) - 1
        while i < last:
            j = last
            step = max(1, (last - i) // 8)
            while j > i + 1 and not visible(here, points[j], radius):
                j = max(i + 1, j - step)
            kept.append(points[j])
            here, i = points[j], j
        if not kept:
            kept.append(points[-1])
        return np.array(kept)

    def step(self, dt: float, robots: np.ndarray | None = None) -> None:
        """Advance everyone ``dt`` seconds; ``robots`` rows are (x, y, vx, vy, radius) in
        the map frame, the robots' true poses and velocities this step. People decide
        (ORCA) every ``decision_period`` (a whole number of steps) and walk the decided
        velocity over it, a step at a time."""
        if len(self._agents) < len(self.active):
            for i in np.flatnonzero(~self.active & (self.start_times <= self.time + 1e-9)):
                if clear_of_robots(self.positions[i], float(self.radii[i]), 0.0, self._robot_discs):
                    self._enter(int(i))  # stands where they enter until the next decision
        if self._steps_left <= 0:
            self._decide(dt, robots)
        if self._steps_left == 1:  # the decided walk's end: where ORCA put everyone
            self.positions[:] = self._to
        else:
            self._p += self._walk
        self._steps_left -= 1
        self.time += dt

    def _decide(self, dt: float, robots: np.ndarray | None) -> None:
        """One ORCA step of ``decision_period`` from where everyone is now: where each
        will be at its end (``_to``) and the velocity that takes them there."""
        sim = self._sim
        self.decisions += 1
        steps = self._steps_left = max(1, round(self.decision_period / dt))
        period = steps * dt
        if abs(self._dt - period) > 1e-12:
            sim.set_time_step(period)
            self._dt = period
        self._set_robots(np.zeros((0, 5)) if robots is None else np.asarray(robots, float))
        if not self._agents:
            sim.do_step()  # robots alone: keep the simulator's clock with the world's
            self._to[:] = self.positions
            self._walk[:] = 0.0
            return
        everyone = self.everyone
        people = self.ids if everyone else np.flatnonzero(self.active)
        who = slice(None) if everyone else people  # views, not copies, when all are in
        pref = self._steer(people, who)
        before = self._p[who].copy()
        sim.do_step()
        # pyrvo has no call for many agents: one C call per person (map: no Python frame)
        self._to[who] = list(map(pyrvo.Vector2.to_tuple, map(sim.get_agent_position, self._agents)))
        if self._blind:
            self._walk_blind(people, before, pref, period)
        self._keep_off_robots(people, who, before, period)
        self._keep_off_walls(people, who, before)
        # RVO2 moves each agent by its new velocity times the step: no need to ask for it
        gone = self._t[who] - before
        self._walk[who] = gone / steps
        self._v[who] = v = gone / period
        going = np.abs(v) >= self._stall[who]
        final = self._final[who]
        if final.any():
            going |= final & (np.abs(self._g[who] - self._t[who]) < 2 * ARRIVED)
        self._slow_since[who] = np.where(
            going, np.inf, np.minimum(self._slow_since[who], self.time)
        )

    def _enter(self, i: int) -> None:
        r = float(self.radii[i])
        self._agent[i] = self._sim.add_agent(
            list(self.positions[i]),
            NEIGHBOR_DIST,
            MAX_NEIGHBORS,
            TIME_HORIZON,
            TIME_HORIZON_OBST,
            r,
            float(self.speeds[i] * SPEED_HEADROOM),
        )
        self.active[i] = True
        self._agents = self._agent[self.active].tolist()
        self._to[i] = self.positions[i]
        self._walk[i] = 0.0
        self._next_check[i] = self.time + REPLAN_PERIOD * (1 + i % 10) / 10
        goals = self._goals[i]
        if not goals:
            self._next_goal(i)  # nowhere to go: stands
            return
        if not self._on_route[i]:  # a wanderer's first goal; a route starts on its leg
            self._goal_index[i] = int(self.rng.integers(len(goals)))
        self._route_to(i, goals[int(self._goal_index[i])])

    def _set_robots(self, robots: np.ndarray) -> None:
        sim = self._sim
        self._robot_discs = robots[:, (0, 1, 4)]
        while len(self._robot_agents) < len(robots):
            self._robot_agents.append(sim.add_agent([1e6, 1e6 + 10 * len(self._robot_agents)]))
        for k, a in enumerate(self._robot_agents):
            if k < len(robots):
                x, y, vx, vy, r = robots[k].tolist()
                sim.set_agent_position(a, (x, y))
                sim.set_agent_velocity(a, (vx, vy))
                sim.set_agent_pref_velocity(a, (vx, vy))
                sim.set_agent_radius(a, r + ROBOT_MARGIN)
            else:  # a robot gone from the world: far away, out of everyone's sight
                sim.set_agent_position(a, (1e6, 1e6 + 10 * k))
                sim.set_agent_velocity(a, (0.0, 0.0))
                sim.set_agent_pref_velocity(a, (0.0, 0.0))

    def _steer(self, people: np.ndarray, who: slice | np.ndarray) -> np.ndarray:
        """Each walking person's preferred velocity (complex): towards its waypoint at its
        speed (slowing into its goal); ``who`` selects ``people`` from the arrays."""
        here = self._p[who]
        delta = self._g[who] - here
        dist = np.abs(delta)
        slow = self._slow_since[who]
        # a waypoint reached, or someone held up (pushed aside, maybe out of its sight) due
        # for a look at its way
        due = (dist < self._reach[who]) | ((self._next_check[who] <= self.time) & (slow < np.inf))
        if due.any():
            for i in people[due].tolist():
                self._advance(i)
            delta = self._g[who] - here
            dist = np.abs(delta)
        speeds = self.speeds[who]
        speed = np.where(self._final[who], np.minimum(speeds, dist), speeds)
        pref = delta * (speed / np.maximum(dist, 1e-9))
        # ORCA stalls in perfect symmetry (head on into someone standing): RVO2's own
        # examples perturb the preferred velocities a little; one held up for a while
        # also bears right, as people do.
        blocked = slow <= self.time - STALL_TIME
        if blocked.any():
            pref[blocked] *= _BEAR_RIGHT
        pref += _plane(self.rng.normal(0.0, PERTURBATION, (len(pref), 2)))
        xy = pref.view(np.float64).reshape(-1, 2).tolist()
        list(map(self._sim.set_agent_pref_velocity, self._agents, xy))
        return pref

    def _advance(self, i: int) -> None:
        """Pass reached waypoints; a reached goal draws the next; one lost from sight
        (pushed aside by a crowd or a robot) is planned anew."""
        x, y = self.positions[i].tolist()
        points = self._waypoints[i]
        k = int(self._waypoint[i])
        last = len(points) - 1
        px, py = points[k].tolist()
        while k < last and math.hypot(px - x, py - y) < REACHED:
            k += 1
            px, py = points[k].tolist()
        self._set_waypoint(i, k)
        if k == last and math.hypot(px - x, py - y) < ARRIVED:
            self._next_goal(i)
            return
        if self.time >= self._next_check[i]:
            self._next_check[i] = self.time + REPLAN_PERIOD
            radius = float(self.radii[i]) * 0.9
            if not self._sim.query_visibility([x, y], [px, py], radius):
                goals = self._goals[i]
                if goals:
                    self._route_to(i, goals[int(self._goal_index[i])])

    def _set_waypoint(self, i: int, k: int) -> None:
        self._waypoint[i] = k
        self._target[i] = self._waypoints[i][k]
        self._final[i] = final = k == len(self._waypoints[i]) - 1
        self._reach[i] = ARRIVED if final else REACHED

    def _room_at(self, points: np.ndarray) -> np.ndarray:
        """Distance from each point to the nearest wall or unknown cell, m (-inf off the map)."""
        grid = self._grid
        if grid.origin.yaw != 0.0:
            rows, cols = grid.world_to_cell(points)
        else:  # the same cells, a few array operations fewer (every step, everyone)
            cell = np.floor((points - (grid.origin.x, grid.origin.y)) / grid.resolution)
            cols, rows = cell.astype(np.int64).T
        # off the map: clipped onto the border of -inf
        flat = np.ravel_multi_index((rows + 1, cols + 1), self._room.shape, mode="clip")
        return self._room.ravel().take(flat)

    def _walk_blind(
        self, people: np.ndarray, before: np.ndarray, pref: np.ndarray, dt: float
    ) -> None:
        """The inattentive walk their preferred velocity whatever ORCA says (others still
        avoid them: they are agents whose step is set)."""
        blind = self._inattentive[people]
        for j in np.flatnonzero(blind):
            i = int(people[j])
            self._put(i, complex(before[j] + pref[j] * dt), complex(pref[j]))

    def _keep_off_robots(
        self, people: np.ndarray, who: slice | np.ndarray, before: np.ndarray, period: float
    ) -> None:
        """The guard beside ORCA for robots: ORCA shares the avoidance between two agents,
        but a robot's agent never takes its half (the robot drives its own way), and in a
        squeeze between a robot and a wall people gave up the robot's room first (they came
        0.12-0.15 m from a waffle's footprint in a doorway). A step that ends nearer a
        robot's footprint than ``ROBOT_MARGIN``, and nearer than the person was, loses its
        part towards the robot (they walk past, not into it); still nearer, it is refused.
        An inattentive person's step stops only at the robot's body: they bump into it,
        they do not shove it."""
        discs = self._robot_discs
        if not len(discs):
            return
        to = self._t[who]
        room = self.radii[who] + np.where(self._inattentive[who], 0.0, ROBOT_MARGIN)
        changed = np.zeros(len(to), dtype=bool)
        for x, y, r in discs.tolist():
            c = complex(x, y)
            need = room + r
            near = np.abs(to - c) < need
            if not near.any():
                continue
            gap = np.abs(before - c)
            j = np.flatnonzero(near & (np.abs(to - c) < gap))
            if not len(j):
                continue
            away = (before[j] - c) / np.maximum(gap[j], 1e-9)  # from the robot, unit
            towards = ((to[j] - before[j]) * away.conjugate()).real  # < 0: closing in
            there = to[j] - np.minimum(towards, 0.0) * away
            refused = np.abs(there - c) < np.minimum(gap[j], need[j])
            to[j] = np.where(refused, before[j], there)
            changed[j] = True
        if not changed.any():
            return
        for j in np.flatnonzero(changed).tolist():
            self._put(int(people[j]), complex(to[j]), complex(to[j] - before[j]) / period)

    def _keep_off_walls(
        self, people: np.ndarray, who: slice | np.ndarray, before: np.ndarray
    ) -> None:
        """The guard under ORCA: a step that would end with the person's body further into
        a wall than WALL_SLACK, and further in than before, is refused (they stay put; a
        step out is always allowed; a guard at half their radius let people stand 12 cm
        into a wall, one refusing any step in stalled them there)."""
        room = self._room_at(self._to[who])
        deep = np.flatnonzero(room < self._wall_room[who])
        if not len(deep):
            return
        deeper = room[deep] < self._room_at(before[deep].view(np.float64).reshape(-1, 2))
        for j in deep[deeper].tolist():
            self._put(int(people[j]), complex(before[j]), 0j)

    def _put(self, i: int, at: complex, velocity: complex) -> None:
        """Person ``i`` ends the decided walk at ``at`` with ``velocity`` (a guard moved
        them from where ORCA put them): so in ORCA too."""
        self._t[i] = at
        a = int(self._agent[i])
        self._sim.set_agent_position(a, (at.real, at.imag))
        self._sim.set_agent_velocity(a, (velocity.real, velocity.imag))


def _plane(xy: np.ndarray) -> np.ndarray:
    """(n, 2) float64 points (C-ordered) as n complex numbers sharing their memory."""
    return xy.view(np.complex128)[:, 0]
