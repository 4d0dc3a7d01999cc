"""Map an area: frontier exploration while SLAM builds the map, then save it."""

from __future__ import annotations

import math
from typing import Any, Protocol

import numpy as np
import py_trees
from py_trees.common import Status
from scipy import ndimage

from agv_mission.behaviors.revisit import KnownGround
from agv_mission.geometry import Bounds, Pose2D, wrap_angle
from agv_mission.mapping.frontiers import Frontier, find_frontiers
from agv_mission.mapping.session import MappingSession
from agv_mission.maps.costmap import Costmap
from agv_mission.maps.grid import OCCUPIED, UNKNOWN, OccupancyGrid
from agv_mission.navigation.handle import RobotHandle
from agv_mission.navigation.navigator import NavStatus


class Mapper(Protocol):
    """Starts and ends the mapping session a :class:`MapArea` explores with."""

    def begin(self, bounds: Bounds | None) -> MappingSession:
        """SLAM takes over pose and map (the whole known map's extent without bounds)."""
        ...

    def end(self, stem: str) -> dict[str, Any]:
        """Save the map as ``stem``; returns what to report about it."""
        ...


class MapArea(py_trees.behaviour.Behaviour):
    """Drive to the nearest reachable frontier until none is left, then save the map.

    Stops early at a ``coverage`` share of known cells in the bounds or after
    ``time_limit`` simulated seconds.

    Goals are chosen on the grid of the costmap the navigator plans on (the mapping
    session's last one), not on the newer SLAM map: a goal that is free on the newer map
    may still be unknown, i.e. an obstacle, on the planner's, and fail at once. After a
    goal ends, the next one waits for a fresh costmap.

    A goal the navigator fails to reach, or reaches while its frontier remains (it cannot
    be mapped from there), is blacklisted: its frontier is skipped until the map has grown
    by ``RETRY_GROWTH`` known cells since (the map it failed on may have been missing
    the way there), and for good after ``MAX_ATTEMPTS`` tries, so exploration never
    loops on an unreachable frontier and still ends.

    The nearest frontier wins while SLAM is sure of its pose. As its position std
    grows past ``UNCERTAIN_SIGMA`` (a long drive where the lidar saw too little to
    match), a frontier costs more the farther its goal lies from mapped structure
    (beyond ``FEATURE_RANGE``): the robot heads where its scans will meet walls and
    columns already in the map and correct the estimate, not deeper into open floor
    (:func:`choose_frontier`).

    Past ``revisit_sigma`` (:func:`~agv_mission.behaviors.revisit.revisit_sigma`: the
    lidar's own range precision where it matches structure) the robot stops exploring
    and drives back to known ground: the nearest place, by driving on the current map,
    where it stood earlier while SLAM was sure of its pose
    (:class:`~agv_mission.behaviors.revisit.KnownGround`). There its scans
    meet the map as it was built while the estimate was sure, so the scan matcher (and a
    ``graph`` SLAM's loop closure) pulls the estimate back before the map takes in more
    of its error. The revisit ends as soon as the std is under ``UNCERTAIN_SIGMA`` again
    (or the place is reached or cannot be); the next one waits until the std has been
    that low again and the frontier goal set after the revisit has ended, so an estimate
    that no revisit helps does not keep the robot driving back and forth, and a frontier
    across open floor is reached at last.
    """

    RESELECT_PERIOD = 5.0  # s: re-check that the frontier being approached still exists
    GOAL_TOLERANCE = 0.25  # m: a frontier is seen from near its goal point
    GOAL_MARGIN = 0.1  # m: clearance beyond the planner's a goal gets where there is room
    SPIN_RATE = 0.8  # rad/s of the first look around
    BLACKLIST_RADIUS = 0.3  # m: a frontier whose goal lies this near a blacklisted goal
    MAX_ATTEMPTS = 3  # tries of one goal (within BLACKLIST_RADIUS) before it is given up
    RETRY_GROWTH = 800  # known cells the map must gain before a blacklisted goal is retried
    UNSEEN = 0.05  # bounds known below this share have not been seen: drive towards them
    LOOKS_BEFORE_DONE = 1  # looks all around, each on a fresh costmap, before "none left"
    BACKUP_SPEED = 0.1  # m/s backwards out of a spot the planner will not start from
    BACKUP_TIME = 1.5  # s: 0.15 m, Nav2's BackUp recovery's default distance
    MAX_BACKUPS = 3  # in a row before such failures count against the goals again
    UNCERTAIN_SIGMA = 0.03  # m: SLAM's position std beyond which open floor costs more
    FEATURE_RANGE = 2.0  # m: structure this near is matched well (an LDS-01's 3.5 m
    # returns carry 6 cm of noise at the far end, too much for the refinement's normals)

    def __init__(
        self,
        name: str,
        handle: RobotHandle,
        mapper: Mapper,
        bounds: Bounds | None,
        save_map: str,
        coverage: float | None,
        time_limit: float | None,
        min_frontier_size: int,
        clearance: float,
        revisit_sigma: float = math.inf,
    ):
        super().__init__(name)
        self.handle = handle
        self.mapper = mapper
        self.mapping: MappingSession | None = None
        self.bounds = bounds
        self.save_map = save_map
        self.coverage = coverage
        self.time_limit = time_limit
        self.min_frontier_size = min_frontier_size
        self.clearance = clearance
        self.revisit_sigma = revisit_sigma
        self.goal: Pose2D | None = None
        #: The known place being driven back to (see the class), None while exploring.
        self.revisit: Pose2D | None = None
        #: Where the estimate was sure: the places a revisit drives back to.
        self.known = KnownGround()
        #: Goals given up on (for now): [x, y, attempts, known cells at the last attempt].
        self.attempts: list[list[float]] = []
        self._deadline = math.inf
        self._failure: str | None = None
        self._reselect_at = 0.0
        self.frontiers_visited = 0
        self.revisits = 0

    def initialise(self) -> None:
        self.mapping = self.mapper.begin(self.bounds)
        self.goal = None
        self.revisit = None
        self.known = KnownGround()
        self._revisit_armed = True  # the std was under UNCERTAIN_SIGMA since the last one
        self._goals_started = 0  # frontier goals set so far
        self._revisited_at = -2  # ... when the last revisit began
        self._revisit_from = (0.0, 0.0)  # time and std when the revisit began
        self.attempts = []
        self.frontiers_visited = 0
        self.revisits = 0
        now = self.handle.state.time
        self._deadline = now + self.time_limit if self.time_limit else math.inf
        self._failure = None
        self._reselect_at = now
        self._turned = 0.0
        self._last_yaw = self.handle.state.estimate.yaw
        self._looks = 0  # looks around since a reachable frontier was last found
        self._backup_until = -math.inf
        self._backups = 0  # backups in a row

    def update(self) -> Status:
        handle, state = self.handle, self.handle.state
        mapping = self.mapping
        assert mapping is not None
        if mapping.slam.integrations == 0:
            # Stand still until SLAM has its first scan: the map is anchored where the
            # robot was at the start, not at a pose dead reckoning guessed after a turn.
            handle.stop()
            self._last_yaw = state.estimate.yaw
            return Status.RUNNING
        if self._turned < 2.0 * math.pi:  # look all around before choosing a frontier
            self._turned += abs(wrap_angle(state.estimate.yaw - self._last_yaw))
            self._last_yaw = state.estimate.yaw
            handle.drive(0.0, self.SPIN_RATE)
            return Status.RUNNING
        if state.time < self._backup_until:
            handle.drive(-self.BACKUP_SPEED, 0.0)
            return Status.RUNNING
        nav = handle.navigator
        if (
            self.goal is not None
            and nav.status is NavStatus.FAILED
            and self._start_blocked(nav.reason)
        ):
            # Not the goal's fault: the robot stands where the planner will not start (a
            # tight spot between furniture). Back out of it and choose again, as Nav2's
            # BackUp recovery does, instead of giving up on every frontier in turn.
            self._backups += 1
            self._backup_until = state.time + self.BACKUP_TIME
            self.goal = None
            mapping.request_refresh()
            self._reselect_at = self._backup_until
            handle.drive(-self.BACKUP_SPEED, 0.0)
            return Status.RUNNING
        if nav.status is NavStatus.SUCCEEDED or (
            self.goal is not None and nav.status is NavStatus.RUNNING
        ):
            self._backups = 0
        if self.goal is not None and nav.status in (NavStatus.FAILED, NavStatus.SUCCEEDED):
            # Failed, or reached: seen from there already, so if its frontier is still
            # there it cannot be mapped from there.
            if nav.status is NavStatus.SUCCEEDED:
                self.frontiers_visited += 1
            self._give_up(self.goal)
            self.goal = None
            # choose the next goal on a costmap that holds what was seen from here
            mapping.request_refresh()
            self._reselect_at = state.time + 1e-6
        done = self._done(state.time)
        if done is None and mapping.costmap is None:
            handle.drive(0.0, self.SPIN_RATE)  # no map to plan on yet: keep looking
            return Status.RUNNING
        if done is None and self._revisiting():
            cmd = nav.update(state)
            handle.drive(cmd.v, cmd.w)
            return Status.RUNNING
        if done is None and state.time >= self._reselect_at:
            self._reselect_at = state.time + self.RESELECT_PERIOD
            done = self._next_goal()
        if done is not None:
            nav.cancel()
            handle.stop()
            known = mapping.known_fraction()
            summary = self.mapper.end(self.save_map)
            self.mapping = None
            failure = self._failure
            # coverage as result.json reports it: of the free space the robot can reach
            covered = float(summary.get("coverage", known))
            if failure is None and self.coverage is not None and covered < self.coverage:
                failure = (
                    f"coverage {covered:.3f} is below the {self.coverage:g} the task asks ({done})"
                )
            handle.log(
                "map_saved",
                reason=failure or done,
                frontiers=self.frontiers_visited,
                revisits=self.revisits,
                **summary,
            )
            self.feedback_message = failure or done
            return Status.FAILURE if failure else Status.SUCCESS
        cmd = nav.update(state)
        handle.drive(cmd.v, cmd.w)
        return Status.RUNNING

    def terminate(self, new_status: Status) -> None:
        """Halted while exploring: stop, let go of the navigator and end the mapping
        session (the map so far is saved), so localisation takes over again."""
        if new_status is not Status.INVALID or self.mapping is None:
            return
        self.handle.navigator.cancel()
        self.handle.stop()
        self.mapping = None
        summary = self.mapper.end(self.save_map)
        self.handle.log(
            "map_saved",
            reason="halted",
            frontiers=self.frontiers_visited,
            revisits=self.revisits,
            **summary,
        )

    def _revisiting(self) -> bool:
        """Whether the robot drives back to known ground now: remembers the sure places,
        starts a revisit when the std passes ``revisit_sigma`` and ends it (see the
        class). Never without a ``revisit_sigma``."""
        if not math.isfinite(self.revisit_sigma):
            return False
        state, nav = self.handle.state, self.handle.navigator
        sigma = self._position_sigma()
        est = state.estimate
        if sigma < self.UNCERTAIN_SIGMA and self._goals_started > self._revisited_at + 1:
            self._revisit_armed = True
        self.known.note(est.x, est.y, sigma)
        if self.revisit is not None:
            ended = nav.status in (NavStatus.SUCCEEDED, NavStatus.FAILED)
            if sigma >= self.UNCERTAIN_SIGMA and not ended:
                return True
            t0, s0 = self._revisit_from
            self.handle.log(
                "revisit_done",
                x=round(self.revisit.x, 3),
                y=round(self.revisit.y, 3),
                outcome="sure again" if sigma < self.UNCERTAIN_SIGMA else nav.status.value,
                duration=round(state.time - t0, 2),
                std_before=round(s0, 4),
                std_after=round(sigma, 4),
            )
            nav.cancel()
            self.revisit = None
            assert self.mapping is not None
            self.mapping.request_refresh()
            self._reselect_at = state.time + 1e-6
            return False
        if sigma < self.revisit_sigma or not self._revisit_armed:
            return False
        self._revisit_armed = False
        self._revisited_at = self._goals_started
        assert self.mapping is not None and self.mapping.costmap is not None
        place = self.known.nearest(self.mapping.costmap, (est.x, est.y), self.clearance)
        if place is None:
            return False
        self.goal = None  # the frontier waits, not blamed
        self.revisit = Pose2D(place[0], place[1], math.atan2(place[1] - est.y, place[0] - est.x))
        self.revisits += 1
        self._revisit_from = (state.time, sigma)
        self.handle.log("revisit", x=round(place[0], 3), y=round(place[1], 3), std=round(sigma, 4))
        nav.start(self.revisit, state, xy_tolerance=self.GOAL_TOLERANCE, yaw_tolerance=math.pi)
        return True

    def _start_blocked(self, reason: str | None) -> bool:
        """Whether a failure is the planner's refusal to start where the robot stands: the
        start not free, or in a pocket of free space no goal connects to (and backing out
        has not been tried MAX_BACKUPS times in a row)."""
        if reason is None or self._backups >= self.MAX_BACKUPS:
            return False
        start_not_free = "start (" in reason and "is not free" in reason
        return start_not_free or "not connected by free space" in reason

    def _done(self, now: float) -> str | None:
        if now >= self._deadline:
            return "time limit of the task reached"
        if self.coverage is not None and self.mapping.known_fraction() >= self.coverage:
            return f"coverage target {self.coverage:g} reached"
        return None

    def _next_goal(self) -> str | None:
        """Aim at the nearest frontier; ``"no reachable frontier left"`` when done."""
        handle, state = self.handle, self.handle.state
        assert self.mapping is not None
        costmap = self.mapping.costmap
        assert costmap is not None
        est = state.estimate
        frontiers = self._frontiers(costmap, est, self.bounds)
        unseen = self.bounds is not None and self.mapping.known_fraction() < self.UNSEEN
        if not frontiers and unseen:
            towards = self._frontier_towards_bounds(costmap, est)
            if towards is None:
                xmin, xmax, ymin, ymax = self.bounds or (0.0, 0.0, 0.0, 0.0)
                self._failure = (
                    f"the bounds (x {xmin:g}..{xmax:g}, y {ymin:g}..{ymax:g}) cannot be "
                    "reached: they are not in sight and no reachable frontier leads there"
                )
                return self._failure
            frontiers = [towards]
        if not frontiers:
            if self._looks < self.LOOKS_BEFORE_DONE:
                # Standing in a tight spot the map may show no way out for a moment (a
                # cell of wall too many beside a piece of furniture): look all around and
                # ask again on a costmap that holds what that showed.
                self._looks += 1
                self._turned = 0.0
                self._last_yaw = est.yaw
                self.mapping.request_refresh()
                self._reselect_at = state.time
                handle.navigator.cancel()
                self.goal = None
                return None
            return "no reachable frontier left"
        self._looks = 0
        if self.goal is not None and any(
            math.hypot(f.goal[0] - self.goal.x, f.goal[1] - self.goal.y) < 0.5
            for f in frontiers
            if f.goal is not None
        ):
            return None  # the frontier being approached is still there: keep driving
        best = choose_frontier(
            frontiers,
            costmap.grid,
            self._position_sigma(),
            self.UNCERTAIN_SIGMA,
            self.FEATURE_RANGE,
        )
        assert best.goal is not None
        gx, gy = best.goal
        yaw = math.atan2(best.centroid[1] - gy, best.centroid[0] - gx)
        self.goal = Pose2D(gx, gy, yaw)
        self._goals_started += 1
        handle.navigator.start(
            self.goal, state, xy_tolerance=self.GOAL_TOLERANCE, yaw_tolerance=math.pi
        )
        return None

    def _position_sigma(self) -> float:
        """SLAM's position std now (m): the root of its xy covariance's largest
        eigenvalue (the covariance is the SLAM protocol's)."""
        assert self.mapping is not None
        cov = np.asarray(self.mapping.slam.covariance)[:2, :2]
        return float(math.sqrt(max(float(np.linalg.eigvalsh(cov)[-1]), 0.0)))

    def _frontiers(self, costmap: Costmap, est: Pose2D, bounds: Bounds | None) -> list[Frontier]:
        """Reachable frontiers within ``bounds`` (None: anywhere), nearest first."""
        return find_frontiers(
            costmap.grid,
            bounds=bounds,
            robot=(est.x, est.y),
            robot_radius=costmap.robot_radius,
            clearance=self.clearance,
            min_size=self.min_frontier_size,
            goal_margin=self.GOAL_MARGIN,
            blacklist=self._blacklist(costmap.grid),
            blacklist_radius=self.BLACKLIST_RADIUS,
        )

    def _frontier_towards_bounds(self, costmap: Costmap, est: Pose2D) -> Frontier | None:
        """The reachable frontier (anywhere) nearest to bounds not seen yet: driving there
        brings them into sight."""
        assert self.bounds is not None
        xmin, xmax, ymin, ymax = self.bounds
        everywhere = self._frontiers(costmap, est, None)

        def gap(f: Frontier) -> float:
            cx, cy = f.centroid
            return math.hypot(max(xmin - cx, 0.0, cx - xmax), max(ymin - cy, 0.0, cy - ymax))

        return min(everywhere, key=gap, default=None)

    def _give_up(self, goal: Pose2D) -> None:
        """Blacklist ``goal`` (one more attempt at the spot, if it was tried before)."""
        mapping = self.mapping
        assert mapping is not None
        grid = mapping.costmap.grid if mapping.costmap is not None else mapping.grid
        known = float(np.count_nonzero(grid.data != UNKNOWN))
        for entry in self.attempts:
            if math.hypot(entry[0] - goal.x, entry[1] - goal.y) <= self.BLACKLIST_RADIUS:
                entry[2] += 1
                entry[3] = known
                return
        self.attempts.append([goal.x, goal.y, 1.0, known])

    def _blacklist(self, grid: OccupancyGrid) -> list[tuple[float, float]]:
        """The goals to skip now: tried too often, or the map has not grown much since."""
        known = float(np.count_nonzero(grid.data != UNKNOWN))
        return [
            (x, y)
            for x, y, tries, then in self.attempts
            if tries >= self.MAX_ATTEMPTS or known < then + self.RETRY_GROWTH
        ]

    @property
    def blacklist(self) -> list[tuple[float, float]]:
        """Every goal given up on so far (for now or for good)."""
        return [(x, y) for x, y, _, _ in self.attempts]


def choose_frontier(
    frontiers: list[Frontier],
    grid: OccupancyGrid,
    sigma: float,
    uncertain_sigma: float,
    feature_range: float,
) -> Frontier:
    """The frontier to explore next (``frontiers`` nearest first): the one of least
    driving distance plus, per metre its goal lies beyond ``feature_range`` of the
    nearest OCCUPIED cell of ``grid``, ``sigma / uncertain_sigma`` metres: the nearest
    while the position std ``sigma`` is small, one near mapped structure (where a scan
    corrects the estimate) as it grows."""
    weight = sigma / uncertain_sigma if uncertain_sigma > 0.0 else 0.0
    if weight < 1.0 or len(frontiers) < 2:
        return frontiers[0]
    to_structure = ndimage.distance_transform_edt(grid.data != OCCUPIED) * grid.resolution
    best, best_cost = frontiers[0], math.inf
    for f in frontiers:
        if f.goal is None:
            continue
        r, c = grid.world_to_cell(np.asarray(f.goal, dtype=float))
        blind = max(float(to_structure[int(r), int(c)]) - feature_range, 0.0)
        cost = f.distance + weight * blind
        if cost < best_cost:
            best, best_cost = f, cost
    return best
