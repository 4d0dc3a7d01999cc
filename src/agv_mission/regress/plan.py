"""Scenario regression: run missions that carry an ``expect:`` block and check them.

A *scenario* is a mission file; its ``expect:`` block (see ``expectations.py``) says what
the run must achieve, and a scenario without one is expected to succeed. ``agv-mission
regress PATHS...`` takes files and directories (searched recursively for YAML
missions: task lists, trees, fleets; other YAML files are skipped, saying why), expands
them into *jobs* and runs every job in its own process:

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
table per variant: success rate, mean and p95 sim time, distance driven, planned /
shortest and driven / shortest per leg (the shortest path through the costmap between a
leg's start and goal, computed once per leg; mean and worst over the legs that
succeeded), clearance and planner / controller solve times (time and distance driven
over the succeeded runs only).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import yaml

from agv_mission.missions.load.errors import MissionError, Problem
from agv_mission.missions.load.overrides import Override
from agv_mission.missions.load.schema.mission import MAX_SEED
from agv_mission.yaml_safe import safe_load

# Result keys that come from the wall clock: they differ between any two runs.
WALL_CLOCK_METRICS = (
    "real_time_factor",
    "navigation.planning_time_ms_mean",
    "navigation.controller_solve_ms_p50",
    "navigation.controller_solve_ms_p99",
)


class RegressError(Exception):
    """Invalid regress input (paths, sweeps, backend); the CLI exits 2."""

    def __init__(self, message: str, problems: Sequence[Problem] = ()) -> None:
        super().__init__(message)
        self.problems = list(problems)


# ----------------------------------------------------------------------------- discovery

#: Keys that make a YAML mapping a mission: a task list, a tree, a fleet (the loader
#: then says what else it lacks).
MISSION_KEYS = ("tasks", "tree", "robots")
#: Keys of the mission file (``mission-format.md``) that no rooms, robot, world or map file
#: has: a mapping with one of them is a mission, however broken.
MISSION_ONLY_KEYS = (
    "world",
    "robot",
    "start",
    "stack",
    "limits",
    "expect",
    "trees",
    "fleet",
    "people",
    "zones",
    "faults",
    "blackboard",
    "seed",
)
SCENARIO_SUFFIXES = (".yaml", ".yml")
#: Most runs one regress plans (scenarios x variants x seeds): a sweep of a million is
#: days of CPU on a cluster, and its plan alone (a dict a run) would fill the memory first.
MAX_JOBS = 1_000_000


@dataclass
class Discovery:
    """What a regress run found: the missions it runs and every other file it looked at,
    with why it does not run it."""

    missions: list[Path]
    skipped: list[tuple[Path, str]] = field(default_factory=list)


def survey(paths: Iterable[str | Path]) -> Discovery:
    """Mission files under ``paths``: files as given; directories searched recursively for
    YAML missions (task lists, trees, fleets). A YAML that is not a mission (a rooms,
    robot, world or map file) is skipped with the reason; one that cannot be read is
    kept, so that the loader fails on it rather than the suite dropping it."""
    paths = list(map(Path, paths))
    found: list[Path] = []
    skipped: list[tuple[Path, str]] = []
    xml: list[Path] = []
    for p in paths:
        if p.is_dir():
            for f in sorted(p.rglob("*")):
                if not f.is_file():
                    continue
                if f.suffix.lower() in SCENARIO_SUFFIXES:
                    why = not_a_mission(f)
                    if why is None:
                        found.append(f)
                    else:
                        skipped.append((f.resolve(), why))
                elif f.suffix.lower() == ".xml":
                    xml.append(f.resolve())
        elif p.is_file() and p.suffix.lower() == ".xml":
            by = _trees_named(
                [f for f in sorted(p.parent.glob("*.y*ml")) if not_a_mission(f) is None]
            ).get(p.resolve())
            raise RegressError(
                f"{p}: a behaviour tree (XML), not a mission: regress runs the mission that "
                "names it in `tree:`" + (f" ({', '.join(str(m) for m in by)})" if by else "")
            )
        elif p.is_file():
            found.append(p)
        else:
            raise RegressError(f"{p}: no such file or directory")
    unique = list(dict.fromkeys(f.resolve() for f in found))
    named = _trees_named(unique)
    for f in xml:
        by = named.get(f)
        skipped.append(
            (
                f,
                f"a behaviour tree (XML): it runs through {', '.join(m.name for m in by)}"
                if by
                else "a behaviour tree (XML) that no mission here names: it runs only "
                "through a mission's `tree:`",
            )
        )
    if not unique:
        raise RegressError(
            f"no mission files (*.yaml with tasks, tree or robots) in {', '.join(map(str, paths))}"
        )
    return Discovery(unique, sorted(dict(skipped).items()))


def discover(paths: Iterable[str | Path]) -> list[Path]:
    """The mission files of :func:`survey`."""
    return survey(paths).missions


def not_a_mission(path: Path) -> str | None:
    """Why ``path`` is not a mission file, or None when it is one (or may be one: a file
    that cannot be read or parsed is the loader's to report)."""
    try:
        data = safe_load(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, yaml.YAMLError):
        return None
    if data is None:
        return "empty"
    if not isinstance(data, dict):
        return f"not a mission: its top level is a {type(data).__name__}, not a mapping"
    keys = set(map(str, data))
    if keys & set(MISSION_KEYS):
        return None
    if {"image", "resolution"} <= keys:
        return "a map (map_server YAML)"
    if isinstance(data.get("rooms"), dict) and not keys & set(MISSION_ONLY_KEYS):
        return "a rooms file"
    if keys & {"wheel_radius", "wheel_separation", "lidar", "footprint_radius"}:
        return "a robot file"
    if "resolution" in keys and keys & {"bounds", "boxes", "walls", "spawn"}:
        return "a world file"
    if data and all(
        isinstance(v, dict) and {"position", "orientation"} <= set(v) for v in data.values()
    ):
        return "a room record (location_recorder.yaml)"
    if keys & set(MISSION_ONLY_KEYS):
        return None  # a mission without tasks: the loader says so
    return f"not a mission: none of {', '.join(MISSION_KEYS)} (its keys: {', '.join(sorted(keys)[:6])})"


def _trees_named(missions: Sequence[Path]) -> dict[Path, list[Path]]:
    """XML tree files by the missions that name them in ``tree:``."""
    out: dict[Path, list[Path]] = {}
    for m in missions:
        try:
            data = safe_load(m.read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError, yaml.YAMLError):
            continue
        tree = data.get("tree") if isinstance(data, dict) else None
        if isinstance(tree, str) and tree.lower().endswith(".xml"):
            out.setdefault((m.parent / tree).resolve(), []).append(m)
    return out


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


def sweep_overrides(items: Iterable[str]) -> list[Override]:
    """A variant's ``KEY=VALUE`` items as overrides that say they came from ``--sweep``."""
    return [Override(item, "--sweep") for item in items]


def expand_variants(sweeps: Sequence[str]) -> list[Variant]:
    """The cartesian product of every ``--sweep``; one unnamed variant without sweeps."""
    if not sweeps:
        return [Variant("")]
    parsed = [parse_sweep(s) for s in sweeps]
    keys = [k for k, _ in parsed]
    if len(set(keys)) != len(keys):
        raise RegressError(f"--sweep: a key is swept twice ({', '.join(keys)})")
    count = math.prod(len(values) for _, values in parsed)
    if count > MAX_JOBS:
        raise RegressError(f"--sweep: {count:.3g} variants, more than {MAX_JOBS:,} runs")
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
    skipped: list[tuple[Path, str]] = field(default_factory=list)  # not missions, and why


def plan_jobs(
    paths: Iterable[str | Path],
    sweeps: Sequence[str] = (),
    seeds: int = 1,
    output_root: str | Path | None = None,
) -> Plan:
    """Discover, expand and validate (load every scenario x variant once, here).

    Invalid scenarios are collected in ``Plan.problems`` and get no jobs.
    """
    from agv_mission.missions.load.loader import load_mission

    if seeds < 1:
        raise RegressError("--seeds must be at least 1")
    found = survey(paths)
    scenarios = found.missions
    variants = expand_variants(sweeps)
    runs = len(scenarios) * len(variants) * seeds
    if runs > MAX_JOBS:
        raise RegressError(
            f"{len(scenarios)} scenario(s) x {len(variants)} variant(s) x {seeds} seed(s) = "
            f"{runs:,}: more than {MAX_JOBS:,} runs"
        )
    if output_root is None:
        stamp = datetime.now(timezone.utc).strftime("%Y%m%dT%H%M%SZ")
        output_root = Path("runs") / f"regress-{stamp}"
    root = Path(output_root).resolve()
    jobs: list[dict[str, Any]] = []
    problems: list[Problem] = []
    for s_index, path in enumerate(scenarios):
        for v_index, variant in enumerate(variants):
            try:
                loaded = load_mission(path, sweep_overrides(variant.overrides))
            except MissionError as exc:
                problems += exc.problems
                continue
            base = loaded.mission.seed
            if base + seeds - 1 > MAX_SEED:
                last = f"seed {base} and {seeds} seeds after it pass {MAX_SEED}"
                problems.append(Problem(str(path), None, "seed", f"{last} (from --seeds)"))
                continue
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
    return Plan(jobs, scenarios, variants, seeds, root, problems, found.skipped)
