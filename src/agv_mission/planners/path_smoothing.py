"""Smoothing a grid path for :mod:`cost_grid`: any-angle shortcuts that keep clearance,
then circular fillets at the corners, and the curvature measure the tests use.

1. **Any-angle smoothing.** The cell path becomes a polyline whose vertices are the
   cells where it turns; a vertex is dropped when the straight segment that replaces it
   is free and comes no nearer to an obstacle than the path it replaces did (nor nearer
   than the edge of the inflation zone, beyond which every cell costs nothing).
2. **Fillets.** Each remaining corner is rounded by a circular arc of radius up to
   ``max_turn_radius`` that keeps the same clearance, so the curvature the robot must
   follow is bounded and it need not stop at corners.
"""

from __future__ import annotations

import math

import numpy as np

from agv_mission.planners.free_space import EDGE_EPS, FreeSpace

# Shortcuts may end at any turn of the cell path and at every few cells between: the
# tangent to an obstacle often touches the middle of a straight run.
SHORTCUT_EVERY = 4


def _turns(cells: np.ndarray, w: int, every: int = 0) -> np.ndarray:
    """Indices into ``cells`` of the path's ends, of every cell where it turns and (with
    ``every``) of every ``every``-th cell: the vertices shortcuts may end at."""
    rows, cols = np.divmod(cells, w)
    if len(cells) <= 2:
        return np.arange(len(cells))
    d = np.stack([np.diff(rows), np.diff(cols)], axis=1)
    turn = np.any(d[1:] != d[:-1], axis=1)
    idx = [[0], np.flatnonzero(turn) + 1, [len(cells) - 1]]
    if every > 0:
        idx.append(np.arange(0, len(cells), every))
    return np.unique(np.concatenate(idx))


def segments_cells(space: FreeSpace, a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, ...]:
    """The cells of many segments ``a[i] -> b[i]`` at once, the same cells
    :meth:`FreeSpace.segment_cells` finds for one (the cells at the ends and either side
    of every grid-line crossing, both cells within ``EDGE_EPS`` of an edge; it may leave
    out a cell whose corner the segment passes within ``EDGE_EPS``).

    Returns ``(cells, mask, inside)``: flat indices (m, p), which of them are real, and
    which segments stay on the grid.
    """
    res = space.res
    u0, v0 = a[:, 0] / res, a[:, 1] / res
    du, dv = b[:, 0] / res - u0, b[:, 1] / res - v0
    m = len(a)
    parts = [np.zeros((m, 1)), np.ones((m, 1))]
    for c0, d in ((u0, du), (v0, dv)):
        lo = np.ceil(np.minimum(c0, c0 + d))
        count = np.where(d != 0.0, np.floor(np.maximum(c0, c0 + d)) - lo + 1.0, 0.0)
        most = int(count.max(initial=0.0))
        if most > 0:
            k = np.arange(most)
            with np.errstate(divide="ignore", invalid="ignore"):
                t = (lo[:, None] + k[None, :] - c0[:, None]) / d[:, None]
            t[k[None, :] >= count[:, None]] = np.nan
            parts.append(t)
    # The cells either side of every crossing cover every piece between crossings too:
    # no need for the pieces' midpoints (nor to sort the crossings).
    t = np.concatenate(parts, axis=1)
    valid = ~np.isnan(t)
    t = np.where(valid, t, 0.0)
    u, v = u0[:, None] + t * du[:, None], v0[:, None] + t * dv[:, None]
    cols = np.floor(np.concatenate([u - EDGE_EPS, u + EDGE_EPS, u - EDGE_EPS, u + EDGE_EPS], 1))
    rows = np.floor(np.concatenate([v - EDGE_EPS, v - EDGE_EPS, v + EDGE_EPS, v + EDGE_EPS], 1))
    mask = np.tile(valid, 4)
    on_grid = (cols >= 0) & (rows >= 0) & (cols < space.width) & (rows < space.height)
    inside = np.all(on_grid | ~mask, axis=1)
    mask &= on_grid
    cells = np.where(mask, rows * space.width + cols, 0).astype(np.int64)
    return cells, mask, inside


def segments_clearance(space: FreeSpace, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Least obstacle distance along each segment ``a[i] -> b[i]``; -inf where it crosses a
    cell that is not free or leaves the grid."""
    cells, mask, inside = segments_cells(space, a, b)
    free = np.all(space.free_flat[cells] | ~mask, axis=1) & inside
    least = np.min(np.where(mask, space.distance_flat[cells], np.inf), axis=1)
    return np.where(free, least, -np.inf)


def any_angle(
    space: FreeSpace, pts: np.ndarray, seg_floor: np.ndarray, comfort: float
) -> np.ndarray:
    """Greedy line-of-sight shortcuts of the polyline ``pts`` (local frame).

    ``seg_floor[i]`` is the least clearance of the path between vertices i and i + 1.
    A run of vertices is replaced by one segment when that segment crosses only free
    cells, none nearer to an obstacle than the run came (capped at ``comfort``), give or
    take a cell. From each vertex, the segments to vertices 1, 2, 4, 8, ... ahead are
    checked in one batch (:func:`segments_clearance`), then 16 at a time between the
    farthest one reached and the nearest one missed.
    """
    n = len(pts)
    if n <= 2:
        return pts
    floor = np.minimum(seg_floor, comfort)
    slack = space.res  # a cell of clearance is not worth a zigzag
    out = [0]
    i = 0
    while i < n - 1:
        lowest = np.minimum.accumulate(floor[i:])  # lowest[e - 1 - i]: the run i..e

        def reaches(ends: np.ndarray, i: int = i, lowest: np.ndarray = lowest) -> np.ndarray:
            starts = np.repeat(pts[i : i + 1], len(ends), axis=0)
            return segments_clearance(space, starts, pts[ends]) >= lowest[ends - 1 - i] - slack

        # gallop (i + 2, i + 3, i + 5, i + 9, ..., the end), then narrow down between the
        # last end reached and the first one missed, 16 ends at a time
        ends = np.unique(np.minimum(i + 1 + 2 ** np.arange(int(math.log2(n - i)) + 2), n - 1))
        lo, hi = i + 1, n
        while True:
            ends = ends[(ends > lo) & (ends < hi)]
            if ends.size == 0:
                break
            ok = reaches(ends)
            if ok.all():
                lo = int(ends[-1])
            else:
                fail = int(np.argmin(ok))
                lo, hi = (int(ends[fail - 1]) if fail > 0 else lo), int(ends[fail])
            ends = np.unique(np.linspace(lo + 1, hi - 1, 16).round().astype(np.int64))
        out.append(lo)
        i = lo
    return pts[out]


def _segment_clearance(space: FreeSpace, a: np.ndarray, b: np.ndarray) -> float:
    seg = space.segment_cells(a[0], a[1], b[0], b[1])
    return 0.0 if seg is None else float(space.distance_flat[seg].min())


def _arc_clear(space: FreeSpace, arc: np.ndarray, floor: float) -> bool:
    return bool(np.all(segments_clearance(space, arc[:-1], arc[1:]) >= floor - 1e-6))


def fillet(
    space: FreeSpace,
    pts: np.ndarray,
    comfort: float,
    max_radius: float,
    min_radius: float,
    spacing: float,
) -> np.ndarray:
    """Round each corner of ``pts`` with the largest circular arc (<= ``max_radius``) that
    stays free and no nearer to obstacles than the two segments it joins (capped at
    ``comfort``). Arcs are sampled every ``spacing`` metres; corners that take no arc of
    at least ``min_radius`` stay sharp."""
    n = len(pts)
    if n <= 2 or max_radius <= 0.0:
        return pts
    clear = [_segment_clearance(space, pts[i], pts[i + 1]) for i in range(n - 1)]
    lengths = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    out: list[np.ndarray] = [pts[:1]]
    for i in range(1, n - 1):
        a, v, b = pts[i - 1], pts[i], pts[i + 1]
        u1, u2 = (v - a) / lengths[i - 1], (b - v) / lengths[i]
        cross = u1[0] * u2[1] - u1[1] * u2[0]
        turn = math.atan2(cross, float(np.dot(u1, u2)))  # signed deflection
        if abs(turn) < 1e-3 or abs(turn) > math.pi - 1e-3:
            out.append(v[None])
            continue
        half_tan = math.tan(abs(turn) / 2.0)
        t_max = min(
            lengths[i - 1] * (1.0 if i == 1 else 0.5), lengths[i] * (1.0 if i == n - 2 else 0.5)
        )
        radius = min(max_radius, t_max / half_tan)
        normal = np.array([-u1[1], u1[0]]) * math.copysign(1.0, turn)
        start_angle = math.atan2(-normal[1], -normal[0])
        arc = None
        # Keep the clearance the path had; failing that, any radius the robot can take
        # at speed is worth coming closer (never inside the required clearance).
        for floor, smallest in (
            (min(clear[i - 1], clear[i], comfort), min_radius),
            (0.0, min_radius),
        ):
            r = radius
            while arc is None and r >= smallest:
                t = r * half_tan
                centre = v - u1 * t + normal * r
                steps = max(2, math.ceil(r * abs(turn) / spacing) + 1)
                angles = start_angle + np.linspace(0.0, turn, steps)
                candidate = centre + r * np.stack([np.cos(angles), np.sin(angles)], axis=1)
                if _arc_clear(space, candidate, floor):
                    arc = candidate
                r *= 0.7
        out.append(v[None] if arc is None else arc)
    out.append(pts[-1:])
    return np.concatenate(out, axis=0)


def max_curvature(points: np.ndarray, window: float = 0.2) -> float:
    """Largest heading change per metre over any ``window`` of arclength of a polyline:
    about 1/r on an arc of radius r > window, and (turn angle) / window at a corner."""
    pts = np.asarray(points, dtype=float)
    seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    pts = pts[np.concatenate([[True], seg > 1e-9])]
    if len(pts) < 3:
        return 0.0
    cum = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(pts, axis=0), axis=1))])
    step = window / 10.0
    s = np.arange(0.0, cum[-1], step)
    xy = np.stack([np.interp(s, cum, pts[:, 0]), np.interp(s, cum, pts[:, 1])], axis=1)
    d = np.diff(xy, axis=0)
    heading = np.unwrap(np.arctan2(d[:, 1], d[:, 0]))
    if len(heading) <= 10:
        return float(abs(heading[-1] - heading[0]) / max(cum[-1], window))
    return float(np.max(np.abs(heading[10:] - heading[:-10])) / window)


def smooth(
    space: FreeSpace,
    start: tuple[float, float],
    goal: tuple[float, float],
    cells: np.ndarray,
    floor_cap: float,
    max_radius: float,
    min_radius: float,
) -> np.ndarray:
    """Cell path -> any-angle polyline -> filleted polyline (local frame). Shortcuts and
    arcs keep the clearance the path had, capped at ``floor_cap``; ``max_radius`` 0
    leaves the corners sharp."""
    w = space.width
    dist = space.distance_flat[cells]
    turns = _turns(cells, w, SHORTCUT_EVERY)
    centres = space.cell_centres(cells[turns] // w, cells[turns] % w)
    # least clearance of the cell path between consecutive turn vertices
    seg_floor = np.minimum.reduceat(dist, turns[:-1]) if len(turns) > 1 else dist[:1]
    seg_floor = np.minimum(seg_floor, dist[turns[1:]])
    pts = centres.copy()
    pts[0], pts[-1] = start, goal
    if not space.segment_free(*pts[0], *pts[1]):
        pts = np.vstack([[start], centres])
        seg_floor = np.concatenate([[dist[0]], seg_floor])
    if not space.segment_free(*pts[-2], *pts[-1]):
        pts = np.vstack([pts[:-1], centres[-1:], [goal]])
        seg_floor = np.concatenate([seg_floor, [dist[-1]]])
    pts = any_angle(space, pts, seg_floor, floor_cap)
    pts = fillet(space, pts, floor_cap, max_radius, min_radius, space.res)
    keep = np.ones(len(pts), dtype=bool)
    keep[1:] = np.linalg.norm(np.diff(pts, axis=0), axis=1) > 1e-9
    return pts[keep]


def path_length(pts: np.ndarray) -> float:
    """Length of a polyline (N, 2)."""
    return float(np.sum(np.linalg.norm(np.diff(pts, axis=0), axis=1)))
