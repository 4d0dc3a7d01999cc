"""Start-up of the command line: what a user waits for before anything happens.

Each command runs as a fresh process (`.venv/bin/agv-mission ...`), 7 times; the median
wall time is reported, beside the bare interpreter's start-up measured in the same run
(the machine's speed drifts):

* ``startup.validate_s``: ``agv-mission validate missions/*.yaml`` (issue 16: under 1 s).
* ``startup.run_help_s``: ``agv-mission run --help`` (issue 16: under 1 s).
* ``startup.python_s``: ``python -c pass``, the floor under both.
"""

from __future__ import annotations

import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CLI = Path(sys.executable).parent / "agv-mission"
REPEATS = 7


def _median_wall(command: list[str]) -> float:
    times = []
    for _ in range(REPEATS):
        start = time.perf_counter()
        subprocess.run(command, cwd=ROOT, capture_output=True, check=True)
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def run() -> dict[str, float]:
    missions = sorted(str(p) for p in (ROOT / "missions").glob("*.yaml"))
    return {
        "startup.python_s": round(_median_wall([sys.executable, "-c", "pass"]), 3),
        "startup.validate_s": round(_median_wall([str(CLI), "validate", *missions]), 3),
        "startup.run_help_s": round(_median_wall([str(CLI), "run", "--help"]), 3),
    }


if __name__ == "__main__":
    print(run())
