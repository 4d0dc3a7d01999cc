"""`make bench`: measure what the issues ask for; print a table, write benchmarks/results.json.

Each ``bench_*.py`` module beside this file exposes ``run() -> dict[str, float]``. The
machine's CPU speed can flip about 2x between runs: compare options within one run.
"""

from __future__ import annotations

import importlib
import json
import platform
import sys
import time
from datetime import datetime, timezone
from pathlib import Path

from rich.console import Console
from rich.table import Table

from agv_mission.atomic import atomic_write_text

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

import figures  # noqa: E402
from targets import SUFFIX_TARGETS, TARGETS  # noqa: E402

MODULES = [
    "bench_sim",
    "bench_planners",
    "bench_mpc",
    "bench_amcl",
    "bench_slam",
    "bench_localization",
    "bench_imu",
    "bench_mission",
    "bench_breakdown",
    "bench_regress",
    "bench_startup",
    "bench_bags",
    "bench_service",
    "bench_dashboard",
    "bench_battery",
    "bench_trees",
    "bench_vda5050",
    "bench_fleet",
    "bench_people",
    "bench_shortest_way",
    "bench_barn",
]


def main() -> int:
    console = Console()
    only = set(sys.argv[1:])
    unknown = only - set(MODULES)
    if unknown:
        console.print(
            f"unknown benchmark(s): {', '.join(sorted(unknown))}; known: {', '.join(MODULES)}"
        )
        return 2
    results: dict[str, float] = {}
    seconds: dict[str, float] = {}  # how long each module took: what a whole run costs
    failed: list[str] = []
    for name in MODULES:
        if only and name not in only:
            continue
        start = time.perf_counter()
        console.print(f"[bold]{name}[/] ...")
        try:
            module = importlib.import_module(name)
            values = module.run()
        except Exception:  # noqa: BLE001 (the other modules still measure; the run is partial)
            console.print_exception()
            failed.append(name)
            continue
        results.update(values)
        for extra in getattr(module, "tables", lambda _: [])(values):
            console.print(extra)
        seconds[name] = round(time.perf_counter() - start, 1)
        console.print(f"  done in {seconds[name]:.1f} s")
    table = Table(title="agv-mission benchmarks", header_style="bold")
    table.add_column("metric")
    table.add_column("value", justify="right")
    table.add_column("target")
    for key in sorted(results):
        target = figures.target_of(key, TARGETS, SUFFIX_TARGETS)
        value = results[key]
        mark = ""
        if target is not None:
            ok = figures.met(value, target)
            mark = f"{target[0]} {target[1]:g} " + ("[green]ok[/]" if ok else "[red]MISSED[/]")
        table.add_row(key, figures.fmt(value), mark)
    console.print(table)
    doc = {
        "when": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "machine": {
            "python": platform.python_version(),
            "cpu": platform.processor(),
            "cores": __import__("os").cpu_count(),
        },
        "modules": sorted(only) if only else MODULES,
        "seconds": seconds,
        "results": results,
    }
    if failed:
        doc["failed"] = failed
        console.print(f"[red]failed:[/] {', '.join(failed)}")
    if only or failed:
        # A partial run (``run.py bench_mpc``) never patches results.json: the docs quote
        # only figures of one whole run.
        out = HERE / "results.partial.json"
        atomic_write_text(out, json.dumps(doc, indent=2) + "\n")
        console.print(f"wrote {out} (a partial run: results.json and the docs unchanged)")
        return 1 if failed else 0
    atomic_write_text(HERE / "results.json", json.dumps(doc, indent=2) + "\n")
    figures.publish(doc, TARGETS, SUFFIX_TARGETS)
    unmatched = [k for k in TARGETS if k not in results]
    if unmatched:
        console.print(f"[red]targets no benchmark wrote:[/] {', '.join(unmatched)}")
    console.print(f"wrote {HERE / 'results.json'}, {figures.PAGE} and the docs' tagged figures")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
