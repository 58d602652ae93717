"""Where a study's data lasts: participants, their assignment and progress, games and answers, in SQLite.

One file per study (``<recordings>/<study id>/study.sqlite`` by default), written through the
standard library's ``sqlite3`` in WAL mode, every change in one transaction, so that a crash or
a kill loses nothing that was answered. The SQL is plain and portable (no SQLite-only types): a
server database later means another ``connect()`` and the same statements.
"""

from __future__ import annotations

import json
import sqlite3
import threading
import time
from pathlib import Path

SCHEMA_VERSION = 1
SCHEMA = """
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS participants (
    pid TEXT PRIMARY KEY,
    session TEXT NOT NULL,
    arm INTEGER NOT NULL,
    conditions TEXT NOT NULL,          -- JSON: the condition index of each trial, in play order
    status TEXT NOT NULL,              -- active | completed
    step INTEGER NOT NULL DEFAULT 0,   -- the page (of the participant's expanded pages) they are on
    url_params TEXT NOT NULL,          -- JSON: the id and kept parameters of the link they came with
    user_agent TEXT NOT NULL,
    started REAL NOT NULL,             -- seconds since the epoch
    completed REAL,
    updated REAL NOT NULL
);
CREATE TABLE IF NOT EXISTS games (
    pid TEXT NOT NULL,
    step INTEGER NOT NULL,
    attempt INTEGER NOT NULL,          -- 0, then 1, 2... when a game was lost (disconnected, server stopped)
    kind TEXT NOT NULL,                -- practice | trial
    trial_index INTEGER,               -- 0-based among the trials (null for practice)
    condition INTEGER,                 -- index into the study's conditions (null for practice)
    settings TEXT NOT NULL,            -- JSON: the game's settings (follower, show_belief, mode, ...)
    game_id TEXT NOT NULL,
    replay_id TEXT,
    ended TEXT,                        -- null while live; then the replay's reason (complete, idle, ...)
    scores TEXT,                       -- JSON: team, leader, follower
    started REAL NOT NULL,
    finished REAL,
    PRIMARY KEY (pid, step, attempt)
);
CREATE TABLE IF NOT EXISTS answers (
    pid TEXT NOT NULL,
    step INTEGER NOT NULL,
    page TEXT NOT NULL,                -- the questionnaire's name
    trial_index INTEGER,               -- for questions after a trial: which trial
    question TEXT NOT NULL,
    value TEXT,                        -- JSON: a number (likert), a string (choice, text) or null (skipped)
    answered REAL NOT NULL,
    PRIMARY KEY (pid, step, question)
);
CREATE TABLE IF NOT EXISTS events (
    pid TEXT NOT NULL,
    t REAL NOT NULL,
    kind TEXT NOT NULL,                -- joined, resumed, refused, consented, advanced, completed
    detail TEXT NOT NULL               -- JSON
);
"""


def connect(path: str | Path) -> sqlite3.Connection:
    """An open study database (created with its tables if new)."""
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    db = sqlite3.connect(str(path), check_same_thread=False, isolation_level=None, timeout=10)
    db.row_factory = sqlite3.Row
    db.execute("PRAGMA journal_mode=WAL")
    db.execute("PRAGMA synchronous=FULL")  # an answer that was acknowledged survives a power cut
    db.executescript(SCHEMA)
    return db


class StudyStore:
    """The study's tables, safe to use from the event loop's worker threads (one lock, short transactions)."""

    def __init__(self, path: str | Path, study_id: str, study_hash: str):
        self.path = Path(path)
        self.db = connect(self.path)
        self.lock = threading.Lock()
        with self.transaction() as db:
            known = dict(db.execute("SELECT key, value FROM meta").fetchall())
            if known.get("study_id", study_id) != study_id:
                raise ValueError(f"{self.path} belongs to study {known['study_id']!r}, not {study_id!r}")
            db.execute("INSERT OR IGNORE INTO meta VALUES ('study_id', ?), ('schema', ?), ('created', ?)",
                       (study_id, str(SCHEMA_VERSION), str(time.time())))
            db.execute("INSERT OR REPLACE INTO meta VALUES ('study_hash', ?)", (study_hash,))
            self.changed_study = known.get("study_hash", study_hash) != study_hash

    # ---------------------------------------------------------------- plumbing
    class _Transaction:
        def __init__(self, store: "StudyStore"):
            self.store = store

        def __enter__(self) -> sqlite3.Connection:
            self.store.lock.acquire()
            self.store.db.execute("BEGIN IMMEDIATE")
            return self.store.db

        def __exit__(self, kind, err, tb):
            try:
                self.store.db.execute("COMMIT" if kind is None else "ROLLBACK")
            finally:
                self.store.lock.release()

    def transaction(self) -> "_Transaction":
        return StudyStore._Transaction(self)

    def close(self) -> None:
        with self.lock:
            self.db.close()

    # ---------------------------------------------------------------- participants
    def participant(self, pid: str) -> sqlite3.Row | None:
        with self.lock:
            return self.db.execute("SELECT * FROM participants WHERE pid = ?", (pid,)).fetchone()

    def arm_counts(self, db: sqlite3.Connection, arms: int) -> list[int]:
        counts = [0] * arms
        for arm, n in db.execute("SELECT arm, COUNT(*) FROM participants GROUP BY arm"):
            if 0 <= arm < arms:
                counts[arm] = n
        return counts

    def log(self, db: sqlite3.Connection, pid: str, kind: str, **detail) -> None:
        db.execute("INSERT INTO events VALUES (?, ?, ?, ?)", (pid, time.time(), kind, json.dumps(detail)))

    def rows(self, sql: str, *args) -> list[sqlite3.Row]:
        with self.lock:
            return self.db.execute(sql, args).fetchall()
