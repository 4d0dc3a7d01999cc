"""The people of a run: the crowd stepped with the world, what the robots are told of them,
their contacts, and what the run directory keeps: ``people.csv`` (``t, id, x, y``, one row
per person present at each control step), their tracks on ``run.png``, ``metrics.people``."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from agv_mission.atomic import atomic_write_text
from agv_mission.missions.run.people_metrics import people_metrics
from agv_mission.navigation.state import STANDING, TRACKED_PERSON
from agv_mission.world.crowd import Crowd
from agv_mission.world.simulation import SimulatedWorld

PEOPLE_COLUMNS = ("t", "id", "x", "y")


class PeopleTrack:
    """Everyone's position at each control step (float32: 50 people for an hour take
    14 MB); NaN while a person is not in the world yet."""

    def __init__(self, ids: np.ndarray, radii: np.ndarray):
        self.ids = np.asarray(ids, dtype=np.int64)
        self.radii = np.asarray(radii, dtype=float)
        self._t: list[float] = []
        self._xy: list[np.ndarray] = []

    def add(self, t: float, positions: np.ndarray, active: np.ndarray, everyone: bool) -> None:
        if everyone:
            row = positions.astype(np.float32)
        else:
            row = np.full((len(self.ids), 2), np.nan, dtype=np.float32)
            row[active] = positions[active]
        self._t.append(float(t))
        self._xy.append(row)

    @property
    def t(self) -> np.ndarray:
        return np.asarray(self._t, dtype=float)

    @property
    def xy(self) -> np.ndarray:
        """(steps, people, 2)."""
        if not self._xy:
            return np.zeros((0, len(self.ids), 2))
        return np.stack(self._xy).astype(float)


def write_people_csv(path: Path, t: np.ndarray, xy: np.ndarray, ids: np.ndarray) -> None:
    """``people.csv``: the contract's ``t, id, x, y``, time-major, people present only;
    the bytes ``"%.6f,%d,%.4f,%.4f"`` gives each row (the track's float32 positions times
    10^4 are exact in float64, so rounding them to integers rounds as ``%.4f`` does), the
    positions' digits made by array arithmetic: half the time of formatting each number."""
    steps, n = xy.shape[:2]
    flat = np.asarray(xy, dtype=float).reshape(-1, 2)
    present = np.flatnonzero(~np.isnan(flat[:, 0]))
    step, person = np.divmod(present, max(n, 1))
    t_text = _right_aligned([f"{v:.6f}" for v in np.asarray(t, float).tolist()])
    id_text = _right_aligned([str(i) for i in np.asarray(ids).tolist()])
    fields = [
        (t_text[0][step], t_text[1][step]),
        (id_text[0][person], id_text[1][person]),
        _fixed_point(flat[present, 0], 4),
        _fixed_point(flat[present, 1], 4),
    ]
    rows = len(present)
    blocks, keep = [], []
    for k, (chars, first) in enumerate(fields):
        end = np.full((rows, 1), 10 if k == len(fields) - 1 else 44, np.uint8)  # "\n" or ","
        blocks += [chars, end]
        keep += [np.arange(chars.shape[1]) >= first[:, None], np.ones((rows, 1), bool)]
    table = np.hstack(blocks) if rows else np.zeros((0, 0), np.uint8)
    body = table[np.hstack(keep)].tobytes() if rows else b""
    atomic_write_text(path, ",".join(PEOPLE_COLUMNS) + "\n" + body.decode("ascii"))


def _right_aligned(texts: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """``texts`` as rows of right-aligned ASCII (n, width) and each one's first column."""
    width = max((len(s) for s in texts), default=1)
    chars = np.frombuffer("".join(s.rjust(width) for s in texts).encode("ascii"), np.uint8)
    first = width - np.array([len(s) for s in texts], dtype=np.int64)
    return chars.reshape(len(texts), width), first


def _fixed_point(values: np.ndarray, decimals: int) -> tuple[np.ndarray, np.ndarray]:
    """``values`` as ``%.{decimals}f`` writes them, as :func:`_right_aligned` rows."""
    scale = 10**decimals
    q = np.rint(np.abs(values) * scale).astype(np.int64)
    whole, frac = np.divmod(q, scale)
    digits = 1 + np.searchsorted(10 ** np.arange(1, 19, dtype=np.int64), whole, side="right")
    negative = np.signbit(values)  # "-0.0000" for a small negative, as %f writes it
    wide = int(digits.max(initial=1))
    width = 2 + wide + decimals
    chars = np.empty((len(values), width), dtype=np.uint8)
    for k in range(decimals):
        chars[:, width - 1 - k] = 48 + frac % 10
        frac //= 10
    chars[:, width - 1 - decimals] = ord(".")
    for k in range(wide):
        chars[:, width - 2 - decimals - k] = 48 + whole % 10
        whole //= 10
    chars[:, 0] = ord(" ")
    first = width - 1 - decimals - digits - negative
    chars[np.flatnonzero(negative), first[negative]] = ord("-")
    return chars, first


def plot_people(ax: Any, xy: np.ndarray, radii: np.ndarray) -> None:
    """Everyone's walk as faint lines (one artist, not antialiased: 50 walks of smooth
    lines made the PNG 4x larger and its encoding most of their cost) and where they stood
    at the end as discs (one collection)."""
    from matplotlib.collections import PatchCollection
    from matplotlib.patches import Circle

    if not xy.size:
        return
    gap = np.full((1, xy.shape[1], 2), np.nan)
    thin = xy[:: max(1, len(xy) // 400)]  # 400 points a walk draw the same at this size
    lines = np.concatenate([thin, gap]).transpose(1, 0, 2).reshape(-1, 2)  # NaN between
    ax.plot(
        lines[:, 0],
        lines[:, 1],
        "-",
        lw=0.5,
        color="tab:brown",
        alpha=0.35,
        antialiased=False,
        label="people",
    )
    discs = []
    for i in range(xy.shape[1]):
        seen = xy[~np.isnan(xy[:, i, 0]), i]
        if len(seen):
            discs.append(Circle(tuple(seen[-1]), float(radii[i])))
    if discs:
        ax.add_collection(PatchCollection(discs, color="tab:brown", alpha=0.7))


def _robot_rows(robots: list[Any]) -> np.ndarray:
    """The robots as the crowd sees them: rows (x, y, vx, vy, radius), true poses."""
    rows = np.zeros((len(robots), 5))
    for k, r in enumerate(robots):
        pose = r.sim.true_pose()
        v, _ = r.sim.true_velocity()
        c, s = math.cos(pose.yaw), math.sin(pose.yaw)
        rows[k] = (pose.x, pose.y, v * c, v * s, r.robot.footprint_radius)
    return rows


class PeopleRun:
    """The people of a run: the crowd walking in the world, what each robot is told of
    them, the contacts they had with robots and their track for the run directory."""

    def __init__(self, crowd: Crowd, world: SimulatedWorld) -> None:
        self.crowd = crowd
        self.world = world
        self.track = PeopleTrack(self.crowd.ids, self.crowd.radii)
        self.touching: set[tuple[int, int]] = set()
        self.touches: list[list[tuple[int, int]]] = []  # (robot, person) pairs at each step
        self._still_since = np.full(len(self.crowd.ids), np.inf)  # when each stopped
        # the tracked rows, refreshed in place (velocities and who stands: at decisions)
        self._rows = np.zeros((len(self.crowd.ids), len(TRACKED_PERSON)))
        self._rows[:, 2] = self.crowd.radii
        self._decided = -1  # the crowd's decision the rows' velocities are from

    def sense(self, now: float, robots: list[Any]) -> None:
        """Before the robots decide: hand each the people present, rows (x, y, radius, vx,
        vy, still) (a perfect tracker, as HuNavSim's robots get; still: seconds standing),
        and note who touches whom (each new touch an event of that robot)."""
        crowd = self.crowd
        everyone = crowd.everyone
        self.track.add(now, crowd.positions, crowd.active, everyone)
        rows = self._rows
        if crowd.decisions != self._decided:  # new velocities: who stands, since when
            self._decided = crowd.decisions
            rows[:, 3:5] = v = crowd.velocities
            standing = v[:, 0] * v[:, 0] + v[:, 1] * v[:, 1] < STANDING * STANDING
            self._still_since = np.where(standing, np.minimum(self._still_since, now), np.inf)
        rows[:, 0:2] = crowd.positions
        still = rows[:, 5]
        np.subtract(now, self._still_since, out=still)  # -inf for those walking
        np.maximum(still, 0.0, out=still)
        rows = rows.copy() if everyone else rows[crowd.active]
        for r in robots:
            r.handle.state.people = rows
        touching = self.world.person_contacts()
        if not touching and not self.touching:
            self.touches.append([])
            return
        for k, person in sorted(touching - self.touching):
            p = robots[k].sim.true_pose()
            robots[k].handle.log(
                "person_collision", person=int(person), x=round(p.x, 3), y=round(p.y, 3)
            )
        self.touching = touching
        self.touches.append(sorted(touching))

    def present(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(ids, xy, radii) of the people in the world now (observers keep them: the
        positions a copy; ids and radii, which never change, may be the crowd's own)."""
        crowd = self.crowd
        if crowd.everyone:  # the ids and radii do not change: the same arrays each step
            return crowd.ids, crowd.positions.copy(), crowd.radii
        on = crowd.active
        return crowd.ids[on], crowd.positions[on], crowd.radii[on]

    def move(self, dt: float, robots: list[Any]) -> None:
        """Walk everyone one control period among the robots where they truly are."""
        if not self.crowd.deciding:  # walking on what they decided: no robots needed
            self.crowd.step(dt)
        else:
            self.crowd.step(dt, _robot_rows(robots))
        self.world.move_people(self.crowd.positions, self.crowd.active)

    def metrics(
        self, k: int, trajectory: np.ndarray, robot_radius: float, legs: list[Any], end: float
    ) -> dict[str, Any]:
        """``metrics.people`` of robot ``k`` (its trajectory rows align with the track's)."""
        steps = min(len(trajectory), len(self.touches))
        touched = np.zeros((steps, len(self.crowd.ids)), dtype=bool)
        for i, pairs in enumerate(self.touches[:steps]):
            for robot, person in pairs:
                if robot == k:
                    touched[i, person] = True
        spans = [(leg.t_start, leg.t_end if leg.t_end is not None else end) for leg in legs]
        return people_metrics(
            trajectory[:steps, 0],
            trajectory[:steps, 1:3],
            self.track.xy[:steps],
            float(robot_radius),
            self.crowd.radii,
            spans,
            touching=touched,
            robot_yaw=trajectory[:steps, 3],
        )


def fleet_people_metrics(records: list[Any]) -> dict[str, Any]:
    """A fleet's ``metrics.people``: contacts of all its robots, the closest any came, and
    the worst robot's times (each robot's own set is under ``robots``)."""
    own = [r.metrics["people"] for r in records if r.metrics.get("people")]
    distances = [m["min_distance"] for m in own if m["min_distance"] is not None]
    return {
        "people": own[0]["people"] if own else 0,
        "min_distance": min(distances) if distances else None,
        "intimate_time": max((m["intimate_time"] for m in own), default=0.0),
        "personal_time": max((m["personal_time"] for m in own), default=0.0),
        "collisions": sum(m["collisions"] for m in own),
        "time_not_moving": max((m["time_not_moving"] for m in own), default=0.0),
    }
