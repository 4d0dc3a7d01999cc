"""Start-up of the command line: what a user waits for before anything happens.

Each command runs as a fresh process (`.venv/bin/agv-mission ...`), 7 times; the median
wall time is reported, beside the bare interpreter's start-up measured in the same run
(the machine's speed drifts):

* ``startup.validate_s``: ``agv-mission validate missions/*.yaml`` (issue 16: under 1 s),
  with the values a validate stores for later processes stored (``agv_mission.stored``:
  the worlds' free space and distance fields, OMPL's planner list), as every validate
  after the first on this machine finds them.
* ``startup.validate_cold_s``: the same, each run with an empty store (a first validate:
  it imports scipy.ndimage and OMPL to compute them).
* ``startup.run_help_s``: ``agv-mission run --help`` (issue 16: under 1 s).
* ``startup.python_s``: ``python -c pass``, the floor under both.

The package's bytecode is compiled first, as installing it does (pip compiles a wheel's
modules, and an editable install writes it on first import): a process run with
``PYTHONDONTWRITEBYTECODE`` set, as this machine's sessions are, would otherwise compile
every module it imports (~0.25 s for validate's ~100) on every start.
"""

from __future__ import annotations

import compileall
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CLI = Path(sys.executable).parent / "agv-mission"
REPEATS = 7


def _median_wall(command: list[str], store: Path | None = None) -> float:
    """Median wall time of ``command``; with ``store``: each run with a new empty store
    under it."""
    times = []
    for k in range(REPEATS):
        env = None if store is None else {**os.environ, "AGV_MISSION_STORE": str(store / str(k))}
        start = time.perf_counter()
        subprocess.run(command, cwd=ROOT, capture_output=True, check=True, env=env)
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def run() -> dict[str, float]:
    compileall.compile_dir(ROOT / "src" / "agv_mission", quiet=1)
    missions = sorted(str(p) for p in (ROOT / "missions").glob("*.yaml"))
    validate = [str(CLI), "validate", *missions]
    subprocess.run(validate, cwd=ROOT, capture_output=True, check=True)  # fills the store
    with tempfile.TemporaryDirectory() as empty:
        cold = _median_wall(validate, Path(empty))
    return {
        "startup.python_s": round(_median_wall([sys.executable, "-c", "pass"]), 3),
        "startup.validate_s": round(_median_wall(validate), 3),
        "startup.validate_cold_s": round(cold, 3),
        "startup.run_help_s": round(_median_wall([str(CLI), "run", "--help"]), 3),
    }


if __name__ == "__main__":
    print(run())
