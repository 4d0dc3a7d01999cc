"""Rooms: labelled polygons of the map frame, with an optional anchor pose to visit."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from agv_mission.geometry import Pose2D


@dataclass(frozen=True)
class Room:
    """A labelled room. A robot is in the room when its position lies inside ``polygon``."""

    label: str
    polygon: tuple[tuple[float, float], ...]
    anchor: Pose2D | None = None

    def contains(self, x: float, y: float) -> bool:
        """Even-odd point-in-polygon test."""
        poly = np.asarray(self.polygon, dtype=float)
        xs, ys = poly[:, 0], poly[:, 1]
        xj, yj = np.roll(xs, 1), np.roll(ys, 1)
        crosses = (ys > y) != (yj > y)
        with np.errstate(divide="ignore", invalid="ignore"):
            x_at = (xj - xs) * (y - ys) / (yj - ys) + xs
        return bool(np.count_nonzero(crosses & (x < x_at)) % 2)

    def centroid(self) -> tuple[float, float]:
        poly = np.asarray(self.polygon, dtype=float)
        return float(poly[:, 0].mean()), float(poly[:, 1].mean())
