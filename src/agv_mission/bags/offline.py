"""``agv-mission map BAG``: the configured SLAM over a recording, as fast as it goes.

A recording is a bag or a CARMEN log (:mod:`agv_mission.bags.carmen`). The map is saved
cropped to what was seen plus :data:`~agv_mission.mapping.crop.CROP_MARGIN`; against a
ground truth the report gives the trajectory's RMSE and the relative pose error of
Kümmerle et al. (2009) over pairs :data:`RPE_DELTA` metres of travel apart.

The SLAM runs on the *lidar's* poses: odometry of the base composed with the mount, and
scans turned upright (:func:`~agv_mission.bags.reader.upright`), so an off-centre or
upside-down lidar traces its beams from where it really is. The map frame is the bag's
``map`` frame when the bag has ``map -> odom`` at the first scan (so the map lines up
with the one the robot used), else the odometry frame, as gmapping starts.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from agv_mission.bags.reader import BagData, interpolate_poses, read_bag, upright
from agv_mission.bags.recording import BagError
from agv_mission.geometry import Pose2D
from agv_mission.json_values import finite
from agv_mission.mapping.base import Slam
from agv_mission.mapping.crop import crop_to_known
from agv_mission.mapping.log_odds_map import MapTooLarge
from agv_mission.mapping.quality import relative_pose_error
from agv_mission.maps.grid import OccupancyGrid
from agv_mission.maps.ros_map import save_ros_map
from agv_mission.registry import UnknownPluginError, registry

_ORIGIN = Pose2D(0.0, 0.0, 0.0)


@dataclass
class OfflineMap:
    """A map built from a bag, with what it took."""

    grid: OccupancyGrid
    trajectory: np.ndarray  # (n, 4) t, x, y, yaw of the base frame in the map frame
    report: dict[str, Any] = field(default_factory=dict)


def _pose(row: np.ndarray) -> Pose2D:
    return Pose2D(float(row[0]), float(row[1]), float(row[2]))


def map_bag(
    path: Path,
    slam_config: Any | Callable[[float], Any],
    scan_topic: str | None = None,
    odom_topic: str | None = None,
    truth_topic: str | None = None,
    max_odom_gap: float = 1.0,
    robot: str | None = None,
) -> OfflineMap:
    """Build a map from the bag at ``path`` with the SLAM plugin ``slam_config`` (or the
    one ``slam_config(range_max)`` picks for the bag's scanner: :func:`default_slam`);
    ``robot``: whose topics, in a bag of several robots (a fleet run's).

    Raises :class:`~agv_mission.bags.reader.BagError` for input that cannot be mapped.
    """
    t_read = time.perf_counter()
    data = read_bag(path, scan_topic, odom_topic, truth_topic, robot)
    read_s = time.perf_counter() - t_read
    times, odom_at, used, outside = _covered_scans(path, data, max_odom_gap)
    mount, inv_mount = data.mount, _ORIGIN.relative_to(data.mount)
    first = int(used[0])
    start = _start_pose(data, times[first], _pose(odom_at[first]))
    if callable(slam_config):
        slam_config = slam_config(max(s.range_max for s in data.scans))
    try:
        slam: Slam = registry.create("slam", slam_config, bounds=None, rng=None)
        slam.reset(start.compose(mount), _pose(odom_at[first]).compose(mount))
    except MapTooLarge as exc:  # the first map: the settings' size (scans': _replay)
        raise BagError(f"{path}: stack.slam (--set): {exc}") from None
    slam_s = _replay(path, slam, data, odom_at, times, used)
    base = _base_trajectory(slam, inv_mount)
    fit = _map_frame_fit(data, base)
    # the finished poses moved, the map rendered from them (no new SLAM run); or not
    reframed = fit is not None and slam.reframe(fit)
    if reframed:
        base = _base_trajectory(slam, inv_mount)
    canvas = slam.occupancy_grid()
    grid = crop_to_known(canvas)
    wall = time.perf_counter() - t_read
    duration = float(times[used].max() - times[used].min()) if len(used) > 1 else 0.0
    known = data.timed and duration > 0.0
    report: dict[str, Any] = {
        "bag": str(path),
        **({"input": data.notes} if data.notes else {}),
        **({"robot": data.robot} if data.robot else {}),
        "scan_topic": data.scan_topic,
        "scan_frame": data.scan_frame,
        "odometry": data.odom_source,
        "base_frame": data.base_frame,
        "lidar_mount": {
            "x": round(mount.x, 4),
            "y": round(mount.y, 4),
            "yaw": round(mount.yaw, 4),
            "upside_down": data.flipped,
            "from_tf": data.mount_found,
        },
        "slam": slam_config.model_dump(mode="json"),
        "map_frame": _fit_report(fit, reframed),
        "scans": {
            "total": len(data.scans),
            "used": len(used),
            **outside,
            "beams": sorted({len(s.ranges) for s in data.scans}),
            "scan_gaps": _gaps(times),
        },
        "odometry_messages": len(data.odom),
        "trajectory_poses": len(base),
        "bag_duration": round(duration, 3) if known else None,
        "wall_time": round(wall, 3),
        "read_time": round(read_s, 3),
        "slam_time": round(slam_s, 3),
        "scans_per_second": round(len(used) / slam_s, 1) if slam_s > 0 else None,
        "speed_vs_real_time": round(duration / wall, 2) if known and wall > 0 else None,
        "map": {
            "width": grid.width,
            "height": grid.height,
            "resolution": grid.resolution,
            "origin": [round(grid.origin.x, 4), round(grid.origin.y, 4), 0.0],
            "canvas": [canvas.width, canvas.height],
        },
    }
    report["slam_diagnostics"] = slam.diagnostics()
    if data.truth is not None and len(base):
        report.update(_accuracy(base, data.truth, data.truth_topic))
    return OfflineMap(grid=grid, trajectory=base, report=report)


def _base_trajectory(slam: Slam, inv_mount: Pose2D) -> np.ndarray:
    """SLAM's trajectory (of the lidar) as the base frame's, rows t, x, y, yaw."""
    sensor = np.asarray(slam.trajectory, dtype=float).reshape(-1, 4)
    rows = [(t, *Pose2D(x, y, a).compose(inv_mount).as_array()) for t, x, y, a in sensor]
    return np.array(rows).reshape(-1, 4)


#: Metres the mapped trajectory must span for its fit to the bag's map frame to fix a
#: heading (a robot that turned on the spot gives a rotation nothing pins).
FIT_MIN_SPAN = 1.0


def _map_frame_fit(data: BagData, base: np.ndarray) -> Pose2D | None:
    """The rigid motion that lines the mapped trajectory up, in the least-squares sense,
    with the robot's own estimate while it ran (the bag's ``map -> odom`` composed with
    the odometry at the same stamps), or ``None`` when the bag's map frame is only the
    odometry's (``map -> odom`` never moved: no localiser corrected it, and fitting to
    the odometry would bend the map by its drift).

    SLAM starts from the estimate at the first scan, so a heading a few milliradians off
    there turns the whole map about the start; the fit weighs every pose instead."""
    rows = data.map_to_odom
    if rows is None or len(rows) < 2 or len(base) < 3:
        return None
    corrections = np.ptp(rows[:, 1:3], axis=0).max(), np.ptp(np.unwrap(rows[:, 3]))
    if max(corrections) < 1e-6:
        return None
    if np.ptp(base[:, 1:3], axis=0).max() < FIT_MIN_SPAN:
        return None
    t = base[:, 0]
    m2o, _ = interpolate_poses(rows, t, np.inf)
    odom, _ = interpolate_poses(data.odom, t, np.inf)
    ref = np.array(
        [_pose(m).compose(_pose(o)).as_array()[:2] for m, o in zip(m2o, odom, strict=True)]
    )
    return rigid_fit(base[:, 1:3], ref)


def rigid_fit(p: np.ndarray, g: np.ndarray) -> Pose2D:
    """The rotation and translation ``T`` minimising the sum of ``|T(p_i) - g_i|^2``
    over points (n, 2) (Umeyama / Kabsch in 2-D, no scale), as a pose: ``T(p)`` is
    ``pose.compose(Pose2D(*p))``."""
    pm, gm = p.mean(axis=0), g.mean(axis=0)
    u, _, vt = np.linalg.svd((p - pm).T @ (g - gm))
    d = np.sign(np.linalg.det(vt.T @ u.T)) or 1.0
    r = vt.T @ np.diag([1.0, d]) @ u.T
    t = gm - r @ pm
    return Pose2D(float(t[0]), float(t[1]), float(np.arctan2(r[1, 0], r[0, 0])))


def _fit_report(fit: Pose2D | None, applied: bool) -> dict[str, Any]:
    """How the map frame was placed: the bag's at the first scan, or fitted to the
    robot's estimate over the whole run (the correction applied)."""
    if fit is None or not applied:
        return {"fitted": False}
    return {"fitted": True, "x": round(fit.x, 4), "y": round(fit.y, 4), "yaw": round(fit.yaw, 5)}


def _covered_scans(
    path: Path, data: Any, max_odom_gap: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict[str, int]]:
    """The scans' stamps, the odometry at each, the scans it covers (none further than
    ``max_odom_gap`` from an odometry message) and how many it does not (before, after,
    in a gap)."""
    times = np.array([s.time for s in data.scans])
    odom_at, ok = interpolate_poses(data.odom, times, max_odom_gap)
    before = int(np.count_nonzero(times < data.odom[0, 0] - 1e-6))
    after = int(np.count_nonzero(times > data.odom[-1, 0] + 1e-6))
    in_gap = int(np.count_nonzero(~ok)) - before - after
    used = np.flatnonzero(ok)
    if not len(used):
        raise MappingFailed(
            f"{path}: no scan falls inside the odometry ({data.odom_source}: "
            f"{data.odom[0, 0]:.3f}..{data.odom[-1, 0]:.3f} s; scans "
            f"{times.min():.3f}..{times.max():.3f} s)"
        )
    outside = {"before_odometry": before, "after_odometry": after, "in_odometry_gaps": in_gap}
    return times, odom_at, used, outside


def _replay(
    path: Path, slam: Slam, data: Any, odom_at: np.ndarray, times: np.ndarray, used: np.ndarray
) -> float:
    """Feed SLAM the used scans (upright, with the odometry at each, at the lidar's
    mount) and its final pass; the seconds it took."""
    mount = data.mount
    t0 = time.perf_counter()
    for i in used:
        scan = upright(data.scans[i], data.flipped)
        odom = _pose(odom_at[i])
        try:
            slam.update(odom.compose(mount), scan, _ORIGIN, float(times[i]))
        except MapTooLarge as exc:
            scan_at = (
                f"scan {i + 1} of {len(data.scans)} (t = {times[i]:.3f} s, odometry at x "
                f"{odom.x:.4g} y {odom.y:.4g}, lidar {mount.x:.4g} m ahead, ranges to "
                f"{data.scans[i].range_max:.4g} m)"
            )
            raise BagError(f"{path}: {scan_at}: {exc}") from None
    slam.finish()  # the whole recording seen: a final pass (the protocol's: none)
    return time.perf_counter() - t0


def _accuracy(base: np.ndarray, truth: np.ndarray, truth_topic: str | None) -> dict[str, Any]:
    """How far the mapped trajectory (rows t, x, y, yaw) lies from the bag's ground truth:
    its RMSE and its relative pose error over ``RPE_DELTA`` metres."""
    report: dict[str, Any] = {"ground_truth_topic": truth_topic, "rmse": _rmse(base, truth)}
    rpe = relative_pose_error(base, truth, RPE_DELTA)
    if rpe:
        report["relative_pose_error"] = {
            "translation_m": round(rpe["translation_mean"], 4),
            "rotation_deg": round(float(np.degrees(rpe["rotation_mean"])), 3),
            "translation_max_m": round(rpe["translation_max"], 4),
            "rotation_max_deg": round(float(np.degrees(rpe["rotation_max"])), 3),
            "pairs": int(rpe["pairs"]),
            "delta_m": RPE_DELTA,
        }
    return report


#: Metres of true travel between the poses of each relative-pose-error pair (consecutive
#: pairs, as the issue's figures and the usual 1 m-scale comparisons on these logs).
RPE_DELTA = 1.0


class MappingFailed(Exception):
    """The bag was readable but no map came out of it (exit code 1)."""


def _start_pose(data: BagData, t: float, odom: Pose2D) -> Pose2D:
    """The base pose in the map frame at the first scan: through the bag's map -> odom
    when it has one, else the odometry frame is the map frame."""
    if data.map_to_odom is None or not len(data.map_to_odom):
        return odom
    rows = data.map_to_odom
    k = int(np.clip(np.searchsorted(rows[:, 0], t), 0, len(rows) - 1))
    if k > 0 and abs(rows[k - 1, 0] - t) < abs(rows[k, 0] - t):
        k -= 1
    return _pose(rows[k, 1:]).compose(odom)


def _gaps(times: np.ndarray) -> int:
    """Intervals between scans longer than three times the median interval."""
    if len(times) < 3:
        return 0
    d = np.diff(np.sort(times))
    return int(np.count_nonzero(d > 3.0 * float(np.median(d))))


def _rmse(est: np.ndarray, truth: np.ndarray) -> dict[str, float]:
    """Position RMSE against ground truth at the same stamps: in the map frame as is, and
    after the best rigid alignment (the usual ATE, for truth in another frame)."""
    t = truth[:, 0]
    keep = (est[:, 0] >= t[0]) & (est[:, 0] <= t[-1])
    e = est[keep]
    if not len(e):
        return {}
    gx = np.interp(e[:, 0], t, truth[:, 1])
    gy = np.interp(e[:, 0], t, truth[:, 2])
    g = np.stack([gx, gy], axis=1)
    p = e[:, 1:3]
    raw = float(np.sqrt(np.mean(np.sum((p - g) ** 2, axis=1))))
    fit = rigid_fit(p, g)
    c, s = np.cos(fit.yaw), np.sin(fit.yaw)
    aligned = p @ np.array([[c, s], [-s, c]]) + (fit.x, fit.y)
    ate = float(np.sqrt(np.mean(np.sum((aligned - g) ** 2, axis=1))))
    return {"position_rmse": round(raw, 4), "ate_aligned": round(ate, 4), "poses": int(len(e))}


def save_outputs(result: OfflineMap, stem: Path) -> dict[str, Path]:
    """``stem.pgm`` + ``stem.yaml`` (map_saver), ``stem_trajectory.csv``, ``stem_report.json``."""
    if stem.suffix.lower() in (".pgm", ".yaml", ".yml"):
        stem = stem.with_suffix("")
    pgm, yaml_path = save_ros_map(result.grid, stem)
    traj = stem.parent / (stem.name + "_trajectory.csv")
    np.savetxt(traj, result.trajectory, delimiter=",", header="t,x,y,yaw", comments="", fmt="%.6f")
    report = stem.parent / (stem.name + "_report.json")
    report.write_text(json.dumps(finite(result.report), indent=2) + "\n", encoding="utf-8")
    return {"pgm": pgm, "yaml": yaml_path, "trajectory": traj, "report": report}


def report_lines(result: OfflineMap, paths: dict[str, Path]) -> list[str]:
    """What ``agv-mission map`` made, a line each: scans used, speed, odometry source, the
    trajectory's RMSE and relative pose error against ground truth (when the bag has one)
    and the files written."""
    r = result.report
    scans = r["scans"]
    if r["bag_duration"] is None:
        span = "its stamps tell no duration" if scans["used"] > 1 else "one scan: no duration"
        speed = f"{r['scans_per_second']} scans a second"
    else:
        span = f"{r['bag_duration']:.1f} s of bag"
        speed = f"{r['speed_vs_real_time']}x real time"
    lines = [
        f"mapped {scans['used']}/{scans['total']} scans of {r['scan_topic']} "
        f"({span}) in {r['wall_time']:.1f} s ({speed}); odometry from {r['odometry']}"
    ]
    if r.get("rmse"):
        lines.append(
            f"trajectory RMSE vs {r['ground_truth_topic']}: {r['rmse']['position_rmse']:.3f} m "
            f"(aligned {r['rmse']['ate_aligned']:.3f} m)"
        )
    if r.get("relative_pose_error"):
        e = r["relative_pose_error"]
        lines.append(
            f"relative pose error vs {r['ground_truth_topic']} ({e['pairs']} pairs "
            f"{e['delta_m']:g} m of travel apart): {e['translation_m']:.3f} m, "
            f"{e['rotation_deg']:.2f} deg"
        )
    lines += [f"{what}: {path}" for what, path in paths.items()]
    return lines


#: The SLAM ``agv-mission map`` runs unless told otherwise: loop closure (real bags drive
#: loops); a scan is matched once the robot moved 10 cm / 0.1 rad (gmapping's and
#: Cartographer's motion filter; a real log's scans overlap, see below); the
#: correlative search scores the points within 10 m, one per cell (a real lidar's 40 m
#: returns made its window and angular steps huge), and is skipped when the refinement
#: from the odometry lands well (Cartographer's 2-D default skips it always); a miss
#: weighs a quarter of a hit (Cartographer: 0.55 / 0.49; a beam grazing a wall is weak
#: evidence that the wall is not there); the odometry prior is a wheeled robot's (2 % of
#: the distance, 0.03 rad per metre and 5 % of each turn: the few-percent errors
#: Borenstein and Feng's UMBmark measured on differential drives), not the mission
#: SLAM's slipping-wheel one: over a metre a real robot's odometry beats a scan match,
#: and trusting it less made the relative pose error on the Freiburg 079 log 0.028 m
#: instead of 0.021 m; loops are searched every eighth keyframe (every sixteenth cost the
#: thinned ACES log half its loop closures and a tenth of its walls); a scan is integrated
#: every 0.3 m / 0.3 rad. Those two, against 5 cm / 0.2 m, side by side on Freiburg 079
#: (issue 32: mapping at 40x the log's
#: duration; with this round's faster matcher and field refresh, against the code and
#: settings before it): 1.67x less CPU time (27.3 s instead of 45.5 s), relative pose
#: error 0.0093 m instead of 0.0095 m, walls within 0.1 m of the reference 0.977 instead
#: of 0.953 (with ``wall_faces``), free cells 0.902 instead of 0.893:
#: the scans of a 0.1 m-apart log overlap so much that the extra matches and
#: integrations added time, not accuracy. (Four refinement steps instead of six
#: saved little more, and left the front end alone drifting three times as far on a
#: simulated 100 m loop: not taken.) A cell is FREE below 0.196,
#: map_saver's ``free_thresh``; a wall is a cell
#: that returned two beams (a single return at the end of a long beam through a door,
#: a person, a grazed edge is no wall: with the true poses of the ACES log, 99 % of the
#: walls within 0.1 m of the reference instead of 91 %); once the log ends the trajectory
#: is smoothed with the odometry (poses within 4 cm / 0.02 rad: twice the front end's own
#: error over a metre, its errors being correlated from pose to pose) and the map
#: rendered from it (relative pose error on the first 1500 scans of Freiburg 079 0.010 m
#: instead of 0.022 m; odometry alone makes 0.011 m over a metre, but drifts).
#: Both draw walls at their faces (``wall_faces``: a noisy lidar's returns from a face on a
#: cell boundary fall on both sides; on the house, 72-81 % of a map's border wall cells
#: stood a cell in front of the face, 20-25 % with it, and localising in the house on a map
#: made from a patrol's bag: 0.071 m RMSE instead of 0.075 m).
#: Loops are searched wider the longer since the last closure (3 cm per metre: the ACES
#: log drifts 7 m in 250 m, and its big loops were never found), also every 3 m driven
#: (a log of a scan a metre, ACES's, has a keyframe a scan: every eighth keyframe was
#: every 6 m there), and the odometry's scale is learnt where the scan sees the motion
#: (2 % prior: a wheel radius off by a percent or two; the converted logs' odometry runs
#: 1 % long, which made ACES's map 0.5-0.8 % too large).
#: The mission SLAM's defaults: what maps a short-range lidar's bag (an LDS-01's 3.5 m) best.
SHORT_RANGE_SLAM: dict[str, Any] = {
    "type": "graph",
    "match_min_d": 0.05,
    "match_min_a": 0.05,
    "wall_faces": True,
}

#: Scanners reaching this far (m) are mapped with :data:`DEFAULT_SLAM`.
LONG_RANGE_MIN = 10.0

#: Tuned on real long-range logs (SICK scanners of the CARMEN logs, 80 m): a tight odometry
#: prior, a ranged wide search, cells that ever returned a beam never free, no-return beams
#: clearing 3 m.
DEFAULT_SLAM: dict[str, Any] = {
    "type": "graph",
    "match_min_d": 0.1,
    "match_min_a": 0.1,
    "search_max_range": 10.0,
    "fast_match_score": 0.5,
    "log_odds_free": -0.2,
    "odom_translation_noise": 0.02,
    "odom_rotation_per_metre": 0.03,
    "odom_rotation_noise": 0.05,
    "odom_scale_std": 0.02,
    "loop_check_every": 8,
    "loop_check_distance": 3.0,
    "loop_search_growth": 0.03,
    "update_min_d": 0.3,
    "update_min_a": 0.3,
    "free_threshold": 0.196,
    "free_max_hits": 0,
    "missing_data_ray_length": 3.0,
    "occupied_min_hits": 2,
    "wall_faces": True,
    "final_smoothing": True,
    "smoothing_sigma": (0.04, 0.02),
    # the odometry's systematic errors learnt and taken out before the final smoothing,
    # and its motion as edges of the keyframe graph too, weighted by how steady this
    # recording's wheels are (pose_graph.odometry_heading_spread): it lifts sparse logs
    # recorded with steady wheels and leaves wheels that slip at random (the simulated
    # 100 m loop of tests/test_graph_slam.py) to the scans
    "smoothing_calibration": True,
    "final_odometry_edges": True,
    # random odometry error once its systematic part is learnt: 2 % of the distance (wheel
    # slip, a tyre's load), 5 % of a turn (tyre scrub moves the wheels' contact points),
    # 0.3 deg per metre (floor seams and bumps)
    "smoothing_odom_noise": (0.02, 0.05, 0.005),
    # a loop closure's heading is a scan match's, as good as a consecutive pair's: the
    # corrected logs' scans, placed at their corrected poses, disagree with the next scan's
    # match by 0.3 deg (median) and 0.6-0.8 deg (std) on ACES, CSAIL, Freiburg 079 and the
    # Intel lab alike; the graph default's 0.05 rad (2.9 deg) left the heading to the chain
    "loop_edge_sigma": (0.05, 0.01),
}


def default_slam(overrides: list[str]) -> Callable[[float], Any]:
    """``map``'s SLAM for a bag whose scanner reaches ``range_max``: :data:`DEFAULT_SLAM`
    for long-range scanners, :data:`SHORT_RANGE_SLAM` for short-range ones, each with the
    ``--set`` items (checked against both now: bad input fails before the bag is read)."""
    long_range = slam_config(overrides)
    short_range = slam_config(overrides, SHORT_RANGE_SLAM)
    return lambda range_max: long_range if range_max >= LONG_RANGE_MIN else short_range


def slam_config(overrides: list[str], base: dict[str, Any] | None = None) -> Any:
    """The SLAM plugin config from ``base`` (default :data:`DEFAULT_SLAM`) and ``--set``
    items (``stack.slam.KEY=VALUE`` or ``KEY=VALUE``); :class:`MissionError` when invalid."""
    from pydantic import ValidationError

    from agv_mission.missions.load.errors import MissionError, Problem
    from agv_mission.missions.load.overrides import override_error, override_value
    from agv_mission.missions.load.schema import Stack

    doc = dict(DEFAULT_SLAM if base is None else base)
    for item in overrides:
        key, sep, raw = item.partition("=")
        key = key.strip().removeprefix("stack.").removeprefix("slam.")
        if not sep or not key or "." in key:
            raise override_error(item, "expected KEY=VALUE of the SLAM, e.g. type=grid")
        value = override_value(raw)
        if key == "type" and value != doc.get("type"):
            doc = {k: v for k, v in doc.items() if k in _slam_fields(value)}
        doc[key] = value
    try:
        return Stack.model_validate({"slam": doc}).slam
    except ValidationError as exc:
        raise MissionError(
            [
                Problem("--set", None, _dotted(err["loc"], doc.get("type")), err["msg"])
                for err in exc.errors()
            ]
        ) from None


def _slam_fields(name: Any) -> set[str]:
    """The config keys of SLAM plugin ``name`` (none when there is no such plugin)."""
    try:
        return set(registry.config("slam", str(name)).model_fields)
    except UnknownPluginError:  # validation names it
        return set()


def _dotted(loc: tuple[Any, ...], plugin: Any) -> str:
    """``stack.slam.KEY`` from pydantic's location (which names the union's tag too)."""
    parts = [str(p) for p in loc if p != plugin]
    return ".".join(["stack", *parts])
