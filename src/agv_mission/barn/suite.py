"""``agv-mission barn``: BARN's worlds, each one mission, run in parallel (barn.md).

:func:`plan_worlds` reads the BARN directory (``world_K.world`` and
``path_files/path_K.npy``) and the ``--worlds`` selection; :func:`run_world` runs one world
(in a worker process or on Ray) into a normal run directory ``OUTPUT/world_K/``;
:func:`summarise` makes barn.md's summary. Jobs and results are plain dicts.
"""

from __future__ import annotations

import io
import json
import re
import shutil
import tarfile
import tempfile
import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from agv_mission.barn.protocol import (
    STATUSES,
    BarnReferee,
    PathFileError,
    mission_text,
    path_length,
)

WORLD_FILE = re.compile(r"^world_(\d+)\.world$")
PATH_FOLDER = "path_files"


class BarnInputError(ValueError):
    """Invalid input to ``agv-mission barn``: the message names the file or the option."""


@dataclass
class BarnPlan:
    """The worlds to run: index -> world file and reference path length."""

    root: Path
    worlds: dict[int, Path]
    lengths: dict[int, float]


def parse_selection(text: str) -> list[int]:
    """``0-49,120,200-299`` as sorted world indices."""
    chosen: set[int] = set()
    for part in text.split(","):
        part = part.strip()
        m = re.fullmatch(r"(\d+)(?:\s*-\s*(\d+))?", part)
        if not m:
            raise BarnInputError(
                f"--worlds {text!r}: {part!r} is not a world index or a range like 0-49"
            )
        first, last = int(m.group(1)), int(m.group(2) or m.group(1))
        if last < first:
            raise BarnInputError(f"--worlds {text!r}: the range {part!r} runs backwards")
        if last - first > 100_000:
            raise BarnInputError(f"--worlds {text!r}: the range {part!r} is too long")
        chosen.update(range(first, last + 1))
    return sorted(chosen)


def plan_worlds(root: Path, selection: str | None = None) -> BarnPlan:
    """The selected worlds of the BARN directory ``root``, each with its path file's
    length; every missing file is named."""
    if not root.is_dir():
        raise BarnInputError(f"{root}: not a directory (BARN's worlds: world_K.world files)")
    present = {
        int(m.group(1)): p for p in root.iterdir() if (m := WORLD_FILE.match(p.name)) is not None
    }
    if selection is None:
        if not present:
            raise BarnInputError(f"{root}: holds no world_K.world file")
        indices = sorted(present)
    else:
        indices = parse_selection(selection)
        missing = [k for k in indices if k not in present]
        if missing:
            names = ", ".join(f"world_{k}.world" for k in missing[:10])
            more = f" and {len(missing) - 10} more" if len(missing) > 10 else ""
            raise BarnInputError(f"{root}: no {names}{more} (--worlds {selection})")
    problems, lengths = [], {}
    for k in indices:
        path_file = root / PATH_FOLDER / f"path_{k}.npy"
        if not path_file.is_file():
            problems.append(f"{path_file}: missing (world_{k}'s reference path)")
            continue
        try:
            lengths[k] = path_length(path_file)
        except PathFileError as exc:
            problems.append(str(exc))
    if problems:
        raise BarnInputError("\n".join(problems))
    return BarnPlan(root, {k: present[k] for k in indices}, lengths)


def world_jobs(
    plan: BarnPlan,
    overrides: list[str],
    seed: int,
    output_root: Path,
    observers: Callable[[Any], list[Any]] | None = None,
) -> list[dict[str, Any]]:
    """One job a world; ``observers`` (module level: a worker receives it by name) gives
    each run what the front door adds to a run, e.g. its bag writer."""
    return [
        {
            "world": k,
            "world_file": str(plan.worlds[k].resolve()),
            "path_length": plan.lengths[k],
            "overrides": list(overrides),
            "seed": seed,
            "output_root": str(output_root.resolve()),
            "observers": observers,
        }
        for k in sorted(plan.worlds)
    ]


def load_world_mission(job: dict[str, Any], world_file: Path | None = None) -> Any:
    """A job's world as a loaded mission (raises MissionError for bad input)."""
    from agv_mission.missions.load.loader import load_mission

    world_file = world_file or Path(job["world_file"])
    text = mission_text(world_file, job["seed"], Path(job["output_root"]))
    virtual = world_file.with_name(f"{world_file.stem}.mission.yaml")  # names its problems
    return load_mission(virtual, job["overrides"], text=text)


def run_world(job: dict[str, Any], stop: Any = None) -> dict[str, Any]:
    """Run one world into ``OUTPUT/world_K/``; barn.md's entry for it, never raising (an
    error is a ``failed`` world with ``error`` set)."""
    from agv_mission.missions.load.errors import MissionError
    from agv_mission.missions.report.directory import run_in

    t0 = time.perf_counter()
    k = job["world"]
    shipped = "world_bytes" in job  # on a remote worker: the world came with the job
    scratch = Path(tempfile.mkdtemp(prefix="agv-barn-")) if shipped else None
    try:
        world_file = None
        if scratch is not None:
            world_file = scratch / f"world_{k}.world"
            world_file.write_bytes(job["world_bytes"])
        loaded = load_world_mission(job, world_file)
        root = scratch if scratch is not None else Path(job["output_root"])
        run_dir = root / f"world_{k}"
        run_dir.mkdir(parents=True, exist_ok=False)
        referee = BarnReferee(stop)
        observers = job["observers"](loaded) if job.get("observers") else []
        done = run_in(run_dir, loaded, control=referee, observers=observers)
        record, result = done.record, done.result
        outcome = referee.outcome(
            record.status,
            record.reason,
            record.trajectory,
            int(record.metrics.get("collisions") or 0),
            job["path_length"],
        )
        error = None if record.status in ("succeeded", "failed") else record.reason
        barn = {
            "world": k,
            "status": outcome.status,
            "success": outcome.success,
            "time": outcome.time,
            "metric": outcome.metric,
            "path_length": outcome.path_length,
            "run_dir": str(run_dir),
        }
        result["barn"] = barn
        _write_json(run_dir / "result.json", result)
    except MissionError as exc:
        problems = "invalid input:\n" + "\n".join(map(str, exc.problems))
        return failed_result(job, problems, time.perf_counter() - t0, invalid=True)
    except Exception:  # noqa: BLE001 (one world's failure must not stop the others)
        return failed_result(job, traceback.format_exc(), time.perf_counter() - t0)
    out = {
        **barn,
        "reason": outcome.reason,
        "error": error,
        "wall_time": round(time.perf_counter() - t0, 3),
    }
    if scratch is not None:
        out["archive"] = _pack(run_dir)
        shutil.rmtree(scratch, ignore_errors=True)
    return out


def _write_json(path: Path, doc: dict[str, Any]) -> None:
    from agv_mission.missions.report.outputs import write_json

    write_json(path, doc)


def failed_result(
    job: dict[str, Any], error: str, wall_time: float | None = None, invalid: bool = False
) -> dict[str, Any]:
    """The entry of a world that could not run to its end (``error`` says why)."""
    return {
        "world": job["world"],
        "status": "failed",
        "success": False,
        "time": 0.0,
        "metric": 0.0,
        "path_length": job["path_length"],
        "run_dir": None,
        "reason": error.strip().splitlines()[-1] if error.strip() else "error",
        "error": error,
        "invalid": invalid,
        "wall_time": round(wall_time, 3) if wall_time is not None else None,
    }


def _pack(run_dir: Path) -> bytes:
    buf = io.BytesIO()
    with tarfile.open(fileobj=buf, mode="w:gz") as tar:
        tar.add(run_dir, arcname=run_dir.name)
    return buf.getvalue()


def unpack(result: dict[str, Any], output_root: Path) -> dict[str, Any]:
    """A shipped run directory extracted under ``output_root``; the result points there."""
    archive = result.pop("archive", None)
    if archive is None:
        return result
    output_root.mkdir(parents=True, exist_ok=True)
    with tarfile.open(fileobj=io.BytesIO(archive), mode="r:gz") as tar:
        tar.extractall(output_root, filter="data")
    run_dir = output_root / f"world_{result['world']}"
    result["run_dir"] = str(run_dir)
    doc = json.loads((run_dir / "result.json").read_text(encoding="utf-8"))
    doc["run_dir"] = doc["barn"]["run_dir"] = str(run_dir)
    _write_json(run_dir / "result.json", doc)
    return result


WORLD_KEYS = ("world", "status", "success", "time", "metric", "path_length", "run_dir")


def summarise(results: list[dict[str, Any]], wall_time: float, workers: int) -> dict[str, Any]:
    """barn.md's summary of the worlds' results."""
    n = len(results)
    counts = {s: sum(r["status"] == s for r in results) for s in STATUSES}
    times = [r["time"] for r in results if r["success"]]

    def rate(count: int) -> float | None:
        return round(count / n, 4) if n else None

    return {
        "worlds": n,
        "success_rate": rate(counts["succeeded"]),
        "collision_rate": rate(counts["collided"]),
        "timeout_rate": rate(counts["timeout"]),
        "failed_rate": rate(counts["failed"]),
        "successes": counts["succeeded"],
        "collisions": counts["collided"],
        "timeouts": counts["timeout"],
        "failed": counts["failed"],
        "mean_time": round(sum(times) / len(times), 3) if times else None,
        "mean_metric": round(sum(r["metric"] for r in results) / n, 4) if n else None,
        "wall_time": round(wall_time, 3),
        "workers": workers,
    }


def json_document(results: list[dict[str, Any]], summary: dict[str, Any]) -> dict[str, Any]:
    """``--json``'s document: the summary and one entry a world (barn.md's keys)."""
    return {"summary": summary, "worlds": [{k: r[k] for k in WORLD_KEYS} for r in results]}
