"""Scenario regression scaling: ``agv-mission regress tests/scenarios`` on 1 and 2 workers.

The whole suite (fast and slow scenarios, as ``make regress`` runs it), end to end through
the command line, run directories in a temporary folder:

* ``regress.wall_s.1_worker`` / ``regress.wall_s.2_workers``: wall time of the command.
* ``regress.speedup_ratio``: 2-worker time / 1-worker time, measured back to back in the
  same run (the machine's speed drifts between runs). Issue target: <= 0.6.
* ``regress.runs``: scenario runs per pass (one per mission file: task lists, trees,
  fleets); ``regress.skipped``: files found that are not missions (an XML tree runs
  through the mission naming it); ``regress.passed``: 1 when both passes exited 0
  (every expectation met).
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

SCENARIOS = Path(__file__).resolve().parents[1] / "tests" / "scenarios"
CLI = Path(sys.executable).parent / "agv-mission"


def _pass(workers: int, root: Path) -> tuple[float, bool, int, int]:
    summary = root / f"w{workers}.json"
    command = [str(CLI), "regress", str(SCENARIOS), "--workers", str(workers)]
    command += ["--output", str(root / f"w{workers}"), "--json", str(summary)]
    start = time.perf_counter()
    done = subprocess.run(command, capture_output=True, text=True)
    wall = time.perf_counter() - start
    doc = json.loads(summary.read_text()) if summary.is_file() else {}
    runs = doc.get("counts", {}).get("runs", 0)
    return wall, done.returncode == 0, runs, len(doc.get("skipped", []))


def run() -> dict[str, float]:
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        one, ok1, runs, skipped = _pass(1, root)
        two, ok2, _, _ = _pass(2, root)
    return {
        "regress.runs": float(runs),
        "regress.skipped": float(skipped),
        "regress.wall_s.1_worker": round(one, 2),
        "regress.wall_s.2_workers": round(two, 2),
        "regress.speedup_ratio": round(two / one, 3),
        "regress.passed": float(ok1 and ok2),
    }
