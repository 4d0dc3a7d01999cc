"""Nav2's collision monitor: a safety layer between the controller and the wheels.

It works in the robot's frame on the raw lidar points (not the costmap), so it acts on
what the lidar sees now, whatever the planners believed. Each zone proposes an action on
the command; the most restrictive wins:

* ``stop``: zero the command while at least ``min_points`` points lie inside the polygon;
* ``slowdown``: scale it by ``slowdown_ratio`` while they lie inside (polygon or radius);
* ``approach``: cap the speed so the footprint, driven on with the current command,
  reaches the nearest point no sooner than ``time_before_collision``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Annotated, Literal

import numpy as np
import shapely
from pydantic import BaseModel, ConfigDict, Field, model_validator

from agv_mission.geometry import Footprint

Point = Annotated[list[float], Field(min_length=2, max_length=2, description="[x, y], m")]

#: The order actions rank in (the most restrictive last).
ACTIONS = ("none", "approach", "slowdown", "stop")


class CollisionZone(BaseModel):
    """One zone of the monitor, in the robot's frame (x forward, y left, metres)."""

    model_config = ConfigDict(extra="forbid", defer_build=True)

    name: str = Field(min_length=1, max_length=100)
    type: Literal["stop", "slowdown", "approach"]
    polygon: list[Point] | None = Field(None, min_length=3, max_length=100)
    radius: float | None = Field(None, gt=0.0, description="a circle round the robot, m")
    min_points: int = Field(2, ge=1, description="points inside that trigger the action")
    slowdown_ratio: float = Field(0.5, gt=0.0, lt=1.0, description="command scale (slowdown)")
    time_before_collision: float = Field(
        1.0, gt=0.0, le=10.0, description="seconds to the nearest point, at least (approach)"
    )
    simulation_time_step: float = Field(
        0.1, gt=0.0, le=1.0, description="step of the forward simulation (approach), s"
    )

    @model_validator(mode="after")
    def _shape(self) -> CollisionZone:
        if self.type == "approach":
            if self.polygon is not None or self.radius is not None:
                raise ValueError("an approach zone uses the footprint: no polygon or radius")
            return self
        if (self.polygon is None) == (self.radius is None):
            raise ValueError(f"a {self.type} zone has a `polygon` or a `radius`, not both")
        if self.type == "stop" and self.radius is not None:
            raise ValueError("a stop zone is a polygon")
        if self.polygon is not None:
            shape = shapely.Polygon([tuple(p) for p in self.polygon])
            if not shape.is_valid or shape.area <= 0.0:
                raise ValueError("polygon must be simple (no crossing edges) with a non-zero area")
        return self


class CollisionMonitorConfig(BaseModel):
    """The mission's ``stack.collision_monitor`` block (people-and-zones.md)."""

    model_config = ConfigDict(extra="forbid", defer_build=True)

    enabled: bool = True
    zones: list[CollisionZone] | None = Field(
        None,
        max_length=20,
        description="default: stop, slowdown and approach zones sized from the footprint "
        "(see default_zones)",
    )


def default_zones(radius: float, footprint: Footprint | None = None) -> list[CollisionZone]:
    """Zones sized from a circular footprint of ``radius``, or from a polygon ``footprint``
    (its half-width, and its front for the bumper).

    * stop: the footprint's width, from the centre to 5 cm ahead of the bumper. Lateral
      walls (a doorway, a corridor) stay outside it: the planners keep the footprint clear
      of them by their clearance margin; only something right in front stops the robot.
    * slowdown (half speed): the same width, 20 cm ahead of the bumper.
    * approach: 1 s to the nearest point along the current arc (a burger at 0.22 m/s
      needs 0.22 s and 2.4 cm to stop at 1 m/s^2; 1 s leaves room for a late scan).

    A stop leaves the turn: at a goal by a wall, a stop that zeroed the turn too held a
    waffle 9-13 s from turning to its goal's heading (24-28 % of a mission among people).
    """
    half, front = radius, radius
    if footprint is not None:
        half, front = footprint.half_width, footprint.front
    return [
        CollisionZone(
            name="stop",
            type="stop",
            polygon=[[0.0, half], [front + 0.05, half], [front + 0.05, -half], [0.0, -half]],
        ),
        CollisionZone(
            name="slow",
            type="slowdown",
            polygon=[[0.0, half], [front + 0.2, half], [front + 0.2, -half], [0.0, -half]],
            slowdown_ratio=0.5,
        ),
        CollisionZone(name="ttc", type="approach", time_before_collision=1.0),
    ]


@dataclass
class ZoneStats:
    activations: int = 0
    time: float = 0.0


@dataclass
class MonitorOutput:
    v: float
    w: float
    action: str  # "none", "stop", "slowdown", "approach"
    zone: str | None  # the zone whose action won


@dataclass
class CollisionMonitor:
    """The zones of a :class:`CollisionMonitorConfig` over a circular footprint of
    ``robot_radius``, or a polygon ``footprint`` where one is given."""

    config: CollisionMonitorConfig
    robot_radius: float
    period: float
    footprint: Footprint | None = None
    stats: dict[str, ZoneStats] = field(default_factory=dict)
    action: str = "none"
    zone: str | None = None
    changed: bool = False

    def __post_init__(self) -> None:
        self.zones = self.config.zones or default_zones(self.robot_radius, self.footprint)
        self._body = None
        if self.footprint is not None:
            self._body = shapely.Polygon(self.footprint.polygon)
            shapely.prepare(self._body)
        self._shapes = [
            shapely.Polygon([tuple(p) for p in z.polygon]) if z.polygon is not None else None
            for z in self.zones
        ]
        for shape in self._shapes:
            if shape is not None:
                shapely.prepare(shape)
        # which way each zone lies: +1 ahead, -1 behind, 0 around (acts both ways)
        self._ahead = [
            0.0 if shape is None or shape.bounds[0] < 0.0 < shape.bounds[2]
            else math.copysign(1.0, shape.centroid.x)
            for shape in self._shapes
        ]  # fmt: skip
        self.stats = {z.name: ZoneStats() for z in self.zones}
        reach = [0.0]
        for z, shape in zip(self.zones, self._shapes, strict=True):
            if z.radius is not None:
                reach.append(z.radius)
            elif shape is not None:
                reach.append(float(np.max(np.hypot(*np.asarray(z.polygon).T))))
        self._zone_reach = max(reach)  # of the stop and slowdown zones
        self._horizon = max(
            (z.time_before_collision for z in self.zones if z.type == "approach"), default=0.0
        )

    def __call__(self, v: float, w: float, points: np.ndarray) -> MonitorOutput:
        """The command after the monitor; ``points`` (N, 2) in the robot's frame. A change
        of the winning action is :attr:`changed` until the next call."""
        best = MonitorOutput(v, w, "none", None)
        reach = self.reach(v)
        if len(points):
            near = points[(points[:, 0] ** 2 + points[:, 1] ** 2) <= reach * reach]
        else:
            near = points.reshape(0, 2)
        if len(near) and self.config.enabled and abs(v) < 1e-6 and self._body is not None:
            best = self._turn(w, near, best)  # a polygon's corners sweep as it turns
        elif len(near) and self.config.enabled and abs(v) >= 1e-6:  # a circle turns freely
            for z, shape, ahead in zip(self.zones, self._shapes, self._ahead, strict=True):
                if ahead * v < 0.0:  # a zone on the side the robot moves away from
                    continue
                out = self._zone(z, shape, v, w, near)
                if out is not None and _more_restrictive(out, best):
                    best = out
            if best.action == "stop" and self._body is not None:
                best = self._turn(best.w, near, best)  # the turn it leaves, checked
        self.changed = (best.action, best.zone) != (self.action, self.zone)
        if self.changed and best.zone is not None:
            self.stats[best.zone].activations += 1
        if best.zone is not None:
            self.stats[best.zone].time += self.period
        self.action, self.zone = best.action, best.zone
        return best

    def _turn(self, w: float, pts: np.ndarray, best: MonitorOutput) -> MonitorOutput:
        """Turning on the spot: the approach zones cap the turn rate so the polygon's
        corners reach no point sooner than their time (a stop zone does not stop a
        turn)."""
        clear = ~shapely.contains_xy(self._body, pts[:, 0], pts[:, 1])
        pts = pts[clear]  # what the body already holds: turning away is the way out
        for z in self.zones:
            if z.type == "approach" and abs(w) >= 1e-6 and len(pts):
                t = self._polygon_time_to_collision(0.0, w, pts, z)
                if t < z.time_before_collision:
                    scale = max(t / z.time_before_collision, 0.0)
                    if abs(w * scale) < abs(best.w):
                        stopped = best.action == "stop"
                        best = MonitorOutput(
                            0.0,
                            w * scale,
                            best.action if stopped else "approach",
                            best.zone if stopped else z.name,
                        )
        return best

    def reach(self, v: float) -> float:
        """How far from the robot a point can matter at speed ``v``: the zones' polygons, or
        the footprint driven on within the approach horizon."""
        return max(self._zone_reach, abs(v) * self._horizon + self.robot_radius)

    def _zone(
        self, z: CollisionZone, shape: shapely.Polygon | None, v: float, w: float, pts: np.ndarray
    ) -> MonitorOutput | None:
        if z.type == "approach":
            t = self._time_to_collision(v, w, pts, z)
            if t >= z.time_before_collision:
                return None
            scale = max(t / z.time_before_collision, 0.0)
            return MonitorOutput(v * scale, w * scale, "approach", z.name)
        if shape is not None:
            x0, y0, x1, y1 = shape.bounds
            box = pts[(pts[:, 0] >= x0) & (pts[:, 0] <= x1) & (pts[:, 1] >= y0) & (pts[:, 1] <= y1)]
            if len(box) < z.min_points:
                return None
            inside = int(np.count_nonzero(shapely.contains_xy(shape, box[:, 0], box[:, 1])))
        else:
            inside = int(np.count_nonzero(np.hypot(pts[:, 0], pts[:, 1]) <= z.radius))
        if inside < z.min_points:
            return None
        if z.type == "stop":  # turning on the spot is free: a round footprint sweeps nothing
            return MonitorOutput(0.0, w, "stop", z.name)
        return MonitorOutput(v * z.slowdown_ratio, w * z.slowdown_ratio, "slowdown", z.name)

    def _time_to_collision(self, v: float, w: float, pts: np.ndarray, z: CollisionZone) -> float:
        """When the footprint, driven on at (v, w), first touches a point (inf: never
        within the zone's time), to the simulation step, rounded down (the safe side)."""
        r = self.robot_radius
        if self._body is not None:
            return self._polygon_time_to_collision(v, w, pts, z)
        if np.any(np.hypot(pts[:, 0], pts[:, 1]) <= r):
            return 0.0
        steps = int(math.ceil(z.time_before_collision / z.simulation_time_step))
        t = np.arange(1, steps + 1) * z.simulation_time_step
        yaw = w * t
        if abs(w) < 1e-6:
            x, y = v * t, np.zeros_like(t)
        else:
            x, y = v / w * np.sin(yaw), v / w * (1.0 - np.cos(yaw))
        d = np.hypot(pts[None, :, 0] - x[:, None], pts[None, :, 1] - y[:, None])
        hit = np.nonzero((d <= r).any(axis=1))[0]
        if not len(hit):
            return math.inf
        # contact falls within the step before the first hit: its start is the safe bound
        return float(t[hit[0]] - z.simulation_time_step)

    def _polygon_time_to_collision(
        self, v: float, w: float, pts: np.ndarray, z: CollisionZone
    ) -> float:
        """As :meth:`_time_to_collision`, the polygon carried along the arc: each point
        seen from each predicted pose, inside the body or not."""
        body = self._body
        steps = int(math.ceil(z.time_before_collision / z.simulation_time_step))
        t = np.arange(0, steps + 1) * z.simulation_time_step
        yaw = w * t
        if abs(w) < 1e-6:
            x, y = v * t, np.zeros_like(t)
        else:
            x, y = v / w * np.sin(yaw), v / w * (1.0 - np.cos(yaw))
        c, s = np.cos(yaw)[:, None], np.sin(yaw)[:, None]
        dx, dy = pts[None, :, 0] - x[:, None], pts[None, :, 1] - y[:, None]
        inside = shapely.contains_xy(body, c * dx + s * dy, c * dy - s * dx)
        hit = np.nonzero(inside.any(axis=1))[0]
        if not len(hit):
            return math.inf
        if hit[0] == 0:
            return 0.0
        return float(t[hit[0]] - z.simulation_time_step)

    def report(self) -> dict[str, dict[str, float | int]]:
        """``metrics.collision_monitor``: activations and seconds per zone."""
        return {
            name: {"activations": s.activations, "time": round(s.time, 3)}
            for name, s in self.stats.items()
        }


def _more_restrictive(a: MonitorOutput, b: MonitorOutput) -> bool:
    """Whether ``a`` leaves less speed than ``b`` (ties: the higher-ranked action)."""
    if abs(a.v) != abs(b.v):
        return abs(a.v) < abs(b.v)
    return ACTIONS.index(a.action) > ACTIONS.index(b.action)
