"""A scenario's ``expect:`` block checked against its run's result document (the content
of ``result.json``): :func:`check` lists every bound the run did not meet. The block's
model is :class:`~agv_mission.missions.load.schema.expect.Expectations`."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

from agv_mission.missions.load.schema.expect import (
    DEFAULT_EXPECTATIONS,
    Expectations,
    TaskStatus,
)


@dataclass(frozen=True)
class Failure:
    """One expectation a run did not meet."""

    metric: str  # the expect key, or ``tasks.<i>`` for a per-task status
    expected: Any
    actual: Any
    by: float | None = None  # how far past the bound a numeric metric is (always >= 0)

    def __str__(self) -> str:
        text = f"{self.metric}: expected {_show(self.expected)}, got {_show(self.actual)}"
        if self.by is not None:
            text += f" (off by {_num(self.by)})"
        return text

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["message"] = str(self)
        return d


def check(expect: Expectations | None, result: dict[str, Any]) -> list[Failure]:
    """Every expectation of ``expect`` that the result document ``result`` does not meet."""
    e = expect if expect is not None else DEFAULT_EXPECTATIONS
    b = _Bounds()
    metrics = result.get("metrics") or {}
    _check_outcome(e, result, b)
    _check_motion(e, result, metrics, b)
    _check_navigation(e, metrics, b)
    _check_maps(e, result, b)
    _check_work(e, result, metrics, b)
    _check_fleet(e, result, b)
    return b.failures


class _Bounds:
    """The failures found so far, and the two numeric bounds that add to them."""

    def __init__(self) -> None:
        self.failures: list[Failure] = []

    def at_most(self, key: str, bound: float | None, actual: Any) -> None:
        if bound is None:
            return
        if not _is_number(actual):
            self.failures.append(Failure(key, f"<= {_num(bound)}", actual))
        elif actual > bound:
            self.failures.append(Failure(key, f"<= {_num(bound)}", actual, actual - bound))

    def at_least(self, key: str, bound: float | None, actual: Any) -> None:
        if bound is None:
            return
        if not _is_number(actual):
            self.failures.append(Failure(key, f">= {_num(bound)}", actual))
        elif actual < bound:
            self.failures.append(Failure(key, f">= {_num(bound)}", actual, bound - actual))


def _check_outcome(e: Expectations, result: dict[str, Any], b: _Bounds) -> None:
    """The run's status and reason, its tasks' and named nodes' statuses."""
    if e.status is not None and result.get("status") != e.status:
        actual = result.get("status")
        if result.get("reason"):
            actual = f"{actual} ({result['reason']})"
        b.failures.append(Failure("status", e.status, actual))
    if e.reason_contains is not None and e.reason_contains not in (result.get("reason") or ""):
        b.failures.append(
            Failure(
                "reason_contains", f"reason containing {e.reason_contains!r}", result.get("reason")
            )
        )
    if e.tasks is not None:
        b.failures += _check_tasks(e.tasks, result.get("tasks") or [])
    for key, want in (e.nodes or {}).items():
        found = [n for n in result.get("tree") or [] if key in (n.get("name"), n.get("path"))]
        if not found:
            b.failures.append(Failure(f"nodes.{key}", want, "no such node in the tree"))
        for node in found:
            if node.get("status") != want:
                b.failures.append(Failure(f"nodes.{key}", want, node.get("status")))


def _check_motion(
    e: Expectations, result: dict[str, Any], metrics: dict[str, Any], b: _Bounds
) -> None:
    """Time, contacts, clearance, distance, zones and the people around."""
    b.at_most("sim_time_max", e.sim_time_max, result.get("sim_time"))
    b.at_least("sim_time_min", e.sim_time_min, result.get("sim_time"))
    b.at_most("collisions_max", e.collisions_max, metrics.get("collisions"))
    b.at_least("min_clearance_min", e.min_clearance_min, metrics.get("min_clearance"))
    b.at_most("distance_driven_max", e.distance_driven_max, metrics.get("distance_driven"))
    zones = metrics.get("zones") or {}
    b.at_most("keepout_time_max", e.keepout_time_max, zones.get("keepout_time"))
    b.at_most(
        "keepout_time_after_exit_max",
        e.keepout_time_after_exit_max,
        zones.get("keepout_time_after_exit"),
    )
    b.at_most(
        "speed_violation_time_max", e.speed_violation_time_max, zones.get("speed_violation_time")
    )
    b.at_most("speed_ratio_max", e.speed_ratio_max, zones.get("max_speed_ratio"))
    people = metrics.get("people") or {}
    b.at_most("people_collisions_max", e.people_collisions_max, people.get("collisions"))
    b.at_least("people_min_distance_min", e.people_min_distance_min, people.get("min_distance"))
    b.at_most("personal_time_max", e.personal_time_max, people.get("personal_time"))
    stood, sim = people.get("time_not_moving"), result.get("sim_time")
    share = stood / sim if _is_number(stood) and _is_number(sim) and sim > 0 else stood
    b.at_most("not_moving_share_max", e.not_moving_share_max, share)


def _check_navigation(e: Expectations, metrics: dict[str, Any], b: _Bounds) -> None:
    """How the way driven compares with the planned and shortest; localisation error."""
    navigation = metrics.get("navigation") or {}
    for key, bound in (
        ("driven_vs_shortest_max", e.driven_vs_shortest_max),
        ("driven_vs_planned_max", e.driven_vs_planned_max),
        ("planned_vs_shortest_max", e.planned_vs_shortest_max),
        ("driven_vs_shortest_free_max", e.driven_vs_shortest_free_max),
        ("planned_vs_shortest_free_max", e.planned_vs_shortest_free_max),
    ):
        b.at_most(key, bound, navigation.get(key))
    b.at_most("stops_max", e.stops_max, navigation.get("stops"))
    localization = metrics.get("localization") or {}
    b.at_most("localization_rmse_max", e.localization_rmse_max, localization.get("position_rmse"))
    b.at_most(
        "localization_max_error_max",
        e.localization_max_error_max,
        localization.get("position_max_error"),
    )
    b.at_least(
        "localization_consistency_min",
        e.localization_consistency_min,
        localization.get("consistency_2sigma"),
    )


def _check_maps(e: Expectations, result: dict[str, Any], b: _Bounds) -> None:
    """Every built map against the world (IoU, coverage)."""
    for key, bound in (
        ("map_iou_min", e.map_iou_min),
        ("map_occupied_iou_min", e.map_occupied_iou_min),
        ("map_coverage_min", e.map_coverage_min),
    ):
        if bound is None:
            continue
        values = map_values(result, MAP_KEYS[key])
        if not values:
            b.failures.append(Failure(key, f">= {_num(bound)}", "no map reported"))
        for value in values:
            b.at_least(key, bound, value)


def _check_work(
    e: Expectations, result: dict[str, Any], metrics: dict[str, Any], b: _Bounds
) -> None:
    """The battery, the rooms recorded and the waypoints reached."""
    battery = metrics.get("battery") or {}
    b.at_least("battery_min_min", e.battery_min_min, battery.get("minimum"))
    b.at_least("battery_end_min", e.battery_end_min, battery.get("end"))
    b.at_most("battery_energy_used_max", e.battery_energy_used_max, battery.get("energy_used"))
    b.at_least("dockings_min", e.dockings_min, battery.get("dockings"))
    if e.rooms_recorded is not None:
        recorded = set(result.get("rooms_recorded") or {})
        missing = [r for r in e.rooms_recorded if r not in recorded]
        if missing:
            b.failures.append(
                Failure(
                    "rooms_recorded",
                    e.rooms_recorded,
                    f"{sorted(recorded)} (missing {missing})",
                    float(len(missing)),
                )
            )
    if e.waypoints_reached is not None:
        reached = waypoints_reached(result)
        if reached < e.waypoints_reached:
            b.failures.append(
                Failure(
                    "waypoints_reached",
                    f">= {e.waypoints_reached}",
                    reached,
                    float(e.waypoints_reached - reached),
                )
            )


def _check_fleet(e: Expectations, result: dict[str, Any], b: _Bounds) -> None:
    """The fleet's summary, and each named robot's own expectations."""
    fleet = result.get("fleet") or {}
    b.at_most(
        "robot_robot_collisions_max",
        e.robot_robot_collisions_max,
        fleet.get("robot_robot_collisions"),
    )
    b.at_least(
        "robot_robot_min_distance_min",
        e.robot_robot_min_distance_min,
        fleet.get("robot_robot_min_distance"),
    )
    b.at_most("makespan_max", e.makespan_max, fleet.get("makespan"))
    b.at_most("deadlocks_max", e.deadlocks_max, fleet.get("deadlocks"))
    robots = result.get("robots") or {}
    for name, sub in (e.robots or {}).items():
        if name not in robots:
            b.failures.append(Failure(f"robots.{name}", "a robot of the fleet", "no such robot"))
            continue
        for f in check(sub, robots[name]):
            b.failures.append(Failure(f"robots.{name}.{f.metric}", f.expected, f.actual, f.by))


def waypoints_reached(result: dict[str, Any]) -> int:
    """Patrol waypoints reached over every patrol task and loop."""
    return sum(
        w.get("status") == "reached"
        for task in result.get("tasks") or []
        for w in task.get("waypoints") or []
    )


# Where each map expectation looks in a map's report (first key present wins).
MAP_KEYS = {
    "map_iou_min": ("free_iou", "iou"),
    "map_occupied_iou_min": ("occupied_iou",),
    "map_coverage_min": ("coverage",),
}


def map_values(result: dict[str, Any], keys: tuple[str, ...]) -> list[float]:
    """One value per map the result reports (``maps[i]``, else ``metrics.map``)."""
    reports = [m for m in result.get("maps") or [] if isinstance(m, dict)]
    if not reports and isinstance((result.get("metrics") or {}).get("map"), dict):
        reports = [result["metrics"]["map"]]
    values = []
    for report in reports:
        value = next((report[k] for k in keys if k in report), None)
        if _is_number(value):
            values.append(float(value))
    return values


def _check_tasks(
    spec: list[TaskStatus | None] | dict[int, TaskStatus], tasks: list[dict[str, Any]]
) -> list[Failure]:
    wanted = dict(enumerate(spec, start=1)) if isinstance(spec, list) else dict(spec)
    failures = []
    if isinstance(spec, list) and len(spec) != len(tasks):
        failures.append(Failure("tasks", f"{len(spec)} task(s)", f"{len(tasks)} task(s)"))
    for index, status in sorted(wanted.items()):
        if status is None:
            continue
        task = tasks[index - 1] if 1 <= index <= len(tasks) else None
        if task is None:
            failures.append(Failure(f"tasks.{index}", status, "no such task"))
        elif task.get("status") != status:
            actual = task.get("status")
            if task.get("reason"):
                actual = f"{actual} ({task['reason']})"
            failures.append(Failure(f"tasks.{index}", status, actual))
    return failures


def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _num(v: float) -> str:
    return f"{v:.4g}" if isinstance(v, float) else str(v)


def _show(v: Any) -> str:
    return _num(v) if _is_number(v) else str(v)
