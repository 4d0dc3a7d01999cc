"""A finished run's result document in words: one row a task and one line of metrics.

Light on purpose (no numpy, no simulator): ``agv-mission submit`` prints a service's
result with it too.
"""

from __future__ import annotations

from typing import Any


def task_rows(result: dict[str, Any]) -> list[tuple[str, str, str]]:
    """``(task, status, detail)`` a task: waypoints or rooms reached, and the reason, each
    part separated by ``;`` (never run together)."""
    rows = []
    for task in result["tasks"]:
        details = []
        if "waypoints" in task:
            reached = sum(w["status"] == "reached" for w in task["waypoints"])
            planned = task.get("waypoints_planned", len(task["waypoints"]))
            details.append(f"{reached}/{planned} waypoints reached")
        if "rooms" in task:
            reached = sum(r["status"] == "reached" for r in task["rooms"])
            recorded = sum(bool(r.get("recorded")) for r in task["rooms"])
            details.append(f"{reached}/{len(task['rooms'])} rooms reached, {recorded} recorded")
        if task.get("reason"):
            details.append(str(task["reason"]))
        who = f"{task['robot']}: " if task.get("robot") else ""
        rows.append((f"{who}{task['index']}. {task['type']}", task["status"], "; ".join(details)))
    return rows


#: Tree nodes a summary lists at most (a generated tree can be large; result.json has all).
TREE_ROWS = 40


def tree_rows(result: dict[str, Any]) -> list[tuple[str, str, str]]:
    """``(node, status, detail)`` a node of the mission's tree, indented by depth: what a
    tree mission did, where a task list has :func:`task_rows`. A fleet's rows name each
    robot's tree."""
    rows: list[tuple[str, str, str]] = []
    trees = [("", result.get("tree") or [])]
    if result.get("robots"):
        trees = [(f"{name}: ", r.get("tree") or []) for name, r in result["robots"].items()]
    for who, nodes in trees:
        for node in nodes:
            depth = node["path"].count("/") - (node["path"] == "/")
            label = (
                node["name"] if node["name"] == node["type"] else f"{node['name']} ({node['type']})"
            )
            detail = []
            if node.get("started"):
                detail.append(f"started {node['started']}x")
            if node.get("running_time"):
                detail.append(f"ran {node['running_time']:g} s")
            rows.append((f"{who}{'  ' * depth}{label}", str(node.get("status")), ", ".join(detail)))
    if len(rows) > TREE_ROWS:
        rest = len(rows) - TREE_ROWS
        rows = [*rows[:TREE_ROWS], (f"... {rest} more node(s) in result.json", "", "")]
    return rows


def headline(result: dict[str, Any]) -> str:
    """What the mission was: its tasks, or its tree when it has no tasks."""
    tasks = result.get("tasks") or []
    if tasks or not result.get("tree"):
        return f"{len(tasks)} task(s)"
    return f"a behaviour tree of {len(result['tree'])} node(s)"


def metrics_line(result: dict[str, Any]) -> str:
    """Time, speed, distance, collisions, clearance and localisation error in one line."""
    m = result["metrics"]
    fleet = result.get("fleet")
    if fleet is not None:
        return (
            f"sim {result['sim_time']:.1f} s in {result['wall_time']:.1f} s wall "
            f"({m['real_time_factor']}x real time), {m['robots']} robots drove "
            f"{m['distance_driven']:.2f} m, collisions {m['collisions']} "
            f"({fleet['robot_robot_collisions']} robot-robot), closest robots "
            f"{fleet['robot_robot_min_distance']} m, waits {fleet['waits']['count']}, "
            f"deadlocks {fleet['deadlocks']}, makespan {fleet['makespan']} s"
        )
    loc = m["localization"]
    return (
        f"sim {result['sim_time']:.1f} s in {result['wall_time']:.1f} s wall "
        f"({m['real_time_factor']}x real time), driven {m['distance_driven']:.2f} m, "
        f"collisions {m['collisions']}, min clearance {m['min_clearance']} m, "
        "position RMSE "
        + (f"{loc['position_rmse']:.3f} m" if loc["position_rmse"] is not None else "n/a")
    )


def leg_rows(result: dict[str, Any]) -> list[tuple[str, ...]]:
    """``(leg, goal, status, planned m, shortest m, driven m, planned/shortest,
    driven/shortest)`` a leg (each goal pursued), from ``metrics.navigation.legs``."""

    def num(value: Any, digits: int) -> str:
        return "-" if value is None else f"{value:.{digits}f}"

    legs = ((result.get("metrics") or {}).get("navigation") or {}).get("legs") or []
    return [
        (
            str(i),
            f"{leg['goal'][0]:.2f},{leg['goal'][1]:.2f}",
            leg["status"],
            num(leg["planned"], 2),
            num(leg["shortest"], 2),
            num(leg["driven"], 2),
            num(leg["planned_vs_shortest"], 3),
            num(leg["driven_vs_shortest"], 3),
        )
        for i, leg in enumerate(legs, 1)
    ]


#: The columns of :func:`leg_rows`.
LEG_COLUMNS = (
    "leg",
    "goal",
    "status",
    "planned m",
    "shortest m",
    "driven m",
    "planned\n/shortest",
    "driven\n/shortest",
)
