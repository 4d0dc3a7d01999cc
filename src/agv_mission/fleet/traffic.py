"""Traffic control by reservations: robots never touch and never wait forever.

Every control step (:meth:`ReservationTraffic.decide`):

1. **Reserve.** Each robot's plan sweeps, over the next ``horizon`` seconds, the prefix
   of its remaining path of ``max_speed * horizon + lookahead`` metres; that prefix
   buffered by the footprint (plus half the ``margin``) is what it asks to reserve.
2. **Grant**, in a fixed priority order (robots stepping aside first, then the fleet's
   order). A robot may advance along its prefix while its body keeps ``margin`` from
   every reservation granted before it and from every other robot's body (or, where it
   is already closer, while it gets no closer). It gets ``go`` with the distance it may
   advance (``limit``), or ``wait`` for the robot whose space it would enter first; what
   it was granted is its reservation.
3. **Find deadlocks** in the wait-for graph (each waiting robot points at its blocker):
   a cycle of waits (two robots facing each other in a one-robot-wide aisle), or a wait
   on a robot that has no plan and will not move (parked, or its tree is done), standing
   for ``deadlock_delay`` seconds; and any wait on the same robot longer than
   ``wait_timeout``.
4. **Break them.** In a cycle, the member with the shortest way out of the others'
   remaining paths ``yield``s: it drives to that detour pose (found by a search over its
   costmap's free cells) and stays there until those paths no longer cross its own, then
   resumes its goal. A robot waiting on a parked robot first ``replan``s around it (the
   parked body as lethal cells); if that does not clear the way within
   ``replan_patience``, the parked robot yields. A wait past ``wait_timeout`` replans
   around the blocker's reservation, then yields.

Every wait, its end, every deadlock broken and every yield's end is an event.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from shapely.geometry import LineString, Point

from agv_mission.fleet.base import (
    FleetEvent,
    TrafficDecision,
    TrafficRobot,
    TrafficUpdate,
)
from agv_mission.fleet.configs import ReservationsConfig
from agv_mission.fleet.detour import Detour, Keepout, find_detour
from agv_mission.fleet.reservations import (
    MIN_GO,
    STEP,
    Grant,
    cover,
    grant_reservations,
    rest_of_path,
)
from agv_mission.geometry import Pose2D

ARRIVED = 0.15  # m from its detour pose a yielding robot counts as there
REPEAT_WINDOW = 30.0  # s within which a cycle seen again is another member's turn
SLACK = 0.05  # m a robot without a goal keeps beyond the margin before it stops stepping aside


@dataclass
class _Yield:
    """A robot stepping aside: for whom, to where, and the way it will resume."""

    to: tuple[str, ...]
    detour: Pose2D
    route: np.ndarray | None  # its own path when asked (None: it had no goal)
    since: float
    reason: str


@dataclass
class _Wait:
    blocker: str
    since: float
    replanned: float | None = None  # when a timeout last made it replan


class ReservationTraffic:
    """The default ``traffic`` plugin (see the module docstring)."""

    Config = ReservationsConfig

    def __init__(self, config: ReservationsConfig | None = None) -> None:
        self.config = config or ReservationsConfig()
        self._yields: dict[str, _Yield] = {}
        self._waits: dict[str, _Wait] = {}
        self._stuck_since: dict[tuple[str, ...], float] = {}  # deadlock key -> first seen
        self._parked_replan: dict[tuple[str, str], float] = {}  # (waiter, parked) -> when
        self._last_t: float | None = None
        self._grants: dict[str, Grant] = {}
        self._last_breaker: dict[tuple[str, ...], tuple[str, float]] = {}  # cycle -> who, when
        self._wait_count = 0
        self._wait_time = 0.0
        self._deadlocks = 0

    # ------------------------------------------------------------------ the step

    def decide(self, t: float, robots: Sequence[TrafficRobot]) -> TrafficUpdate:
        dt = 0.0 if self._last_t is None else max(t - self._last_t, 0.0)
        self._last_t = t
        events: list[FleetEvent] = []
        if len(robots) < 2:  # nobody to meet
            return TrafficUpdate({r.name: TrafficDecision() for r in robots}, events)
        by_name = {r.name: r for r in robots}
        self._forget_gone(by_name)
        self._release_yields(t, by_name, events)
        grants = grant_reservations(robots, self.config, self._yields)
        self._grants = grants
        waiting = {
            name: g.blocker
            for name, g in grants.items()
            if g.blocker is not None and (g.limit or 0.0) < MIN_GO
        }
        self._book_waits(t, dt, waiting, events)
        overrides = self._break_deadlocks(t, by_name, grants, waiting, events)
        decisions = {r.name: self._decision(grants[r.name], overrides) for r in robots}
        return TrafficUpdate(decisions, events)

    def stats(self) -> dict[str, Any]:
        return {
            "waits": {"count": self._wait_count, "time": round(self._wait_time, 3)},
            "deadlocks": self._deadlocks,
        }

    def yielding(self) -> dict[str, Pose2D]:
        """Robots stepping aside now, and their detour poses."""
        return {name: y.detour for name, y in self._yields.items()}

    # ------------------------------------------------------------------ waits

    def _book_waits(
        self, t: float, dt: float, waiting: dict[str, str], events: list[FleetEvent]
    ) -> None:
        for name, w in list(self._waits.items()):
            self._wait_time += dt
            if waiting.get(name) != w.blocker:
                events.append(
                    {
                        "event": "wait_end",
                        "t": round(t, 3),
                        "robot": name,
                        "for": w.blocker,
                        "waited": round(t - w.since, 3),
                    }
                )
                del self._waits[name]
        for name, blocker in waiting.items():
            if name not in self._waits:
                self._waits[name] = _Wait(blocker, t)
                self._wait_count += 1
                events.append({"event": "wait", "t": round(t, 3), "robot": name, "for": blocker})

    # ------------------------------------------------------------------ deadlocks

    def _break_deadlocks(
        self,
        t: float,
        robots: dict[str, TrafficRobot],
        grants: dict[str, Grant],
        waiting: dict[str, str],
        events: list[FleetEvent],
    ) -> dict[str, TrafficDecision]:
        """Decisions that replace the granted ones this step: replans (yields are kept in
        ``self._yields`` and issued from there)."""
        cfg = self.config
        overrides: dict[str, TrafficDecision] = {}
        seen: set[tuple[str, ...]] = set()
        for name in waiting:
            cycle = _cycle_from(name, waiting)
            if cycle is not None:
                key = ("cycle", *sorted(cycle))
            elif self._parked(robots[waiting[name]]):
                key = ("parked", name, waiting[name])
            else:
                continue
            seen.add(key)
            first = self._stuck_since.setdefault(key, t)
            if t - first < cfg.deadlock_delay:
                continue
            if cycle is not None:
                self._break_cycle(t, cycle, robots, events)
                del self._stuck_since[key]
            else:
                self._break_parked(t, name, waiting[name], robots, grants, overrides, events)
        for key in list(self._stuck_since):
            if key not in seen:
                del self._stuck_since[key]
        for name, blocker in waiting.items():
            w = self._waits[name]
            since = w.since if w.replanned is None else w.replanned
            if name in overrides or t - since < cfg.wait_timeout:
                continue
            if w.replanned is None:
                w.replanned = t
                overrides[name] = self._replan(name, [blocker], grants, "wait timeout")
                self._count(events, t, "timeout", [name, blocker], name, "replan")
            else:
                w.replanned = t
                self._ask_to_yield(t, name, [blocker], robots, events, "timeout")
        return overrides

    def _parked(self, robot: TrafficRobot) -> bool:
        """A robot that will not move by itself: no plan, or arrived where it steps aside."""
        y = self._yields.get(robot.name)
        if y is not None:
            return robot.pose.distance_to(y.detour) < ARRIVED
        return robot.path is None or len(robot.path) == 0

    def _break_cycle(
        self,
        t: float,
        cycle: list[str],
        robots: dict[str, TrafficRobot],
        events: list[FleetEvent],
    ) -> None:
        """The member with the shortest way out of the others' paths steps aside (one
        already stepping aside only when no other member can)."""
        best: tuple[float, int, str, Pose2D] | None = None
        free = [n for n in cycle if n not in self._yields] or cycle
        # the same cycle again soon after: another member's turn to step aside
        key = tuple(sorted(cycle))
        last = self._last_breaker.get(key)
        if last is not None and t - last[1] < REPEAT_WINDOW and len(free) > 1:
            free = [n for n in free if n != last[0]] or free
        for name in free:
            others = [robots[o] for o in cycle if o != name]
            detour = self._detour(robots[name], others, robots)
            if detour is not None:
                cand = (detour.distance, -self._index(name, robots), name, detour.pose)
                if best is None or cand < best:
                    best = cand
        if best is None:
            return  # nobody can step aside now; the timeouts try again
        _, _, name, pose = best
        self._last_breaker[key] = (name, t)
        others = tuple(o for o in cycle if o != name)
        self._start_yield(t, robots[name], others, pose, "cycle")
        self._count(events, t, "cycle", cycle, name, "yield", pose)

    def _break_parked(
        self,
        t: float,
        waiter: str,
        parked: str,
        robots: dict[str, TrafficRobot],
        grants: dict[str, Grant],
        overrides: dict[str, TrafficDecision],
        events: list[FleetEvent],
    ) -> None:
        """First a replan round the parked robot; if that does not help, it steps aside."""
        asked = self._parked_replan.get((waiter, parked))
        if asked is None:
            self._parked_replan[(waiter, parked)] = t
            overrides[waiter] = self._replan(waiter, [parked], grants, f"{parked} is parked")
            self._count(events, t, "parked", [waiter, parked], waiter, "replan")
        elif t - asked >= self.config.replan_patience:
            if self._ask_to_yield(t, parked, [waiter], robots, events, "parked"):
                del self._parked_replan[(waiter, parked)]
            else:  # nowhere to go now: replan again, and ask again after the patience
                self._parked_replan[(waiter, parked)] = t
                overrides[waiter] = self._replan(waiter, [parked], grants, f"{parked} is parked")

    def _ask_to_yield(
        self,
        t: float,
        name: str,
        to: list[str],
        robots: dict[str, TrafficRobot],
        events: list[FleetEvent],
        kind: str,
    ) -> bool:
        robot = robots[name]
        held = self._yields.get(name)
        keep = list(dict.fromkeys([*(held.to if held else ()), *to]))
        detour = self._detour(robot, [robots[o] for o in keep if o in robots], robots)
        if detour is None:
            return False
        self._start_yield(t, robot, tuple(keep), detour.pose, kind)
        self._count(events, t, kind, [name, *to], name, "yield", detour.pose)
        return True

    def _start_yield(
        self, t: float, robot: TrafficRobot, to: tuple[str, ...], pose: Pose2D, reason: str
    ) -> None:
        held = self._yields.get(robot.name)
        route = held.route if held is not None else None
        if held is None and not robot.idle and robot.path is not None and len(robot.path):
            route = np.asarray(robot.path, dtype=float).copy()
        since = held.since if held is not None else t
        self._yields[robot.name] = _Yield(to, pose, route, since, reason)

    def _detour(
        self,
        robot: TrafficRobot,
        away_from: list[TrafficRobot],
        robots: dict[str, TrafficRobot],
    ) -> Detour | None:
        """Where ``robot`` keeps clear of ``away_from``'s remaining paths and every body;
        out of the other robots' reserved space too, where such a place is in reach."""
        if robot.costmap is None:
            return None
        keep_clear = [Keepout(_route_of(o), o.radius) for o in away_from]
        bodies = [
            Keepout(np.array([[o.pose.x, o.pose.y]]), o.radius)
            for o in robots.values()
            if o.name != robot.name
        ]
        skip = {robot.name, *(o.name for o in away_from)}
        reserved = [
            Keepout(g.pts, g.robot.radius)
            for name, g in self._grants.items()
            if name not in skip and len(g.pts) > 1
        ]
        for extra in [reserved, []] if reserved else [[]]:
            found = find_detour(
                robot.costmap,
                robot.pose,
                robot.radius,
                keep_clear + extra,
                bodies,
                self.config.margin + SLACK,
                self.config.detour_radius,
            )
            if found is not None:
                return found
        return None

    def _replan(
        self, name: str, around: list[str], grants: dict[str, Grant], reason: str
    ) -> TrafficDecision:
        """Plan again with the others' granted reservations as lethal cells (the robot
        itself keeps ``margin / 2`` from them, so its own cell stays free)."""
        polygons = tuple(
            region.polygon() for o in around if (region := grants[o].region) is not None
        )
        return TrafficDecision(
            "replan",
            avoid=cover(polygons, STEP),
            avoid_polygons=polygons,
            blocker=around[0],
            reason=reason,
        )

    def _count(
        self,
        events: list[FleetEvent],
        t: float,
        kind: str,
        robots: list[str],
        breaker: str,
        action: str,
        detour: Pose2D | None = None,
    ) -> None:
        self._deadlocks += 1
        event: FleetEvent = {
            "event": "deadlock",
            "t": round(t, 3),
            "kind": kind,
            "robots": list(robots),
            "robot": breaker,
            "action": action,
        }
        if detour is not None:
            event["detour"] = {
                "x": round(detour.x, 3),
                "y": round(detour.y, 3),
                "yaw": round(detour.yaw, 3),
            }
        events.append(event)

    @staticmethod
    def _index(name: str, robots: dict[str, TrafficRobot]) -> int:
        return list(robots).index(name)

    # ------------------------------------------------------------------ yields

    def _release_yields(
        self, t: float, robots: dict[str, TrafficRobot], events: list[FleetEvent]
    ) -> None:
        """A robot stops stepping aside once the robots it made way for no longer cross
        its own route (or its body, when it has no goal), or after ``yield_timeout``."""
        cfg = self.config
        for name, y in list(self._yields.items()):
            me = robots[name]
            here = np.array([[me.pose.x, me.pose.y]])
            # its way back: from where it stands to where it left its route, then the route
            mine = here if y.route is None else np.concatenate([here, y.route])
            keep = me.radius + cfg.margin + (0.0 if y.route is not None else SLACK)
            # a robot with a goal first gets to its detour: released on the way, it
            # would turn back into the robot it made way for
            there = y.route is None or me.pose.distance_to(y.detour) < ARRIVED
            clear = there and all(
                o not in robots
                or robots[o].path is None
                or len(robots[o].path) == 0
                or not _crosses(robots[o], mine, keep)
                for o in y.to
            )
            if clear or t - y.since >= cfg.yield_timeout:
                del self._yields[name]
                events.append(
                    {
                        "event": "yield_end",
                        "t": round(t, 3),
                        "robot": name,
                        "for": list(y.to),
                        "waited": round(t - y.since, 3),
                    }
                )

    # ------------------------------------------------------------------ out

    def _decision(self, g: Grant, overrides: dict[str, TrafficDecision]) -> TrafficDecision:
        name = g.robot.name
        if name in overrides:
            return overrides[name]
        y = self._yields.get(name)
        if y is not None:
            return TrafficDecision(
                "yield",
                limit=g.limit,
                detour=y.detour,
                blocker=y.to[0] if y.to else None,
                reason=y.reason,
            )
        if g.limit is not None and g.limit < MIN_GO:
            return TrafficDecision("wait", limit=0.0, blocker=g.blocker, reason="reserved")
        if g.limit is not None:
            return TrafficDecision("go", limit=g.limit, blocker=g.blocker, reason="reserved")
        return TrafficDecision()

    def _forget_gone(self, robots: dict[str, TrafficRobot]) -> None:
        for table in (self._yields, self._waits):
            for name in [n for n in table if n not in robots]:
                del table[name]


# ---------------------------------------------------------------------- geometry helpers


def _route_of(robot: TrafficRobot) -> np.ndarray:
    """A robot's remaining path from where it stands (its position when it has none)."""
    here = np.array([[robot.pose.x, robot.pose.y]])
    if robot.path is None or len(robot.path) == 0:
        return here
    return np.concatenate([here, rest_of_path(robot.path, here[0])])


def _crosses(other: TrafficRobot, route: np.ndarray, keep: float) -> bool:
    """Does ``other``'s remaining path come within its radius + ``keep`` of ``route``?"""
    theirs = _route_of(other)
    a = LineString(theirs) if len(theirs) > 1 else Point(theirs[0])
    b = LineString(route) if len(route) > 1 else Point(route[0])
    return bool(a.distance(b) < other.radius + keep)


def _cycle_from(start: str, waits: dict[str, str]) -> list[str] | None:
    """The cycle of the wait-for graph ``start`` is on, if it is on one."""
    path: list[str] = []
    at: str | None = start
    while at is not None and at not in path:
        path.append(at)
        at = waits.get(at)
    if at is None or at != start:
        return None
    return path
