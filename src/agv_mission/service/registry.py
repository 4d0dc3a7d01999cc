"""The run registry: one embedded SQLite database (WAL) under the service's data directory.

Every run the service ever accepted is a row; its directory (``runs/<id>/``) sits beside
the database. Migrations are numbered SQL scripts applied in order and remembered in
``PRAGMA user_version``, so an old data directory opens with a newer service.
"""

from __future__ import annotations

import asyncio
import json
import sqlite3
import uuid
from collections import OrderedDict
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, TypeVar

DB_NAME = "registry.sqlite3"
RUNS_DIR = "runs"
FINAL = frozenset({"succeeded", "failed", "aborted", "error", "interrupted"})
ACTIVE = frozenset({"running", "paused"})
STATUSES = frozenset({"queued"}) | ACTIVE | FINAL
CACHE_ROWS = 4096  # runs kept in memory (the active ones and the latest others)
NO_PROGRESS: dict[str, Any] = {"sim_time": 0.0, "task_index": None, "task_type": None, "detail": ""}
T = TypeVar("T")

MIGRATIONS: tuple[str, ...] = (
    """
    CREATE TABLE runs (
        seq INTEGER PRIMARY KEY AUTOINCREMENT,
        id TEXT NOT NULL UNIQUE,
        name TEXT NOT NULL,
        status TEXT NOT NULL,
        reason TEXT,
        created TEXT NOT NULL,
        started TEXT,
        ended TEXT,
        progress TEXT,
        mission TEXT NOT NULL,
        sets TEXT NOT NULL,
        seed INTEGER
    );
    CREATE INDEX runs_status ON runs(status);
    """,
    """
    ALTER TABLE runs ADD COLUMN worker_pid INTEGER;
    """,
    """
    ALTER TABLE runs ADD COLUMN mission_path TEXT;
    """,
    """
    ALTER TABLE runs ADD COLUMN pace REAL;
    """,
)


def utc_now() -> str:
    return datetime.now(timezone.utc).isoformat(timespec="milliseconds").replace("+00:00", "Z")


@dataclass(frozen=True)
class Submission:
    """What a client sent: the mission text with its overrides, as accepted."""

    name: str
    mission: str
    sets: list[str]
    seed: int | None
    # where the mission sits in its run directory when it came with its files
    # (``inputs/...``); None: it names built-in and data-directory files only
    mission_path: str | None = None
    pace: float | None = None  # simulated seconds per wall second; None: flat out


class Registry:
    """The runs table behind an in-memory cache.

    Every SQLite statement runs, in order, on one database thread, so the service's event
    loop never waits for the disk: writes are queued (``add`` hands back a future to await
    before answering 201, so an accepted run is durable), and reads of recent runs come
    from the cache, which every write updates at once. A read that misses the cache is
    queued behind every earlier write, so it never sees an older row than the cache did.
    """

    def __init__(self, data_dir: Path) -> None:
        self.data_dir = data_dir
        data_dir.mkdir(parents=True, exist_ok=True)
        (data_dir / RUNS_DIR).mkdir(exist_ok=True)
        self._thread = ThreadPoolExecutor(max_workers=1, thread_name_prefix="registry")
        self._db = self._call(self._connect)
        self._rows: OrderedDict[str, dict[str, Any]] = OrderedDict()  # id -> run (LRU)
        self._subs: dict[str, Submission] = {}  # accepted, not yet started
        self._call(self._migrate)

    # ------------------------------------------------------------------ the database thread

    def _connect(self) -> sqlite3.Connection:
        db = sqlite3.connect(
            self.data_dir / DB_NAME, check_same_thread=False, isolation_level=None, timeout=30.0
        )
        db.row_factory = sqlite3.Row
        db.execute("PRAGMA journal_mode=WAL")
        db.execute("PRAGMA synchronous=NORMAL")
        return db

    def _call(self, fn: Callable[..., T], *args: Any) -> T:
        """Run ``fn`` on the database thread and wait for it (start-up, tests, threads)."""
        return self._thread.submit(fn, *args).result()

    def _later(self, fn: Callable[..., T], *args: Any) -> Future[T]:
        return self._thread.submit(fn, *args)

    async def _async(self, fn: Callable[..., T], *args: Any) -> T:
        return await asyncio.wrap_future(self._later(fn, *args))

    @property
    def version(self) -> int:
        return self._call(lambda: int(self._db.execute("PRAGMA user_version").fetchone()[0]))

    def _migrate(self) -> None:
        current = int(self._db.execute("PRAGMA user_version").fetchone()[0])
        for number, script in enumerate(MIGRATIONS[current:], start=current + 1):
            self._db.execute("BEGIN IMMEDIATE")
            try:
                for statement in filter(str.strip, script.split(";")):
                    self._db.execute(statement)
                self._db.execute(f"PRAGMA user_version = {number}")
                self._db.execute("COMMIT")
            except BaseException:
                self._db.execute("ROLLBACK")
                raise

    def _select(self, run_id: str) -> dict[str, Any] | None:
        row = self._db.execute("SELECT * FROM runs WHERE id = ?", (run_id,)).fetchone()
        return _row(row) if row is not None else None

    def _write(self, sql: str, args: tuple[Any, ...]) -> None:
        self._db.execute(sql, args)

    def _insert(self, run_id: str, sql: str, args: tuple[Any, ...]) -> None:
        self.run_dir(run_id).mkdir(parents=True, exist_ok=True)
        self._db.execute(sql, args)

    # ------------------------------------------------------------------ the cache

    def _remember(self, run: dict[str, Any]) -> None:
        self._rows[run["id"]] = run
        self._rows.move_to_end(run["id"])
        while len(self._rows) > CACHE_ROWS:
            self._rows.popitem(last=False)

    def _cached(self, run_id: str) -> dict[str, Any] | None:
        run = self._rows.get(run_id)
        if run is None:
            return None
        self._rows.move_to_end(run_id)
        return {**run, "progress": dict(run["progress"]), "set": list(run["set"])}

    # ------------------------------------------------------------------ runs

    def run_dir(self, run_id: str) -> Path:
        return self.data_dir / RUNS_DIR / run_id

    @staticmethod
    def new_id() -> str:
        return uuid.uuid4().hex[:12]

    def add(
        self, submission: Submission, run_id: str | None = None
    ) -> tuple[dict[str, Any], Future[None]]:
        """A new queued run (``run_id``: one :meth:`new_id` gave, whose directory already
        holds the submission's files): at once in memory; the future says when it is on
        disk."""
        run_id = run_id or self.new_id()
        created = utc_now()
        run = {
            "id": run_id,
            "name": submission.name,
            "status": "queued",
            "reason": None,
            "created": created,
            "started": None,
            "ended": None,
            "progress": dict(NO_PROGRESS),
            "seed": submission.seed,
            "set": list(submission.sets),
            "pace": submission.pace,
        }
        self._remember(run)
        self._subs[run_id] = submission
        done = self._later(
            self._insert,
            run_id,
            "INSERT INTO runs (id, name, status, created, mission, sets, seed, mission_path, "
            "pace) VALUES (?, ?, 'queued', ?, ?, ?, ?, ?, ?)",
            (
                run_id,
                submission.name,
                created,
                submission.mission,
                json.dumps(submission.sets),
                submission.seed,
                submission.mission_path,
                submission.pace,
            ),
        )
        return self._cached(run_id) or run, done

    def get(self, run_id: str) -> dict[str, Any] | None:
        """One run (blocking on a cache miss: not for the event loop, see :meth:`aget`)."""
        run = self._cached(run_id)
        if run is None and (run := self._call(self._select, run_id)) is not None:
            self._remember(run)
            run = self._cached(run_id)
        return run

    async def aget(self, run_id: str) -> dict[str, Any] | None:
        """One run, without blocking the event loop."""
        run = self._cached(run_id)
        if run is None and (run := await self._async(self._select, run_id)) is not None:
            if run_id not in self._rows:  # a write may have cached a newer one meanwhile
                self._remember(run)
            run = self._cached(run_id)
        return run

    def submission(self, run_id: str) -> Submission:
        sub = self._subs.pop(run_id, None)
        if sub is not None:
            return sub

        def read() -> Submission:
            row = self._db.execute(
                "SELECT name, mission, sets, seed, mission_path, pace FROM runs WHERE id = ?",
                (run_id,),
            ).fetchone()
            return Submission(
                row["name"],
                row["mission"],
                json.loads(row["sets"]),
                row["seed"],
                row["mission_path"],
                row["pace"],
            )

        return self._call(read)

    def forget_submission(self, run_id: str) -> None:
        """A queued run cancelled before it started: its text is no longer needed in memory."""
        self._subs.pop(run_id, None)

    def preload(self, run_ids: list[str]) -> None:
        """Read the submissions of runs about to start (at start-up, off the event loop)."""
        for run_id in run_ids:
            self._subs[run_id] = self.submission(run_id)

    def _list(self, status: str | None, limit: int) -> list[dict[str, Any]]:
        query, args = "SELECT * FROM runs", []
        if status is not None:
            query += " WHERE status = ?"
            args.append(status)
        query += " ORDER BY seq DESC LIMIT ?"
        args.append(limit)
        return [_row(r) for r in self._db.execute(query, args).fetchall()]

    def list(self, status: str | None = None, limit: int = 100) -> list[dict[str, Any]]:
        return self._call(self._list, status, limit)

    async def alist(self, status: str | None = None, limit: int = 100) -> list[dict[str, Any]]:
        """Newest first; queued behind every earlier write, so as fresh as the cache."""
        return await self._async(self._list, status, limit)

    def ids_with_status(self, *statuses: str) -> list[str]:
        marks = ",".join("?" * len(statuses))

        def read() -> list[str]:
            rows = self._db.execute(
                f"SELECT id FROM runs WHERE status IN ({marks}) ORDER BY seq", statuses
            ).fetchall()
            return [r["id"] for r in rows]

        return self._call(read)

    def update(self, run_id: str, **fields: Any) -> None:
        """Set columns of one run (``progress`` as a dict): in the cache now, on disk soon."""
        cached = self._rows.get(run_id)
        if cached is not None:
            for key, value in fields.items():
                if key in cached:
                    cached[key] = dict(value) if key == "progress" and value else value
        if "progress" in fields and fields["progress"] is not None:
            fields["progress"] = json.dumps(fields["progress"])
        sets = ", ".join(f"{k} = ?" for k in fields)
        self._later(self._write, f"UPDATE runs SET {sets} WHERE id = ?", (*fields.values(), run_id))

    def set_status(self, run_id: str, status: str, reason: str | None = None, **more: Any) -> None:
        fields: dict[str, Any] = {"status": status, **more}
        if reason is not None:
            fields["reason"] = reason
        if status in FINAL:
            fields["ended"] = utc_now()
        self.update(run_id, **fields)
        if status in ACTIVE:  # the first start only
            now = utc_now()
            cached = self._rows.get(run_id)
            if cached is not None and cached["started"] is None:
                cached["started"] = now
            self._later(
                self._write,
                "UPDATE runs SET started = COALESCE(started, ?) WHERE id = ?",
                (now, run_id),
            )

    def flush(self) -> None:
        """Wait until every queued write is on disk."""
        self._call(lambda: None)

    def recover(self) -> tuple[list[str], list[str]]:
        """After a stop of any kind: runs that were running are ``interrupted``; the queued
        ones come back in submission order. Returns (interrupted ids, queued ids)."""
        interrupted = self.ids_with_status(*ACTIVE)
        for run_id in interrupted:
            self.set_status(run_id, "interrupted", "the service stopped while this run was running")
        queued = self.ids_with_status("queued")
        self.preload(queued)
        return interrupted, queued

    def close(self) -> None:
        self._call(self._db.close)
        self._thread.shutdown(wait=True)


def _row(row: sqlite3.Row) -> dict[str, Any]:
    progress = json.loads(row["progress"]) if row["progress"] else None
    return {
        "id": row["id"],
        "name": row["name"],
        "status": row["status"],
        "reason": row["reason"],
        "created": row["created"],
        "started": row["started"],
        "ended": row["ended"],
        "progress": progress or dict(NO_PROGRESS),
        "seed": row["seed"],
        "set": json.loads(row["sets"]),
        "pace": row["pace"],
    }
