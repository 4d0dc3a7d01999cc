"""Beams cast in the plane against a world of many pillars see what MuJoCo's ray cast sees."""

from __future__ import annotations

import math
from pathlib import Path

import mujoco
import numpy as np

from agv_mission.maps.world_loader import load_world
from agv_mission.maps.worlds import Box
from agv_mission.world.model import world_spec
from agv_mission.world.planar_cast import PlanarWalls
from agv_mission.world.walls import Walls

BARN = Path(__file__).parent / "data" / "barn"


def test_planar_beams_match_mujocos_ray_cast():
    world = load_world(str(BARN / "world_1.world"), scan_height=0.3)
    world.boxes += [
        Box(-2.0, 6.0, 0.3, 0.1, 0.4),
        Box(1.0, 1.0, 0.5, 0.5),
        Box(-6.0, 3.0, 0.05, 3.0),
    ]
    model = world_spec(world, 0.002).compile()
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)

    def ids(prefix: str, count: int) -> np.ndarray:
        names = (f"{prefix}{i}" for i in range(count))
        return np.array([mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, n) for n in names])

    planar = PlanarWalls(
        Walls(world), ids("wall_", len(world.boxes)), ids("pillar_", len(world.cylinders))
    )
    walls_only = np.array([0, 1, 0, 0, 0, 0], dtype=np.uint8)
    rng = np.random.default_rng(3)
    n, hits = 1440, 0
    for _ in range(60):
        origin = np.array([rng.uniform(-6.5, 2.0), rng.uniform(-2.0, 12.0), 0.3])
        yaw, tilt = rng.uniform(-math.pi, math.pi), rng.uniform(-0.03, 0.03)
        a = yaw + np.arange(n) * 2.0 * math.pi / n
        vec = np.stack(
            [np.cos(a) * math.cos(tilt), np.sin(a) * math.cos(tilt), np.full(n, math.sin(tilt))],
            axis=1,
        )
        vec = vec.ravel().copy()
        want_id, want = np.zeros(n, dtype=np.int32), np.zeros(n)
        mujoco.mj_multiRay(
            model, data, origin, vec, walls_only, 1, -1, want_id, want, None, n, 11.0
        )
        got_id, got = np.full(n, -1, dtype=np.int32), np.full(n, -1.0)
        planar.cast(origin, vec, got, got_id, 11.0)
        seen = ((want >= 0) & (want < 10.0)) | ((got >= 0) & (got < 10.0))
        assert np.array_equal(want[seen] < 0, got[seen] < 0)
        both = seen & (want >= 0)
        assert np.allclose(got[both], want[both], atol=1e-4)
        assert np.array_equal(got_id[both], want_id[both])
        hits += int(both.sum())
    assert hits > 20_000
