"""Scenario regression: run missions that carry an ``expect:`` block and check them.

A *scenario* is a mission file; its ``expect:`` block (see ``expectations.py``) says what
the run must achieve, and a scenario without one is expected to succeed. ``agv-mission
regress PATHS...`` takes files and directories (searched recursively for ``*.yaml``
files that look like missions, i.e. hold a ``tasks`` key), expands them into *jobs* and
runs every job in its own process:

* **Variants.** ``--sweep KEY=V1,V2,...`` (repeatable) gives values for one dotted mission
  key; several sweeps combine as a cartesian product. Each value is parsed as YAML and
  applied exactly like ``agv-mission run --set KEY=VALUE`` (commas inside ``[]``, ``{}``
  or quotes do not split values).
* **Seeds.** ``--seeds N`` runs each variant with the seeds ``S, S+1, ..., S+N-1`` where
  ``S`` is the mission's own ``seed`` (or the variant's, when a sweep sets ``seed``): so
  ``--seeds 1`` is exactly the scenario as written, and the expectations, tuned for ``S``,
  keep meaning what they meant.
* **Backends.** ``local``: a process pool of ``--workers`` processes (``forkserver``
  workers that import the stack once; ``--workers 1`` runs in this process). ``ray``:
  one Ray task per job, on a local Ray instance or the cluster at ``--address``. A job
  is a plain dict and returns a plain dict, so both give the same results: a run is a
  function of its mission and seed (wall-clock timings excepted, see
  :data:`WALL_CLOCK_METRICS`).

Jobs are started longest first (by ``limits.time``) so a pool finishes together.
Each job writes an ordinary run directory under the output root. The results feed a
table, a JUnit XML file, a JSON summary and, with variants or seeds, a comparison
table per variant: success rate, mean and p95 sim time, path length, clearance and
planner / controller solve times (time and path length over the succeeded runs only).
"""

from __future__ import annotations

import itertools
import json
import math
import multiprocessing
import os
import socket
import time
import traceback
import xml.etree.ElementTree as ET
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from agv_mission.missions.errors import MissionError, Problem

# Result keys that come from the wall clock: they differ between any two runs.
WALL_CLOCK_METRICS = (
    "real_time_factor",
    "navigation.planning_time_ms_mean",
    "navigation.controller_solve_ms_p50",
    "navigation.controller_solve_ms_p99",
)

ResultCallback = Callable[[dict[str, Any], int, int], None]


class RegressError(Exception):
    """Invalid regress input (paths, sweeps, backend); the CLI exits 2."""

    def __init__(self, message: str, problems: Sequence[Problem] = ()) -> None:
        super().__init__(message)
        self.problems = list(problems)


# ----------------------------------------------------------------------------- discovery


def discover(paths: Iterable[str | Path]) -> list[Path]:
    """Scenario files: files as given, directories searched recursively for ``*.yaml``
    files holding a ``tasks`` key (rooms files and the like are skipped)."""
    found: list[Path] = []
    for p in map(Path, paths):
        if p.is_dir():
            found += [f for f in sorted(p.rglob("*.yaml")) if _looks_like_mission(f)]
        elif p.is_file():
            found.append(p)
        else:
            raise RegressError(f"{p}: no such file or directory")
    unique = list(dict.fromkeys(f.resolve() for f in found))
    if not unique:
        raise RegressError(f"no scenario files (*.yaml with tasks) in {', '.join(map(str, paths))}")
    return unique


def _looks_like_mission(path: Path) -> bool:
    try:
        data = yaml.safe_load(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, yaml.YAMLError):
        return True  # let the loader report what is wrong with it
    return isinstance(data, dict) and "tasks" in data


# ------------------------------------------------------------------------------ variants


@dataclass(frozen=True)
class Variant:
    """One combination of sweep values: ``--set`` overrides and a short label."""

    label: str
    overrides: tuple[str, ...] = ()


def parse_sweep(item: str) -> tuple[str, list[str]]:
    """``KEY=V1,V2,...`` -> (KEY, [raw V1, raw V2, ...])."""
    key, sep, raw = item.partition("=")
    key = key.strip()
    if not sep or not key or not raw.strip():
        raise RegressError(
            f"--sweep {item!r}: expected KEY=V1,V2,..., "
            "e.g. stack.global_planner.planner=RRTConnect,RRTstar"
        )
    values = [v.strip() for v in _split_values(raw)]
    if any(not v for v in values):
        raise RegressError(f"--sweep {item!r}: empty value")
    return key, values


def _split_values(raw: str) -> list[str]:
    """Split on commas outside brackets, braces and quotes."""
    parts, depth, quote, current = [], 0, "", []
    for ch in raw:
        if quote:
            quote = "" if ch == quote else quote
        elif ch in "'\"":
            quote = ch
        elif ch in "[{":
            depth += 1
        elif ch in "]}":
            depth -= 1
        elif ch == "," and depth == 0:
            parts.append("".join(current))
            current = []
            continue
        current.append(ch)
    parts.append("".join(current))
    return parts


def expand_variants(sweeps: Sequence[str]) -> list[Variant]:
    """The cartesian product of every ``--sweep``; one unnamed variant without sweeps."""
    if not sweeps:
        return [Variant("")]
    parsed = [parse_sweep(s) for s in sweeps]
    keys = [k for k, _ in parsed]
    if len(set(keys)) != len(keys):
        raise RegressError(f"--sweep: a key is swept twice ({', '.join(keys)})")
    short = [k.rsplit(".", 1)[-1] for k in keys]
    names = short if len(set(short)) == len(short) else keys
    variants = []
    for combo in itertools.product(*(values for _, values in parsed)):
        label = " ".join(f"{n}={v}" for n, v in zip(names, combo, strict=True))
        overrides = tuple(f"{k}={v}" for k, v in zip(keys, combo, strict=True))
        variants.append(Variant(label, overrides))
    return variants


# ---------------------------------------------------------------------------------- jobs


@dataclass
class Plan:
    """Every job of a regress run, validated, in start order."""

    jobs: list[dict[str, Any]]
    scenarios: list[Path]
    variants: list[Variant]
    seeds: int
    output_root: Path
    problems: list[Problem] = field(default_factory=list)  # invalid scenarios / variants


def plan_jobs(
    paths: Iterable[str | Path],
    sweeps: Sequence[str] = (),
    seeds: int = 1,
    output_root: str | Path | None = None,
) -> Plan:
    """Discover, expand and validate (load every scenario x variant once, here).

    Invalid scenarios are collected in ``Plan.problems`` and get no jobs.
    """
    from agv_mission.missions.loader import load_mission

    if seeds < 1:
        raise RegressError("--seeds must be at least 1")
    scenarios = discover(paths)
    variants = expand_variants(sweeps)
    if output_root is None:
        stamp = datetime.now(timezone.utc).strftime("%Y%m%dT%H%M%SZ")
        output_root = Path("runs") / f"regress-{stamp}"
    root = Path(output_root).resolve()
    jobs: list[dict[str, Any]] = []
    problems: list[Problem] = []
    for s_index, path in enumerate(scenarios):
        for v_index, variant in enumerate(variants):
            try:
                loaded = load_mission(path, list(variant.overrides))
            except MissionError as exc:
                problems += exc.problems
                continue
            base = loaded.mission.seed
            for i in range(seeds):
                seed = base + i
                run_name = loaded.name
                if len(variants) > 1:
                    run_name += f"-v{v_index + 1}"
                if seeds > 1:
                    run_name += f"-s{seed}"
                jobs.append(
                    {
                        "id": len(jobs),
                        "order": (s_index, v_index, i),
                        "scenario": str(path),
                        "name": loaded.name,
                        "variant": variant.label,
                        "overrides": list(variant.overrides),
                        "seed": seed,
                        "run_name": run_name,
                        "output_root": str(root),
                        "cost": loaded.mission.limits.time,
                    }
                )
    # Longest first: a pool then finishes its last jobs together.
    jobs.sort(key=lambda j: -j["cost"])
    return Plan(jobs, scenarios, variants, seeds, root, problems)


def run_job(job: dict[str, Any]) -> dict[str, Any]:
    """Run one job (load, run, write the run directory, check); a plain dict back.

    Never raises: an exception becomes a result with status ``error``.
    """
    from agv_mission.missions.expectations import check
    from agv_mission.missions.loader import load_mission
    from agv_mission.missions.outputs import make_run_dir, write_mission, write_run
    from agv_mission.missions.runner import run_mission

    t0 = time.perf_counter()
    try:
        loaded = load_mission(job["scenario"], job["overrides"], job["seed"])
        run_dir = make_run_dir(Path(job["output_root"]), job["run_name"])
        write_mission(run_dir, loaded)
        record = run_mission(loaded, run_dir)
        doc = write_run(run_dir, loaded, record)
        doc = json.loads(json.dumps(doc, default=_json_default))  # plain types only
        failures = [f.to_dict() for f in check(loaded.mission.expect, doc)]
    except MissionError as exc:
        return error_result(job, "invalid input:\n" + "\n".join(map(str, exc.problems)))
    except Exception:
        return error_result(job, traceback.format_exc())
    return {
        **_job_keys(job),
        "status": doc["status"],
        "reason": doc["reason"],
        "sim_time": doc["sim_time"],
        "wall_time": round(time.perf_counter() - t0, 3),
        "run_dir": doc["run_dir"],
        "metrics": doc["metrics"],
        "tasks": doc["tasks"],
        "rooms_recorded": sorted(doc.get("rooms_recorded") or {}),
        "failures": failures,
        "passed": not failures,
        "error": None,
    }


def error_result(job: dict[str, Any], error: str) -> dict[str, Any]:
    """The result of a job that could not run to its end."""
    return {
        **_job_keys(job),
        "status": "error",
        "reason": error.strip().splitlines()[-1] if error.strip() else "error",
        "sim_time": None,
        "wall_time": None,
        "run_dir": None,
        "metrics": {},
        "tasks": [],
        "rooms_recorded": [],
        "failures": [],
        "passed": False,
        "error": error,
    }


def _job_keys(job: dict[str, Any]) -> dict[str, Any]:
    keys = ("id", "order", "scenario", "name", "variant", "overrides", "seed")
    return {k: job[k] for k in keys}


def _json_default(value: Any) -> Any:
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    raise TypeError(f"not JSON serialisable: {type(value).__name__}")


# ------------------------------------------------------------------------------ backends


WORKER_PRELOAD = [
    "agv_mission.regress.report",
    "agv_mission.missions.loader",
    "agv_mission.missions.runner",
    "agv_mission.missions.outputs",
    "matplotlib",
]


def _pool_context() -> Any:
    ctx = multiprocessing.get_context("forkserver")
    ctx.set_forkserver_preload(WORKER_PRELOAD)
    return ctx


def warm_up(backend: str = "local", workers: int | None = None) -> None:
    """Start the local pool's fork server now, so that it imports the stack while this
    process plans (call before :func:`plan_jobs`; harmless otherwise)."""
    if backend == "local" and (workers or os.cpu_count() or 1) > 1:
        from multiprocessing import forkserver

        _pool_context()
        forkserver.ensure_running()


def run_jobs(
    jobs: Sequence[dict[str, Any]],
    backend: str = "local",
    workers: int | None = None,
    address: str | None = None,
    on_result: ResultCallback | None = None,
) -> list[dict[str, Any]]:
    """Run every job on ``backend``; results in the order of the plan (scenario, variant,
    seed), whatever order they finished in."""
    workers = max(1, workers or os.cpu_count() or 1)
    results: list[dict[str, Any]] = []

    def collect(result: dict[str, Any]) -> None:
        results.append(result)
        if on_result is not None:
            on_result(result, len(results), len(jobs))

    if backend == "local":
        _run_local(jobs, workers, collect)
    elif backend == "ray":
        _run_ray(jobs, workers, address, collect)
    else:
        raise RegressError(f"unknown backend {backend!r} (local or ray)")
    return sorted(results, key=lambda r: tuple(r["order"]))


def _run_local(jobs: Sequence[dict[str, Any]], workers: int, collect: Callable) -> None:
    if workers == 1 or len(jobs) <= 1:
        for job in jobs:
            collect(run_job(job))
        return
    with ProcessPoolExecutor(
        max_workers=min(workers, len(jobs)), mp_context=_pool_context()
    ) as pool:
        futures = {pool.submit(run_job, job): job for job in jobs}
        for future in as_completed(futures):
            try:
                result = future.result()
            except Exception as exc:  # a worker died (killed, out of memory, ...)
                result = error_result(futures[future], f"worker process failed: {exc!r}")
            collect(result)


def _run_ray(
    jobs: Sequence[dict[str, Any]], workers: int, address: str | None, collect: Callable
) -> None:
    try:
        import ray
    except ImportError:
        raise RegressError(
            "the ray backend needs Ray, which is not installed: pip install 'agv-mission[ray]'"
        ) from None
    started = False
    if not ray.is_initialized():
        options: dict[str, Any] = {"include_dashboard": False, "logging_level": "WARNING"}
        if address:
            options["address"] = address
        else:
            options["num_cpus"] = workers
        try:
            ray.init(**options)
        except Exception as exc:
            raise RegressError(f"cannot start or reach Ray ({address or 'local'}): {exc}") from None
        started = True
    try:
        task = ray.remote(num_cpus=1, max_retries=0)(run_job)
        pending = {task.remote(job): job for job in jobs}
        while pending:
            done, _ = ray.wait(list(pending), num_returns=1)
            for ref in done:
                job = pending.pop(ref)
                try:
                    result = ray.get(ref)
                except Exception as exc:
                    result = error_result(job, f"ray task failed: {exc!r}")
                collect(result)
    finally:
        if started:
            ray.shutdown()


# ------------------------------------------------------------------------------- results


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
    return {
        "scenario": name,
        "variant": variant,
        "runs": len(rs),
        "succeeded": len(ok),
        "success_rate": round(len(ok) / len(rs), 4) if rs else None,
        "passed": sum(r["passed"] for r in rs),
        "sim_time_mean": mean(times),
        "sim_time_p95": round(float(np.percentile(times, 95)), 4) if times else None,
        "path_length_mean": mean(values(ok, "metrics.distance_driven")),
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
        ("dist m", "right"),
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
        title="comparison per variant (time and path over succeeded runs)",
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
        ("path m", "right"),
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
            _fmt(s["path_length_mean"], 2),
            _fmt(s["min_clearance_mean"], 3),
            _fmt(s["min_clearance_min"], 3),
            str(s["collisions"]),
            _fmt(s["planning_ms_mean"], 1),
            _fmt(s["solve_ms_p50_mean"], 2),
            _fmt(s["solve_ms_p99_max"], 2),
        )
    return table


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
    errors = sum(1 for r in results if r["status"] == "error") + len(plan.problems)
    tests = len(results) + len(plan.problems)
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
    for p in plan.problems:
        case = ET.SubElement(
            suite,
            "testcase",
            {"classname": f"scenarios.{Path(p.file).stem}", "name": "load", "file": p.file},
        )
        ET.SubElement(case, "error", {"message": str(p), "type": "InvalidInput"}).text = str(p)
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
        atomic_write_text(json_path, json.dumps(doc, indent=2, default=_json_default) + "\n")
