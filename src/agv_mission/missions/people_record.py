"""What a run keeps of its people and writes of them: ``people.csv`` (``t, id, x, y``, one
row per person present at each control step) and their tracks on ``run.png``."""

from __future__ import annotations

import io
from pathlib import Path
from typing import Any

import numpy as np

from agv_mission.atomic import atomic_write_text

PEOPLE_COLUMNS = ("t", "id", "x", "y")


class PeopleTrack:
    """Everyone's position at each control step (float32: 50 people for an hour take
    14 MB); NaN while a person is not in the world yet."""

    def __init__(self, ids: np.ndarray, radii: np.ndarray):
        self.ids = np.asarray(ids, dtype=np.int64)
        self.radii = np.asarray(radii, dtype=float)
        self._t: list[float] = []
        self._xy: list[np.ndarray] = []

    def add(self, t: float, positions: np.ndarray, active: np.ndarray) -> None:
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
    """``people.csv``: the contract's ``t, id, x, y``, time-major, people present only."""
    steps, n = xy.shape[:2]
    times = np.repeat(np.asarray(t, float), n)
    who = np.tile(np.asarray(ids, float), steps)
    flat = xy.reshape(-1, 2)
    present = ~np.isnan(flat[:, 0])
    table = np.column_stack([times, who, flat])[present]
    buf = io.StringIO()
    buf.write(",".join(PEOPLE_COLUMNS) + "\n")
    if table.size:
        np.savetxt(buf, table, delimiter=",", fmt=["%.6f", "%d", "%.4f", "%.4f"])
    atomic_write_text(path, buf.getvalue())


def plot_people(ax: Any, xy: np.ndarray, radii: np.ndarray) -> None:
    """Each person's walk as a faint line and where they stood at the end as a disc."""
    from matplotlib.patches import Circle

    for i in range(xy.shape[1]):
        track = xy[:, i]
        seen = ~np.isnan(track[:, 0])
        if not seen.any():
            continue
        ax.plot(
            track[seen, 0],
            track[seen, 1],
            "-",
            lw=0.5,
            color="tab:brown",
            alpha=0.35,
            label="people" if i == 0 else None,
        )
        x, y = track[seen][-1]
        ax.add_patch(Circle((x, y), float(radii[i]), color="tab:brown", alpha=0.7))
