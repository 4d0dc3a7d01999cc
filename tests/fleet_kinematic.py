"""A kinematic fleet for testing the traffic layer's algorithm on real maps.

Each robot follows real ``cost_grid`` plans on its real costmap, advancing along its path
at its top speed as far as the traffic decision allows (no dynamics: the end-to-end runs
with MuJoCo bodies are the scenarios'). The harness does what a navigator does with a
decision: ``go`` up to the limit, ``wait`` in place keeping the plan, ``yield`` to the
detour pose and back to the goal, ``replan`` with the avoided cells lethal.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from agv_mission.fleet.base import TrafficDecision, TrafficRobot
from agv_mission.fleet.reservations import rest_of_path
from agv_mission.fleet.traffic import ReservationTraffic
from agv_mission.geometry import Pose2D
from agv_mission.maps.costmap import Costmap, CostmapConfig
from agv_mission.maps.world_loader import load_world
from agv_mission.maps.worlds import World
from agv_mission.planners.base import PlanningError
from agv_mission.planners.configs import CostGridConfig
from agv_mission.planners.cost_grid import CostGridPlanner

WORLDS = Path(__file__).parent / "worlds"
DT = 0.1  # s, the runs' control period
ARRIVED = 0.05  # m

BURGER = (0.105, 0.22)  # footprint radius (m), max speed (m/s): robots/description.py
WAFFLE = (0.22, 0.26)


def world(name: str) -> World:
    return load_world(str(WORLDS / f"{name}.yaml"))


@dataclass
class Bot:
    name: str
    pose: Pose2D
    goals: list[Pose2D]
    costmap: Costmap
    radius: float = BURGER[0]
    max_speed: float = BURGER[1]
    path: np.ndarray | None = None
    detour: Pose2D | None = None
    arrived: list[float] = field(default_factory=list)  # when each goal was reached
    travelled: float = 0.0
    stuck: bool = False  # keeps its plan but never moves (a robot that broke down)

    @property
    def target(self) -> Pose2D | None:
        return self.detour if self.detour is not None else (self.goals[0] if self.goals else None)


class KinematicFleet:
    """Robots on one map, stepped every ``DT`` by a traffic controller's decisions."""

    def __init__(self, world: World, traffic: ReservationTraffic | None = None) -> None:
        self.world = world
        self.traffic = traffic or ReservationTraffic()
        self.planner = CostGridPlanner(CostGridConfig())
        self.bots: list[Bot] = []
        self.t = 0.0
        self.events: list[dict] = []
        self.min_gap = math.inf  # smallest distance between two footprints seen
        self.decisions: dict[str, list[str]] = {}
        self._costmaps: dict[float, Costmap] = {}

    def add(
        self, name: str, start: Pose2D, goals: list[Pose2D], kind: tuple[float, float] = BURGER
    ) -> Bot:
        radius, speed = kind
        if radius not in self._costmaps:
            self._costmaps[radius] = Costmap.from_grid(self.world.map, radius, CostmapConfig())
        bot = Bot(name, start, list(goals), self._costmaps[radius], radius, speed)
        self.bots.append(bot)
        self.decisions[name] = []
        self._plan(bot)
        return bot

    # ------------------------------------------------------------------ running

    def run(self, until: float) -> bool:
        """Step until every robot has reached its goals (True) or ``until`` seconds."""
        while self.t < until:
            if all(not b.goals and b.detour is None for b in self.bots):
                return True
            self.step()
        return all(not b.goals for b in self.bots)

    def step(self) -> None:
        states = [
            TrafficRobot(
                b.name,
                b.pose,
                b.radius,
                b.max_speed,
                path=b.path,
                idle=not b.goals,
                costmap=b.costmap,
            )
            for b in self.bots
        ]
        update = self.traffic.decide(self.t, states)
        self.events += update.events
        for b in self.bots:
            decision = update.decisions[b.name]
            self.decisions[b.name].append(decision.action)
            self._obey(b, decision)
        self.t = round(self.t + DT, 6)
        self._measure()

    def _obey(self, b: Bot, d: TrafficDecision) -> None:
        if d.action == "yield":
            if b.detour is None or b.detour != d.detour:
                b.detour = d.detour
                self._plan(b)
            self._advance(b, d.limit)
            return
        if b.detour is not None:  # released: back to the goal
            b.detour = None
            self._plan(b)
        if d.action == "replan":
            self._plan(b, d.avoid)
        elif d.action == "go":
            self._advance(b, d.limit)

    def _plan(self, b: Bot, avoid: np.ndarray | None = None) -> None:
        target = b.target
        if target is None:
            b.path = None
            return
        costmap = b.costmap
        if avoid is not None and len(avoid):
            marks = np.zeros(costmap.grid.data.shape, dtype=bool)
            rows, cols = costmap.grid.world_to_cell(avoid)
            inside = costmap.grid.in_bounds(rows, cols)
            marks[rows[inside], cols[inside]] = True
            costmap = costmap.with_obstacles(marks)
        try:
            b.path = self.planner.plan(costmap, b.pose, target).points
        except PlanningError:
            if avoid is None:
                raise
            # no way round: keep the plan (and wait), as a navigator does

    def _advance(self, b: Bot, limit: float | None) -> None:
        if b.path is None or b.stuck:
            return
        step = b.max_speed * DT if limit is None else min(b.max_speed * DT, limit)
        here = np.array([b.pose.x, b.pose.y])
        rest = np.concatenate([here[None], rest_of_path(b.path, here)])
        seg = np.hypot(*np.diff(rest, axis=0).T)
        cum = np.concatenate([[0.0], np.cumsum(seg)])
        step = max(0.0, min(step, float(cum[-1])))
        x, y = np.interp(step, cum, rest[:, 0]), np.interp(step, cum, rest[:, 1])
        k = int(np.searchsorted(cum, step, "right"))
        yaw = b.pose.yaw
        if step > 1e-9:
            yaw = math.atan2(y - b.pose.y, x - b.pose.x)
        b.travelled += step
        b.pose = Pose2D(float(x), float(y), yaw)
        b.path = np.concatenate([[[x, y]], rest[k:]]) if k < len(rest) else np.array([[x, y]])
        if float(cum[-1]) - step <= ARRIVED:
            self._reached(b)

    def _reached(self, b: Bot) -> None:
        if b.detour is not None:
            b.path = None  # stay at the detour pose until released
            return
        if b.goals:
            b.goals.pop(0)
            b.arrived.append(self.t)
        self._plan(b)

    def _measure(self) -> None:
        for i, a in enumerate(self.bots):
            for b in self.bots[i + 1 :]:
                gap = a.pose.distance_to(b.pose) - a.radius - b.radius
                self.min_gap = min(self.min_gap, gap)

    # ------------------------------------------------------------------ reports

    def longest_wait(self) -> float:
        """Seconds of the longest single wait that ended (or still stands)."""
        longest, started = 0.0, {}
        for e in self.events:
            if e["event"] == "wait":
                started[e["robot"]] = e["t"]
            elif e["event"] == "wait_end":
                longest = max(longest, e["waited"])
                started.pop(e["robot"], None)
        for t0 in started.values():
            longest = max(longest, self.t - t0)
        return longest

    def kinds(self, event: str) -> list[dict]:
        return [e for e in self.events if e["event"] == event]
