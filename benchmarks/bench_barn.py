"""BARN: the 300 public worlds by BARN's protocol (barn.md), for the default stack and for
``pure_pursuit``, beside BARN's own DWA baseline; how long the 300 took on 2 workers.

The worlds are read from a clone of ``Daffan/the-barn-challenge`` (MIT licence): its root or
its ``jackal_helper/worlds/BARN`` folder, named by the environment variable
``AGV_MISSION_BARN`` or the first argument (``python benchmarks/bench_barn.py DIR``).
Without it the module reports ``barn.available = 0`` and the DWA baseline only.
``AGV_MISSION_BARN_WORLDS`` (e.g. ``0-19``) runs a subset, for a quick look; the keys then
say how many worlds ran (``barn.<stack>.worlds``).

Each stack is one ``agv-mission barn DIR --workers 2`` command, end to end (run directories
with their bags in a temporary folder):

* ``barn.<stack>.success_rate``, ``.collision_rate``, ``.timeout_rate``: shares of the worlds;
* ``barn.<stack>.mean_time_s``: mean time of the successes (BARN's clock);
* ``barn.<stack>.mean_metric``: BARN's metric, averaged over every world;
* ``barn.<stack>.wall_s``: wall time of the command (issue 33's target: <= 600 s for 300).

``barn.dwa.*``: BARN's published move_base + DWA baseline (its README), not measured here.

``barn.drawn.*``: the default stack on 120 new worlds drawn by BARN's own recipe
(:mod:`agv_mission.barn.draws`, seed 2026: ten of each of the recipe's twelve parameter
sets), the class of the challenge's held-out worlds (issue 33: success >= 0.95, collisions
<= 0.02, mean metric >= 0.35 on them). Needs no clone: the recipe draws them.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from rich.table import Table

CLI = Path(sys.executable).parent / "agv-mission"
WORKERS = 2
DRAWN_WORLDS, DRAWN_SEED = 120, 2026
STACKS = {
    "default": [],
    "pure_pursuit": ["--set", "stack.local_planner.type=pure_pursuit"],
}
#: BARN's README: move_base with DWA on the 300 public worlds (Gazebo, 1x real time).
DWA_BASELINE = {
    "mean_metric": 0.1693,
    "success_rate": 0.88,
    "collision_rate": 0.048,
    "timeout_rate": 0.072,
}
SUMMARY_KEYS = {
    "success_rate": "success_rate",
    "collision_rate": "collision_rate",
    "timeout_rate": "timeout_rate",
    "mean_time_s": "mean_time",
    "mean_metric": "mean_metric",
}


def barn_dir(argument: str | None = None) -> Path | None:
    """The BARN worlds folder named by the argument or ``AGV_MISSION_BARN`` (a clone's
    root or its worlds folder); None when neither names one."""
    named = argument or os.environ.get("AGV_MISSION_BARN")
    if not named:
        return None
    root = Path(named).expanduser()
    for candidate in (root, root / "jackal_helper" / "worlds" / "BARN"):
        if (candidate / "path_files").is_dir() and any(candidate.glob("world_*.world")):
            return candidate
    return None


def run_stack(directory: Path, extra: list[str], root: Path, name: str) -> dict[str, float]:
    summary = root / f"{name}.json"
    command = [str(CLI), "barn", str(directory), "--workers", str(WORKERS), *extra]
    command += ["--output", str(root / name), "--json", str(summary)]
    worlds = os.environ.get("AGV_MISSION_BARN_WORLDS")
    if worlds:
        command += ["--worlds", worlds]
    start = time.perf_counter()
    done = subprocess.run(command, capture_output=True, text=True)
    wall = time.perf_counter() - start
    if done.returncode != 0 or not summary.is_file():
        tail = (done.stderr or done.stdout).strip().splitlines()[-3:]
        print(f"  barn {name}: exit {done.returncode}: {' / '.join(tail)}")
        return {f"barn.{name}.exit_code": float(done.returncode)}
    doc = json.loads(summary.read_text())["summary"]
    out = {f"barn.{name}.worlds": float(doc["worlds"]), f"barn.{name}.wall_s": round(wall, 1)}
    for key, source in SUMMARY_KEYS.items():
        if doc.get(source) is not None:
            out[f"barn.{name}.{key}"] = round(float(doc[source]), 4)
    return out


def drawn(root: Path) -> dict[str, float]:
    """The default stack on new worlds drawn by BARN's recipe."""
    from agv_mission.barn.draws import draw_worlds, write_worlds

    folder = root / "drawn_worlds"
    write_worlds(folder, draw_worlds(DRAWN_WORLDS, DRAWN_SEED))
    return run_stack(folder, [], root, "drawn")


def run(argument: str | None = None) -> dict[str, float]:
    directory = barn_dir(argument)
    results: dict[str, float] = {f"barn.dwa.{k}": v for k, v in DWA_BASELINE.items()}
    with tempfile.TemporaryDirectory() as tmp:
        results.update(drawn(Path(tmp)))
        if directory is None:
            print(
                "  BARN not available: set AGV_MISSION_BARN to a clone of "
                "Daffan/the-barn-challenge (or its jackal_helper/worlds/BARN)"
            )
            return {"barn.available": 0.0, **results}
        results["barn.available"] = 1.0
        for name, extra in STACKS.items():
            results.update(run_stack(directory, extra, Path(tmp), name))
    return results


def tables(values: dict[str, float]) -> list[Table]:
    """The README's table: each stack beside BARN's DWA baseline."""
    if not values.get("barn.available") and "barn.drawn.worlds" not in values:
        return []
    table = Table(title="BARN's public worlds", header_style="bold")
    for column in ("stack", "worlds", "success", "collisions", "timeouts", "mean time s"):
        table.add_column(column, justify="right")
    table.add_column("mean metric", justify="right")
    table.add_column("wall s (2 workers)", justify="right")

    def cell(key: str, digits: int = 3) -> str:
        value = values.get(key)
        return "-" if value is None else f"{value:.{digits}f}"

    for name in [*STACKS, "drawn", "dwa"]:
        if name != "dwa" and f"barn.{name}.worlds" not in values:
            continue
        label = {"dwa": "BARN's DWA (Gazebo)", "drawn": "default, new worlds (BARN's recipe)"}
        table.add_row(
            label.get(name, name),
            cell(f"barn.{name}.worlds", 0) if name != "dwa" else "300",
            cell(f"barn.{name}.success_rate"),
            cell(f"barn.{name}.collision_rate"),
            cell(f"barn.{name}.timeout_rate"),
            cell(f"barn.{name}.mean_time_s", 2),
            cell(f"barn.{name}.mean_metric", 4),
            cell(f"barn.{name}.wall_s", 0),
        )
    return [table]


if __name__ == "__main__":
    from rich.console import Console

    found = run(sys.argv[1] if len(sys.argv) > 1 else None)
    console = Console()
    for extra_table in tables(found):
        console.print(extra_table)
    console.print(found)
