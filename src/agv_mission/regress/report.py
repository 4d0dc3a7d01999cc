"""Regress reports: deterministic views, statistics per variant, tables, JUnit XML and
the JSON summary."""

from __future__ import annotations

import json
import math
import socket
import xml.etree.ElementTree as ET
from collections.abc import Sequence
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np

from agv_mission.json_values import json_default
from agv_mission.regress.plan import WALL_CLOCK_METRICS, Plan


def deterministic_view(result: dict[str, Any]) -> dict[str, Any]:
    """A result without what the wall clock decides (for comparing backends)."""
    view = json.loads(json.dumps(result))
    for key in ("wall_time", "run_dir", "id"):
        view.pop(key, None)
    for dotted in WALL_CLOCK_METRICS:
        node = view.get("metrics") or {}
        *parents, leaf = dotted.split(".")
        for p in parents:
            node = node.get(p) or {}
        node.pop(leaf, None)
    return view


def plan_line(plan: Plan, seeds: int, backend: str, workers: int, address: str | None) -> str:
    """What is about to run, and where: runs, scenarios x variants x seeds, the backend."""
    where = f"({workers} workers)" if backend == "local" else f"({address or 'local Ray'})"
    return (
        f"{len(plan.jobs)} run(s): {len(plan.scenarios)} scenario(s) x {len(plan.variants)} "
        f"variant(s) x {seeds} seed(s) on {backend} " + where
    )


def skipped_lines(plan: Plan) -> list[str]:
    """One line per file found that is not a mission: the file and why it does not run."""
    return [f"skipped {f}: {why}" for f, why in plan.skipped]


def interrupted_line(results: Sequence[dict[str, Any]], plan: Plan) -> str:
    """How much of an interrupted suite ran."""
    return (
        f"interrupted: {len(results)} of {len(plan.jobs)} run(s) ran (the running ones "
        "ended aborted); the queued ones were cancelled"
    )


def run_label(result: dict[str, Any], variants: int = 1, seeds: int = 1) -> str:
    label = result["name"]
    extra = []
    if variants > 1 and result["variant"]:
        extra.append(result["variant"])
    if seeds > 1:
        extra.append(f"seed {result['seed']}")
    return label + (f" [{', '.join(extra)}]" if extra else "")


def failure_text(result: dict[str, Any]) -> str:
    if result["status"] == "error":
        return f"error: {result['reason']}"
    return "; ".join(f["message"] for f in result["failures"])


def compare(results: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """One row per (scenario, variant) -- plus per variant over all scenarios when there
    are several -- with success rate and the means the planner choice turns on."""
    groups: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for r in results:
        groups.setdefault((r["name"], r["variant"]), []).append(r)
    if len({r["name"] for r in results}) > 1:
        for r in results:
            groups.setdefault(("(all)", r["variant"]), []).append(r)
    return [_stats(name, variant, rs) for (name, variant), rs in groups.items()]


def leg_values(results: Sequence[dict[str, Any]], key: str) -> list[float]:
    """``key`` (a ratio of ``metrics.navigation.legs``) of every leg that succeeded, over
    ``results``: each leg's shortest path is computed once, when the leg begins."""
    out = []
    for r in results:
        nav = (r.get("metrics") or {}).get("navigation") or {}
        for leg in nav.get("legs") or []:
            value = leg.get(key)
            if leg.get("status") == "succeeded" and isinstance(value, (int, float)):
                out.append(float(value))
    return out


def _stats(name: str, variant: str, rs: list[dict[str, Any]]) -> dict[str, Any]:
    ok = [r for r in rs if r["status"] == "succeeded"]
    ran = [r for r in rs if r["status"] != "error"]

    def values(rows: list[dict[str, Any]], dotted: str) -> list[float]:
        out = []
        for r in rows:
            node: Any = r
            for part in dotted.split("."):
                node = node.get(part) if isinstance(node, dict) else None
            if isinstance(node, (int, float)) and math.isfinite(node):
                out.append(float(node))
        return out

    def mean(v: list[float]) -> float | None:
        return round(float(np.mean(v)), 4) if v else None

    times = values(ok, "sim_time")
    clear = values(ran, "metrics.min_clearance")
    planned_ratio = leg_values(ran, "planned_vs_shortest")
    driven_ratio = leg_values(ran, "driven_vs_shortest")
    return {
        "scenario": name,
        "variant": variant,
        "runs": len(rs),
        "succeeded": len(ok),
        "success_rate": round(len(ok) / len(rs), 4) if rs else None,
        "passed": sum(r["passed"] for r in rs),
        "sim_time_mean": mean(times),
        "sim_time_p95": round(float(np.percentile(times, 95)), 4) if times else None,
        "driven_length_mean": mean(values(ok, "metrics.distance_driven")),
        "planned_length_mean": mean(values(ok, "metrics.navigation.planned_length")),
        "planned_vs_shortest_mean": mean(planned_ratio),
        "planned_vs_shortest_max": max(planned_ratio, default=None),
        "driven_vs_shortest_mean": mean(driven_ratio),
        "driven_vs_shortest_max": max(driven_ratio, default=None),
        "min_clearance_mean": mean(clear),
        "min_clearance_min": round(min(clear), 4) if clear else None,
        "collisions": int(sum(values(ran, "metrics.collisions"))),
        "planning_ms_mean": mean(values(ran, "metrics.navigation.planning_time_ms_mean")),
        "solve_ms_p50_mean": mean(values(ran, "metrics.navigation.controller_solve_ms_p50")),
        "solve_ms_p99_max": max(
            values(ran, "metrics.navigation.controller_solve_ms_p99"), default=None
        ),
    }


def results_table(results: Sequence[dict[str, Any]], variants: int = 1, seeds: int = 1) -> Any:
    """The per-run table (rich)."""
    from rich.table import Table

    table = Table(show_header=True, header_style="bold", box=None, pad_edge=False)
    for col, justify in [
        ("scenario", "left"),
        ("status", "left"),
        ("sim s", "right"),
        ("wall s", "right"),
        ("driven m", "right"),
        ("planned/shortest", "right"),
        ("driven/shortest", "right"),
        ("coll", "right"),
        ("clear m", "right"),
        ("rmse m", "right"),
        ("expectations", "left"),
    ]:
        table.add_column(col, justify=justify)  # type: ignore[arg-type]
    for r in results:
        m = r["metrics"] or {}
        loc = m.get("localization") or {}
        verdict = "[green]ok[/]" if r["passed"] else f"[red]{_escape(failure_text(r))}[/]"
        colour = {"succeeded": "green", "failed": "yellow"}.get(r["status"], "red")
        table.add_row(
            _escape(run_label(r, variants, seeds)),
            f"[{colour}]{r['status']}[/]",
            _fmt(r["sim_time"], 1),
            _fmt(r["wall_time"], 1),
            _fmt(m.get("distance_driven"), 2),
            _ratios(leg_values([r], "planned_vs_shortest")),
            _ratios(leg_values([r], "driven_vs_shortest")),
            _fmt(m.get("collisions"), 0),
            _fmt(m.get("min_clearance"), 3),
            _fmt(loc.get("position_rmse"), 3),
            verdict,
        )
    return table


def comparison_table(rows: Sequence[dict[str, Any]]) -> Any:
    """The per-variant comparison (rich)."""
    from rich.table import Table

    table = Table(
        title="comparison per variant (time and driven length over succeeded runs; "
        "planned|driven / shortest per succeeded leg: mean (worst))",
        show_header=True,
        header_style="bold",
        box=None,
        pad_edge=False,
    )
    cols = [
        ("scenario", "left"),
        ("variant", "left"),
        ("runs", "right"),
        ("success", "right"),
        ("mean s", "right"),
        ("p95 s", "right"),
        ("driven m", "right"),
        ("planned/shortest", "right"),
        ("driven/shortest", "right"),
        ("clear m", "right"),
        ("min clear", "right"),
        ("coll", "right"),
        ("plan ms", "right"),
        ("solve ms", "right"),
        ("solve p99", "right"),
    ]
    for col, justify in cols:
        table.add_column(col, justify=justify)  # type: ignore[arg-type]
    for s in rows:
        rate = s["success_rate"]
        table.add_row(
            _escape(s["scenario"]),
            _escape(s["variant"] or "-"),
            str(s["runs"]),
            f"{rate:.0%}" if rate is not None else "-",
            _fmt(s["sim_time_mean"], 1),
            _fmt(s["sim_time_p95"], 1),
            _fmt(s["driven_length_mean"], 2),
            _mean_max(s["planned_vs_shortest_mean"], s["planned_vs_shortest_max"]),
            _mean_max(s["driven_vs_shortest_mean"], s["driven_vs_shortest_max"]),
            _fmt(s["min_clearance_mean"], 3),
            _fmt(s["min_clearance_min"], 3),
            str(s["collisions"]),
            _fmt(s["planning_ms_mean"], 1),
            _fmt(s["solve_ms_p50_mean"], 2),
            _fmt(s["solve_ms_p99_max"], 2),
        )
    return table


def _ratios(values: list[float]) -> str:
    """Per-leg ratios of one run: their mean and, in brackets, the worst."""
    if not values:
        return "-"
    return _mean_max(float(np.mean(values)), max(values))


def _mean_max(mean: float | None, worst: float | None) -> str:
    return "-" if mean is None or worst is None else f"{mean:.3f} ({worst:.3f})"


def _fmt(v: Any, digits: int) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "-"
    return f"{v:.{digits}f}" if digits else str(int(v))


def _escape(text: str) -> str:
    from rich.markup import escape

    return escape(text)


# ------------------------------------------------------------------------------- reports


def junit_xml(results: Sequence[dict[str, Any]], plan: Plan, wall_time: float) -> bytes:
    """JUnit XML: one testcase per run, ``<failure>`` naming each failed expectation,
    ``<error>`` for runs that did not finish."""
    variants, seeds = len(plan.variants), plan.seeds
    failures = sum(1 for r in results if r["status"] != "error" and not r["passed"])
    invalid: dict[str, list[str]] = {}  # one test case per invalid file, every problem in it
    for p in plan.problems:
        invalid.setdefault(p.file, []).append(str(p))
    errors = sum(1 for r in results if r["status"] == "error") + len(invalid)
    tests = len(results) + len(invalid)
    attrs = {
        "name": "agv-mission regress",
        "tests": str(tests),
        "failures": str(failures),
        "errors": str(errors),
        "time": f"{wall_time:.3f}",
    }
    root = ET.Element("testsuites", attrs)
    suite = ET.SubElement(
        root,
        "testsuite",
        {
            **attrs,
            "skipped": "0",
            "timestamp": datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%S"),
            "hostname": socket.gethostname(),
        },
    )
    for r in results:
        case = ET.SubElement(
            suite,
            "testcase",
            {
                "classname": f"scenarios.{Path(r['scenario']).stem}",
                "name": run_label(r, variants, seeds),
                "file": r["scenario"],
                "time": f"{r['wall_time'] or 0.0:.3f}",
            },
        )
        if r["status"] == "error":
            el = ET.SubElement(case, "error", {"message": r["reason"], "type": "RunError"})
            el.text = r["error"]
        elif not r["passed"]:
            el = ET.SubElement(
                case,
                "failure",
                {"message": failure_text(r), "type": "ExpectationFailed"},
            )
            el.text = "\n".join(
                f"{f['metric']}: expected {f['expected']}, actual {f['actual']}"
                + (f", off by {f['by']:.4g}" if f["by"] is not None else "")
                for f in r["failures"]
            ) + (f"\nrun status: {r['status']}" + (f" ({r['reason']})" if r["reason"] else ""))
        out = ET.SubElement(case, "system-out")
        out.text = (
            f"status {r['status']}, sim {r['sim_time']} s, seed {r['seed']}"
            + (f", overrides {' '.join(r['overrides'])}" if r["overrides"] else "")
            + f"\nrun directory: {r['run_dir']}"
        )
    for file, problems in invalid.items():
        case = ET.SubElement(
            suite,
            "testcase",
            {"classname": f"scenarios.{Path(file).stem}", "name": "load", "file": file},
        )
        error = ET.SubElement(case, "error", {"message": problems[0], "type": "InvalidInput"})
        error.text = "\n".join(problems)
    if plan.skipped:  # not test cases: files that are not missions, and why
        ET.SubElement(suite, "system-out").text = "\n".join(skipped_lines(plan))
    ET.indent(root)
    return ET.tostring(root, encoding="utf-8", xml_declaration=True) + b"\n"


def summary(
    results: Sequence[dict[str, Any]],
    plan: Plan,
    wall_time: float,
    backend: str,
    workers: int | None,
) -> dict[str, Any]:
    """The JSON summary: counts, every run's result and the comparison rows."""
    return {
        "tool": "agv-mission regress",
        "created": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "backend": backend,
        "workers": workers,
        "wall_time": round(wall_time, 3),
        "output_root": str(plan.output_root),
        "scenarios": [str(s) for s in plan.scenarios],
        "variants": [{"label": v.label, "overrides": list(v.overrides)} for v in plan.variants],
        "seeds": plan.seeds,
        "passed": all(r["passed"] for r in results) and not plan.problems,
        "counts": {
            "runs": len(results),
            "passed": sum(r["passed"] for r in results),
            "failed": sum(1 for r in results if r["status"] != "error" and not r["passed"]),
            "errors": sum(1 for r in results if r["status"] == "error"),
            "invalid": len(plan.problems),
        },
        "problems": [str(p) for p in plan.problems],
        "skipped": [{"file": str(f), "reason": why} for f, why in plan.skipped],
        "runs": list(results),
        "comparison": compare(results),
    }


def write_reports(
    results: Sequence[dict[str, Any]],
    plan: Plan,
    wall_time: float,
    backend: str,
    workers: int | None,
    junit: Path | None = None,
    json_path: Path | None = None,
) -> None:
    from agv_mission.atomic import atomic_write_bytes, atomic_write_text

    if junit is not None:
        junit.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_bytes(junit, junit_xml(results, plan, wall_time))
    if json_path is not None:
        json_path.parent.mkdir(parents=True, exist_ok=True)
        doc = summary(results, plan, wall_time, backend, workers)
        atomic_write_text(json_path, json.dumps(doc, indent=2, default=json_default) + "\n")
