"""The localiser's shortcuts: each closed form, fused lookup, prefix count and shared table
gives what the general computation it stands in for gives (on random inputs), and the
filter runs coarse only while the scan-to-map refinement tracks."""

from __future__ import annotations

import math

import numpy as np
import pytest

from agv_mission.geometry import Pose2D
from agv_mission.localization import pose_tracker
from agv_mission.localization.beam_model import SensorParams, beam_model
from agv_mission.localization.distance_field import SignedDistanceField, signed_distance_field
from agv_mission.localization.histogram import (
    KldBound,
    bin_keys,
    heaviest_cluster,
    kld_count,
    weighted_pose,
)
from agv_mission.localization.pose_tracker import PoseTracker, RefineParams
from agv_mission.maps import map_cache
from agv_mission.maps.grid import OccupancyGrid
from test_amcl import ROOM, cast, drive, make

FLOOR = np.array([0.01, 0.01, 0.005])


def random_spd(rng: np.random.Generator, scale: np.ndarray) -> np.ndarray:
    a = rng.normal(size=(3, 3))
    return (a @ a.T + 0.1 * np.eye(3)) * np.outer(scale, scale)


def test_saturated_step_is_the_capped_gauss_newton_step():
    rng = np.random.default_rng(0)
    scaled = np.outer(FLOOR, FLOOR)
    saturated = weak = 0
    for _ in range(300):
        # Information from barely pinned (eigenvalues ~0.1 in floor units) to far past the cap.
        h_full = random_spd(rng, 1.0 / FLOOR) * 10.0 ** rng.uniform(-1.0, 3.0)
        g_full = rng.normal(size=3) * 1e3
        prior_info = random_spd(rng, 1.0 / np.array([0.05, 0.05, 0.03]))
        dx = rng.normal(size=3) * 1e-3
        capped_post = prior_info + np.diag(1.0 / FLOOR**2)
        step = pose_tracker._saturated_step(h_full, g_full, dx, prior_info, FLOOR, capped_post)
        h, gvec = pose_tracker._capped_step(h_full, g_full, FLOOR, scaled)
        if np.linalg.eigvalsh(h_full * scaled)[0] > 1.0:
            saturated += 1
            expected = -np.linalg.solve(prior_info + h, prior_info @ dx + gvec)
            assert step is not None
            np.testing.assert_allclose(step, expected, rtol=1e-7, atol=1e-12)
            np.testing.assert_allclose(h, np.diag(1.0 / FLOOR**2), rtol=1e-9, atol=1e-6)
        else:
            weak += 1
            assert step is None  # a direction below the cap: the eigendecomposition decides
    assert saturated > 50 and weak > 50


def test_floor_covariance_and_inverse_closed_forms():
    rng = np.random.default_rng(1)
    for _ in range(300):
        cov = random_spd(rng, FLOOR) * 10.0 ** rng.uniform(-2.0, 1.0)
        dinv = np.diag(1.0 / FLOOR)
        vals, vecs = np.linalg.eigh(dinv @ cov @ dinv)
        d = np.diag(FLOOR)
        expected = d @ ((vecs * np.maximum(vals, 1.0)) @ vecs.T) @ d
        np.testing.assert_allclose(
            pose_tracker.floor_covariance(cov, FLOOR), expected, rtol=1e-9, atol=1e-15
        )
        inv = pose_tracker._inverse3(cov)
        np.testing.assert_allclose(inv, np.linalg.inv(cov), rtol=1e-8)
        assert np.array_equal(inv, inv.T)


def test_prediction_is_the_ekf_prediction():
    rng = np.random.default_rng(2)
    tracker = PoseTracker(ROOM, RefineParams())
    p = tracker.params
    for _ in range(100):
        mean, cov = rng.normal(size=3), random_spd(rng, np.array([0.05, 0.05, 0.03]))
        tracker.start(mean, cov)
        tracker.noise_scale = rng.uniform(1.0, 10.0)
        dx, dy, dth = rng.normal(size=3) * [0.05, 0.01, 0.05]
        th = mean[2]
        c, s = math.cos(th), math.sin(th)
        f = np.array([[1, 0, -s * dx - c * dy], [0, 1, c * dx - s * dy], [0, 0, 1]])
        g = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
        dist = math.hypot(dx, dy)
        q = np.diag(
            [
                p.noise_along**2 * dist,
                p.noise_lateral**2 * dist,
                p.noise_turn**2 * abs(dth) + p.noise_yaw_per_m**2 * dist,
            ]
        )
        expected = f @ tracker.cov @ f.T + tracker.noise_scale * (g @ q @ g.T)
        tracker.predict(np.array([dx, dy, dth]))
        np.testing.assert_allclose(tracker.cov, expected, rtol=1e-10, atol=1e-15)
        assert tracker.mean[0] == pytest.approx(mean[0] + c * dx - s * dy)


@pytest.mark.parametrize("origin_yaw", [0.0, 0.4])
def test_fused_scan_system_matches_the_lookup_and_its_derivative(origin_yaw):
    grid = OccupancyGrid(ROOM.data, ROOM.resolution, Pose2D(-0.5, -0.5, origin_yaw))
    sdf = SignedDistanceField(grid, 1.0)
    rng = np.random.default_rng(3)
    pts = rng.uniform(-3.0, 3.0, size=(200, 2))
    out = np.empty((4, 200))
    for pose in ((3.0, 2.5, 0.3), (-20.0, 4.0, -2.0)):  # on and off the map
        sdf.scan_system(pts.T.copy(), pose, 0.01, out)
        c, s = math.cos(pose[2]), math.sin(pose[2])
        rxy = pts @ np.array([[c, s], [-s, c]])
        d, grad = sdf.lookup(rxy + pose[:2])
        np.testing.assert_allclose(out[3], d - 0.01, atol=1e-9)
        np.testing.assert_allclose(out[:2].T, grad, atol=1e-6)
        np.testing.assert_allclose(
            out[2], grad[:, 1] * rxy[:, 0] - grad[:, 0] * rxy[:, 1], atol=1e-6
        )
    # The yaw column is the derivative (away from cell borders, where bilinear kinks).
    eps = 1e-7
    d0 = sdf.scan_system(pts.T.copy(), (3.0, 2.5, 0.3), 0.0, np.empty((4, 200)))
    d1 = sdf.scan_system(pts.T.copy(), (3.0, 2.5, 0.3 + eps), 0.0, np.empty((4, 200)))
    fd = (d1[3] - d0[3]) / eps
    assert np.median(np.abs(fd - d0[2])) < 1e-4


def test_kld_count_over_prefixes_is_the_count_over_all_candidates():
    rng = np.random.default_rng(4)
    bound = KldBound(0.02, 0.99, 500, 3000)
    for spread in (0.01, 0.3, 1.0, 3.0, 20.0):
        candidates = rng.normal(size=(3000, 3)) * [spread, spread, min(spread, 3.0)]
        _, first = np.unique(bin_keys(candidates), return_index=True)
        is_first = np.zeros(3000, dtype=np.int64)
        is_first[first] = 1
        over = np.flatnonzero(np.arange(1, 3001) > bound(np.cumsum(is_first)))
        expected = int(over[0]) + 1 if over.size else 3000
        assert kld_count(candidates, 3000, bound) == expected


def test_map_tables_are_built_once_per_map_content_and_read_only():
    map_cache.clear()
    copy = OccupancyGrid(ROOM.data.copy(), ROOM.resolution, ROOM.origin)
    assert signed_distance_field(ROOM, 1.0) is signed_distance_field(copy, 1.0)
    params = SensorParams()
    assert beam_model(ROOM, params, 3.5) is beam_model(copy, params, 3.5)
    assert beam_model(ROOM, params, 3.5) is not beam_model(ROOM, params, 3.0)
    edited = ROOM.data.copy()
    edited[60, 60] = 100
    other = OccupancyGrid(edited, ROOM.resolution, ROOM.origin)
    sdf = signed_distance_field(other, 1.0)
    assert sdf is not signed_distance_field(ROOM, 1.0)
    with pytest.raises(ValueError, match="read-only"):
        sdf.values[0, 0] = 0.0
    for k in range(2 * map_cache.MAX_ENTRIES):  # bounded: old maps are dropped
        signed_distance_field(ROOM, 1.0 + 0.1 * k)
    assert len(map_cache._tables) <= map_cache.MAX_ENTRIES


def test_filter_runs_coarse_only_while_the_refinement_tracks():
    loc = make(refine_filter_particles=200, refine_filter_beams=30)
    err = drive(loc, 12.0)
    assert loc.refining and err[-20:, 1].max() < 0.03
    counts = [n for _, n in loc.particle_counts]
    assert counts[0] == 3000 and set(counts[2:]) == {200}
    # The refinement gives up (here: told to): the next filter update is KLD's again.
    loc.tracker.stop()
    odom, here = loc._track_odom, loc._estimate
    loc.request_nomotion_update()
    loc.update(odom, cast(ROOM, here), here, 20.0)
    assert loc.particle_counts[-1][1] >= 500


def reference_clusters(p: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, float]:
    """The heaviest cluster by brute force: bins adjacent when x, y and yaw (circular, 36
    bins) each differ by at most one bin; components by search."""
    keys = np.stack(
        [
            np.floor(p[:, 0] / 0.5),
            np.floor(p[:, 1] / 0.5),
            np.floor((p[:, 2] + math.pi) / math.radians(10.0)) % 36,
        ],
        axis=1,
    ).astype(int)
    bins = sorted({tuple(k) for k in keys})
    comp: dict[tuple[int, ...], int] = {}
    for start in bins:
        if start in comp:
            continue
        comp[start], todo = len(comp), [start]
        while todo:
            a = todo.pop()
            for b in bins:
                da = abs(a[2] - b[2])
                near = abs(a[0] - b[0]) <= 1 and abs(a[1] - b[1]) <= 1 and min(da, 36 - da) <= 1
                if near and b not in comp:
                    comp[b] = comp[start]
                    todo.append(b)
    lab = np.array([comp[tuple(k)] for k in keys])
    totals = np.bincount(lab, weights=w)
    sel = lab == int(np.argmax(totals))
    return weighted_pose(p[sel], w[sel]), float(totals.max())


def test_heaviest_cluster_is_the_brute_force_one_across_the_yaw_seam():
    rng = np.random.default_rng(5)
    for _ in range(60):
        n = int(rng.integers(20, 400))
        spread = rng.choice([0.05, 0.4, 1.5])
        p = rng.normal(size=(n, 3)) * [spread, spread, rng.choice([0.05, 0.3, 3.0])]
        p[:, 2] = (p[:, 2] + rng.choice([0.0, math.pi]) + math.pi) % (2 * math.pi) - math.pi
        p[: n // 3, :2] += rng.uniform(-4.0, 4.0, 2)  # a second, separate cloud
        w = rng.random(n)
        mean, weight = heaviest_cluster(p, w)
        ref_mean, ref_weight = reference_clusters(p, w)
        np.testing.assert_allclose(mean, ref_mean, atol=1e-12)
        assert weight == pytest.approx(ref_weight)
