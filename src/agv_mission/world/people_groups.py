"""The people of a run by group: :class:`PeopleGroup` (one ``people:`` entry, resolved to
the map frame) and where each person starts and which goals they walk to, drawn from the
run's generator (:func:`place_people`): wanderers on free cells of their area away from
each other, a route's people spread round its loop, nobody within a robot's reach.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np

from agv_mission.world.walking_routes import RouteGrid

#: m people keep from a machine on top of its footprint (they give AGVs room)
ROBOT_MARGIN = 0.3
# m more between a person's start and a robot's footprint than ROBOT_MARGIN: nobody starts
# in (or at) a robot's reach; someone due to enter where a robot stands waits until it left
START_GAP = 0.3
# Wander goals: a pool per group drawn from the seed (each costs one routing tree, kept).
WANDER_GOALS_MIN, WANDER_GOALS_MAX = 8, 24


@dataclass(frozen=True)
class PeopleGroup:
    """One ``people:`` entry, resolved to the map frame: ``count`` people who wander inside
    ``area`` or walk ``route`` round and round."""

    count: int
    behaviour: Literal["wander", "route"]
    area: tuple[tuple[float, float], ...] = ()  # wander: the polygon they walk in
    route: tuple[tuple[float, float], ...] = ()  # route: the points, in order, looping
    speed: float = 1.2  # m/s preferred
    radius: float = 0.25  # m
    start_time: float = 0.0  # s: absent from the world before
    attentive: bool = True  # False: walks its way as if nobody were there


@dataclass
class StartPlan:
    """Where everyone starts and walks: positions (n, 2), each person's goal cells (a
    route's in order), the goal each walks to first, and goal cells that stand for a
    given point (a route's points)."""

    positions: np.ndarray
    goals: list[list[int]]
    goal_index: np.ndarray
    exact: dict[int, np.ndarray]


def place_people(
    groups: Sequence[PeopleGroup],
    routers: Sequence[RouteGrid],
    rng: np.random.Generator,
    discs: np.ndarray,
    room_at: Callable[[np.ndarray], np.ndarray],
) -> StartPlan:
    """Start positions and goals of everyone in ``groups``, all drawn from the run's
    generator; ``routers``: each person's routing grid, ``discs``: the robots' footprints
    (rows x, y, radius), ``room_at``: each point's distance to the nearest wall."""
    n = sum(g.count for g in groups)
    plan = StartPlan(np.zeros((n, 2)), [], np.zeros(n, dtype=np.int64), {})
    k = 0
    for group in groups:
        if group.count == 0:
            continue
        router = routers[k]
        if group.behaviour == "route":
            points = np.array(group.route, dtype=float)
            cells = [router.node(p) for p in points]
            goals = [c for c in cells if c is not None]
            exact = {c: p for c, p in zip(cells, points, strict=True) if c is not None}
            plan.exact.update(exact)  # walk to the route's points, not their cells
            for j in range(group.count):
                start, leg = _route_start(points, j / group.count, group.radius, discs)
                if room_at(start[None, :])[0] < group.radius:
                    cell = router.node(start)  # a corner cut by the loop: the nearest cell
                    if cell is not None:
                        start = router.points[cell].copy()
                plan.positions[k] = start
                plan.goals.append(goals)
                plan.goal_index[k] = leg % max(1, len(goals))
                k += 1
            continue
        pool = router.cells_within(group.area)
        if pool.size == 0:
            raise ValueError(f"no walkable space for a {group.radius:g} m person in the area")
        taken = plan.positions[:k]
        size = min(len(pool), max(WANDER_GOALS_MIN, 2 * group.count), WANDER_GOALS_MAX)
        goals = [int(c) for c in rng.choice(pool, size=size, replace=False)]
        centres = router.points[pool]
        clear = clear_of_robots(centres, group.radius, START_GAP, discs)
        if clear.any():  # else a robot fills the area: start where it least is
            centres = centres[clear]
        for _ in range(group.count):
            plan.positions[k] = _free_start(centres, taken, group.radius, rng)
            taken = plan.positions[: k + 1]
            plan.goals.append(goals)
            k += 1
    return plan


def clear_of_robots(points: np.ndarray, radius: float, gap: float, discs: np.ndarray) -> np.ndarray:
    """Which of ``points`` a person of ``radius`` may stand on: more than ROBOT_MARGIN
    and ``gap`` from every robot's footprint (``discs``: rows x, y, radius)."""
    points = np.asarray(points, dtype=float)
    if not len(discs):
        return np.ones(points.shape[:-1], dtype=bool)
    d = (
        np.hypot(points[..., None, 0] - discs[:, 0], points[..., None, 1] - discs[:, 1])
        - discs[:, 2]
    )
    return (d > radius + ROBOT_MARGIN + gap).all(axis=-1)


def _route_start(
    points: np.ndarray, fraction: float, radius: float, discs: np.ndarray
) -> tuple[np.ndarray, int]:
    """Where on the loop a route's person starts: ``fraction`` of the way round, or on
    from there to the first place clear of the robots (steps of a tenth of a metre)."""
    ends = np.roll(points, -1, axis=0)
    total = float(np.hypot(*(ends - points).T).sum()) if len(points) > 1 else 0.0
    step = 0.1 / total if total > 0.0 else 1.0
    at = fraction
    for _ in range(max(1, int(1.0 / step))):
        start, leg = _along_loop(points, at % 1.0)
        if clear_of_robots(start, radius, START_GAP, discs):
            return start, leg
        at += step
    return _along_loop(points, fraction)  # the whole loop near a robot: as placed


def _free_start(
    centres: np.ndarray, taken: np.ndarray, radius: float, rng: np.random.Generator
) -> np.ndarray:
    """A random one of the pool's cell ``centres`` not overlapping anyone placed so far
    (the best of a few draws when the area is crowded)."""
    best, best_gap = centres[0], -np.inf
    for _ in range(20):
        point = centres[rng.integers(len(centres))]
        gap = np.min(np.hypot(*(taken - point).T), initial=np.inf) - 2 * radius
        if gap > 0.1:
            return point
        if gap > best_gap:
            best, best_gap = point, gap
    return best


def _along_loop(points: np.ndarray, fraction: float) -> tuple[np.ndarray, int]:
    """The point ``fraction`` of the way round the closed polyline ``points`` and the index
    of the point it walks to next."""
    if len(points) == 1:
        return points[0].copy(), 0
    ends = np.roll(points, -1, axis=0)
    lengths = np.hypot(*(ends - points).T)
    total = float(lengths.sum())
    if total <= 0.0:
        return points[0].copy(), 1 % len(points)
    at = fraction * total
    cumulative = np.concatenate([[0.0], np.cumsum(lengths)])
    leg = int(np.searchsorted(cumulative, at, side="right") - 1)
    leg = min(leg, len(points) - 1)
    t = (at - cumulative[leg]) / max(lengths[leg], 1e-12)
    return points[leg] + t * (ends[leg] - points[leg]), (leg + 1) % len(points)
