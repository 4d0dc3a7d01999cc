"""New BARN worlds drawn by the dataset's own recipe, to measure a stack on worlds it has
never seen, as the challenge's held-out worlds are drawn (barn.md: "same generator, new
draws").

The recipe is that of BARN's generator (``dperille/jackal-map-creation``:
``gen_world_ca.py``, ``generator.py``, ``world_writer.py``; Perille et al. 2020), written
again here with numpy:

* a 30 x 30 grid of 0.15 m cells whose first and last rows are walls, filled at random
  with probability ``fill`` (BARN: 0.15, 0.20, 0.25, 0.30) and smoothed ``smoothing``
  times (BARN: 2, 3, 4) by a cellular automaton: a cell with 5 or more filled neighbours
  fills, one with 1 or fewer empties (cells beyond the first and last rows count as
  filled);
* the Jackal's C-space blocks every cell within 2 cells of a filled one; the world is kept
  when the largest open region touching the entry side (column 0) and the largest
  touching the exit side (column 29) are one region;
* the path file is the C-space's cheapest path between a random open cell of each side:
  steps of one cell turning at most 45 degrees, each costing its length plus BARN's
  penalty of 5 / d for cells within d <= 2 cells of a C-space wall (BARN's A* has the
  same moves and penalty);
* a 0.075 m cylinder stands on each filled cell that has an empty neighbour, at BARN's
  coordinates (cell (r, c) at x = 0.15 r - 4.425, y = 0.15 c + 5.175), with BARN's
  containment walls behind the start.
"""

from __future__ import annotations

import heapq
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy import ndimage

from agv_mission.atomic import atomic_write_bytes

ROWS = COLS = 30
CELL = 0.15  # m: a cylinder's diameter, BARN's grid
RADIUS = CELL / 2.0
JACKAL_CELLS = 2  # the Jackal's C-space: cells blocked around a filled one (BARN's)
PENALTY = 5.0  # BARN's A*: extra cost 5 / d within the inflation radius ...
INFLATION_CELLS = 2  # ... of 0.3 m (2 cells) from a C-space wall
FILLS = (0.15, 0.20, 0.25, 0.30)  # generator.py: four fill levels ...
SMOOTHINGS = (2, 3, 4)  # ... by three smoothing levels, 25 worlds each
WALL_LENGTH = 5.0  # m: world_writer.py's containment walls behind the field
X0, Y0 = -4.425, 5.175  # the field's cell (0, 0) in the world


@dataclass(frozen=True)
class DrawnWorld:
    """One world: its occupancy (30 x 30, 1 filled), its C-space and the path file's
    cells ((n, 2): row, column, as BARN's ``path_K.npy``)."""

    grid: np.ndarray
    cspace: np.ndarray
    path: np.ndarray


_EIGHT = np.array([[1, 1, 1], [1, 0, 1], [1, 1, 1]])


def _neighbours(grid: np.ndarray) -> np.ndarray:
    """Filled cells among each cell's eight, rows beyond the grid counting as filled."""
    padded = np.pad(grid, ((1, 1), (0, 0)), constant_values=1)
    return ndimage.correlate(padded.astype(int), _EIGHT, mode="constant", cval=0)[1:-1]


def cellular_grid(rng: np.random.Generator, fill: float, smoothing: int) -> np.ndarray:
    """BARN's obstacle grid: random fill, walls on the first and last rows, smoothed."""
    grid = (rng.random((ROWS, COLS)) < fill).astype(np.int8)
    grid[0, :] = grid[-1, :] = 1
    for _ in range(smoothing):
        count = _neighbours(grid)
        grid = np.where(count >= 5, 1, np.where(count <= 1, 0, grid)).astype(np.int8)
    return grid


def cspace(grid: np.ndarray, cells: int = JACKAL_CELLS) -> np.ndarray:
    """Cells where the Jackal's centre cannot be: within ``cells`` of a filled one."""
    square = np.ones((2 * cells + 1, 2 * cells + 1), dtype=bool)
    return ndimage.binary_dilation(grid.astype(bool), square).astype(np.int8)


def _largest(labels: np.ndarray, column: int) -> int:
    """The largest region with a cell in ``column`` (0: none)."""
    touching = sorted(set(labels[:, column].tolist()) - {0})
    if not touching:
        return 0
    sizes = np.bincount(labels.ravel())
    return max(touching, key=lambda k: sizes[k])


def wall_distance(blocked: np.ndarray) -> np.ndarray:
    """Each cell's distance in cells to the nearest blocked cell of the C-space."""
    if not blocked.any():
        return np.full(blocked.shape, np.inf)
    return ndimage.distance_transform_edt(blocked == 0)


def cheapest_path(blocked: np.ndarray, start: tuple[int, int], goal: tuple[int, int]) -> list:
    """The cheapest path of cells from ``start`` to ``goal`` (BARN's moves and costs), or
    [] when there is none."""
    dist = wall_distance(blocked)
    rows, cols = blocked.shape
    moves = [(-1, -1), (-1, 0), (-1, 1), (0, 1), (1, 1), (1, 0), (1, -1), (0, -1)]

    def penalty(r: int, c: int) -> float:
        d = dist[r, c]
        return PENALTY / d if d <= INFLATION_CELLS else 0.0

    best: dict[tuple[int, int, int], float] = {}
    parent: dict[tuple[int, int, int], tuple[int, int, int] | None] = {}
    queue: list[tuple[float, int, int, int]] = []
    for k in range(len(moves)):
        best[(*start, k)] = 0.0
        parent[(*start, k)] = None
        heapq.heappush(queue, (0.0, start[0], start[1], k))
    while queue:
        cost, r, c, k = heapq.heappop(queue)
        if cost > best[(r, c, k)]:
            continue
        if (r, c) == goal:
            path, state = [], (r, c, k)
            while state is not None:
                path.append(state[:2])
                state = parent[state]
            return path[::-1]
        turns = range(len(moves)) if (r, c) == start else (k - 1, k, k + 1)
        for j in turns:
            j %= len(moves)
            dr, dc = moves[j]
            rr, cc = r + dr, c + dc
            if not (0 <= rr < rows and 0 <= cc < cols) or blocked[rr, cc]:
                continue
            if dr and dc and blocked[r + dr, c] and blocked[r, c + dc]:
                continue
            new = cost + math.hypot(dr, dc) + penalty(rr, cc)
            if new < best.get((rr, cc, j), math.inf):
                best[(rr, cc, j)] = new
                parent[(rr, cc, j)] = (r, c, k)
                heapq.heappush(queue, (new, rr, cc, j))
    return []


def draw(rng: np.random.Generator, fill: float, smoothing: int) -> DrawnWorld | None:
    """One draw of the recipe; None when the recipe throws the world away (no way
    through)."""
    grid = cellular_grid(rng, fill, smoothing)
    blocked = cspace(grid)
    labels, _ = ndimage.label(blocked == 0)  # 4-connected, as BARN's flood fill
    entry, exit_ = _largest(labels, 0), _largest(labels, COLS - 1)
    if not entry or entry != exit_:
        return None
    starts = np.nonzero(labels[:, 0] == entry)[0]
    goals = np.nonzero(labels[:, COLS - 1] == entry)[0]
    start = (int(rng.choice(starts)), 0)
    goal = (int(rng.choice(goals)), COLS - 1)
    path = cheapest_path(blocked, start, goal)
    if not path:
        return None
    return DrawnWorld(grid, blocked, np.array(path, dtype=np.int64))


def draw_worlds(count: int, seed: int) -> list[DrawnWorld]:
    """``count`` kept worlds, the recipe's twelve parameter sets in turn (BARN draws 25 of
    each set for its 300)."""
    rng = np.random.default_rng(seed)
    sets = [(f, s) for f in FILLS for s in SMOOTHINGS]
    worlds: list[DrawnWorld] = []
    while len(worlds) < count:
        fill, smoothing = sets[len(worlds) % len(sets)]
        world = draw(rng, fill, smoothing)
        if world is not None:
            worlds.append(world)
    return worlds


def cylinders(grid: np.ndarray) -> list[tuple[float, float]]:
    """The cylinders' (x, y) as BARN's world writer places them: the containment walls,
    then each filled cell with an empty neighbour (or on the grid's edge)."""
    out: list[tuple[float, float]] = []
    r_lower, r_upper = -RADIUS, X0
    x = r_lower
    while x >= r_upper - 1e-9:
        out.append((x, RADIUS))
        x -= CELL
    y = RADIUS + CELL
    while y <= RADIUS + WALL_LENGTH + 1e-9:
        out += [(r_lower, y), (r_upper, y)]
        y += CELL
    padded = np.pad(grid, 1, constant_values=0)
    for r, c in zip(*np.nonzero(grid), strict=True):
        if padded[r : r + 3, c : c + 3].all():
            continue
        out.append((X0 + r * CELL, Y0 + c * CELL))
    return out


_HEAD = """<?xml version='1.0'?>
<sdf version='1.6'>
  <world name='default'>
    <model name='ground_plane'>
      <static>1</static>
      <link name='link'>
        <collision name='collision'>
          <geometry><plane><normal>0 0 1</normal><size>100 100</size></plane></geometry>
        </collision>
      </link>
    </model>
"""
_MODEL = """    <model name='unit_cylinder_{i}'>
      <static>1</static>
      <pose frame=''>{x:.6f} {y:.6f} 0 0 -0 0</pose>
      <link name='link'>
        <collision name='collision'>
          <geometry><cylinder><radius>{r:.6f}</radius><length>1</length></cylinder></geometry>
        </collision>
      </link>
    </model>
"""
_STATE = """      <model name='unit_cylinder_{i}'>
        <pose frame=''>{x:.6f} {y:.6f} 0.5 0 -0 0</pose>
        <link name='link'><pose frame=''>{x:.6f} {y:.6f} 0.5 0 -0 0</pose></link>
      </model>
"""


def world_text(grid: np.ndarray) -> str:
    """The world as a Gazebo SDF file: the cylinders as static models and, as a saved
    Gazebo world has them, again in its ``<state>``."""
    cyl = cylinders(grid)
    parts = [_HEAD]
    parts += [_MODEL.format(i=i, x=x, y=y, r=RADIUS) for i, (x, y) in enumerate(cyl)]
    parts.append("    <state world_name='default'>\n      <sim_time>0 0</sim_time>\n")
    parts += [_STATE.format(i=i, x=x, y=y) for i, (x, y) in enumerate(cyl)]
    parts.append("    </state>\n  </world>\n</sdf>\n")
    return "".join(parts)


def write_worlds(folder: Path, worlds: list[DrawnWorld]) -> None:
    """BARN's layout: ``world_K.world`` and ``path_files/path_K.npy``."""
    (folder / "path_files").mkdir(parents=True, exist_ok=True)
    for k, world in enumerate(worlds):
        atomic_write_bytes(folder / f"world_{k}.world", world_text(world.grid).encode())
        np.save(folder / "path_files" / f"path_{k}.npy", world.path)
