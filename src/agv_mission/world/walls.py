"""The world's walls as arrays (planar distance queries) and the rolling window of wall
slots that holds the walls near the moving bodies in a large world."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import shapely

from agv_mission.maps.worlds import World
from agv_mission.world.model import PARKED_GROUP, WALL_BIT, WALL_GROUP


class Walls:
    """The world's static boxes and cylinders as arrays, for planar distance queries."""

    def __init__(self, world: World) -> None:
        boxes = world.boxes
        self.box_c = np.array([[b.x, b.y] for b in boxes], dtype=float).reshape(-1, 2)
        self.box_h = np.array([[b.half_x, b.half_y] for b in boxes], dtype=float).reshape(-1, 2)
        self.box_yaw = np.array([b.yaw for b in boxes], dtype=float)
        self.box_cs = np.stack([np.cos(self.box_yaw), np.sin(self.box_yaw)], axis=1).reshape(-1, 2)
        # Rows cx, cy, cos, sin, half_x, half_y: one array for the per-step distance query.
        self._box = np.vstack((self.box_c.T, self.box_cs.T, self.box_h.T))
        cyl = world.cylinders
        self.cyl = np.array([[c.x, c.y, c.radius] for c in cyl], dtype=float).reshape(-1, 3)

    def box_distance(self, x: float, y: float, idx: np.ndarray | slice = slice(None)) -> np.ndarray:
        """Planar distance from (x, y) to each box (negative inside)."""
        b = self._box if isinstance(idx, slice) and idx == slice(None) else self._box[:, idx]
        cx, cy, c, s, hx, hy = b
        dx, dy = x - cx, y - cy
        qx = np.abs(c * dx + s * dy) - hx
        qy = np.abs(-s * dx + c * dy) - hy
        ox, oy = np.maximum(qx, 0.0), np.maximum(qy, 0.0)
        return np.sqrt(ox * ox + oy * oy) + np.minimum(np.maximum(qx, qy), 0.0)

    def cyl_distance(self, x: float, y: float, idx: np.ndarray | slice = slice(None)) -> np.ndarray:
        cyl = self.cyl[idx]
        return np.hypot(cyl[:, 0] - x, cyl[:, 1] - y) - cyl[:, 2]

    def polygon_distance(self, polygon: np.ndarray, reach: float) -> float:
        """Planar distance from the polygon (k, 2) to the nearest wall or pillar within
        ``reach`` of its vertices' mean (a pillar whose centre is inside: minus its radius;
        a box overlapping it: 0); inf when none is."""
        cx, cy = (float(v) for v in polygon.mean(axis=0))
        shape = shapely.Polygon(polygon)
        best = math.inf
        if len(self.cyl):
            near = np.flatnonzero(self.cyl_distance(cx, cy) <= reach)
            if len(near):
                cyl = self.cyl[near]
                d = shapely.distance(shapely.points(cyl[:, 0:2]), shape) - cyl[:, 2]
                best = min(best, float(d.min()))
        if len(self.box_c):
            near = np.flatnonzero(self.box_distance(cx, cy) <= reach)
            for i in near.tolist():
                (x, y), (hx, hy), (c, s) = self.box_c[i], self.box_h[i], self.box_cs[i]
                corners = [(sx * hx, sy * hy) for sx, sy in ((1, 1), (-1, 1), (-1, -1), (1, -1))]
                box = shapely.Polygon([(x + c * a - s * b, y + s * a + c * b) for a, b in corners])
                best = min(best, float(shapely.distance(box, shape)))
        return best


class WallWindow:
    """The rolling window of a large world: the walls near the moving bodies, moved into
    the model's wall slots (see :mod:`agv_mission.world.model`) whenever a body has moved
    ``refresh`` metres from where its part of the window was last centred.

    Every wall within ``radius`` (the longest lidar range plus the refresh distance) of a
    centre gets a slot, nearest first, so the lidars and the contact search see exactly the
    walls they could touch; the cost per step no longer grows with the size of the map.
    """

    def __init__(
        self,
        model: mujoco.MjModel,
        walls: Walls,
        height: float,
        radius: float,
        refresh: float = 0.25,
    ) -> None:
        self.model, self.walls = model, walls
        self.height, self.radius, self.refresh = height, radius, refresh

        def ids(prefix: str) -> np.ndarray:
            out = []
            while (
                i := mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, f"{prefix}{len(out)}")
            ) >= 0:
                out.append(i)
            return np.array(out, dtype=np.int64)

        self.box_slots = ids("wall_slot_")
        self.cyl_slots = ids("pillar_slot_")
        # The world body's bounding-volume tree, refitted bottom-up after every move.
        adr, num = int(model.body_bvhadr[0]), int(model.body_bvhnum[0])
        nodes = np.arange(adr, adr + num)
        geom = model.bvh_nodeid[adr : adr + num]
        children = model.bvh_child[adr : adr + num] + adr
        depth = model.bvh_depth[adr : adr + num]
        is_slot = np.isin(geom, np.concatenate((self.box_slots, self.cyl_slots)))
        self._slot_leaves, self._slot_leaf_geoms = nodes[is_slot], geom[is_slot]
        inner = geom < 0
        self._levels = [
            (nodes[inner & (depth == d)], children[inner & (depth == d)])
            for d in range(int(depth.max(initial=0)), -1, -1)
            if np.any(inner & (depth == d))
        ]
        self.centres: np.ndarray | None = None  # (k, 2): one per body
        self.active_boxes = np.zeros(0, dtype=np.int64)
        self.active_cylinders = np.zeros(0, dtype=np.int64)
        self.overflow = False  # more walls within the radius than slots (nearest kept)

    def update(self, centres: np.ndarray) -> bool:
        """Re-centre when a body (a row of ``centres``, x and y) has moved far enough;
        True when the slots changed."""
        if self.centres is not None and len(self.centres) == len(centres):
            moved = np.hypot(*(centres - self.centres).T)
            if not np.any(moved >= self.refresh):
                return False
        self.centres = np.array(centres, dtype=float)
        w, m, h = self.walls, self.model, self.height
        self.active_boxes = self._nearest(
            self._min_over(w.box_distance, self.centres), len(self.box_slots)
        )
        self.active_cylinders = self._nearest(
            self._min_over(w.cyl_distance, self.centres), len(self.cyl_slots)
        )

        used, idx = self.box_slots[: len(self.active_boxes)], self.active_boxes
        half = w.box_h[idx]
        yaw = w.box_yaw[idx]
        m.geom_pos[used] = np.column_stack((w.box_c[idx], np.full(len(idx), h / 2)))
        m.geom_quat[used] = np.column_stack(
            (np.cos(yaw / 2), np.zeros(len(idx)), np.zeros(len(idx)), np.sin(yaw / 2))
        )
        m.geom_size[used] = np.column_stack((half, np.full(len(idx), h / 2)))
        m.geom_aabb[used] = np.column_stack((np.zeros((len(idx), 3)), m.geom_size[used]))
        m.geom_rbound[used] = np.linalg.norm(m.geom_size[used], axis=1)
        self._enable(used, self.box_slots[len(idx) :])

        used, idx = self.cyl_slots[: len(self.active_cylinders)], self.active_cylinders
        cyl = w.cyl[idx]
        m.geom_pos[used] = np.column_stack((cyl[:, 0:2], np.full(len(idx), h / 2)))
        m.geom_size[used] = np.column_stack(
            (cyl[:, 2], np.full(len(idx), h / 2), np.zeros(len(idx)))
        )
        m.geom_aabb[used] = np.column_stack(
            (np.zeros((len(idx), 3)), cyl[:, 2], cyl[:, 2], np.full(len(idx), h / 2))
        )
        m.geom_rbound[used] = np.hypot(cyl[:, 2], h / 2)
        self._enable(used, self.cyl_slots[len(idx) :])
        self._refit()
        return True

    def _refit(self) -> None:
        """World-frame boxes of the slot leaves, then every inner node as the union of its
        children, deepest level first (MuJoCo keeps the tree it compiled; its boxes must
        follow the slots)."""
        m = self.model
        aabb = m.bvh_aabb
        g = self._slot_leaf_geoms
        q = m.geom_quat[g]  # yaw only: (cos, 0, 0, sin) of yaw / 2
        c = np.abs(1.0 - 2.0 * q[:, 3] ** 2)
        s = np.abs(2.0 * q[:, 0] * q[:, 3])
        size = m.geom_size[g]
        box = m.geom_type[g] == mujoco.mjtGeom.mjGEOM_BOX
        hx = size[:, 0]
        hy = np.where(box, size[:, 1], size[:, 0])
        hz = np.where(box, size[:, 2], size[:, 1])
        aabb[self._slot_leaves, 0:3] = m.geom_pos[g]
        aabb[self._slot_leaves, 3:6] = np.column_stack((c * hx + s * hy, s * hx + c * hy, hz))
        for nodes, children in self._levels:
            a, b = aabb[children[:, 0]], aabb[children[:, 1]]
            lo = np.minimum(a[:, 0:3] - a[:, 3:6], b[:, 0:3] - b[:, 3:6])
            hi = np.maximum(a[:, 0:3] + a[:, 3:6], b[:, 0:3] + b[:, 3:6])
            aabb[nodes, 0:3] = (lo + hi) / 2
            aabb[nodes, 3:6] = (hi - lo) / 2

    @staticmethod
    def _min_over(distance: object, centres: np.ndarray) -> np.ndarray:
        """Each wall's distance to the nearest of ``centres``."""
        rows = [distance(float(x), float(y)) for x, y in centres]  # type: ignore[operator]
        return rows[0] if len(rows) == 1 else np.min(rows, axis=0)

    def _nearest(self, distance: np.ndarray, slots: int) -> np.ndarray:
        idx = np.flatnonzero(distance < self.radius)
        if len(idx) > slots:
            self.overflow = True
            idx = idx[np.argsort(distance[idx])[:slots]]
        return idx

    def _enable(self, used: np.ndarray, parked: np.ndarray) -> None:
        m = self.model
        m.geom_group[used] = WALL_GROUP
        m.geom_conaffinity[used] = WALL_BIT  # no contype: slots never test each other
        m.geom_group[parked] = PARKED_GROUP
        m.geom_conaffinity[parked] = 0
        m.geom_pos[parked] = (0.0, 0.0, -10.0)

    def min_distance(self, x: float, y: float) -> float | None:
        """Distance from (x, y), a body's position, to the nearest wall when the window
        decides it (else ``None``)."""
        best = math.inf
        if len(self.active_boxes):
            best = float(self.walls.box_distance(x, y, self.active_boxes).min())
        if len(self.active_cylinders):
            best = min(best, float(self.walls.cyl_distance(x, y, self.active_cylinders).min()))
        # Walls outside the window are farther than radius - refresh from the robot.
        if best < self.radius - self.refresh and not self.overflow:
            return best
        return None
