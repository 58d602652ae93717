"""Where a study's data lasts: participants, their assignment and progress, games and answers.

The one place that speaks SQL, through SQLAlchemy Core: the tables are declared once (in
``server.study.tables``, with the steps that bring an older schema to this one) and every statement is
built from them, so the same code runs on **SQLite** (the default: one file,
``<recordings>/<study id>/study.sqlite``, WAL, ``synchronous=FULL``) and on **PostgreSQL** (one
database that several play-server processes share). Every change is one transaction, so that a
crash or a kill loses nothing that was answered.

Assigning a participant (``StudyStore.transaction(assign=True)``) holds a lock the database gives,
so that counts read and the row written are one step even across processes: SQLite's
``BEGIN IMMEDIATE`` (every write transaction here takes it) and PostgreSQL's
``pg_advisory_xact_lock`` on a key derived from the study id. The participant id is the primary
key and an insert that finds it there returns the row already stored.

The ``meta`` table names the study and the schema version; a database of another study or of a
schema this code does not know is refused (``ValueError``, one line). A version 1 file (before
the per-game figures) is brought to version 2 when a study opens it; the export reads either.
"""

from __future__ import annotations

import hashlib
import json
import time
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path

from sqlalchemy import create_engine, event, func, insert, inspect, select, update
from sqlalchemy.dialects import postgresql, sqlite
from sqlalchemy.engine import URL, Connection, Engine, make_url
from sqlalchemy.exc import ArgumentError, DBAPIError

from colorgrid.enums import GameKind
from server.study.tables import (  # noqa: F401 (FIGURE_COLUMNS: read from here too)
    FIGURE_COLUMNS,
    SCHEMA_VERSION,
    add_figure_columns,
    answers,
    events,
    games,
    meta,
    migrate_1_to_2,
    participants,
    tables,
)

BACKENDS = ("sqlite", "postgresql")


# ---------------------------------------------------------------- opening a database
def database_url(database: str | Path) -> URL:
    """The SQLAlchemy URL of a study database: a path (an SQLite file) or a ``sqlite:///PATH`` or
    ``postgresql+psycopg://USER@HOST:PORT/DB`` URL (``postgresql://`` means the same driver)."""
    if isinstance(database, Path):
        return URL.create("sqlite", database=str(database))
    try:
        url = make_url(database)
    except ArgumentError:
        url = None
    if url is None or url.get_backend_name() not in BACKENDS or not url.database:
        raise ValueError(f"--database {database!r}: a study database is a sqlite:///PATH or "
                         "postgresql+psycopg://USER@HOST:PORT/DB URL")
    if url.drivername == "postgresql":
        url = url.set(drivername="postgresql+psycopg")
    if url.get_backend_name() == "postgresql":
        from colorgrid.extras import require

        require("postgres", "a PostgreSQL study database")
    return url


def describe(url: URL) -> str:
    """How messages name a database: an SQLite file's path, else the URL without its password."""
    return url.database if url.get_backend_name() == "sqlite" else url.render_as_string(hide_password=True)


def open_engine(url: URL, read_only: bool = False) -> Engine:
    """An engine for ``url``; SQLite in WAL mode, ``synchronous=FULL``, whose write transactions begin with
    ``BEGIN IMMEDIATE`` (a connection with the execution option ``read_only`` begins a plain ``BEGIN``)."""
    if url.get_backend_name() != "sqlite":
        return create_engine(url, pool_pre_ping=True)
    path = Path(url.database)
    if read_only:
        url = url.set(database=f"file:{path}?mode=ro", query={"uri": "true"})
    else:
        path.parent.mkdir(parents=True, exist_ok=True)
    engine = create_engine(url, connect_args={"timeout": 10, "check_same_thread": False})

    @event.listens_for(engine, "connect")
    def configure(connection, record):
        connection.isolation_level = None  # sqlite3 leaves BEGIN to us (below)
        if not read_only:
            connection.execute("PRAGMA journal_mode=WAL")
            connection.execute("PRAGMA synchronous=FULL")  # an answer that was acknowledged survives a power cut

    @event.listens_for(engine, "begin")
    def begin(connection):
        writes = not read_only and not connection.get_execution_options().get("read_only")
        connection.exec_driver_sql("BEGIN IMMEDIATE" if writes else "BEGIN")

    return engine


def lock_key(study_id: str) -> int:
    """The PostgreSQL advisory lock of a study: a signed 64-bit number derived from its id."""
    return int.from_bytes(hashlib.sha256(f"colorgrid-study:{study_id}".encode()).digest()[:8], "big", signed=True)


def read_meta(conn: Connection) -> dict[str, str]:
    return dict(conn.execute(select(meta.c.key, meta.c.value)).tuples().all())


def check_meta(known: dict[str, str], study_id: str, where: str) -> int:
    """The schema version of a database whose ``meta`` is ``known`` (0: new); raises ``ValueError`` for another
    study's database or a schema version this code does not read."""
    if known.get("study_id", study_id) != study_id:
        raise ValueError(f"{where} belongs to study {known['study_id']!r}, not {study_id!r}: give this study its "
                         "own database")
    version = known.get("schema")
    if version is None:
        return 0
    if version not in {str(v) for v in range(1, SCHEMA_VERSION + 1)}:
        raise ValueError(f"{where} is a study database of schema version {version}; this colorgrid reads versions "
                         f"1 to {SCHEMA_VERSION} (another colorgrid made it: use that one, or another database)")
    return int(version)


def connect_error(url: URL, err: DBAPIError) -> ValueError:
    first = str(err.orig).strip().splitlines()[0] if err.orig is not None else str(err)
    return ValueError(f"{describe(url)}: cannot open the study database: {first}")


def rows_of(result) -> list[dict]:
    return [dict(r) for r in result.mappings()]


# ---------------------------------------------------------------- a transaction's statements
class Transaction:
    """The statements of one transaction (``StudyStore.transaction``); rows are plain dicts."""

    def __init__(self, conn: Connection):
        self.conn = conn
        self.insert = postgresql.insert if conn.dialect.name == "postgresql" else sqlite.insert

    def participant(self, pid: str) -> dict | None:
        row = self.conn.execute(select(participants).where(participants.c.pid == pid)).mappings().first()
        return dict(row) if row is not None else None

    def count_participants(self) -> int:
        return self.conn.execute(select(func.count()).select_from(participants)).scalar_one()

    def arm_counts(self, arms: int) -> list[int]:
        counts = [0] * arms
        for arm, n in self.conn.execute(select(participants.c.arm, func.count()).group_by(participants.c.arm)):
            if 0 <= arm < arms:
                counts[arm] = n
        return counts

    def add_participant(self, row: dict) -> dict:
        """Insert ``row`` unless its pid is there already; returns the participant's row as stored."""
        self.conn.execute(self.insert(participants).values(**row).on_conflict_do_nothing(index_elements=["pid"]))
        return self.participant(row["pid"])

    def move_on(self, pid: str, step: int, to_step: int, done: bool, now: float) -> bool:
        """Move a participant from page ``step`` to ``to_step``; False when they were no longer on ``step``."""
        moved = self.conn.execute(update(participants).where(participants.c.pid == pid, participants.c.step == step)
                                  .values(step=to_step, updated=now, status="completed" if done else "active",
                                          completed=now if done else None))
        return moved.rowcount == 1

    def answer(self, pid: str, step: int, page: str, trial_index: int | None, question: str, value, now: float):
        row = {"pid": pid, "step": step, "page": page, "trial_index": trial_index, "question": question,
               "value": json.dumps(value), "answered": now}
        self.conn.execute(self.insert(answers).values(**row).on_conflict_do_update(
            index_elements=["pid", "step", "question"], set_={k: row[k] for k in ("page", "trial_index", "value",
                                                                                   "answered")}))

    def last_game(self, pid: str, step: int) -> dict | None:
        row = self.conn.execute(select(games).where(games.c.pid == pid, games.c.step == step)
                                .order_by(games.c.attempt.desc()).limit(1)).mappings().first()
        return dict(row) if row is not None else None

    def add_game(self, row: dict) -> None:
        self.conn.execute(insert(games).values(**row))

    def end_game(self, pid: str, step: int, attempt: int, values: dict, running: bool = False) -> None:
        """Write a game's end; ``running``: only if it has none yet."""
        which = [games.c.pid == pid, games.c.step == step, games.c.attempt == attempt]
        self.conn.execute(update(games).where(*which, *([games.c.ended.is_(None)] if running else []))
                          .values(**values))

    def check_tries(self, pid: str, step: int) -> dict[str, int]:
        """How many times each check of page ``step`` was answered by the participant (``check`` events)."""
        tries: dict[str, int] = {}
        for (detail,) in self.conn.execute(select(events.c.detail).where(events.c.pid == pid,
                                                                         events.c.kind == "check")):
            d = json.loads(detail)
            if d.get("step") == step:
                tries[d["question"]] = tries.get(d["question"], 0) + 1
        return tries

    def log(self, pid: str, kind: str, **detail) -> None:
        self.conn.execute(insert(events).values(pid=pid, t=time.time(), kind=kind, detail=json.dumps(detail)))


# ---------------------------------------------------------------- the store
class StudyStore:
    """A study's database, safe to use from the event loop's worker threads and from several processes.

    ``database``: an SQLite file's path, or a URL (``database_url``)."""

    def __init__(self, database: str | Path, study_id: str, study_hash: str):
        self.url = database_url(database)
        self.path = Path(self.url.database) if self.url.get_backend_name() == "sqlite" else None
        """The SQLite file (None on PostgreSQL)."""
        self.name = describe(self.url)
        self.lock_key = lock_key(study_id)
        self.engine = open_engine(self.url)
        try:
            with self.transaction(assign=True) as tx:  # two processes starting at once create the tables once
                tables.create_all(tx.conn)
                known = read_meta(tx.conn)
                version = check_meta(known, study_id, self.name)
                if version == 1:
                    migrate_1_to_2(tx.conn)
                elif version == 2:
                    add_figure_columns(tx.conn)
                tx.conn.execute(tx.insert(meta).on_conflict_do_nothing(index_elements=["key"]).values(
                    [{"key": "study_id", "value": study_id}, {"key": "created", "value": str(time.time())}]))
                for key, value in (("schema", str(SCHEMA_VERSION)), ("study_hash", study_hash)):
                    tx.conn.execute(tx.insert(meta).values(key=key, value=value).on_conflict_do_update(
                        index_elements=["key"], set_={"value": value}))
                self.changed_study = known.get("study_hash", study_hash) != study_hash
        except DBAPIError as err:
            self.engine.dispose()
            raise connect_error(self.url, err) from None
        except ValueError:
            self.engine.dispose()
            raise

    @property
    def address(self) -> str:
        """The database's URL as text, password included: what another process opens it with (``read_tables``)."""
        return self.url.render_as_string(hide_password=False)

    @contextmanager
    def transaction(self, assign: bool = False) -> Iterator[Transaction]:
        """One write transaction; ``assign``: under the study's lock (assigning participants to arms)."""
        with self.engine.begin() as conn:
            if assign and conn.dialect.name == "postgresql":
                conn.execute(select(func.pg_advisory_xact_lock(self.lock_key)))
            yield Transaction(conn)

    @contextmanager
    def reading(self) -> Iterator[Transaction]:
        """One read-only transaction (on SQLite it takes no write lock)."""
        with self.engine.connect().execution_options(read_only=True) as conn, conn.begin():
            yield Transaction(conn)

    def close(self) -> None:
        self.engine.dispose()

    # ---------------------------------------------------------------- reads
    def participant(self, pid: str) -> dict | None:
        with self.reading() as tx:
            return tx.participant(pid)

    def last_game(self, pid: str, step: int) -> dict | None:
        """The participant's latest attempt at the game of page ``step``."""
        with self.reading() as tx:
            return tx.last_game(pid, step)

    def participants(self) -> list[dict]:
        with self.reading() as tx:
            return rows_of(tx.conn.execute(select(participants)))

    def games(self) -> list[dict]:
        with self.reading() as tx:
            return rows_of(tx.conn.execute(select(games)))

    def answers(self) -> list[dict]:
        with self.reading() as tx:
            return rows_of(tx.conn.execute(select(answers)))

    def refusals(self) -> dict[str, int]:
        """How many joins were refused, by reason (``full``, ``screening:viewport``, ``already started``, ...)."""
        counts: dict[str, int] = {}
        with self.reading() as tx:
            for (detail,) in tx.conn.execute(select(events.c.detail).where(events.c.kind == "refused")):
                reason = json.loads(detail).get("reason", "")
                counts[reason] = counts.get(reason, 0) + 1
        return counts

    def endings(self) -> dict[str, int]:
        """How many games (practice and trials, every attempt) ended each way: ``{"complete": 40,
        "server_lost": 1}``."""
        query = (select(games.c.ended, func.count().label("games")).where(games.c.ended.is_not(None))
                 .group_by(games.c.ended))
        with self.reading() as tx:
            return {r["ended"]: r["games"] for r in rows_of(tx.conn.execute(query))}

    def figures_by_arm(self, lost: Iterable[str]) -> dict[int, dict]:
        """Per arm, over its trials that ended (but not ``lost``): how many, and the mean of each figure."""
        means = {name: func.avg(games.c[name]) for name in ("team_score", "follower_net_pickups",
                                                             "follower_wrong_pickups", "belief_accuracy")}
        query = (select(participants.c.arm, func.count().label("games"), *(m.label(n) for n, m in means.items()))
                 .join_from(games, participants, games.c.pid == participants.c.pid)
                 .where(games.c.kind == GameKind.TRIAL, games.c.ended.is_not(None),
                        games.c.ended.not_in(sorted(map(str, lost))))
                 .group_by(participants.c.arm))
        with self.reading() as tx:
            return {r["arm"]: {k: (float(v) if v is not None and k != "games" else v) for k, v in r.items()
                               if k != "arm"} for r in rows_of(tx.conn.execute(query))}


def read_tables(database: str | Path, study_id: str) -> dict[str, list[dict]]:
    """The ``participants``, ``games`` and ``answers`` of a study's database (schema version 1 or 2), read only:
    participants in the order they joined, games by participant, page and attempt, answers by participant,
    page and question, all as of one moment (a participant joining meanwhile is in none or in all). A version 1
    database's games lack the figure columns."""
    url = database_url(database)
    if url.get_backend_name() == "sqlite" and not Path(url.database).is_file():
        raise FileNotFoundError(f"{url.database}: no study database (run the study first, or pass --db, --database "
                                "or --replays-dir)")
    engine = open_engine(url, read_only=True)
    # sorted here, not by the database: PostgreSQL's collation may order text otherwise than SQLite's
    order = {"participants": lambda r: (r["started"], r["pid"]), "games": lambda r: (r["pid"], r["step"], r["attempt"]),
             "answers": lambda r: (r["pid"], r["step"], r["question"])}
    try:
        with engine.connect() as conn:
            if conn.dialect.name == "postgresql":  # one snapshot for every table (SQLite's one transaction is one)
                conn.execution_options(isolation_level="REPEATABLE READ", postgresql_readonly=True)
            check_meta(read_meta(conn), study_id, describe(url))
            out = {}
            for table in (participants, games, answers):
                present = {c["name"] for c in inspect(conn).get_columns(table.name)}
                rows = rows_of(conn.execute(select(*(c for c in table.columns if c.name in present))))
                out[table.name] = sorted(rows, key=order[table.name])
            return out
    except DBAPIError as err:
        raise connect_error(url, err) from None
    finally:
        engine.dispose()
