"""New BARN worlds drawn by BARN's recipe (agv_mission.barn.draws): the recipe's rules, the
path file's moves, worlds our reader reads as BARN's, and a drawn world run by the
``barn`` command as a public one is."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from agv_mission.barn.draws import (
    COLS,
    JACKAL_CELLS,
    ROWS,
    cellular_grid,
    cspace,
    cylinders,
    draw,
    draw_worlds,
    write_worlds,
)
from agv_mission.barn.protocol import CELL, CELL_OFFSET, path_length
from agv_mission.maps.sdf_world import read_sdf_world


def test_the_automaton_keeps_its_walls_and_its_rules() -> None:
    rng = np.random.default_rng(4)
    before = cellular_grid(rng, 0.25, 0)
    assert before[0].all() and before[-1].all()
    assert 0.15 < before[1:-1].mean() < 0.35  # the random fill
    after = cellular_grid(np.random.default_rng(4), 0.25, 1)
    padded = np.pad(np.pad(before, ((1, 1), (0, 0)), constant_values=1), ((0, 0), (1, 1)))
    for r in range(ROWS):
        for c in range(COLS):
            count = padded[r : r + 3, c : c + 3].sum() - before[r, c]
            expected = 1 if count >= 5 else 0 if count <= 1 else before[r, c]
            assert after[r, c] == expected, (r, c, count)


def test_the_cspace_blocks_the_jackal_s_cells_around_each_obstacle() -> None:
    grid = np.zeros((ROWS, COLS), dtype=np.int8)
    grid[10, 10] = 1
    blocked = cspace(grid)
    k = JACKAL_CELLS
    assert blocked.sum() == (2 * k + 1) ** 2
    assert blocked[10 - k : 10 + k + 1, 10 - k : 10 + k + 1].all()


@pytest.mark.parametrize("fill", [0.15, 0.2])
def test_a_kept_world_has_a_path_through_free_cspace_turning_at_most_45_degrees(
    fill: float,
) -> None:
    rng = np.random.default_rng(1)
    worlds = [w for w in (draw(rng, fill, 3) for _ in range(20)) if w is not None]
    assert worlds
    for world in worlds:
        path = world.path
        assert path[0, 1] == 0 and path[-1, 1] == COLS - 1
        assert not world.cspace[path[:, 0], path[:, 1]].any()
        steps = np.diff(path, axis=0)
        assert (np.abs(steps).max(axis=1) == 1).all()
        headings = np.arctan2(steps[:, 0], steps[:, 1])
        turns = np.abs(np.angle(np.exp(1j * np.diff(headings))))
        assert (turns <= np.pi / 4 + 1e-9).all()


def test_draws_are_reproducible_from_their_seed() -> None:
    a, b = draw_worlds(3, seed=5), draw_worlds(3, seed=5)
    assert all(
        np.array_equal(x.grid, y.grid) and np.array_equal(x.path, y.path)
        for x, y in zip(a, b, strict=True)
    )
    assert not np.array_equal(a[0].grid, draw_worlds(1, seed=6)[0].grid)


def test_a_drawn_world_reads_as_barn_s_cylinders(tmp_path: Path) -> None:
    world = draw_worlds(1, seed=8)[0]
    write_worlds(tmp_path, [world])
    sdf = read_sdf_world(tmp_path / "world_0.world", scan_height=0.3)
    placed = cylinders(world.grid)
    assert len(sdf.cylinders) == len(placed)
    got = sorted((round(c.x, 3), round(c.y, 3)) for c in sdf.cylinders)
    assert got == sorted((round(x, 3), round(y, 3)) for x, y in placed)
    assert {round(c.radius, 4) for c in sdf.cylinders} == {0.075}
    cells = np.load(tmp_path / "path_files" / "path_0.npy")
    assert np.array_equal(cells, world.path)
    assert path_length(tmp_path / "path_files" / "path_0.npy") > 10.0 - CELL
    assert CELL_OFFSET == (-4.575, 5.075)


@pytest.mark.slow  # a world through the CLI: ~15 s; test_barn.py runs the command fast
def test_the_barn_command_runs_a_drawn_world(tmp_path: Path) -> None:
    write_worlds(tmp_path / "drawn", draw_worlds(1, seed=3))
    out = tmp_path / "out.json"
    done = subprocess.run(
        [sys.executable, "-m", "agv_mission.cli", "barn", str(tmp_path / "drawn"), "--workers", "1",
         "--output", str(tmp_path / "runs"), "--json", str(out)],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    world = json.loads(out.read_text())["worlds"][0]
    assert world["status"] in ("succeeded", "collided", "timeout", "failed")
    assert (Path(world["run_dir"]) / "result.json").is_file()
