"""The study database's schema: its tables, declared once (SQLAlchemy Core), and how a database of an earlier
schema version is brought to this one. ``server.study.store`` builds every statement from these tables.
"""

from __future__ import annotations

import json

from sqlalchemy import Column, Float, Integer, MetaData, Table, Text, inspect, select, update
from sqlalchemy.engine import Connection

from server.study.figures import FIGURES, SCORES, score_figures

SCHEMA_VERSION = 3
"""Version 2 added the per-game figures (``figures.SCORES`` and ``figures.FIGURES``) to ``games``; version 3 the
attention figures (``away_s``, ``idle_s``, ``round_trip_ms``: ``server.study.exclusions``)."""
SQL_TYPES = {int: Integer, float: Float, str: Text}

tables = MetaData()
meta = Table("meta", tables, Column("key", Text, primary_key=True), Column("value", Text, nullable=False))
participants = Table(
    "participants", tables,
    Column("pid", Text, primary_key=True),
    Column("session", Text, nullable=False),
    Column("arm", Integer, nullable=False),
    Column("conditions", Text, nullable=False),  # JSON: the condition index of each trial, in play order
    Column("status", Text, nullable=False),  # active | completed
    Column("step", Integer, nullable=False, server_default="0"),  # the page (of their expanded pages) they are on
    Column("url_params", Text, nullable=False),  # JSON: the id and kept parameters of the link they came with
    Column("user_agent", Text, nullable=False),
    Column("started", Float, nullable=False),  # seconds since the epoch
    Column("completed", Float),
    Column("updated", Float, nullable=False),
)
FIGURE_COLUMNS = [Column(name, Float) for name in SCORES] + [Column(name, SQL_TYPES[kind])
                                                             for name, kind in FIGURES.items()]
"""The ``games`` columns of schema version 2: null while the game runs, and for games recorded before."""
games = Table(
    "games", tables,
    Column("pid", Text, primary_key=True),
    Column("step", Integer, primary_key=True),
    Column("attempt", Integer, primary_key=True),  # 0, then 1, 2... when a game was lost (disconnected, stopped)
    Column("kind", Text, nullable=False),  # practice | trial
    Column("trial_index", Integer),  # 0-based among the trials (null for practice)
    Column("condition", Integer),  # index into the study's conditions (null for practice)
    Column("settings", Text, nullable=False),  # JSON: the game's settings (follower, show_belief, mode, ...)
    Column("game_id", Text, nullable=False),
    Column("replay_id", Text),
    Column("ended", Text),  # null while live; then the replay's reason (complete, idle, ...)
    Column("scores", Text),  # JSON: team, leader, follower
    Column("started", Float, nullable=False),
    Column("finished", Float),
    *FIGURE_COLUMNS,
)
answers = Table(
    "answers", tables,
    Column("pid", Text, primary_key=True),
    Column("step", Integer, primary_key=True),
    Column("page", Text, nullable=False),  # the questionnaire's name
    Column("trial_index", Integer),  # for questions after a trial: which trial
    Column("question", Text, primary_key=True),
    Column("value", Text),  # JSON: a number (likert), a string (choice, text) or null (skipped)
    Column("answered", Float, nullable=False),
)
events = Table(
    "events", tables,
    Column("pid", Text, nullable=False),
    Column("t", Float, nullable=False),
    Column("kind", Text, nullable=False),  # joined, resumed, refused, consented, advanced, completed, check
    Column("detail", Text, nullable=False),  # JSON
)


def add_figure_columns(conn: Connection) -> None:
    """Add the figure columns ``games`` lacks (null for the games recorded before: the export computes what it can
    from their replays)."""
    present = {c["name"] for c in inspect(conn).get_columns("games")}
    quote = conn.dialect.identifier_preparer.quote
    for column in FIGURE_COLUMNS:
        if column.name not in present:
            conn.exec_driver_sql(f"ALTER TABLE games ADD COLUMN {quote(column.name)} "
                                 f"{column.type.compile(dialect=conn.dialect)}")


def migrate_1_to_2(conn: Connection) -> None:
    """Add the figure columns to ``games`` and fill the scores of games already over from their JSON (the other
    figures of those games stay null: the export computes them from the replays)."""
    add_figure_columns(conn)
    done = conn.execute(select(games.c.pid, games.c.step, games.c.attempt, games.c.scores)
                        .where(games.c.scores.is_not(None))).all()
    for pid, step, attempt, scores in done:
        conn.execute(update(games).where(games.c.pid == pid, games.c.step == step, games.c.attempt == attempt)
                     .values(**score_figures(json.loads(scores))))
