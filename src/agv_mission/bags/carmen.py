"""Reading CARMEN logs (``.log``, ``.log.gz``, ``.clf``): the classic 2-D SLAM datasets.

A CARMEN log is text, one message a line, a keyword first. Three are read:

* ``FLASER n r1..rn x y theta odom_x odom_y odom_theta ipc_timestamp host logger_timestamp``:
  a front laser scan (180 degrees, beams counter-clockwise from -90 degrees), the laser's
  pose and the robot's odometry pose when it was taken;
* ``ROBOTLASER1 type start_angle fov resolution max_range accuracy remission_mode n r1..rn
  m e1..em laser_x laser_y laser_theta robot_x robot_y robot_theta tv rv forward_safety
  side_safety turn_axis ipc_timestamp host logger_timestamp``: a scan with its geometry;
* ``ODOM x y theta tv rv accel ipc_timestamp host logger_timestamp``: odometry.

Every other keyword (``PARAM``, ``SYNC``, ``NEFF``, ``TRUEPOS``, ``RLASER``, comments) is
skipped. Readings at or beyond the maximum range (81.83 m, the SICK's "no return" code, in
``FLASER`` logs; ``max_range`` in ``ROBOTLASER1``) become ``+inf``: no return.

What becomes what (``agv-mission map`` reads the result as it reads a bag):

* scans: the laser lines of the kind named by ``--scan-topic`` (``FLASER`` or
  ``ROBOTLASER1``; default: the more frequent one);
* odometry: by default each scan's own odometry pose (logged with it, so no
  interpolation); ``--odom-topic ODOM`` takes the ``ODOM`` lines instead;
* ground truth, only when asked (``--truth-topic FLASER`` / ``ROBOTLASER1`` / ``ODOM``):
  the poses those lines carry. In a *corrected* log (the Radish datasets) those poses were
  fixed by a SLAM afterwards, so they are the truth, but the odometry is corrected too:
  the relative pose error then says how far the SLAM strays from the corrected poses it
  was given, not how well it undoes drift. To measure that, convert the log with drifting
  odometry to a bag (``/ground_truth`` holds the corrected poses).
* the lidar mount: ``FLASER``: ``robot_frontlaser_offset`` metres ahead (a ``PARAM``
  line; 0 without); ``ROBOTLASER1``: its laser pose relative to its robot pose.

Stamps are the ``ipc_timestamp``. Some logs print them with six digits (CSAIL's: 365
scans share one stamp): the log's order is kept, and stamps that do not increase are
spread 1 ms apart, which the report counts.

Bad input is a :class:`~agv_mission.bags.recording.BagError` naming the file, the line and
what is wrong with it; lines are read one at a time, at most ``MAX_LINE`` characters.
"""

from __future__ import annotations

import gzip
import math
from dataclasses import replace
from pathlib import Path
from typing import IO

import numpy as np

from agv_mission.bags.recording import BagData, BagError
from agv_mission.geometry import Pose2D
from agv_mission.sensor_msgs import LaserScan

#: Longest line read (characters): a 100 000-beam scan fits; a binary file does not hang.
MAX_LINE = 1 << 20
#: Most beams a scan may claim.
MAX_BEAMS = 100_000
#: FLASER readings at or beyond this (m) mean "no return" (the SICK LMS's 81.83 m code).
FLASER_NO_RETURN = 80.0
SUFFIXES = (".log", ".log.gz", ".clf", ".clf.gz")
LASERS = ("FLASER", "ROBOTLASER1")


def is_carmen_log(path: Path) -> bool:
    """Whether ``path`` names a CARMEN log (by its suffix)."""
    name = path.name.lower()
    return path.is_file() and name.endswith(SUFFIXES)


def _open(path: Path) -> IO[str]:
    if path.name.lower().endswith(".gz"):
        return gzip.open(path, "rt", encoding="utf-8", errors="replace")
    return path.open("r", encoding="utf-8", errors="replace")


class _Line:
    """The fields of one line, with errors that say where."""

    def __init__(self, path: Path, number: int, fields: list[str]) -> None:
        self.path, self.number, self.fields = path, number, fields

    def error(self, what: str) -> BagError:
        return BagError(f"{self.path}: line {self.number}: {self.fields[0]}: {what}")

    def need(self, count: int, what: str) -> None:
        if len(self.fields) < count:
            raise self.error(f"expected {what}, got {len(self.fields) - 1} fields")

    def number_at(self, k: int, name: str) -> float:
        try:
            value = float(self.fields[k])
        except (ValueError, IndexError):
            got = self.fields[k] if k < len(self.fields) else "nothing"
            raise self.error(f"{name} (field {k}) is not a number: {got!r}") from None
        if not math.isfinite(value):
            raise self.error(f"{name} (field {k}) is not finite: {self.fields[k]!r}")
        return value

    def count_at(self, k: int, name: str) -> int:
        value = self.number_at(k, name)
        if value != int(value) or not 0 < value <= MAX_BEAMS:
            raise self.error(f"{name} (field {k}) must be a count in 1..{MAX_BEAMS}: {value:g}")
        return int(value)

    def ranges(self, start: int, n: int) -> np.ndarray:
        try:
            r = np.array(self.fields[start : start + n], dtype=np.float64)
        except ValueError:
            for k in range(start, start + n):
                self.number_at(k, f"range {k - start + 1}")
            raise
        bad = np.flatnonzero(~np.isfinite(r) | (r < 0))
        if len(bad):
            k = int(bad[0])
            raise self.error(f"range {k + 1} (field {start + k}) is invalid: {r[k]!r}")
        return r


def _flaser(line: _Line) -> tuple[LaserScan, Pose2D, Pose2D, float]:
    line.need(2, "a beam count")
    n = line.count_at(1, "num_readings")
    line.need(2 + n + 7, f"{n} ranges, the laser and odometry poses and the timestamps")
    r = line.ranges(2, n)
    k = 2 + n
    laser = Pose2D(*(line.number_at(k + i, f) for i, f in enumerate(("x", "y", "theta"))))
    odom = Pose2D(
        *(line.number_at(k + 3 + i, f) for i, f in enumerate(("odom_x", "odom_y", "odom_theta")))
    )
    t = line.number_at(k + 6, "ipc_timestamp")
    # CARMEN's convention: 180 degrees; 181 / 361 beams include both ends.
    inc = math.pi / n if n % 2 == 0 else math.pi / max(n - 1, 1)
    ranges = np.where(r >= FLASER_NO_RETURN, np.inf, r).astype(np.float32)
    scan = LaserScan(ranges, -math.pi / 2, inc, 0.0, FLASER_NO_RETURN, t)
    return scan, laser, odom, t


def _robotlaser(line: _Line) -> tuple[LaserScan, Pose2D, Pose2D, float]:
    line.need(9, "the laser's geometry and a beam count")
    start = line.number_at(2, "start_angle")
    fov = line.number_at(3, "field_of_view")
    res = line.number_at(4, "angular_resolution")
    max_range = line.number_at(5, "maximum_range")
    if max_range <= 0:
        raise line.error(f"maximum_range (field 5) must be positive: {max_range:g}")
    n = line.count_at(8, "num_readings")
    line.need(9 + n + 1, f"{n} ranges and a remission count")
    r = line.ranges(9, n)
    k = 9 + n
    m = int(line.number_at(k, "num_remissions"))
    if not 0 <= m <= MAX_BEAMS:
        raise line.error(f"num_remissions (field {k}) must be in 0..{MAX_BEAMS}: {m}")
    k += 1 + m
    line.need(k + 12, f"{m} remissions, the laser and robot poses, 5 values and the timestamps")
    laser = Pose2D(*(line.number_at(k + i, f) for i, f in enumerate(("laser_x", "laser_y", "th"))))
    robot = Pose2D(
        *(line.number_at(k + 3 + i, f) for i, f in enumerate(("robot_x", "robot_y", "theta")))
    )
    t = line.number_at(k + 11, "ipc_timestamp")
    inc = res if res > 0 else (fov / max(n - 1, 1))
    ranges = np.where(r >= max_range, np.inf, r).astype(np.float32)
    scan = LaserScan(ranges, start, inc, 0.0, max_range, t)
    return scan, laser, robot, t


def _odom(line: _Line) -> tuple[float, float, float, float]:
    line.need(8, "x y theta tv rv accel and the timestamps")
    x, y, th = (line.number_at(1 + i, f) for i, f in enumerate(("x", "y", "theta")))
    return line.number_at(7, "ipc_timestamp"), x, y, th


def read_carmen(
    path: Path,
    scan_topic: str | None = None,
    odom_topic: str | None = None,
    truth_topic: str | None = None,
) -> BagData:
    """Scans, odometry, mount and (when asked) ground truth of the CARMEN log at ``path``."""
    _check_topics(path, scan_topic, odom_topic, truth_topic)
    lasers, odom_lines, params = _read_lines(path)
    kind = scan_topic or max(LASERS, key=lambda k: len(lasers[k]))
    rows = lasers[kind]
    if not rows:
        raise BagError(f"{path}: no {kind if scan_topic else 'FLASER or ROBOTLASER1'} line")
    times = np.array([row[3] for row in rows])
    repaired = _increasing(times)
    scans = [replace(row[0], time=float(t)) for row, t in zip(rows, times, strict=True)]
    mount = _laser_mount(path, kind, rows, params)
    inv_mount = Pose2D(0.0, 0.0, 0.0).relative_to(mount)

    def laser_rows(which: str) -> np.ndarray:
        if which == kind:  # the scans' own poses, at the (repaired) scan stamps
            own = [
                (t, *row[1].compose(inv_mount).as_array())
                for row, t in zip(rows, times, strict=True)
            ]
            return np.array(own, dtype=float)
        other = lasers[which]
        if not other:
            raise BagError(f"{path}: no {which} line")
        t = np.array([row[3] for row in other])
        _increasing(t)
        return np.array(
            [(ti, *row[1].compose(inv_mount).as_array()) for row, ti in zip(other, t, strict=True)]
        )

    def odom_rows(which: str | None) -> np.ndarray:
        if which is None or which == kind:
            return np.array([(t, *row[2].as_array()) for row, t in zip(rows, times, strict=True)])
        if which == "ODOM":
            if not odom_lines:
                raise BagError(f"{path}: no ODOM line")
            out = np.array(odom_lines, dtype=float)
            if np.any(np.diff(out[:, 0]) < 0):
                raise BagError(f"{path}: the ODOM lines' timestamps go backwards")
            return out
        other = lasers[which]
        if not other:
            raise BagError(f"{path}: no {which} line")
        return np.array([(row[3], *row[2].as_array()) for row in other])

    odom = odom_rows(odom_topic)
    truth = None
    if truth_topic == "ODOM":
        truth = odom_rows("ODOM")
    elif truth_topic is not None:
        truth = laser_rows(truth_topic)
    n_beams = len(scans[0].ranges)
    return BagData(
        scans=scans,
        scan_topic=kind,
        scan_frame="laser",
        odom=odom,
        odom_source=(
            f"{odom_topic} lines" if odom_topic == "ODOM" else f"{odom_topic or kind} odometry"
        ),
        base_frame="robot",
        mount=mount,
        flipped=False,
        mount_found=True,
        truth=truth,
        truth_topic=truth_topic if truth is not None else None,
        topics={k: f"carmen/{k}" for k in (*LASERS, "ODOM") if lasers.get(k) or k == "ODOM"},
        duration=float(times[-1] - times[0]),
        notes={"format": "carmen", "stamps_spread": repaired, "beams": n_beams},
    )


def _check_topics(
    path: Path, scan_topic: str | None, odom_topic: str | None, truth_topic: str | None
) -> None:
    """Each topic asked for is one a CARMEN log can have."""
    for name, value, allowed in (
        ("--scan-topic", scan_topic, LASERS),
        ("--odom-topic", odom_topic, (*LASERS, "ODOM")),
        ("--truth-topic", truth_topic, (*LASERS, "ODOM")),
    ):
        if value is not None and value not in allowed:
            raise BagError(
                f"{path}: {name} {value!r}: a CARMEN log has {', '.join(allowed)} for it"
            )


def _read_lines(
    path: Path,
) -> tuple[
    dict[str, list[tuple[LaserScan, Pose2D, Pose2D, float]]],
    list[tuple[float, float, float, float]],
    dict[str, str],
]:
    """The log's laser lines (scan, laser pose, robot pose, time) by kind, its ODOM lines
    (t, x, y, yaw) and its PARAMs."""
    lasers: dict[str, list[tuple[LaserScan, Pose2D, Pose2D, float]]] = {k: [] for k in LASERS}
    odom_lines: list[tuple[float, float, float, float]] = []
    params: dict[str, str] = {}
    try:
        with _open(path) as f:
            number = 0
            while True:
                text = f.readline(MAX_LINE)
                if not text:
                    break
                number += 1
                if len(text) >= MAX_LINE and not text.endswith("\n"):
                    raise BagError(f"{path}: line {number}: longer than {MAX_LINE} characters")
                fields = text.split()
                if not fields:
                    continue
                kind = fields[0]
                if kind == "FLASER":
                    lasers[kind].append(_flaser(_Line(path, number, fields)))
                elif kind == "ROBOTLASER1":
                    lasers[kind].append(_robotlaser(_Line(path, number, fields)))
                elif kind == "ODOM":
                    odom_lines.append(_odom(_Line(path, number, fields)))
                elif kind == "PARAM" and len(fields) >= 3:
                    params[fields[1]] = fields[2]
    except (OSError, EOFError, gzip.BadGzipFile) as exc:
        raise BagError(f"{path}: cannot read the log ({exc})") from None
    return lasers, odom_lines, params


def _laser_mount(
    path: Path,
    kind: str,
    rows: list[tuple[LaserScan, Pose2D, Pose2D, float]],
    params: dict[str, str],
) -> Pose2D:
    """Where the laser sits on the robot: ROBOTLASER1 lines give both poses; FLASER's is
    the ``robot_frontlaser_offset`` PARAM ahead of the robot's origin."""
    if kind == "ROBOTLASER1":
        return rows[0][1].relative_to(rows[0][2])
    try:
        return Pose2D(float(params.get("robot_frontlaser_offset", 0.0)), 0.0, 0.0)
    except ValueError:
        raise BagError(
            f"{path}: PARAM robot_frontlaser_offset is not a number: "
            f"{params['robot_frontlaser_offset']!r}"
        ) from None


def _increasing(times: np.ndarray) -> int:
    """Make ``times`` strictly increasing in place (1 ms apart at least); how many moved."""
    moved = 0
    for k in range(1, len(times)):
        if times[k] <= times[k - 1]:
            times[k] = times[k - 1] + 1e-3
            moved += 1
    return moved
