"""Bad input, exhaustively: every file of ``tests/invalid/`` is rejected as its header says.

Each corpus file starts with comment lines naming the problem it must produce::

    # expect-line: 7                 (empty: the problem has no line)
    # expect-field: tasks.0.pose     (empty: a file-level problem)
    # expect-message: outside the map

The files (and the helper files they name, in ``tests/invalid/data/``) are read by
``load_mission`` in-process, and once more all together by one ``agv-mission validate``
subprocess, which must exit 2 without a traceback.
"""

from __future__ import annotations

import re
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

from agv_mission.missions.load.errors import MissionError
from agv_mission.missions.load.loader import load_mission

CORPUS = Path(__file__).resolve().parent / "invalid"
FILES = sorted(CORPUS.glob("*.yaml"))
HEADER = re.compile(r"#\s*expect-(line|field|message):[ \t]*(.*?)\s*$")
DEMO = Path(__file__).resolve().parents[1] / "missions" / "patrol.yaml"


@dataclass(frozen=True)
class Expectation:
    line: int | None
    field: str
    message: str


def expectation(path: Path) -> Expectation:
    found: dict[str, str] = {}
    for raw in path.read_bytes().decode("utf-8", errors="replace").splitlines():
        if not raw.startswith("#"):
            break
        m = HEADER.match(raw)
        if m:
            found[m.group(1)] = m.group(2)
    assert {"line", "field", "message"} <= found.keys(), f"{path.name}: incomplete header"
    assert found["message"], f"{path.name}: empty expect-message"
    line = int(found["line"]) if found["line"] else None
    return Expectation(line, found["field"], found["message"])


def test_corpus_is_large_and_headed() -> None:
    assert len(FILES) >= 30
    for path in FILES:
        expectation(path)


@pytest.mark.parametrize("path", FILES, ids=[p.stem for p in FILES])
def test_invalid_file_is_rejected_as_expected(path: Path) -> None:
    want = expectation(path)
    with pytest.raises(MissionError) as info:
        load_mission(path)
    problems = info.value.problems
    assert problems, "a MissionError must carry at least one problem"
    for p in problems:
        assert p.file == str(path)
        assert str(p).startswith(str(path))
    got = [(p.line, p.field, p.message) for p in problems]
    assert any(
        p.line == want.line and p.field == want.field and want.message in p.message
        for p in problems
    ), f"expected {want}, got {got}"


def test_validate_rejects_the_whole_corpus_in_one_call() -> None:
    """One subprocess for all files: exit 2, every file reported, no traceback."""
    r = subprocess.run(
        [sys.executable, "-m", "agv_mission.cli", "validate", *map(str, FILES)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    output = r.stdout + r.stderr
    assert r.returncode == 2, output
    assert "Traceback" not in output
    assert "valid[/]" not in output and ": valid" not in r.stdout, r.stdout
    assert r.stderr.count("invalid input (") == len(FILES)
    for path in FILES:
        want = expectation(path)
        where = f"{path}:{want.line}:" if want.line else f"{path}:"
        assert where in r.stderr, f"{path.name} not reported as {where!r}"


def test_empty_file(tmp_path: Path) -> None:
    path = tmp_path / "empty.yaml"
    path.write_bytes(b"")
    with pytest.raises(MissionError) as info:
        load_mission(path)
    [p] = info.value.problems
    assert (p.field, p.message) == ("tasks", "required field is missing")


def test_missing_and_unreadable_files(tmp_path: Path) -> None:
    for path, message in (
        (tmp_path / "nope.yaml", "cannot read: No such file or directory"),
        (tmp_path, "cannot read: Is a directory"),
        (tmp_path / ("x" * 300 + ".yaml"), "cannot read: File name too long"),
    ):
        with pytest.raises(MissionError) as info:
            load_mission(path)
        [p] = info.value.problems
        assert p.message == message and p.line is None and p.field == ""


@pytest.mark.parametrize(
    ("item", "field", "message"),
    [
        ("no_equals_sign", "no_equals_sign", "expected KEY=VALUE"),
        ("=3", "=3", "expected KEY=VALUE"),
        ("tasks.5.loops=2", "tasks.5.loops=2", "not an index of a list of 1"),
        ("tasks.first.loops=2", "tasks.first.loops=2", "not an index"),
        ("seed.bits=3", "seed", "valid integer"),
        ("tasks.0.loops=0", "tasks.0.loops", "(from --set tasks.0.loops=0)"),
        ("tasks.0.loops=[unclosed", "tasks.0.loops", "valid integer"),
        ("stack.global_planner.planner=Nope", "stack.global_planner.planner", "Nope"),
        ("stack.local_planner.type=dwa", "stack.local_planner", "unknown type 'dwa'"),
        ("wheels=4", "wheels", "unknown key"),
        ("tasks=", "tasks", "valid list"),
        ("start.x.y=1", "start.x", "valid number"),
        ("stack=" + "[" * 50_000 + "]" * 50_000, "stack=" + "[" * 74 + "...", "nests too deeply"),
    ],
)
def test_bad_set_is_blamed_on_the_override(item: str, field: str, message: str) -> None:
    with pytest.raises(MissionError) as info:
        load_mission(DEMO, [item])
    problems = info.value.problems
    assert any(p.field == field and message in p.message for p in problems), [
        str(p) for p in problems
    ]
    assert all(p.line is None for p in problems)  # an override has no line in the file


def test_bad_seed_option_is_blamed_on_the_option() -> None:
    with pytest.raises(MissionError) as info:
        load_mission(DEMO, seed=-3)
    [p] = info.value.problems
    assert (p.line, p.field) == (None, "seed")
    assert p.message.endswith("(from --seed -3)")
    with pytest.raises(MissionError) as info:  # past what result.json and the registry keep
        load_mission(DEMO, seed=2**63)
    [p] = info.value.problems
    assert p.field == "seed" and "9223372036854775807" in p.message, p.message
