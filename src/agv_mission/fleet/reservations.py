"""What each robot reserves and how far it may go: the first two steps of
:class:`~agv_mission.fleet.traffic.ReservationTraffic` (reserve, grant).

A robot asks for the prefix of its remaining path it could drive within the horizon, swept
by its footprint (a :class:`SweptSpace`); in priority order each gets a :class:`Grant`: the
distance it may advance while its body keeps ``margin`` from every reservation granted
before it and from every other body, and the robot whose space it would enter first.
"""

from __future__ import annotations

from collections.abc import Container, Sequence
from dataclasses import dataclass

import numpy as np
import shapely
from shapely.geometry import LineString, Point
from shapely.geometry.base import BaseGeometry

from agv_mission.fleet.base import TrafficRobot
from agv_mission.fleet.configs import ReservationsConfig

STEP = 0.05  # m between the samples of a reserved prefix
MIN_GO = 0.05  # m: a robot allowed less than this waits
TOL = 0.01  # m: distance changes smaller than this are sampling noise
QUAD_SEGS = 4  # segments per quarter circle of a buffered body


@dataclass
class SweptSpace:
    """Space a body sweeps: the polyline (or point) its centre covers, and its radius
    (the footprint plus half the margin), with the bounding box of the whole."""

    pts: np.ndarray  # (k, 2)
    radius: float
    box: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        (x0, y0), (x1, y1) = self.pts.min(axis=0), self.pts.max(axis=0)
        r = self.radius
        self.box = (float(x0) - r, float(y0) - r, float(x1) + r, float(y1) + r)

    def distance(self, points: np.ndarray) -> np.ndarray:
        """Metres from each of ``points`` (n, 2) to the space (negative inside)."""
        return polyline_distance(points, self.pts) - self.radius

    def polygon(self) -> BaseGeometry:
        if len(self.pts) > 1:
            return LineString(self.pts).buffer(self.radius, quad_segs=QUAD_SEGS)
        return Point(*self.pts[0]).buffer(self.radius, quad_segs=QUAD_SEGS)


@dataclass
class Grant:
    robot: TrafficRobot
    pts: np.ndarray  # (k, 2) samples of the reserved prefix, from the robot's position
    s: np.ndarray  # (k,) arc length of each sample
    limit: float | None = None  # None: the whole prefix
    blocker: str | None = None
    region: SweptSpace | None = None  # the reservation granted


def grant_reservations(
    robots: Sequence[TrafficRobot], config: ReservationsConfig, first: Container[str]
) -> dict[str, Grant]:
    """Each robot's reserved prefix and how far along it it may go, granted in priority
    order: the robots named in ``first`` (stepping aside: they clear the way), then the
    fleet's order."""
    cfg = config
    half = cfg.margin / 2.0
    grants = {r.name: _prefix(r, cfg) for r in robots}
    bodies = {r.name: SweptSpace(grants[r.name].pts[:1], r.radius + half) for r in robots}
    granted: dict[str, SweptSpace] = {}
    for robot in sorted(robots, key=lambda r: r.name not in first):
        g = grants[robot.name]
        if len(g.pts) > 1:
            others = [
                (name, granted.get(name, bodies[name])) for name in bodies if name != robot.name
            ]
            g.limit, g.blocker = _limit(g, robot.radius + half, robot.radius, others)
        upto = len(g.pts) if g.limit is None else int(np.searchsorted(g.s, g.limit, "right"))
        g.region = (
            SweptSpace(g.pts[:upto], robot.radius + half)
            if upto > 1 and (g.limit is None or g.limit >= MIN_GO)
            else bodies[robot.name]
        )
        granted[robot.name] = g.region
    return grants


def _prefix(robot: TrafficRobot, config: ReservationsConfig) -> Grant:
    """The samples of the path a robot asks to reserve, from its own position."""
    here = np.array([[robot.pose.x, robot.pose.y]])
    path = robot.path
    if path is None or len(path) == 0:
        return Grant(robot, here, np.zeros(1))
    length = robot.max_speed * config.horizon + config.lookahead
    pts = np.concatenate([here, rest_of_path(path, here[0])])
    return Grant(robot, *resample(pts, length, STEP))


def _limit(
    g: Grant, keep: float, floor: float, others: list[tuple[str, SweptSpace]]
) -> tuple[float | None, str | None]:
    """How far along its prefix a robot may go, and who stops it: its centre keeps
    ``keep`` metres from every other's space, or, where it is closer already, gets no
    closer (so it can back away or pass alongside) and never nearer than ``floor``
    (unless it stands nearer already: then it may still move away)."""
    (x0, y0), (x1, y1) = g.pts.min(axis=0), g.pts.max(axis=0)
    limit, blocker = None, None
    for name, space in others:
        bx0, by0, bx1, by1 = space.box
        if bx0 > x1 + keep or bx1 < x0 - keep or by0 > y1 + keep or by1 < y0 - keep:
            continue
        d = space.distance(g.pts)
        no_closer = d >= d[0] - TOL
        if d[0] >= floor:
            no_closer &= d >= floor
        ok = (d >= keep - TOL) | no_closer
        if ok.all():
            continue
        k = int(np.argmin(ok))
        reach = float(g.s[k - 1]) if k > 0 else 0.0
        if limit is None or reach < limit:
            limit, blocker = reach, name
    return limit, blocker


# ---------------------------------------------------------------------- path geometry


def rest_of_path(path: np.ndarray, here: np.ndarray) -> np.ndarray:
    """The part of ``path`` ahead of the point on it nearest ``here`` (that point first)."""
    path = np.asarray(path, dtype=float).reshape(-1, 2)
    if len(path) == 1:
        return path
    a, b = path[:-1], path[1:]
    ab = b - a
    denom = np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-12)
    u = np.clip(np.einsum("ij,ij->i", here - a, ab) / denom, 0.0, 1.0)
    foot = a + u[:, None] * ab
    k = int(np.argmin(np.hypot(*(foot - here).T)))
    return np.concatenate([foot[k : k + 1], path[k + 1 :]])


def polyline_distance(points: np.ndarray, line: np.ndarray) -> np.ndarray:
    """Metres from each of ``points`` (n, 2) to the polyline ``line`` (k, 2; one point
    when k = 1)."""
    points = np.asarray(points, dtype=float).reshape(-1, 2)
    if len(line) == 1:
        return np.hypot(points[:, 0] - line[0, 0], points[:, 1] - line[0, 1])
    a, ab = line[:-1], np.diff(line, axis=0)
    denom = np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-12)
    ap = points[:, None, :] - a[None, :, :]
    u = np.clip(np.einsum("nkj,kj->nk", ap, ab) / denom, 0.0, 1.0)
    off = ap - u[..., None] * ab[None, :, :]
    return np.sqrt(np.min(np.einsum("nkj,nkj->nk", off, off), axis=1))


def resample(pts: np.ndarray, length: float, step: float) -> tuple[np.ndarray, np.ndarray]:
    """Points every ``step`` metres along a polyline, up to ``length`` metres (and its end
    if shorter), with their arc lengths."""
    seg = np.hypot(*np.diff(pts, axis=0).T)
    cum = np.concatenate([[0.0], np.cumsum(seg)])
    total = min(float(cum[-1]), length)
    s = np.arange(0.0, total, step)
    s = np.append(s, total) if total - (s[-1] if len(s) else 0.0) > 1e-6 else s
    if len(s) == 0:
        s = np.zeros(1)
    x = np.interp(s, cum, pts[:, 0])
    y = np.interp(s, cum, pts[:, 1])
    return np.stack([x, y], axis=1), s


def cover(polygons: Sequence[BaseGeometry], step: float) -> np.ndarray:
    """Points every ``step`` metres inside ``polygons`` and along their borders: what a
    costmap marks as lethal cells."""
    out = []
    for poly in polygons:
        x0, y0, x1, y1 = poly.bounds
        xs, ys = np.meshgrid(np.arange(x0, x1 + step, step), np.arange(y0, y1 + step, step))
        inside = shapely.contains_xy(poly, xs, ys)
        out.append(np.stack([xs[inside], ys[inside]], axis=1))
        ring = shapely.segmentize(poly.exterior, step)
        out.append(np.asarray(ring.coords)[:, :2])
    return np.concatenate(out) if out else np.zeros((0, 2))
