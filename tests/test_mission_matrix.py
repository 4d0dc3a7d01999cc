"""The class, not the cases: every kind of mission through every way in that takes it.

The kinds are the small missions of ``tests/matrix/`` (a task list, a YAML tree, a BT.CPP
XML tree through its YAML, a fleet, people, ``map_area``), each a few simulated seconds in
turtlebot3_world. The ways in are the real commands, each in a process of its own: ``run``,
``regress``, ``serve`` + ``submit``, the VDA 5050 master (``vda5050 vehicles`` +
``vda5050 dispatch`` over Debian's mosquitto) and ``map`` on the bag a run wrote. A way in
that cannot take a kind (an order carries no tree) must refuse it clearly: exit 2 and a
message, never a traceback.

Cells that need a second long-lived process for each kind are ``slow``; one of each way in
stays in ``make test``.
"""

from __future__ import annotations

import json
import os
import subprocess
import xml.etree.ElementTree as ET
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest

from service_server import AGV, Server

MATRIX = Path(__file__).resolve().parent / "matrix"
KINDS = ("task_list", "yaml_tree", "xml_tree", "fleet", "people", "map_area")
TREES = ("yaml_tree", "xml_tree")
#: kinds a VDA 5050 order can carry (go_to, patrol, visit_rooms tasks)
ORDERED = ("task_list", "fleet", "people")
TIMEOUT = 600  # s: a test's deadline for one command on a loaded machine, not a timing


def agv(*args: str | Path, timeout: float = TIMEOUT) -> subprocess.CompletedProcess[str]:
    """``agv-mission ARGS`` as a user runs it: its exit code, stdout and stderr."""
    return subprocess.run(
        [AGV, *map(str, args)],
        capture_output=True,
        text=True,
        timeout=timeout,
        env={**os.environ, "COLUMNS": "200"},
    )


def said(proc: subprocess.CompletedProcess[str]) -> str:
    return f"exit {proc.returncode}\n--- stdout\n{proc.stdout[-3000:]}\n--- stderr\n{proc.stderr[-3000:]}"


def slow_unless(*fast: str) -> list[Any]:
    """The kinds as parameters, all but ``fast`` marked slow."""
    return [pytest.param(k, marks=() if k in fast else [pytest.mark.slow], id=k) for k in KINDS]


# ---------------------------------------------------------------------------- run


class Runs:
    """``agv-mission run`` of each kind, once per module (the ``map`` cells read its bag)."""

    def __init__(self, root: Path) -> None:
        self.root = root
        self.done: dict[str, tuple[subprocess.CompletedProcess[str], Path | None]] = {}

    def __call__(self, kind: str) -> tuple[subprocess.CompletedProcess[str], Path | None]:
        if kind not in self.done:
            out = self.root / kind
            proc = agv("run", MATRIX / f"{kind}.yaml", "--output", out)
            dirs = sorted(p for p in out.glob("*") if (p / "result.json").exists())
            self.done[kind] = proc, dirs[-1] if dirs else None
        return self.done[kind]


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> Runs:
    return Runs(tmp_path_factory.mktemp("matrix-run"))


@pytest.mark.parametrize("kind", KINDS)
def test_run(runs: Runs, kind: str) -> None:
    proc, run_dir = runs(kind)
    assert proc.returncode == 0, said(proc)
    assert run_dir is not None, said(proc)
    result = json.loads((run_dir / "result.json").read_text())
    assert result["status"] == "succeeded", result["reason"]
    first = proc.stdout.splitlines()[0]
    assert "0 task(s)" not in first, first
    if kind in TREES:  # summarised by its tree: the header and a row a tree node
        assert "a behaviour tree of" in first, first
        assert "tree node" in proc.stdout and "dwell" in proc.stdout, proc.stdout
    # every report counts tasks from 1: result.json's tasks and the events naming a task
    numbered = [e["task"] for e in result["events"] if "task" in e]
    assert all(n >= 1 for n in numbered), numbered
    if kind == "fleet":
        assert set(result["robots"]) == {"agv1", "agv2"}
        assert [d["task"] for d in result["fleet"]["dispatch"]] == [2]
    if kind == "people":
        assert result["metrics"]["people"]["collisions"] == 0
    if kind == "map_area":
        assert (run_dir / "matrix_map.yaml").exists() or result.get("maps"), sorted(
            p.name for p in run_dir.iterdir()
        )
    assert (run_dir / "bag").is_dir()


# ---------------------------------------------------------------------------- regress


def test_regress_runs_every_kind(tmp_path: Path) -> None:
    """One suite of every kind: one test case per mission file, each passing; the XML tree
    file beside its YAML, and a rooms file and a robot file in another folder, are said to
    be skipped, not run."""
    beside = tmp_path / "beside"
    beside.mkdir()
    (beside / "rooms.yaml").write_text("rooms: {k: {polygon: [[0, 0], [1, 0], [1, 1]]}}\n")
    (beside / "robot.yaml").write_text("name: r\nwheel_radius: 0.03\nwheel_separation: 0.2\n")
    junit = tmp_path / "junit.xml"
    proc = agv(
        "regress", MATRIX, beside, "--output", tmp_path / "runs", "--junit", junit, "-j", "2"
    )  # fmt: skip
    assert proc.returncode == 0, said(proc)
    assert f"{len(KINDS)}/{len(KINDS)} passed" in proc.stdout, said(proc)
    assert "rooms.yaml: a rooms file" in proc.stderr and "robot.yaml: a robot file" in proc.stderr
    assert "xml_tree.xml: a behaviour tree (XML): it runs through xml_tree.yaml" in proc.stderr
    root = ET.parse(junit).getroot()
    assert root.get("tests") == str(len(KINDS))
    cases = list(root.iter("testcase"))
    assert sorted(c.get("file", "").rsplit("/", 1)[-1] for c in cases) == sorted(
        f"{kind}.yaml" for kind in KINDS
    )
    names = sorted(c.get("name", "") for c in cases)
    for kind in KINDS:
        assert any(f"matrix-{kind.replace('_', '-')}" in n or kind in n for n in names), names


# ---------------------------------------------------------------------------- serve + submit


@pytest.fixture(scope="module")
def service(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Server]:
    with Server(tmp_path_factory.mktemp("matrix-serve"), "--workers", "2") as server:
        yield server


@pytest.mark.parametrize("kind", slow_unless("task_list", "yaml_tree", "fleet"))
def test_serve_and_submit(service: Server, kind: str) -> None:
    """``submit --follow`` of each kind (the XML travels with its mission) ends as ``run``
    would: exit 0, the run succeeded, its result summarised the same way."""
    proc = agv("submit", MATRIX / f"{kind}.yaml", "--server", service.url, "--follow")
    assert proc.returncode == 0, said(proc)
    run_id = proc.stdout.split()[0]
    run = httpx.get(f"{service.url}/api/runs/{run_id}", timeout=30).json()
    assert run["status"] == "succeeded", run.get("reason")
    assert "0 task(s)" not in proc.stdout, proc.stdout
    if kind in TREES:
        assert "a behaviour tree of" in proc.stdout, proc.stdout
    files = httpx.get(f"{service.url}/api/runs/{run_id}/files", timeout=30).json()["files"]
    assert "result.json" in files and "run.png" in files, files


# ---------------------------------------------------------------------------- VDA 5050


@pytest.fixture(scope="module")
def broker(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    from vda5050_peers import Mosquitto

    mosquitto = Mosquitto(tmp_path_factory.mktemp("matrix-mqtt"))
    mosquitto.start()
    yield f"mqtt://127.0.0.1:{mosquitto.port}"
    mosquitto.stop()


@pytest.mark.parametrize("kind", slow_unless("task_list", "yaml_tree"))
def test_vda5050_master(broker: str, kind: str, tmp_path: Path) -> None:
    """Kinds an order carries: our vehicles driven by our master to the mission's result.
    The others: refused before anything is sent, exit 2 with the reason."""
    mission = MATRIX / f"{kind}.yaml"
    if kind not in ORDERED:
        proc = agv("vda5050", "dispatch", mission, "--broker", broker, "--output", tmp_path)
        assert proc.returncode == 2, said(proc)
        assert "Traceback" not in proc.stderr, said(proc)
        return
    manufacturer = f"matrix-{kind}"
    vehicles = subprocess.Popen(
        [AGV, "vda5050", "vehicles", str(mission), "--broker", broker]
        + ["--manufacturer", manufacturer, "--time-scale", "5"],
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
    )
    try:
        assert vehicles.stdout is not None
        up = 0  # each vehicle prints its topics once it is on the broker
        while up < (2 if kind == "fleet" else 1):
            line = vehicles.stdout.readline()
            assert line, "the vehicles ended before they were up"
            up += ": uagv/v2/" in line
        proc = agv(
            "vda5050",
            "dispatch",
            mission,
            "--broker",
            broker,
            "--manufacturer",
            manufacturer,
            "--output",
            tmp_path,
        )
    finally:
        vehicles.terminate()
        vehicles.communicate(timeout=60)
    assert proc.returncode == 0, said(proc)
    results = list(tmp_path.glob("*/result.json"))
    assert results, said(proc)
    assert json.loads(results[0].read_text())["status"] == "succeeded"


# ---------------------------------------------------------------------------- map on the bag


@pytest.mark.parametrize("kind", slow_unless("task_list"))
def test_map_on_its_bag(runs: Runs, kind: str, tmp_path: Path) -> None:
    """SLAM on the bag each kind's run wrote (a fleet's: one robot's topics)."""
    proc, run_dir = runs(kind)
    assert run_dir is not None, said(proc)
    stem = tmp_path / "map"
    extra = ["--robot", "agv1"] if kind == "fleet" else []
    proc = agv("map", run_dir / "bag", "--save-map", stem, *extra)
    assert proc.returncode == 0, said(proc)
    assert stem.with_suffix(".yaml").exists() and stem.with_suffix(".pgm").exists()
