"""The location recorder: ``location_recorder.yaml``, one ROS-style pose per room label.

The layout is the contract's (``mission-format.md``, "room record layout"), i.e. what the
seed's ``rosservice call room_service "kitchen"`` appends from ``amcl_pose``::

    kitchen:
      position:
        x: 7.0123
        y: -2.0051
        z: 0.0
      orientation:
        x: 0.0
        y: 0.0
        z: 0.012345
        w: 0.999924

Every :meth:`LocationRecorder.record` rewrites the file atomically (temporary file,
fsync, rename), so a crash or ``kill -9`` at any moment leaves either the previous file
or the new one, never a partial one. Recording a label again replaces its entry in place;
the other entries keep their order, and the rest of the file's text (comments, blank
lines, the spelling of the other entries) is kept byte for byte.

Several processes may record into one file at once (two runs whose missions name the same
``recorder:`` file, a teleop session beside a run): each write holds a lock file beside
the recorder file (``.<name>.lock``, removed again once written) and re-reads the file
under it, so no entry is lost.
"""

from __future__ import annotations

import contextlib
import math
import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml
from filelock import FileLock, Timeout

from agv_mission.atomic import InputFileError, atomic_write_text, read_input_text, write_target
from agv_mission.geometry import Pose2D, quaternion_from_yaw, yaw_from_quaternion
from agv_mission.yaml_safe import FastSafeLoader

RECORDER_FILENAME = "location_recorder.yaml"

POSITION_DECIMALS = 4  # 0.1 mm
ORIENTATION_DECIMALS = 6  # yaw to about 2e-6 rad
QUATERNION_TOLERANCE = 1e-3  # as for mission poses
LOCK_TIMEOUT = 30.0  # seconds to wait for another writer of the same file
_STR_TAG = "tag:yaml.org,2002:str"

POSITION_KEYS = ("x", "y", "z")
ORIENTATION_KEYS = ("x", "y", "z", "w")

# libyaml's emitter when present (same text, several times faster than pure Python)
_DUMPER = getattr(yaml, "CSafeDumper", yaml.SafeDumper)
_LOADER = FastSafeLoader  # libyaml where installed; a 5000-digit number is a YAML error

Entry = dict[str, dict[str, float]]  # {"position": {x, y, z}, "orientation": {x, y, z, w}}


class RecorderFileError(ValueError):
    """A recorder file that cannot be read or is not in the contract's layout."""

    def __init__(self, path: str | os.PathLike[str], message: str) -> None:
        self.path = Path(path)
        self.message = message
        super().__init__(f"{self.path}: {message}")


def _round(value: float, decimals: int) -> float:
    return round(float(value), decimals) + 0.0  # + 0.0 turns -0.0 into 0.0


def pose_entry(pose: Pose2D) -> Entry:
    """The contract's layout of a planar pose (z = 0, rotation about +z only)."""
    qx, qy, qz, qw = quaternion_from_yaw(pose.yaw)
    if qw < 0.0:  # one of the two equal quaternions, w >= 0 as tf gives it
        qz, qw = -qz, -qw
    return {
        "position": {
            "x": _round(pose.x, POSITION_DECIMALS),
            "y": _round(pose.y, POSITION_DECIMALS),
            "z": 0.0,
        },
        "orientation": {
            "x": _round(qx, ORIENTATION_DECIMALS),
            "y": _round(qy, ORIENTATION_DECIMALS),
            "z": _round(qz, ORIENTATION_DECIMALS),
            "w": _round(qw, ORIENTATION_DECIMALS),
        },
    }


def entry_pose(entry: Entry) -> Pose2D:
    """The planar pose of an entry (its yaw about +z)."""
    p, q = entry["position"], entry["orientation"]
    return Pose2D(p["x"], p["y"], yaw_from_quaternion(q["x"], q["y"], q["z"], q["w"]))


def dump_entries(entries: dict[str, Entry]) -> str:
    """YAML text of ``entries`` in the contract's layout and key order."""
    if not entries:
        return "{}\n"
    doc = {
        label: {
            "position": {k: float(e["position"][k]) for k in POSITION_KEYS},
            "orientation": {k: float(e["orientation"][k]) for k in ORIENTATION_KEYS},
        }
        for label, e in entries.items()
    }
    return yaml.dump(
        doc, Dumper=_DUMPER, sort_keys=False, default_flow_style=False, allow_unicode=True
    )


def parse_entries(text: str, path: str | os.PathLike[str] = "<text>") -> dict[str, Entry]:
    """Entries of a recorder file's text; :class:`RecorderFileError` names what is wrong."""
    try:
        doc = yaml.load(text, Loader=_LOADER)  # noqa: S506 (a safe loader)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"line {mark.line + 1}: " if mark is not None else ""
        problem = getattr(exc, "problem", None) or str(exc)
        raise RecorderFileError(path, f"{where}invalid YAML: {problem}") from None
    if doc is None:
        return {}
    if not isinstance(doc, dict):
        raise RecorderFileError(
            path,
            f"expected a mapping of room labels to poses, got {type(doc).__name__}",
        )
    entries: dict[str, Entry] = {}
    for label, value in doc.items():
        if not isinstance(label, str) or not label:
            raise RecorderFileError(
                path, f"label {label!r} is not a non-empty string (quote it in the file)"
            )
        entries[label] = _parse_entry(path, label, value)
    return entries


def _parse_entry(path: str | os.PathLike[str], label: str, value: Any) -> Entry:
    def bad(message: str) -> RecorderFileError:
        return RecorderFileError(path, f"{label}: {message}")

    if not isinstance(value, dict) or set(value) != {"position", "orientation"}:
        got = sorted(map(str, value)) if isinstance(value, dict) else type(value).__name__
        raise bad(f"expected exactly the keys position and orientation, got {got}")
    entry: Entry = {}
    for part, keys in (("position", POSITION_KEYS), ("orientation", ORIENTATION_KEYS)):
        block = value[part]
        if not isinstance(block, dict) or set(block) != set(keys):
            got = sorted(map(str, block)) if isinstance(block, dict) else type(block).__name__
            raise bad(f"{part}: expected exactly the keys {', '.join(keys)}, got {got}")
        numbers = {}
        for k in keys:
            v = block[k]
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise bad(f"{part}.{k}: expected a finite number, got {v!r}")
            numbers[k] = float(v)
        entry[part] = numbers
    q = entry["orientation"]
    norm = math.sqrt(sum(v * v for v in q.values()))
    if abs(norm - 1.0) > QUATERNION_TOLERANCE:
        raise bad(f"orientation: quaternion has length {norm:.6f}; expected unit length")
    return entry


def read_text(path: str | os.PathLike[str]) -> str:
    """The text of a recorder file; :class:`RecorderFileError` when it cannot be read."""
    path = Path(path)
    try:
        return read_input_text(path)
    except InputFileError as exc:
        message = "recorder file not found" if exc.missing else str(exc)
        raise RecorderFileError(path, message) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise RecorderFileError(path, f"cannot read recorder file: {exc}") from None


def load_entries(path: str | os.PathLike[str]) -> dict[str, Entry]:
    """Read a recorder file (see :func:`parse_entries`)."""
    return parse_entries(read_text(path), path)


@dataclass(frozen=True)
class RecorderFile:
    """An existing recorder file as it was read and checked: what a recorder appending to
    it starts from (a mission's ``recorder:`` is read once, when the mission loads)."""

    path: Path
    text: str
    #: the file's signature with the text, if it still held that text once read (a
    #: recorder writing into this very file then need not parse it again)
    unchanged: tuple[tuple[int, int, int], str] | None

    @classmethod
    def read(cls, path: str | os.PathLike[str]) -> RecorderFile:
        """Read and check ``path``; :class:`RecorderFileError` names what is wrong."""
        path = Path(path)
        text = read_text(path)
        parse_entries(text, path)
        return cls(path, text, _unchanged_since_read(path, text))


def upsert_text(text: str, label: str, entry: Entry) -> str:
    """``text`` with ``label``'s entry replaced where it stands, or appended at the end.

    Only the entry's own lines change: comments, blank lines and the other entries keep
    their bytes. A file whose top level is not a block mapping (``{}``, flow style) is
    rewritten from its entries, keeping any text around the mapping.
    """
    block = dump_entries({label: entry})
    root = yaml.compose(text, Loader=_LOADER) if text.strip() else None
    if root is None:  # empty, or comments only
        return text + ("\n" if text and not text.endswith("\n") else "") + block
    if isinstance(root, yaml.MappingNode) and not root.flow_style:
        for key, value in root.value:
            if key.tag == _STR_TAG and key.value == label and key.start_mark.column == 0:
                end = _last_end(value)
                return text[: key.start_mark.index] + block.rstrip("\n") + text[end:]
        if all(key.start_mark.column == 0 for key, _ in root.value):
            return text + ("" if text.endswith("\n") else "\n") + block
    entries = parse_entries(text)
    entries[label] = entry
    start, end = root.start_mark.index, root.end_mark.index
    return text[:start] + dump_entries(entries).rstrip("\n") + text[end:]


def _last_end(node: yaml.Node) -> int:
    """Where the text of ``node`` ends (a block collection: where its last scalar ends)."""
    if isinstance(node, yaml.MappingNode) and not node.flow_style and node.value:
        return _last_end(node.value[-1][1])
    if isinstance(node, yaml.SequenceNode) and not node.flow_style and node.value:
        return _last_end(node.value[-1])
    return node.end_mark.index


class LocationRecorder:
    """Records poses under room labels into ``path``.

    ``initial``: an existing recorder file (:meth:`RecorderFile.read`) whose entries are
    kept and appended to (it may be ``path`` itself, as the seed's service appends to its
    own file). Nothing is written until the first :meth:`record` (or :meth:`save`). A
    ``path`` that is a symlink is followed: its target is the file written.
    """

    def __init__(self, path: str | os.PathLike[str], initial: RecorderFile | None = None) -> None:
        self.path = Path(path)
        self._initial_text = initial.text if initial is not None else "{}\n"
        self._entries: dict[str, Entry] = parse_entries(
            self._initial_text, initial.path if initial is not None else "<empty>"
        )
        self._written: tuple[tuple[int, int, int], str] | None = None  # (signature, text)
        if initial is not None and _same_file(initial.path, self.path):
            self._written = initial.unchanged

    @property
    def entries(self) -> dict[str, Pose2D]:
        """``{label: pose}`` in file order (a copy)."""
        return {label: entry_pose(e) for label, e in self._entries.items()}

    @property
    def labels(self) -> list[str]:
        return list(self._entries)

    def __len__(self) -> int:
        return len(self._entries)

    def __contains__(self, label: object) -> bool:
        return label in self._entries

    def record(self, label: str, pose: Pose2D) -> Path:
        """Store ``pose`` under ``label`` and rewrite the file atomically; returns the path.

        A new label is appended; a known one is replaced where it stands. Under the file's
        lock the file is read again first, so entries other processes recorded meanwhile
        are kept.
        """
        if not isinstance(label, str) or not label.strip():
            raise ValueError("a room label must be a non-empty string")
        if not all(math.isfinite(v) for v in (pose.x, pose.y, pose.yaw)):
            raise ValueError(f"cannot record a non-finite pose {pose}")
        entry = pose_entry(pose)
        with self._locked():
            text, entries = self._current()
            new_text = upsert_text(text, label, entry)
            entries[label] = entry
            self._write(new_text)
        self._entries = entries  # only once the file holds it
        return self.path

    def save(self) -> Path:
        """Write the current entries (e.g. those appended to) atomically, keeping entries
        another process wrote to the file meanwhile."""
        with self._locked():
            text, entries = self._current()
            for label, entry in self._entries.items():
                if label not in entries:
                    text = upsert_text(text, label, entry)
                    entries[label] = entry
            self._write(text)
        self._entries = entries
        return self.path

    def to_yaml(self) -> str:
        return dump_entries(self._entries)

    def _current(self) -> tuple[str, dict[str, Entry]]:
        """The file's text and entries now (the initial ones while it does not exist).

        A file unchanged since this recorder wrote it (same inode, size and mtime) is not
        parsed again: it holds what was written.
        """
        target = write_target(self.path)
        try:
            st = target.stat()
        except FileNotFoundError:
            return self._initial_text, dict(self._entries)
        if self._written is not None and _signature(st) == self._written[0]:
            return self._written[1], dict(self._entries)
        text = read_text(target)
        return text, parse_entries(text, self.path)  # refuses a file that is not a recorder's

    def _write(self, text: str) -> None:
        target = atomic_write_text(self.path, text)
        self._written = (_signature(target.stat()), text)

    def _locked(self) -> FileLock:
        target = write_target(self.path)
        lock = _Lock(str(target.parent / f".{target.name}.lock"), timeout=LOCK_TIMEOUT)
        lock.recorder_path = self.path
        return lock


def open_recorders(
    run_dir: Path | None,
    mission_file: RecorderFile | None,
    recorder_file: Path | None = None,
    append: Path | None = None,
) -> list[LocationRecorder]:
    """The recorders a session writes room poses into, the one to show first.

    * ``recorder_file``: record straight into it, appending to its entries when it exists
      (as the seed's service does); ``append`` may only name that same file.
    * else ``run_dir/location_recorder.yaml`` (when there is a run directory), starting from
      ``append``'s entries, or from those of ``mission_file`` (the mission's ``recorder``
      file, as it was read when the mission loaded), which is then also updated in place.

    Raises :class:`RecorderFileError` for a clash of ``recorder_file`` and ``append``.
    """
    if recorder_file is not None:
        exists = recorder_file.exists()
        if append is not None and exists and append.resolve() != recorder_file.resolve():
            raise RecorderFileError(
                recorder_file,
                f"exists and would be replaced by the entries of {append}; "
                "--recorder appends to an existing file by itself",
            )
        initial = append if append is not None else (recorder_file if exists else None)
        start = RecorderFile.read(initial) if initial is not None else None
        return [LocationRecorder(recorder_file, start)]
    if append is not None:
        if run_dir is None:
            raise ValueError("appending needs a run directory or a recorder file")
        return [LocationRecorder(run_dir / RECORDER_FILENAME, RecorderFile.read(append))]
    recorders = []
    if run_dir is not None:
        recorders.append(LocationRecorder(run_dir / RECORDER_FILENAME, mission_file))
    if mission_file is not None:
        recorders.append(LocationRecorder(mission_file.path, mission_file))
    return recorders


def _signature(st: os.stat_result) -> tuple[int, int, int]:
    return (st.st_ino, st.st_size, st.st_mtime_ns)


def _same_file(a: str | os.PathLike[str], b: str | os.PathLike[str]) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


def _unchanged_since_read(path: Path, text: str) -> tuple[tuple[int, int, int], str] | None:
    """The signature of ``path`` if the file holds ``text``: taken before reading it, so a
    change after the signature makes the next check fail, never the other way round."""
    try:
        with open(path, "rb") as f:
            st = os.fstat(f.fileno())
            same = f.read(len(text.encode("utf-8")) + 1) == text.encode("utf-8")
    except OSError:
        return None
    return (_signature(st), text) if same else None


class _Lock(FileLock):
    """The recorder file's lock, removed when released (no ``.<name>.lock`` left beside
    the file); a timeout is a :class:`RecorderFileError` naming the file.

    The holder unlinks the lock file before it unlocks, so a waiter may lock an inode no
    longer at the path: it then unlocks and locks the path again, and mutual exclusion
    holds (filelock keeps its lock files; this is the usual protocol to remove them)."""

    recorder_path: Path

    def __enter__(self) -> _Lock:
        deadline = time.monotonic() + LOCK_TIMEOUT
        while True:
            try:
                self.acquire(timeout=max(0.0, deadline - time.monotonic()))
            except Timeout:
                raise RecorderFileError(
                    self.recorder_path,
                    f"another process has held its lock ({self.lock_file}) for "
                    f"{LOCK_TIMEOUT:g} s; not recorded",
                ) from None
            except OSError as exc:
                raise RecorderFileError(
                    self.recorder_path, f"cannot create the lock file {self.lock_file}: {exc}"
                ) from None
            if self._holds_its_path():
                return self
            self.release()  # the previous holder removed this inode: lock the path again

    def __exit__(self, *exc_info: object) -> None:
        if self.lock_counter == 1 and self._holds_its_path():
            with contextlib.suppress(OSError):
                os.unlink(self.lock_file)
        self.release()

    def _holds_its_path(self) -> bool:
        """The locked file is the one at the lock's path (not one a holder removed)."""
        fd = self._context.lock_file_fd
        if fd is None:
            return False
        try:
            held, named = os.fstat(fd), os.stat(self.lock_file)
        except OSError:
            return False
        return (held.st_dev, held.st_ino) == (named.st_dev, named.st_ino)
