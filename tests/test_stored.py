"""Values stored on disk for later processes (``agv_mission.stored``): read back instead of
computed again, computed again when damaged or not writable, bounded, and each kind keyed
by what it depends on (a map table by the mask's content, OMPL's planner list by its
build)."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest
from scipy.ndimage import distance_transform_edt

from agv_mission import stored
from agv_mission.maps import map_cache
from agv_mission.maps.grid import FREE
from agv_mission.planners.configs import available_planners
from test_local_costs import room


def test_stored_tables_are_read_back_by_a_later_process(tmp_path, monkeypatch):
    """A fresh process (here: the memory cache cleared) reads the table from disk instead
    of building it; a damaged file, or a store that cannot be written, costs only a build."""
    store = tmp_path / "store"
    monkeypatch.setenv(stored.STORE_ENV, str(store))
    grid = room()
    blocked = grid.data != FREE
    builds = []

    def build() -> np.ndarray:
        builds.append(1)
        return (distance_transform_edt(~blocked) * grid.resolution).astype(np.float32)

    map_cache.clear()
    built = map_cache.stored_array_table("test_distance", blocked, 0.05, build)
    [table_file] = store.glob("test_distance-*.npy")
    map_cache.clear()
    read = map_cache.stored_array_table("test_distance", blocked, 0.05, build)
    assert len(builds) == 1 and read is not built
    assert read.dtype == np.float32 and np.array_equal(read, built)
    assert not read.flags.writeable
    map_cache.clear()  # another resolution is another table
    map_cache.stored_array_table("test_distance", blocked, 0.1, build)
    assert len(builds) == 2 and len(list(store.glob("test_distance-*.npy"))) == 2

    table_file.write_bytes(table_file.read_bytes()[:100])  # cut short
    map_cache.clear()
    assert np.array_equal(
        map_cache.stored_array_table("test_distance", blocked, 0.05, build), built
    )
    assert len(builds) == 3 and np.array_equal(np.load(table_file), built)  # stored again, whole

    monkeypatch.setenv(stored.STORE_ENV, str(table_file / "below_a_file"))  # cannot be written
    map_cache.clear()
    assert np.array_equal(
        map_cache.stored_array_table("test_distance", blocked, 0.05, build), built
    )
    assert len(builds) == 4


def test_stored_tables_are_bounded_least_recently_used_first(tmp_path, monkeypatch):
    store = tmp_path / "store"
    monkeypatch.setenv(stored.STORE_ENV, str(store))
    monkeypatch.setattr(stored, "MAX_STORED", 3)
    map_cache.clear()
    masks = [np.eye(4, k=k, dtype=bool) for k in range(4)]
    for mask in masks[:3]:
        map_cache.stored_array_table("test_mask", mask, None, lambda m=mask: ~m)
        for path in store.glob("*.npy"):  # distinct ages, whatever the clock's resolution
            os.utime(path, (path.stat().st_atime, path.stat().st_mtime - 10))
    map_cache.clear()
    map_cache.stored_array_table("test_mask", masks[0], None, lambda: ~masks[0])  # used: newest
    map_cache.stored_array_table("test_mask", masks[3], None, lambda: ~masks[3])
    assert len(list(store.glob("*.npy"))) == 3
    map_cache.clear()
    rebuilt = []
    for i in (0, 2, 3, 1):
        map_cache.stored_array_table(
            "test_mask", masks[i], None, lambda i=i: rebuilt.append(i) or ~masks[i]
        )
    assert rebuilt == [1]  # the least recently used was dropped


def test_planner_names_are_asked_of_ompl_once_per_build_and_stored(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A later process reads the list instead of loading OMPL's libraries; a damaged file
    is asked of OMPL again."""
    from ompl import geometric as og

    monkeypatch.setenv(stored.STORE_ENV, str(tmp_path))
    available_planners.cache_clear()
    try:
        names = available_planners()
        assert "RRTConnect" in names and all(hasattr(og, n) for n in names)
        [listed] = tmp_path.glob("ompl_planners-*.json")
        assert json.loads(listed.read_text()) == list(names)
        listed.write_text('["RRTConnect"]')
        available_planners.cache_clear()
        assert available_planners() == ("RRTConnect",)  # read, not asked
        listed.write_text('["RRT')
        available_planners.cache_clear()
        assert available_planners() == names
        assert json.loads(listed.read_text()) == list(names)
    finally:
        available_planners.cache_clear()


def test_without_a_home_nothing_is_stored_and_everything_is_computed(monkeypatch):
    def no_home() -> Path:
        raise RuntimeError("Could not determine home directory.")

    monkeypatch.delenv(stored.STORE_ENV, raising=False)
    monkeypatch.delenv("XDG_CACHE_HOME", raising=False)
    monkeypatch.setattr(Path, "home", no_home)
    assert stored.store_dir() is None
    map_cache.clear()
    mask = np.eye(5, dtype=bool)
    table = map_cache.stored_array_table("test_no_home", mask, None, lambda: ~mask)
    assert np.array_equal(table, ~mask)
