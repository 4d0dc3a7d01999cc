"""``graph`` SLAM: the ``grid`` SLAM plus loop closure over a pose graph of keyframes.

The ``grid`` plugin (scan-to-map matching) is the front end: it tracks the robot and
builds the map. Every ``keyframe_distance`` / ``keyframe_angle`` of motion its pose and
scan become a keyframe, linked to the previous one by the front end's relative motion.
Every ``loop_check_every`` keyframes (and every ``loop_check_distance`` metres), the
keyframe closest to the current estimate among those more than ``loop_min_travel``
metres of driving ago is a loop candidate, searched within ``loop_search_radius`` plus
``loop_search_growth`` per metre driven since the last closure (the drift since). While
that drift is within ``loop_linear_window`` the current scan is matched over
+-``loop_linear_window``, +-``loop_angular_window`` (the same correlative branch and
bound + point-to-line refinement as the front end) against a submap of the keyframes
around the candidate; beyond, over the whole radius and ``loop_wide_angular_window``
against the keyframes within it (on a field of twice the cell size, then refined). A
match scoring ``loop_min_score`` is a loop closure; one that moves the graph by more
than ``loop_verify`` waits for a second closure that agrees with it
(:mod:`~agv_mission.mapping.pose_graph`).

The graph is then solved (:func:`~agv_mission.mapping.pose_graph.solve_pose_graph`:
Gauss-Newton on scipy's sparse solver with an analytic Jacobian, every verified loop
edge at full weight, a loop edge the solution cannot satisfy dropped) and,
when a keyframe moved by more than ``rebuild_threshold``, the map is rebuilt from the
keyframes' scans at their optimised poses (Karto / slam_toolbox do the same). The front
end continues from the optimised pose, and :attr:`trajectory` is corrected too (each
pose rides on the keyframe before it).

Offline, once a recording ends, :meth:`GraphSlam.finish` (with ``final_smoothing``)
smooths the whole trajectory with the odometry (:func:`smooth_trajectory`) and renders the
map again from the smoothed poses.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from time import perf_counter
from typing import Any

import numpy as np

from agv_mission.geometry import Pose2D, wrap_angles
from agv_mission.mapping.configs import GraphSlamConfig
from agv_mission.mapping.likelihood_field import LikelihoodField
from agv_mission.mapping.pose_graph import (
    OdometryFusion,
    fuse_odometry,
    loop_pair_error,
    smooth_trajectory,
    solve_pose_graph,
)
from agv_mission.mapping.scan_matching import CorrelativeMatcher
from agv_mission.mapping.slam import GridSlam
from agv_mission.maps.grid import OccupancyGrid
from agv_mission.sensor_msgs import LaserScan


@dataclass
class Keyframe:
    scan: LaserScan
    points: np.ndarray  # (n, 2) robot frame, angle-ordered
    travel: float  # metres driven before it


class GraphSlam(GridSlam):
    """Grid SLAM + keyframe pose graph with scan-matched loop closures."""

    Config = GraphSlamConfig

    def __init__(self, config: GraphSlamConfig, bounds: Any = None, rng: Any = None) -> None:
        super().__init__(config, bounds, rng)
        c = config
        self.loop_matcher = CorrelativeMatcher(
            linear_window=c.loop_linear_window,
            angular_window=c.loop_angular_window,
            coarse_block=8,
            refinement=c.refinement,
            iterations=c.refine_iterations,
            point_sigma=c.point_sigma,
            scan_sigma=c.scan_sigma,
            search_max_range=c.search_max_range,
        )
        # After a wide search's coarse optimum: a cell and a few steps left to settle.
        self.loop_refiner = CorrelativeMatcher(
            linear_window=0.3,
            angular_window=math.radians(3.0),
            refinement=c.refinement,
            iterations=c.refine_iterations,
            point_sigma=c.point_sigma,
            scan_sigma=c.scan_sigma,
            search_max_range=c.search_max_range,
        )
        self._clear_graph()

    def _clear_graph(self) -> None:
        self.keyframes: list[Keyframe] = []
        self.nodes = np.zeros((0, 3))
        self.edges: list[tuple[int, int, np.ndarray, np.ndarray, bool]] = []  # i, j, z, sigma, loop
        # Per trajectory entry: its keyframe and its pose in that keyframe's frame.
        self._anchor_keyframe: list[int] = []
        self._anchor_offset: list[tuple[float, float, float]] = []
        # scan, keyframe, offset, trajectory index
        self._integrated: list[tuple[LaserScan, int, Pose2D, int]] = []
        self._odom_at: list[np.ndarray] = []  # the odometry at each trajectory entry
        self._stale = False  # the map lags the graph a little
        self._travel = 0.0
        self._last_pose: Pose2D | None = None
        self.loop_closures = 0
        self.loop_attempts = 0
        self.loops_pending = 0  # closures that waited for a second one
        self.loop_rejections = 0  # loop edges the solved graph could not satisfy
        self._closed_travel = 0.0  # metres driven at the last loop closure
        self._searched_travel = 0.0  # ... at the last loop search
        # Closures waiting for confirmation: i, j, z, travel at j, travel at i, std.
        self._pending: list[tuple[Any, ...]] = []
        self.optimizations = 0
        self.rebuilds = 0
        self.smoothing_s = 0.0
        self.fusion: OdometryFusion | None = None  # the final pass's, when it fused
        self.optimize_times: list[float] = []
        self.rebuild_times: list[float] = []
        self.loop_times: list[float] = []

    def reset(self, pose: Pose2D, odom: Pose2D) -> None:
        super().reset(pose, odom)
        self._clear_graph()

    def diagnostics(self) -> dict[str, Any]:
        """Both ends' counters and timings, and what the final pass learnt of the wheels."""
        counts = {
            "keyframes": len(self.keyframes),
            "loop_attempts": self.loop_attempts,
            "loop_closures": self.loop_closures,
            "loops_pending": self.loops_pending,
            "loop_rejections": self.loop_rejections,
            "optimizations": self.optimizations,
            "map_rebuilds": self.rebuilds,
            "optimize_s": round(float(np.sum(self.optimize_times)), 3),
            "rebuild_s": round(float(np.sum(self.rebuild_times)), 3),
            "loop_search_s": round(float(np.sum(self.loop_times)), 3),
            "smoothing_s": round(self.smoothing_s, 3),
        }
        return super().diagnostics() | counts | (self.fusion.report() if self.fusion else {})

    def update(self, odom: Pose2D, scan: LaserScan | None, truth: Pose2D, time: float) -> Pose2D:
        processed, integrations = len(self.trajectory), self.integrations
        pose = super().update(odom, scan, truth, time)
        if scan is None or len(self.trajectory) == processed:
            return pose
        self._odom_at.append(odom.as_array())
        if self._last_pose is not None:
            self._travel += pose.distance_to(self._last_pose)
        self._last_pose = pose
        new_keyframe = self._keyframe_due(pose)
        if new_keyframe:
            self._add_keyframe(scan, pose)
        k = len(self.keyframes) - 1
        offset = pose.relative_to(Pose2D(*self.nodes[k]))
        self._anchor_keyframe.append(k)
        self._anchor_offset.append((offset.x, offset.y, offset.yaw))
        if self.integrations != integrations:
            self._integrated.append((scan, k, offset, len(self.trajectory) - 1))
        if new_keyframe and self._loop_due(k) and self._close_loop(k):
            # the new edge disagrees with the graph: solve
            pose = self._optimize()
        return pose

    # ------------------------------------------------------------------ graph

    def _keyframe_due(self, pose: Pose2D) -> bool:
        if not self.keyframes:
            return True
        last = Pose2D(*self.nodes[-1])
        c = self.config
        return (
            pose.distance_to(last) >= c.keyframe_distance
            or abs(pose.heading_error_to(last)) >= c.keyframe_angle
        )

    def _add_keyframe(self, scan: LaserScan, pose: Pose2D) -> None:
        c = self.config
        points = self._scan_points(scan)
        if self.keyframes:
            prev = Pose2D(*self.nodes[-1])
            z = pose.relative_to(prev)
            d = math.hypot(z.x, z.y)
            sxy, sa = c.odom_edge_sigma
            floor = np.array([sxy * (0.1 + d), sxy * (0.1 + d), sa * (0.1 + abs(z.yaw))])
            # The front end's own uncertainty, in the previous keyframe's frame: a
            # corridor leaves the motion along it uncertain, and that is where a loop
            # closure's correction should go.
            cy, sy = math.cos(prev.yaw), math.sin(prev.yaw)
            rot = np.array([[cy, sy, 0.0], [-sy, cy, 0.0], [0.0, 0.0, 1.0]])
            local = rot @ self._cov @ rot.T
            sigma = np.sqrt(np.maximum(np.diag(local), 0.0)) + floor
            self.edges.append((len(self.nodes) - 1, len(self.nodes), z.as_array(), sigma, False))
        self.keyframes.append(Keyframe(scan, points, self._travel))
        self.nodes = np.vstack([self.nodes, pose.as_array()])

    def _loop_due(self, k: int) -> bool:
        """Whether keyframe ``k`` searches a loop: every ``loop_check_every`` keyframes, or
        once ``loop_check_distance`` metres were driven since the last search (a log of
        a scan a metre has a keyframe a scan)."""
        c = self.config
        travel = self.keyframes[k].travel
        far = c.loop_check_distance is not None and (
            travel - self._searched_travel >= c.loop_check_distance
        )
        if k % c.loop_check_every == 0 or far:
            self._searched_travel = travel
            return True
        return False

    def _close_loop(self, j: int) -> bool:
        """Search a loop closure for keyframe ``j``; whether the graph needs a solve."""
        c = self.config
        kf = self.keyframes[j]
        if len(kf.points) < c.min_points:
            return False
        travel = np.array([k.travel for k in self.keyframes])
        old = np.flatnonzero(travel < kf.travel - c.loop_min_travel)
        if not len(old):
            return False
        # The drift since the last closure widens the search (Cartographer searches 7 m).
        drift = c.loop_search_growth * (kf.travel - self._closed_travel)
        radius = max(min(c.loop_search_radius + drift, c.loop_max_radius), c.loop_search_radius)
        d = np.hypot(*(self.nodes[old, :2] - self.nodes[j, :2]).T)
        if d.min() > radius:
            return False
        i = int(old[np.argmin(d)])
        t0 = perf_counter()
        self.loop_attempts += 1
        if drift > c.loop_linear_window:
            result = self._wide_match(j, old[d <= radius], radius)
        else:
            lo, hi = max(i - c.loop_submap_keyframes, 0), i + c.loop_submap_keyframes + 1
            allowed = set(old.tolist())
            members = [m for m in range(lo, min(hi, len(self.keyframes))) if m in allowed]
            box = self.loop_matcher.read_box(kf.points, self.nodes[j], self.resolution)
            field = self._submap_field(members, box=box)
            result = self.loop_matcher.match(field, kf.points, self.nodes[j], None)
        self.loop_times.append(perf_counter() - t0)
        if result.score < c.loop_min_score:
            return False
        sigma = self._loop_sigma(result.covariance, float(self.nodes[i, 2]))
        if sigma is None:
            return False
        z = Pose2D(*result.pose).relative_to(Pose2D(*self.nodes[i]))
        now = Pose2D(*self.nodes[j]).relative_to(Pose2D(*self.nodes[i]))
        error = z.relative_to(now)
        shift, turn = math.hypot(error.x, error.y), abs(error.yaw)
        found = (i, j, z.as_array(), kf.travel, self.keyframes[i].travel, sigma)
        if shift <= c.loop_verify[0] and turn <= c.loop_verify[1]:
            accepted = [found]
        else:
            accepted = self._confirmed(found)
            if not accepted:
                return False
        for a, b, zz, _, _, sd in accepted:
            self.edges.append((a, b, zz, sd, True))
        self.loop_closures += len(accepted)
        self._closed_travel = kf.travel
        # A loop edge the graph already agrees with changes nothing worth a solve.
        return len(accepted) > 1 or shift > c.loop_consistent or turn > c.loop_consistent

    def _loop_sigma(self, cov: np.ndarray | None, yaw: float) -> np.ndarray | None:
        """A loop edge's std (in the old keyframe's frame, at ``yaw``): ``loop_edge_sigma``
        widened to the match's own covariance ``cov`` (its refinement's, or its score
        surface's); None when the scan cannot pin the loop, a std in some direction past
        half the loop window or a third of ``loop_verify``'s shift: it saw a ridge (a
        wall, a shelf face, a column or a row of them) along which its optimum lies
        anywhere within a three-sigma reach that spans a correction the pair check would
        hold back, yet it would be taken at once, and the graph, softer between distant
        keyframes, follows it (the depot's east shelf: 0.2 m std, 0.15-0.4 m wrong)."""
        c = self.config
        sxy, sa = c.loop_edge_sigma
        floor = np.array([sxy, sxy, sa])
        if cov is None:
            return floor
        worst = float(np.linalg.eigvalsh(cov[:2, :2])[-1])
        limit = min(0.5 * c.loop_linear_window, c.loop_verify[0] / 3.0)
        if not math.isfinite(worst) or worst > limit**2:
            return None
        cy, sy = math.cos(yaw), math.sin(yaw)
        rot = np.array([[cy, sy, 0.0], [-sy, cy, 0.0], [0.0, 0.0, 1.0]])
        local = rot @ cov @ rot.T
        return np.maximum(floor, np.sqrt(np.maximum(np.diag(local), 0.0)))

    def _confirmed(self, found: tuple[Any, ...]) -> list[tuple[Any, ...]]:
        """``found`` and a pending closure that agrees with it (both to enter the graph),
        or none, ``found`` then waiting for one (see :mod:`pose_graph`)."""
        c = self.config
        travel = found[3]
        self._pending = [p for p in self._pending if travel - p[3] <= c.loop_pair_travel]
        for k in range(len(self._pending) - 1, -1, -1):
            p = self._pending[k]
            shift, turn = loop_pair_error(self.nodes, p[:3], found[:3])
            between = abs(found[3] - p[3]) + abs(found[4] - p[4])
            tol_xy, tol_yaw = c.loop_pair_tolerance
            if shift <= tol_xy + 0.01 * between and turn <= tol_yaw + 0.002 * between:
                del self._pending[k]
                return [p, found]
        self._pending.append(found)
        self.loops_pending += 1
        return []

    def _wide_match(self, j: int, members: np.ndarray, radius: float) -> Any:
        """The match of keyframe ``j`` over +-``radius`` against the keyframes ``members`` (at
        most ``2 loop_submap_keyframes + 1`` of them, evenly spread): a correlative search
        on a field of twice the cell size, then a narrow one on the full resolution."""
        c = self.config
        cap = 2 * c.loop_submap_keyframes + 1
        if len(members) > cap:
            members = members[np.linspace(0, len(members) - 1, cap).round().astype(int)]
        chosen = [int(m) for m in members]
        points, guess = self.keyframes[j].points, self.nodes[j]
        coarse_res = 2.0 * self.resolution
        matcher = CorrelativeMatcher(
            linear_window=radius,
            angular_window=c.loop_wide_angular_window,
            # metres-wide windows: blocks of 32 cells (3.2 m) bound hundreds of positions
            # per angle at once (8 cells took half as long again on acapulco's searches)
            coarse_block=32,
            translation_weight=0.0,  # no pull toward the drifted guess
            rotation_weight=0.0,
            refinement="none",
            search_max_range=c.search_max_range,
        )
        # Each search reads the field no further than its box: the rest is not needed.
        box = matcher.read_box(points, guess, coarse_res)
        coarse = matcher.optimum(self._submap_field(chosen, coarse_res, box), points, guess)
        box = self.loop_refiner.read_box(points, coarse, self.resolution)
        field = self._submap_field(chosen, self.resolution, box)
        return self.loop_refiner.match(field, points, coarse, None)

    def _submap_field(
        self,
        members: list[int],
        res: float | None = None,
        box: tuple[float, float, float, float] | None = None,
    ) -> LikelihoodField:
        """A likelihood field of the keyframes ``members``' scans at their graph poses
        (cells of ``res``, the map's by default; ``box``: see
        :meth:`LikelihoodField.from_points`)."""
        res = self.resolution if res is None else res
        pts = []
        for m in members:
            p = self.nodes[m]
            c, s = math.cos(p[2]), math.sin(p[2])
            q = self.keyframes[m].points
            pts.append(
                np.stack(
                    [p[0] + c * q[:, 0] - s * q[:, 1], p[1] + s * q[:, 0] + c * q[:, 1]], axis=1
                )
            )
        sigma = self.config.likelihood_sigma * res / self.resolution
        return LikelihoodField.from_points(np.vstack(pts), res, sigma, box)

    def _optimize(self) -> Pose2D:
        """Optimise the graph, correct trajectory and map; the new current pose."""
        t0 = perf_counter()
        new, keep = solve_pose_graph(self.nodes, *self._edge_arrays(), self.config.loop_gate)
        if not keep.all():
            self.loop_rejections += int((~keep).sum())
            self.edges = [e for e, k in zip(self.edges, keep, strict=True) if k]
        shift = float(np.hypot(*(new[:, :2] - self.nodes[:, :2]).T).max())
        self.nodes = new
        self.optimizations += 1
        self.optimize_times.append(perf_counter() - t0)
        self._ride_keyframes()
        current = Pose2D(*new[-1])
        if shift > self.config.rebuild_now_threshold:
            self._rebuild()
        elif shift > self.config.rebuild_threshold:
            self._stale = True
        self._pose = current
        self._last_integrated = current
        self._last_pose = current
        return current

    def _edge_arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The graph's edges as arrays: ``ii, jj, z, sigma, loop``."""
        ii, jj, z, sigma, loop = zip(*self.edges, strict=True)
        return np.array(ii), np.array(jj), np.array(z), np.array(sigma), np.array(loop)

    def _ride_keyframes(self) -> None:
        """Every pose of the trajectory rides on its keyframe (Pose2D.compose, all at once)."""
        new = self.nodes
        base = new[np.asarray(self._anchor_keyframe, dtype=np.int64)].reshape(-1, 3)
        rel = np.asarray(self._anchor_offset, dtype=float).reshape(-1, 3)
        c, s = np.cos(base[:, 2]), np.sin(base[:, 2])
        xs = base[:, 0] + c * rel[:, 0] - s * rel[:, 1]
        ys = base[:, 1] + s * rel[:, 0] + c * rel[:, 1]
        yaws = wrap_angles(base[:, 2] + rel[:, 2])
        self.trajectory[:] = [
            (row[0], x, y, a)
            for row, x, y, a in zip(
                self.trajectory, xs.tolist(), ys.tolist(), yaws.tolist(), strict=True
            )
        ]

    def occupancy_grid(self) -> OccupancyGrid:
        if self._stale:
            self._rebuild()
        return super().occupancy_grid()

    def _rebuild(self) -> None:
        """The map again from every integrated scan, each riding on its keyframe's
        optimised pose."""
        t0 = perf_counter()
        self._stale = False
        self._render([Pose2D(*self.nodes[k]).compose(off) for _, k, off, _ in self._integrated])
        self.rebuilds += 1
        self.rebuild_times.append(perf_counter() - t0)

    def _render(self, poses: list[Pose2D]) -> None:
        """A new map of every integrated scan, each at its pose in ``poses``."""
        self._allocate(poses[0] if poses else Pose2D(*self.nodes[0]))
        self.map.reserve([scan for scan, *_ in self._integrated], poses)
        integrations, timed = self.integrations, len(self.integrate_times)
        for (scan, *_), pose in zip(self._integrated, poses, strict=True):
            self._integrate(scan, pose, refresh=False)  # the field once at the end
        self.map.refresh_all()
        self.integrations = integrations + 1  # the grid changed: map users refresh
        del self.integrate_times[timed:]  # front-end timings only
        self._grid_cache = None

    def finish(self) -> None:
        """The whole recording seen (``agv-mission map``): with ``final_smoothing`` the
        trajectory is smoothed with the odometry (:func:`smooth_trajectory`), with
        ``final_odometry_edges`` after the graph is solved again with the calibrated
        odometry's edges (:func:`fuse_odometry`); the map is
        rendered again from it when that moved the integrated scans by more than
        ``rebuild_threshold`` on average (about a centimetre on the real logs: less than
        a cell is not worth the time, as for a rebuild)."""
        c = self.config
        if not c.final_smoothing or len(self.trajectory) < 2:
            return
        t0 = perf_counter()
        poses = np.array([row[1:] for row in self.trajectory])
        noise = c.smoothing_odom_noise or (
            c.odom_translation_noise,
            c.odom_rotation_noise,
            c.odom_rotation_per_metre,
        )
        if c.final_odometry_edges and len(self.nodes) > 1:
            first = np.searchsorted(self._anchor_keyframe, np.arange(len(self.nodes)))
            odom = np.array(self._odom_at)[first]
            self.fusion = fuse_odometry(self.nodes, self._edge_arrays(), odom, noise)
            self.nodes = self.fusion.nodes
            self._ride_keyframes()
        new = smooth_trajectory(
            np.array([row[1:] for row in self.trajectory]) if self.fusion else poses,
            np.array(self._odom_at),
            noise,
            c.smoothing_sigma,
            odom_scale=self.odom_scale,
            calibrate=c.smoothing_calibration,
        )
        self.trajectory[:] = [
            (row[0], float(p[0]), float(p[1]), float(p[2]))
            for row, p in zip(self.trajectory, new, strict=True)
        ]
        idx = [i for *_, i in self._integrated]
        # (no scan integrated, a recording without one valid range: nothing moved)
        moved = float(np.hypot(*(new[idx, :2] - poses[idx, :2]).T).mean()) if idx else 0.0
        # A map lagging the graph is rendered now, from the poses the recording reports.
        if moved > c.rebuild_threshold or self._stale:
            self._stale = False
            self._render([Pose2D(*new[i]) for i in idx])
        self._pose = Pose2D(*new[-1])
        self.smoothing_s = perf_counter() - t0

    def reframe(self, transform: Pose2D) -> bool:
        """Move the map frame: every pose ``p`` becomes ``transform ∘ p`` and the map is
        rendered again from the scans at their moved poses (not resampled: a rotated grid
        would smear the walls by a cell). ``agv-mission map`` lines a finished map up with
        the frame the robot localised in. Always done (True): the scans are kept."""

        def moved(pose: Pose2D) -> Pose2D:
            return transform.compose(pose)

        self.trajectory[:] = [
            (t, *(float(v) for v in moved(Pose2D(x, y, a)).as_array()))
            for t, x, y, a in self.trajectory
        ]
        self.nodes = np.array([moved(Pose2D(*n)).as_array() for n in self.nodes]).reshape(-1, 3)
        self._pose = moved(self._pose)
        if self._last_integrated is not None:
            self._last_integrated = moved(self._last_integrated)
        if self._last_pose is not None:
            self._last_pose = moved(self._last_pose)
        c, s = math.cos(transform.yaw), math.sin(transform.yaw)
        rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        self._cov = rot @ self._cov @ rot.T
        if self._integrated:
            self._stale = False
            self._render([Pose2D(*self.trajectory[i][1:]) for *_, i in self._integrated])
        return True
