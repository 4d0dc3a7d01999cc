"""The back end of ``graph`` SLAM: a 2-D pose graph, its least-squares solution, and the
checks that let a loop closure into it.

A loop closure found by matching a scan against a submap can be wrong (two doorways of
one corridor look alike), and a right one can disagree with the drifted graph by metres.
A robust kernel on the raw residual cannot tell the two apart: Huber caps a wrong edge's
pull but keeps it pulling (on the ACES log one false closure 7.7 m off ended with a
residual of 4 mm: it bent the map to itself). Instead (as Olson's single-cluster check,
Latif et al.'s RRR, and the verify-then-trust practice of Cartographer's constraint
builder): a closure that moves the graph by more than a little must agree with another
closure found nearby (:func:`loop_pair_error`: the cycle the two form with the short
stretches of graph between their ends is the identity); the graph is then solved with
every loop edge at full weight, and a loop edge the solution still cannot satisfy is
dropped and the graph solved again (:func:`solve_pose_graph`).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from scipy.sparse import csr_matrix, diags
from scipy.sparse.linalg import spsolve

from agv_mission.geometry import Pose2D, wrap_angles


def loop_pair_error(
    nodes: np.ndarray, a: tuple[int, int, np.ndarray], b: tuple[int, int, np.ndarray]
) -> tuple[float, float]:
    """How far two loop closures ``(i, j, z)`` (``z``: node ``j`` in node ``i``'s frame)
    disagree (m, rad): the cycle ``i_a -> j_a`` (closure a), ``j_a -> j_b`` (the graph),
    ``j_b -> i_b`` (closure b, inverted), ``i_b -> i_a`` (the graph) is the identity when
    both are right; the graph's stretches are short, so its drift barely enters."""
    ia, ja, za = a
    ib, jb, zb = b
    recent = Pose2D(*nodes[jb]).relative_to(Pose2D(*nodes[ja]))
    old = Pose2D(*nodes[ia]).relative_to(Pose2D(*nodes[ib]))
    cycle = Pose2D(*za).compose(recent).compose(Pose2D(0.0, 0.0, 0.0).relative_to(Pose2D(*zb)))
    cycle = cycle.compose(old)
    return math.hypot(cycle.x, cycle.y), abs(cycle.yaw)


def _edge_errors(
    x: np.ndarray, ii: np.ndarray, jj: np.ndarray, z: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Each edge's error (m, 3) at poses ``x``, and the terms its Jacobian reuses: the
    cosine and sine of node ``ii``'s heading and the two nodes' offset."""
    pi, pj = x[ii], x[jj]
    c, s = np.cos(pi[:, 2]), np.sin(pi[:, 2])
    dx, dy = pj[:, 0] - pi[:, 0], pj[:, 1] - pi[:, 1]
    r = np.stack(
        [
            c * dx + s * dy - z[:, 0],
            -s * dx + c * dy - z[:, 1],
            wrap_angles(pj[:, 2] - pi[:, 2] - z[:, 2]),
        ],
        axis=1,
    )
    return r, c, s, dx, dy


def edge_residuals(
    nodes: np.ndarray, ii: np.ndarray, jj: np.ndarray, z: np.ndarray, sigma: np.ndarray
) -> np.ndarray:
    """Each edge's whitened residual norm at ``nodes``."""
    r = _edge_errors(nodes, ii, jj, z)[0]
    return np.sqrt(((r / sigma) ** 2).sum(axis=1))


def solve_pose_graph(
    nodes: np.ndarray,
    ii: np.ndarray,
    jj: np.ndarray,
    z: np.ndarray,
    sigma: np.ndarray,
    loop: np.ndarray,
    gate: float,
    max_rejections: int = 3,
) -> tuple[np.ndarray, np.ndarray]:
    """The least-squares poses of the graph with every edge at full weight, and which
    loop edges (``loop``: a mask) it kept: while the worst loop edge's whitened residual
    exceeds ``gate``, that edge is dropped (it contradicts the others and the graph) and
    the graph solved again, at most ``max_rejections`` times."""
    keep = np.ones(len(ii), dtype=bool)
    x = optimize_pose_graph(nodes, ii, jj, z, sigma, math.inf)
    for _ in range(max_rejections):
        res = edge_residuals(x, ii, jj, z, sigma)
        res[~(loop & keep)] = 0.0
        worst = int(np.argmax(res)) if len(res) else 0
        if not len(res) or res[worst] <= gate:
            break
        keep[worst] = False
        x = optimize_pose_graph(nodes, ii[keep], jj[keep], z[keep], sigma[keep], math.inf)
    return x, keep


def optimize_pose_graph(
    nodes: np.ndarray,
    ii: np.ndarray,
    jj: np.ndarray,
    z: np.ndarray,
    sigma: np.ndarray,
    huber: float = 3.0,
    iterations: int = 20,
    prior: tuple[np.ndarray, np.ndarray] | None = None,
) -> np.ndarray:
    """Least-squares poses (n, 3) of a 2D pose graph; node 0 stays fixed unless a
    ``prior`` (poses (n, 3) and their stds (n, 3)) holds every node near a pose of its own.

    Edge ``k`` measures node ``jj[k]`` in the frame of node ``ii[k]`` as ``z[k]`` with
    standard deviations ``sigma[k]`` (x, y, yaw). Gauss-Newton on the sparse normal
    equations (analytic Jacobian, ``scipy.sparse.linalg.spsolve``), robustified by
    iteratively reweighted Huber weights on each edge's whitened error, with a little
    Levenberg damping: milliseconds for a few hundred keyframes, where
    ``scipy.optimize.least_squares`` with finite-difference sparse Jacobians took
    seconds.
    """
    x = np.array(nodes, dtype=float)
    n, m = len(x), len(ii)
    if m == 0:
        return x
    w = 1.0 / np.asarray(sigma, dtype=float)
    rows = np.repeat(np.arange(3 * m), 6).reshape(m, 3, 6)
    cols = np.empty((m, 3, 6), dtype=np.int64)
    for a in range(3):
        cols[:, a, :3] = 3 * ii[:, None] + np.arange(3)
        cols[:, a, 3:] = 3 * jj[:, None] + np.arange(3)
    # Node 0 is the gauge (or the prior is); a little damping elsewhere.
    diag = np.full(3 * n, 1e-6)
    if prior is None:
        diag[:3] += 1e9
    else:
        target = np.asarray(prior[0], dtype=float)
        info = (1.0 / np.asarray(prior[1], dtype=float) ** 2).ravel()
        diag += info
    damping = diags(diag, format="csc")
    for _ in range(iterations):
        r, c, s, dx, dy = _edge_errors(x, ii, jj, z)
        rw = r * w
        norm = np.sqrt((rw**2).sum(axis=1))
        robust = np.where(norm <= huber, 1.0, huber / np.maximum(norm, 1e-12))
        j = np.zeros((m, 3, 6))
        j[:, 0, 0], j[:, 0, 1], j[:, 0, 2] = -c, -s, -s * dx + c * dy
        j[:, 1, 0], j[:, 1, 1], j[:, 1, 2] = s, -c, -c * dx - s * dy
        j[:, 0, 3], j[:, 0, 4] = c, s
        j[:, 1, 3], j[:, 1, 4] = -s, c
        j[:, 2, 2], j[:, 2, 5] = -1.0, 1.0
        scale = (w * np.sqrt(robust)[:, None])[:, :, None]
        jac = csr_matrix(((j * scale).ravel(), (rows.ravel(), cols.ravel())), shape=(3 * m, 3 * n))
        res = (rw * np.sqrt(robust)[:, None]).ravel()
        h = (jac.T @ jac).tocsc() + damping
        g = jac.T @ res
        if prior is not None:
            e = x - target
            e[:, 2] = wrap_angles(e[:, 2])
            g = g + info * e.ravel()
        step = spsolve(h, -g)
        x += step.reshape(n, 3)
        x[:, 2] = wrap_angles(x[:, 2])
        if np.abs(step).max() < 1e-6:
            break
    return x


def odometry_steps(odom: np.ndarray) -> np.ndarray:
    """The odometry's motion (n - 1, 3) between consecutive poses of ``odom`` (n, 3),
    each in the frame of the first: the error of a zero edge between them."""
    k = np.arange(len(odom) - 1)
    return _edge_errors(np.asarray(odom, dtype=float), k, k + 1, np.zeros((len(k), 3)))[0]


#: Bounds of a calibration (scale, rad per metre, rad per radian): a wheel radius off by
#: ten percent, wheels unequal enough to curve a degree per metre, a wheelbase ten percent
#: off: past these the odometry is broken, not miscalibrated.
CALIBRATION_BOUNDS = (0.1, 0.02, 0.1)


def calibrate_odometry(poses: np.ndarray, steps: np.ndarray) -> tuple[float, float, float]:
    """The odometry's systematic errors, learnt from the SLAM's ``poses`` (n, 3) and the
    odometry's ``steps`` (n - 1, 3) between them: its scale (the robot's distance per
    odometry metre: a wheel radius off), its heading drift per metre driven (a curvature
    bias: unequal wheel diameters, Borenstein's type A error) and per radian turned (a
    wheelbase off, type B). Least squares of the SLAM's motion against the odometry's over
    every step: each step's matching error is random, the odometry's is the same every
    metre, so over hundreds of steps the bias stands out; steps the fit cannot explain (a
    slipping wheel, a bad match) are dropped and the fit repeated."""
    seen = odometry_steps(poses)  # the SLAM's own motion, step by step
    d = np.hypot(steps[:, 0], steps[:, 1])
    if len(d) < 10 or d.sum() < 5.0:
        return 1.0, 0.0, 0.0
    forward = np.where(steps[:, 0] < 0.0, -d, d)  # a curvature bias flips driving back
    along = (seen[:, 0] * steps[:, 0] + seen[:, 1] * steps[:, 1]) / np.maximum(d, 1e-9)
    turn_error = wrap_angles(seen[:, 2] - steps[:, 2])
    a = np.stack([forward, steps[:, 2]], axis=1)
    keep_t = d > 1e-3
    keep_a = np.ones(len(d), dtype=bool)
    scale, drift = 1.0, np.zeros(2)
    for _ in range(3):
        if keep_t.sum() >= 5:
            scale = float(along[keep_t] @ d[keep_t] / (d[keep_t] @ d[keep_t]))
        if keep_a.sum() >= 5:
            drift = np.linalg.lstsq(a[keep_a], turn_error[keep_a], rcond=None)[0]
        rt = along - scale * d
        ra = turn_error - a @ drift
        keep_t = (d > 1e-3) & (np.abs(rt) <= 3.0 * 1.4826 * np.median(np.abs(rt)) + 1e-6)
        keep_a = np.abs(ra) <= 3.0 * 1.4826 * np.median(np.abs(ra)) + 1e-6
    ks, kd, kt = CALIBRATION_BOUNDS
    return (
        float(np.clip(scale, 1.0 - ks, 1.0 + ks)),
        float(np.clip(drift[0], -kd, kd)),
        float(np.clip(drift[1], -kt, kt)),
    )


def odometry_edges(
    steps: np.ndarray,
    noise: tuple[float, float, float],
    calibration: tuple[float, float, float] = (1.0, 0.0, 0.0),
) -> tuple[np.ndarray, np.ndarray]:
    """The odometry's ``steps`` (m, 3) with its systematic errors (``calibration``: scale,
    rad per metre, rad per radian) taken out, and their stds (m, 3) by Thrun's odometry
    motion model (``noise``: m per metre, rad per radian turned, rad per metre)."""
    z = np.array(steps, dtype=float)
    d = np.hypot(z[:, 0], z[:, 1])
    scale, per_metre, per_radian = calibration
    z[:, 2] += per_metre * np.where(z[:, 0] < 0.0, -d, d) + per_radian * z[:, 2]
    z[:, :2] *= scale
    d *= scale
    st = noise[0] * d + 1e-3
    sa = noise[1] * np.abs(z[:, 2]) + noise[2] * d + 1e-3
    return z, np.stack([st, st, sa], axis=1)


#: Bounds of :func:`odometry_heading_spread`: never below the model (on the real logs the
#: fit finds the wheels steadier, 0.5 to 0.6, but edges that much stronger took ACES's
#: walls within 0.1 m from 0.87 to 0.53, seed 1), at most ten times it, as
#: :func:`honest_spread`.
HEADING_SPREAD_BOUNDS = (1.0, 10.0)


def odometry_heading_spread(
    nodes: np.ndarray,
    z: np.ndarray,
    sigma: np.ndarray,
    lags: tuple[int, ...] = (1, 2, 3, 4, 6, 8),
) -> float:
    """How many times its claimed heading stds (``sigma[:, 2]``) the odometry's steps ``z``
    (m, 3) between consecutive ``nodes`` (m + 1, 3) of a solved graph really err: a
    variance component (Helmert's) of this recording's odometry, told apart from the
    graph's own error by how the two disagree over ``k`` consecutive steps. The
    odometry's heading error is a random walk: its variance grows with the claimed
    variance summed over the stretch; the graph's is tied to its map and loop closures and
    does not grow. So the robust (median) spread of the disagreement over each stretch is
    fitted, window by window over ``lags``, as ``a * claimed + c`` (``c >= 0``, the graph's
    part; by the median of the ratio to ``claimed``, as :func:`honest_spread`), and
    ``sqrt(a)`` returned within :data:`HEADING_SPREAD_BOUNDS`: wheels that slip at random
    (the simulated 100 m loop: ``a`` over a hundred) get weak edges, steady ones keep the
    model's."""
    cum = np.concatenate([[0.0], np.cumsum(z[:, 2])])
    claimed = np.concatenate([[0.0], np.cumsum(sigma[:, 2] ** 2)])
    ratio, inverse = [], []
    for k in lags:
        if len(nodes) - k < 10:
            break
        d = wrap_angles(nodes[k:, 2] - nodes[:-k, 2] - (cum[k:] - cum[:-k]))
        total = claimed[k:] - claimed[:-k]
        ratio.append(np.median(d**2 / total) / 0.455)  # chi2(1)'s median
        inverse.append(np.median(1.0 / total))
    if len(ratio) < 2:
        return 1.0
    q, m = np.array(ratio), np.array(inverse)
    a, c = np.linalg.lstsq(np.stack([np.ones_like(m), m], axis=1), q, rcond=None)[0]
    if c < 0.0:
        a = q[-1]
    return float(np.clip(np.sqrt(max(a, 0.0)), *HEADING_SPREAD_BOUNDS))


def honest_spread(r: np.ndarray, claimed: np.ndarray, other: np.ndarray) -> np.ndarray:
    """Per component (3,), how many times its claimed stds ``claimed`` (m, 3) a
    measurement's errors really are, from its residuals ``r`` (m, 3) against an
    independent measurement of stds ``other``: a variance component estimate (Helmert's),
    by the median so a few bad matches do not count; never below 1."""
    ratio = np.median(r**2 / (claimed**2 + other**2), axis=0) / 0.455  # chi2(1)'s median
    return np.clip(np.sqrt(ratio), 1.0, 10.0)


class OdometryFusion(NamedTuple):
    """What :func:`fuse_odometry` solved and learnt of the recording's wheels: worth
    reporting, as a calibration run (Borenstein's UMBmark) would."""

    nodes: np.ndarray
    #: scale, rad per metre, rad per radian (:func:`calibrate_odometry`)
    calibration: tuple[float, float, float]
    #: the heading noise's factor over the model (:func:`odometry_heading_spread`)
    heading_spread: float

    def report(self) -> dict[str, float]:
        """The learnt wheels, for ``map``'s report."""
        scale, per_metre, per_radian = self.calibration
        return {
            "odometry_scale": round(scale, 5),
            "odometry_drift_deg_per_m": round(math.degrees(per_metre), 4),
            "odometry_turn_error_per_turn": round(per_radian, 5),
            "odometry_heading_spread": round(self.heading_spread, 3),
        }


def fuse_odometry(
    nodes: np.ndarray,
    edges: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray],
    odom: np.ndarray,
    noise: tuple[float, float, float],
) -> OdometryFusion:
    """The pose graph's ``nodes`` solved again with the odometry's motion between
    consecutive ones (``odom``: its pose at each node) as edges of their own: its
    systematic errors learnt from the graph first (:func:`calibrate_odometry`) and taken
    out, its random error by ``noise`` (:func:`odometry_edges`) with the heading's widened
    to what this recording shows (:func:`odometry_heading_spread`), and the sideways error
    that much heading error brings with it. ``edges``: ``ii, jj, z, sigma, loop`` as
    :func:`solve_pose_graph`'s; the stds of the front end's edges between consecutive
    nodes are widened to what their disagreement with the odometry shows
    (:func:`honest_spread`): a match's covariance is only its local curvature, and
    between sparse scans its errors are larger."""
    ii, jj, z, sigma, loop = edges
    steps = odometry_steps(odom)
    calibration = calibrate_odometry(nodes, steps)
    zo, so = odometry_edges(steps, noise, calibration)
    spread = odometry_heading_spread(nodes, zo, so)
    # heading error past the model's, picked up along a step, ends it sideways by about
    # half the step's length times it (a turn spread over the step: Thrun's rot1 and rot2)
    extra = so[:, 2] * math.sqrt(spread**2 - 1.0)
    so[:, 1] = np.hypot(so[:, 1], 0.5 * np.hypot(zo[:, 0], zo[:, 1]) * extra)
    so[:, 2] *= spread
    sigma = np.array(sigma, dtype=float)
    chain = ~loop & (jj == ii + 1)
    if chain.sum() >= 10:
        r = z[chain] - zo[ii[chain]]
        r[:, 2] = wrap_angles(r[:, 2])
        sigma[chain] *= honest_spread(r, sigma[chain], so[ii[chain]])
    k = np.arange(len(nodes) - 1)
    solved = optimize_pose_graph(
        nodes,
        np.concatenate([ii, k]),
        np.concatenate([jj, k + 1]),
        np.vstack([z, zo]),
        np.vstack([sigma, so]),
        math.inf,
    )
    return OdometryFusion(solved, calibration, spread)


def smooth_trajectory(
    poses: np.ndarray,
    odom: np.ndarray,
    odom_noise: tuple[float, float, float],
    pose_sigma: tuple[float, float],
    huber: float = 3.0,
    odom_scale: float = 1.0,
    calibrate: bool = False,
) -> np.ndarray:
    """The poses (n, 3) that best agree with both the SLAM's ``poses`` (each within
    ``pose_sigma``: m, rad) and the odometry's motion between consecutive ones (``odom``,
    (n, 3); std ``odom_noise``: m per metre, rad per radian, rad per metre, Thrun's
    odometry motion model): a fixed-interval smoother. Over a metre wheel odometry errs by
    a centimetre or two, a scan match against a map by about as much per pose and without
    drift: together they beat either. With ``calibrate`` the odometry's systematic errors
    are learnt from the whole trajectory first (:func:`calibrate_odometry`) and taken out
    of its motion, so ``odom_noise`` need only cover its random part; otherwise its
    distances are scaled by ``odom_scale`` (as the front end learnt it). Solved as a pose
    graph (:func:`optimize_pose_graph`) of the odometry's edges with the SLAM's poses as
    priors, Huber-robust against a slipping wheel."""
    n = len(poses)
    steps = odometry_steps(odom)
    calibration = calibrate_odometry(poses, steps) if calibrate else (odom_scale, 0.0, 0.0)
    z, sigma = odometry_edges(steps, odom_noise, calibration)
    k = np.arange(n - 1)
    spread = np.tile([pose_sigma[0], pose_sigma[0], pose_sigma[1]], (n, 1))
    return optimize_pose_graph(
        poses, k, k + 1, z, sigma, huber, iterations=10, prior=(poses, spread)
    )
