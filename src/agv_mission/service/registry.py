"""The run registry: one embedded SQLite database (WAL) under the service's data directory.

Every run the service ever accepted is a row; its directory (``runs/<id>/``) sits beside
the database. Migrations are numbered SQL scripts applied in order and remembered in
``PRAGMA user_version``, so an old data directory opens with a newer service.
"""

from __future__ import annotations

import json
import sqlite3
import threading
import uuid
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

DB_NAME = "registry.sqlite3"
RUNS_DIR = "runs"
FINAL = frozenset({"succeeded", "failed", "aborted", "error", "interrupted"})
ACTIVE = frozenset({"running", "paused"})
STATUSES = frozenset({"queued"}) | ACTIVE | FINAL

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


class Registry:
    """Thread-safe access to the runs table (one connection, one lock: calls are short)."""

    def __init__(self, data_dir: Path) -> None:
        self.data_dir = data_dir
        data_dir.mkdir(parents=True, exist_ok=True)
        (data_dir / RUNS_DIR).mkdir(exist_ok=True)
        self._lock = threading.Lock()
        self._db = sqlite3.connect(
            data_dir / DB_NAME, check_same_thread=False, isolation_level=None, timeout=30.0
        )
        self._db.row_factory = sqlite3.Row
        self._db.execute("PRAGMA journal_mode=WAL")
        self._db.execute("PRAGMA synchronous=NORMAL")
        self._migrate()

    @property
    def version(self) -> int:
        return int(self._db.execute("PRAGMA user_version").fetchone()[0])

    def _migrate(self) -> None:
        with self._lock:
            current = self.version
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

    def run_dir(self, run_id: str) -> Path:
        return self.data_dir / RUNS_DIR / run_id

    def add(self, submission: Submission) -> dict[str, Any]:
        run_id = uuid.uuid4().hex[:12]
        with self._lock:
            self._db.execute(
                "INSERT INTO runs (id, name, status, created, mission, sets, seed) "
                "VALUES (?, ?, 'queued', ?, ?, ?, ?)",
                (
                    run_id,
                    submission.name,
                    utc_now(),
                    submission.mission,
                    json.dumps(submission.sets),
                    submission.seed,
                ),
            )
        self.run_dir(run_id).mkdir(parents=True, exist_ok=True)
        run = self.get(run_id)
        assert run is not None
        return run

    def get(self, run_id: str) -> dict[str, Any] | None:
        with self._lock:
            row = self._db.execute("SELECT * FROM runs WHERE id = ?", (run_id,)).fetchone()
        return _row(row) if row is not None else None

    def submission(self, run_id: str) -> Submission:
        with self._lock:
            row = self._db.execute(
                "SELECT name, mission, sets, seed FROM runs WHERE id = ?", (run_id,)
            ).fetchone()
        return Submission(row["name"], row["mission"], json.loads(row["sets"]), row["seed"])

    def list(self, status: str | None = None, limit: int = 100) -> list[dict[str, Any]]:
        query, args = "SELECT * FROM runs", []
        if status is not None:
            query += " WHERE status = ?"
            args.append(status)
        query += " ORDER BY seq DESC LIMIT ?"
        args.append(limit)
        with self._lock:
            rows = self._db.execute(query, args).fetchall()
        return [_row(r) for r in rows]

    def ids_with_status(self, *statuses: str) -> list[str]:
        marks = ",".join("?" * len(statuses))
        with self._lock:
            rows = self._db.execute(
                f"SELECT id FROM runs WHERE status IN ({marks}) ORDER BY seq", statuses
            ).fetchall()
        return [r["id"] for r in rows]

    def count(self, *statuses: str) -> int:
        marks = ",".join("?" * len(statuses))
        with self._lock:
            row = self._db.execute(
                f"SELECT COUNT(*) FROM runs WHERE status IN ({marks})", statuses
            ).fetchone()
        return int(row[0])

    def update(self, run_id: str, **fields: Any) -> None:
        """Set columns of one run (``progress`` as a dict, stored as JSON)."""
        if "progress" in fields and fields["progress"] is not None:
            fields["progress"] = json.dumps(fields["progress"])
        sets = ", ".join(f"{k} = ?" for k in fields)
        with self._lock:
            self._db.execute(f"UPDATE runs SET {sets} WHERE id = ?", (*fields.values(), run_id))

    def set_status(self, run_id: str, status: str, reason: str | None = None, **more: Any) -> None:
        fields: dict[str, Any] = {"status": status, **more}
        if reason is not None:
            fields["reason"] = reason
        if status in ACTIVE and "started" not in fields:
            with self._lock:
                row = self._db.execute("SELECT started FROM runs WHERE id = ?", (run_id,))
                started = row.fetchone()["started"]
            if started is None:
                fields["started"] = utc_now()
        if status in FINAL:
            fields["ended"] = utc_now()
        self.update(run_id, **fields)

    def recover(self) -> tuple[list[str], list[str]]:
        """After a stop of any kind: runs that were running are ``interrupted``; the queued
        ones come back in submission order. Returns (interrupted ids, queued ids)."""
        interrupted = self.ids_with_status(*ACTIVE)
        for run_id in interrupted:
            self.set_status(run_id, "interrupted", "the service stopped while this run was running")
        return interrupted, self.ids_with_status("queued")

    def close(self) -> None:
        with self._lock:
            self._db.close()


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
        "progress": progress
        or {"sim_time": 0.0, "task_index": None, "task_type": None, "detail": ""},
        "seed": row["seed"],
        "set": json.loads(row["sets"]),
    }
