"""location_recorder.yaml: the contract's layout, replace-in-place, append, atomic writes."""

from __future__ import annotations

import math
import random
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest
import yaml

from agv_mission.geometry import Pose2D
from agv_mission.maps.recorder import (
    RECORDER_FILENAME,
    LocationRecorder,
    RecorderFile,
    RecorderFileError,
    entry_pose,
    pose_entry,
)

# The contract's example (mission-format.md, "room record layout").
CONTRACT_EXAMPLE = """\
livingroom:
  position:
    x: 3.8314
    y: -1.2344
    z: 0.0
  orientation:
    x: 0.0
    y: 0.0
    z: 0.0
    w: 1.0
"""


def test_layout_is_exactly_the_contracts(tmp_path: Path) -> None:
    path = tmp_path / RECORDER_FILENAME
    rec = LocationRecorder(path)
    assert not path.exists()  # nothing is written before the first record
    rec.record("livingroom", Pose2D(3.83144, -1.23442, 0.0))
    assert path.read_text() == CONTRACT_EXAMPLE
    rec.record("kitchen", Pose2D(7.123456789, -2.0, math.pi / 2))
    assert path.read_text() == CONTRACT_EXAMPLE + textwrap.dedent("""\
        kitchen:
          position:
            x: 7.1235
            y: -2.0
            z: 0.0
          orientation:
            x: 0.0
            y: 0.0
            z: 0.707107
            w: 0.707107
        """)
    doc = yaml.safe_load(path.read_text())
    assert list(doc) == ["livingroom", "kitchen"]
    for entry in doc.values():
        assert list(entry) == ["position", "orientation"]
        assert list(entry["position"]) == ["x", "y", "z"]
        assert list(entry["orientation"]) == ["x", "y", "z", "w"]
        assert all(isinstance(v, float) for part in entry.values() for v in part.values())
    kitchen = rec.entries["kitchen"]
    assert kitchen.x == 7.1235 and kitchen.yaw == pytest.approx(math.pi / 2, abs=1e-5)


def test_quaternion_has_w_nonnegative_and_no_negative_zero() -> None:
    entry = pose_entry(Pose2D(-0.00001, 0.0, math.pi))  # yaw pi: q = (0, 0, 1, 0)
    assert entry["position"]["x"] == 0.0 and math.copysign(1, entry["position"]["x"]) == 1
    assert entry["orientation"] == {"x": 0.0, "y": 0.0, "z": 1.0, "w": 0.0}
    yaw = -3.0
    q = pose_entry(Pose2D(0, 0, yaw))["orientation"]
    assert q["w"] >= 0 and entry_pose(pose_entry(Pose2D(0, 0, yaw))).yaw == pytest.approx(
        yaw, abs=1e-5
    )


def test_recording_a_label_again_replaces_it_and_keeps_the_others_in_order(tmp_path: Path) -> None:
    path = tmp_path / RECORDER_FILENAME
    rec = LocationRecorder(path)
    for i, label in enumerate(["livingroom", "recreationroom", "kitchen", "bedroom"]):
        rec.record(label, Pose2D(float(i), 0.0, 0.0))
    rec.record("recreationroom", Pose2D(-0.5, 1.8, 0.3))
    doc = yaml.safe_load(path.read_text())
    assert list(doc) == ["livingroom", "recreationroom", "kitchen", "bedroom"]
    assert doc["recreationroom"]["position"] == {"x": -0.5, "y": 1.8, "z": 0.0}
    assert [doc[k]["position"]["x"] for k in ("livingroom", "kitchen", "bedroom")] == [
        0.0,
        2.0,
        3.0,
    ]
    assert list(rec.entries) == list(doc) and len(rec) == 4 and "kitchen" in rec


def test_append_to_an_existing_file(tmp_path: Path) -> None:
    old = tmp_path / "old.yaml"
    old.write_text(CONTRACT_EXAMPLE)
    # into another file: the old file is left as it was
    new = tmp_path / "run" / RECORDER_FILENAME
    rec = LocationRecorder(new, RecorderFile.read(old))
    assert rec.entries == {"livingroom": Pose2D(3.8314, -1.2344, 0.0)}
    rec.record("kitchen", Pose2D(7.0, -2.0, 0.0))
    assert list(yaml.safe_load(new.read_text())) == ["livingroom", "kitchen"]
    assert old.read_text() == CONTRACT_EXAMPLE
    assert new.read_text().startswith(CONTRACT_EXAMPLE)
    # into the same file, as the seed's service does
    rec = LocationRecorder(old, RecorderFile.read(old))
    rec.record("bedroom", Pose2D(-5.5, -1.5, 0.0))
    assert old.read_text().startswith(CONTRACT_EXAMPLE)
    assert list(yaml.safe_load(old.read_text())) == ["livingroom", "bedroom"]
    # a hand-written file with ints and another indentation is accepted and normalised
    hand = tmp_path / "hand.yaml"
    hand.write_text(
        "kitchen:\n    position: {x: 7, y: -2, z: 0}\n    orientation: {x: 0, y: 0, z: 0, w: 1}\n"
    )
    rec = LocationRecorder(tmp_path / "out.yaml", RecorderFile.read(hand))
    rec.save()
    assert yaml.safe_load((tmp_path / "out.yaml").read_text())["kitchen"]["position"]["x"] == 7.0
    # empty files are files with no entries
    empty = tmp_path / "empty.yaml"
    empty.write_text("")
    assert LocationRecorder(tmp_path / "x.yaml", RecorderFile.read(empty)).entries == {}


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("kitchen: [1, 2\n", "invalid YAML"),
        ("- kitchen\n", "expected a mapping of room labels"),
        ("kitchen: {position: {x: 1, y: 2, z: 0}}\n", "kitchen: expected exactly the keys"),
        (
            "kitchen:\n  position: {x: 1, y: 2}\n  orientation: {x: 0, y: 0, z: 0, w: 1}\n",
            "kitchen: position: expected exactly the keys x, y, z",
        ),
        (
            "kitchen:\n  position: {x: one, y: 2, z: 0}\n  orientation: {x: 0, y: 0, z: 0, w: 1}\n",
            "kitchen: position.x: expected a finite number, got 'one'",
        ),
        (
            "kitchen:\n  position: {x: 1, y: 2, z: 0}\n  orientation: {x: 0, y: 0, z: 0, w: 2}\n",
            "quaternion has length 2.000000",
        ),
        (
            "123:\n  position: {x: 1, y: 2, z: 0}\n  orientation: {x: 0, y: 0, z: 0, w: 1}\n",
            "label 123 is not a non-empty string",
        ),
    ],
)
def test_a_malformed_file_is_a_clear_error(tmp_path: Path, text: str, expected: str) -> None:
    bad = tmp_path / "bad.yaml"
    bad.write_text(text)
    with pytest.raises(RecorderFileError) as info:
        LocationRecorder(tmp_path / "out.yaml", RecorderFile.read(bad))
    assert str(info.value).startswith(f"{bad}: ") and expected in str(info.value)
    with pytest.raises(RecorderFileError, match="not found"):
        LocationRecorder(tmp_path / "out.yaml", RecorderFile.read(tmp_path / "missing.yaml"))


def test_bad_labels_and_poses_are_refused_without_touching_the_file(tmp_path: Path) -> None:
    path = tmp_path / RECORDER_FILENAME
    rec = LocationRecorder(path)
    rec.record("kitchen", Pose2D(7.0, -2.0, 0.0))
    before = path.read_text()
    for label, pose in [("", Pose2D(0, 0, 0)), ("  ", Pose2D(0, 0, 0)), ("x", Pose2D(math.nan, 0))]:
        with pytest.raises(ValueError):
            rec.record(label, pose)
    assert path.read_text() == before and rec.labels == ["kitchen"]


# A writer that records as fast as it can: 300 fixed labels (a ~55 kB file, so a kill
# lands mid-write often) plus one "counter" label rewritten with x = 0, 1, 2, ...
WRITER = """
import sys
from pathlib import Path
from agv_mission.geometry import Pose2D
from agv_mission.maps.recorder import LocationRecorder, RecorderFile, dump_entries, pose_entry

path = Path(sys.argv[1])
if not path.exists():
    rooms = {f"room_{i}": pose_entry(Pose2D(float(i), -float(i), 0.0)) for i in range(300)}
    path.write_text(dump_entries(rooms))
rec = LocationRecorder(path, RecorderFile.read(path))
n = int(rec.entries["counter"].x) + 1 if "counter" in rec else 0
print("ready", n, flush=True)
while True:
    rec.record("counter", Pose2D(float(n), 0.0, 0.0))
    print(n, flush=True)
    n += 1
"""


def test_sigkill_while_writing_leaves_the_previous_or_the_new_file(tmp_path: Path) -> None:
    path = tmp_path / RECORDER_FILENAME
    script = tmp_path / "writer.py"
    script.write_text(WRITER)
    rng = random.Random(5)
    rounds_with_records = 0
    for _ in range(3):
        proc = subprocess.Popen(
            [sys.executable, str(script), str(path)], stdout=subprocess.PIPE, text=True
        )
        assert proc.stdout is not None
        ready, start = proc.stdout.readline().split()
        assert ready == "ready"
        time.sleep(rng.uniform(0.05, 0.25))
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=10)
        done = [int(line) for line in proc.stdout.read().split()]
        assert proc.returncode == -signal.SIGKILL
        last = done[-1] if done else int(start) - 1  # the last completed record
        rounds_with_records += bool(done)

        doc = yaml.safe_load(path.read_text())  # parses: never a partial file
        assert list(doc)[:300] == [f"room_{i}" for i in range(300)]
        assert list(doc)[300:] in ([], ["counter"])
        assert all(doc[f"room_{i}"]["position"]["x"] == float(i) for i in range(300))
        # the last completed record, or the one being written when the kill came
        counter = doc["counter"]["position"]["x"] if "counter" in doc else -1.0
        assert counter in (float(last), float(last + 1)), (counter, done[-3:])
        assert LocationRecorder(path, RecorderFile.read(path)).labels == list(doc)
    assert rounds_with_records >= 2  # the kills did land among writes


def test_comments_and_other_entries_keep_their_bytes(tmp_path: Path) -> None:
    path = tmp_path / RECORDER_FILENAME
    header = "# rooms of the lab, recorded by hand\n\n"
    kitchen = "kitchen:  # by the fridge\n" + textwrap.indent(
        CONTRACT_EXAMPLE.split("\n", 1)[1], ""
    )
    path.write_text(header + CONTRACT_EXAMPLE + "\n# the kitchen\n" + kitchen + "# end\n")
    rec = LocationRecorder(path, RecorderFile.read(path))
    rec.record("livingroom", Pose2D(1.0, 2.0, 0.0))
    rec.record("bedroom", Pose2D(3.0, 4.0, 0.0))
    text = path.read_text()
    assert text.startswith(header + "livingroom:\n  position:\n    x: 1.0\n    y: 2.0\n")
    assert "\n# the kitchen\nkitchen:  # by the fridge\n" in text
    assert "# end\nbedroom:\n" in text
    doc = yaml.safe_load(text)
    assert list(doc) == ["livingroom", "kitchen", "bedroom"]
    assert doc["livingroom"]["position"]["x"] == 1.0 and doc["kitchen"]["position"]["x"] == 3.8314


def test_a_flow_style_or_empty_file_is_appended_to(tmp_path: Path) -> None:
    path = tmp_path / RECORDER_FILENAME
    path.write_text("# nothing yet\n{}\n")
    LocationRecorder(path, RecorderFile.read(path)).record("kitchen", Pose2D(1.0, 0.0, 0.0))
    assert path.read_text().startswith("# nothing yet\nkitchen:\n")
    path.write_text("# only a comment")
    LocationRecorder(path, RecorderFile.read(path)).record("kitchen", Pose2D(1.0, 0.0, 0.0))
    assert path.read_text().startswith("# only a comment\nkitchen:\n")
    assert list(yaml.safe_load(path.read_text())) == ["kitchen"]


def test_a_symlinked_recorder_file_gets_the_entry_through_the_link(tmp_path: Path) -> None:
    target = tmp_path / "shared" / RECORDER_FILENAME
    target.parent.mkdir()
    target.write_text(CONTRACT_EXAMPLE)
    target.chmod(0o644)
    link = tmp_path / "link.yaml"
    link.symlink_to(target)
    LocationRecorder(link, RecorderFile.read(link)).record("kitchen", Pose2D(1.0, 0.0, 0.0))
    assert link.is_symlink()
    assert list(yaml.safe_load(target.read_text())) == ["livingroom", "kitchen"]
    assert target.stat().st_mode & 0o777 == 0o644


# Writers that each record their own labels into one shared file, as fast as they can.
CONCURRENT_WRITER = """
import sys
from pathlib import Path
from agv_mission.geometry import Pose2D
from agv_mission.maps.recorder import LocationRecorder, RecorderFile

path, who, n = Path(sys.argv[1]), sys.argv[2], int(sys.argv[3])
rec = LocationRecorder(path, RecorderFile.read(path) if path.exists() else None)
print("ready", flush=True)
sys.stdin.readline()  # all start together
for i in range(n):
    rec.record(f"{who}_{i}", Pose2D(float(i), 0.0, 0.0))
"""


def test_concurrent_writers_lose_no_entry(tmp_path: Path) -> None:
    path = tmp_path / RECORDER_FILENAME
    path.write_text("# shared by several runs\n" + CONTRACT_EXAMPLE)
    script = tmp_path / "writer.py"
    script.write_text(CONCURRENT_WRITER)
    writers = ["a", "b", "c", "d"]
    procs = [
        subprocess.Popen(
            [sys.executable, str(script), str(path), who, "60"],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
        )
        for who in writers
    ]
    for p in procs:
        assert p.stdout is not None and p.stdout.readline().strip() == "ready"
    for p in procs:
        assert p.stdin is not None
        p.stdin.write("go\n")
        p.stdin.flush()
    for p in procs:
        assert p.wait(timeout=120) == 0
    text = path.read_text()
    assert text.startswith("# shared by several runs\nlivingroom:\n")
    doc = yaml.safe_load(text)
    for who in writers:
        assert [k for k in doc if k.startswith(f"{who}_")] == [f"{who}_{i}" for i in range(60)]
    assert len(doc) == 1 + 60 * len(writers)
    assert sorted(f.name for f in tmp_path.iterdir()) == [RECORDER_FILENAME, "writer.py"]


def test_no_lock_file_is_left_beside_the_recorder_file(tmp_path: Path) -> None:
    path = tmp_path / RECORDER_FILENAME
    recorder = LocationRecorder(path)
    recorder.record("kitchen", Pose2D(1.0, 0.0, 0.0))
    recorder.record("hall", Pose2D(2.0, 0.0, 0.0))
    recorder.save()
    assert [f.name for f in tmp_path.iterdir()] == [RECORDER_FILENAME]
