"""The study database on SQLite and on PostgreSQL (a real cluster, ``tests/pg.py``): assignment under
concurrency, the schema version and study checks, the per-game figures, version 1 files, and an export
that is the same from either database."""

from __future__ import annotations

import itertools
import multiprocessing
import sqlite3
import subprocess
import sys
import tomllib
from collections import Counter
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace

import pandas as pd
import pytest
from sqlalchemy import update

from colorgrid.policies import make_policy
from colorgrid.presets import env_config
from colorgrid.replay import Replay, from_batch, load, save
from colorgrid.rollout import run_episodes
from server.study import service as service_module
from server.study.config import parse_study
from server.study.export import tables
from server.study.figures import FIGURES, SCORES, game_figures
from server.study.service import Refused, StudyService, study_hash
from server.study import store as store_module
from server.study.store import FIGURE_COLUMNS, SCHEMA_VERSION, StudyStore, games, meta, read_tables
from tests.conftest import ROOT
from tests.test_study import SEVERAL_CONDITIONS

EXAMPLE = ROOT / "studies" / "belief_display.toml"


def example_study(quota: int | None):
    data = tomllib.loads(EXAMPLE.read_text())
    data["max_participants"] = 1000
    if quota is not None:
        data["design"]["quota"] = quota
    return parse_study(data)


def open_service(study, database) -> StudyService:
    return StudyService(study, StudyStore(database, study.id, study_hash(study)))


# ---------------------------------------------------------------- assignment under concurrency
def join_all(service: StudyService, pids: list[str], threads: int) -> Counter:
    """Join every pid from ``threads`` threads at once; how each join ended."""
    def join(pid: str) -> str:
        try:
            service.join({"PROLIFIC_PID": pid}, None, "test")
            return "joined"
        except Refused as err:
            return "full" if "full" in str(err) else "already started"

    with ThreadPoolExecutor(threads) as pool:
        return Counter(pool.map(join, pids))


def joins_in_a_process(database: str, quota: int, pids: list[str], start=None) -> Counter:
    """In a process of its own (``multiprocessing``'s spawn): a play server's study service joining ``pids``, once
    every process has its service open (``start``, a barrier), so that the processes' joins overlap."""
    service = open_service(example_study(quota), database)
    if start is not None:
        start.wait(timeout=300)
    try:
        return join_all(service, pids, threads=8)
    finally:
        service.store.close()


def assigned(service: StudyService) -> tuple[Counter, list[str]]:
    rows = service.store.participants()
    return Counter(r["arm"] for r in rows), [r["pid"] for r in rows]


def test_200_participants_joining_at_once_from_threads_are_balanced_and_each_assigned_once(study_database):
    service = open_service(example_study(quota=60), study_database)
    pids = [f"p{i}" for i in range(200)]
    try:  # every pid twice, from 16 threads: the second join of each finds the first
        ends = join_all(service, [pid for pair in zip(pids, reversed(pids)) for pid in pair], threads=16)
        arms, who = assigned(service)
    finally:
        service.store.close()
    assert ends == {"joined": 200, "already started": 200}
    assert sorted(who) == sorted(pids)
    assert sorted(arms) == [0, 1, 2, 3] and max(arms.values()) - min(arms.values()) <= 1, arms


def test_two_processes_assigning_the_same_200_participants_on_postgresql_keep_quotas_exact(postgres):
    database = postgres.new_database()
    study = example_study(quota=45)
    StudyStore(database, study.id, study_hash(study)).close()
    pids = [f"p{i}" for i in range(200)]
    spawn = multiprocessing.get_context("spawn")
    with spawn.Manager() as manager, spawn.Pool(2) as pool:
        start = manager.Barrier(2)
        ends = pool.starmap(joins_in_a_process, [(database, 45, pids, start), (database, 45, pids[::-1], start)])
    service = open_service(study, database)
    try:
        arms, who = assigned(service)
    finally:
        service.store.close()
    assert arms == {0: 45, 1: 45, 2: 45, 3: 45}  # 4 arms at their quota of 45; 20 people turned away
    assert len(who) == len(set(who)) == 180
    total = ends[0] + ends[1]
    assert total == {"joined": 180, "already started": 180, "full": 40}, ends
    assert ends[0]["joined"] > 0 and ends[1]["joined"] > 0, ends  # both processes assigned people


# ---------------------------------------------------------------- what a database is checked for
def test_a_database_of_another_study_or_schema_version_is_refused_in_one_line(study_database):
    StudyStore(study_database, "first_study", "hash").close()
    with pytest.raises(ValueError) as err:
        StudyStore(study_database, "second_study", "hash")
    assert "belongs to study 'first_study', not 'second_study'" in str(err.value) and "\n" not in str(err.value)
    with pytest.raises(ValueError, match="belongs to study 'first_study'"):
        read_tables(study_database, "second_study")

    store = StudyStore(study_database, "first_study", "hash")
    with store.transaction() as tx:
        tx.conn.execute(update(meta).where(meta.c.key == "schema").values(value="7"))
    store.close()
    for open_it in (lambda: StudyStore(study_database, "first_study", "hash"),
                    lambda: read_tables(study_database, "first_study")):
        with pytest.raises(ValueError) as err:
            open_it()
        assert f"schema version 7; this colorgrid reads versions 1 to {SCHEMA_VERSION}" in str(err.value)
        assert "\n" not in str(err.value)


def test_the_same_study_changed_is_noticed_not_refused(study_database):
    first = StudyStore(study_database, "s", "version-1")
    assert not first.changed_study
    first.close()
    again = StudyStore(study_database, "s", "version-2")
    assert again.changed_study
    again.close()
    assert read_tables(again.address, "s")["participants"] == []  # another process opens it by its address
    assert not StudyStore(study_database, "s", "version-2").changed_study


def colorgrid(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "colorgrid_apps", *args], check=False, cwd=ROOT, capture_output=True,
                          text=True, timeout=120)


def test_the_cli_refuses_a_mismatched_database_or_flags_in_one_line(postgres, tmp_path):
    sqlite_file, url = tmp_path / "other.sqlite", postgres.new_database()
    for database in (sqlite_file, url):
        StudyStore(database, "another_study", "hash").close()
    out = str(tmp_path / "out")
    cases = [
        (("study", "export", str(EXAMPLE), "--out", out, "--database", url),
         "belongs to study 'another_study', not 'belief_display'"),
        (("study", "export", str(EXAMPLE), "--out", out, "--db", str(sqlite_file)),
         "belongs to study 'another_study', not 'belief_display'"),
        (("study", "run", str(EXAMPLE), "--port", "0", "--replays-dir", str(tmp_path), "--db", str(sqlite_file)),
         "belongs to study 'another_study', not 'belief_display'"),
        (("study", "export", str(EXAMPLE), "--out", out, "--db", str(sqlite_file), "--database", url),
         "argument --database: not allowed with argument --db"),
        (("study", "run", str(EXAMPLE), "--database", "mysql://me@localhost/study"),
         "a study database is a sqlite:///PATH or postgresql+psycopg://USER@HOST:PORT/DB URL"),
        (("study", "export", str(EXAMPLE), "--out", out, "--db", str(tmp_path / "none.sqlite")),
         "no study database"),
    ]
    for args, message in cases:
        result = colorgrid(*args)
        assert result.returncode == 2 and result.stderr.count("\n") == 1, (args, result.stderr)
        assert message in result.stderr, (args, result.stderr)


# ---------------------------------------------------------------- games, figures and the export
@dataclass
class RecordedGame:
    """What the hub hands the study service: the game's study record, its ids, and the game as a replay."""

    study: dict
    game_id: str
    replay_id: str
    replay: Replay
    finished: bool = True

    def to_replay(self, ended: str, descriptions) -> Replay:
        return self.replay


def play(service: StudyService, pid: str, session: str, replays_dir: Path, seed: int) -> None:
    """The participant's current game, played by an A* leader beside the condition's follower, and saved."""
    settings, meta = service.game_for(pid, session)
    config = env_config(settings.preset, horizon=settings.horizon)
    batch = run_episodes(config, make_policy("astar"), make_policy(settings.follower), 1, seed, record_hashes=True)
    game_id = f"{pid}-{meta['step']}-{meta['attempt']}"
    replay = from_batch(batch, {"leader": {"policy": "human"}, "follower": {"policy": settings.follower}}, "play",
                        meta={"study": meta, "client": {"viewport": [1200, 800], "user_agent": "test"},
                              "deadline_misses": [1] if seed % 2 else []})[0]
    game = RecordedGame(meta, game_id, f"play-{game_id}", replay)
    save(replay, replays_dir / f"{game.replay_id}.replay.json")
    final = replay.final()
    service.game_started(game)
    service.game_over(game, "complete", {"team": final["team_score"], "leader": final["leader_score"],
                                         "follower": final["follower_score"]})


def record_study(database, replays_dir: Path, monkeypatch) -> object:
    """Three participants through a study of four conditions (two to the end, one stopping after a trial), on a clock that
    gives the same times on every run."""
    clock = itertools.count(1_700_000_000.25, 1.5)
    monkeypatch.setattr(service_module, "time", SimpleNamespace(time=lambda: next(clock)))
    study = parse_study(tomllib.loads(SEVERAL_CONDITIONS))
    service = open_service(study, database)
    seeds = itertools.count(3)
    try:
        for pid, pages in (("p-1", None), ("p-2", None), ("p-3", 4)):
            session = service.join({"PROLIFIC_PID": pid, "STUDY_ID": "s"}, None, "test")["session"]
            view = service.view(pid, session)
            while view["kind"] != "debrief" and (pages is None or view["step"] < pages):
                if view.get("game"):
                    play(service, pid, session, replays_dir, next(seeds))
                answers = {q["id"]: {"likert": view["trial_index"] or 1, "choice": (q["options"] or [""])[0]}
                           .get(q["kind"], "fine") for q in view.get("questions", [])}
                view = service.advance(pid, session, view["step"], answers or None, view["kind"] == "consent")
    finally:
        service.store.close()
    return study


def clear_figures(database, study) -> None:
    """Forget the figures stored at the games' ends, as in a database of the time before."""
    store = StudyStore(database, study.id, study_hash(study))
    with store.transaction() as tx:
        tx.conn.execute(update(games).values({c.name: None for c in FIGURE_COLUMNS}))
    store.close()


def test_the_export_from_postgresql_equals_the_export_from_sqlite(postgres, tmp_path, monkeypatch):
    replays_dir = tmp_path / "recordings"
    replays_dir.mkdir()
    exported = {}
    for name, database in (("sqlite", tmp_path / "study.sqlite"), ("postgresql", postgres.new_database())):
        study = record_study(database, replays_dir, monkeypatch)
        exported[name] = tables(study, database, replays_dir)
    assert len(exported["sqlite"]["trials"]) == 2 * 5 + 2 and len(exported["sqlite"]["answers"]) == 2 * 6 + 1
    for table, frame in exported["sqlite"].items():  # (keys and focus come from the replays: none recorded here)
        assert len(frame) > 0 or table in ("keys", "focus", "probes", "statements", "exclusions"), table
        pd.testing.assert_frame_equal(exported["postgresql"][table], frame, obj=table)


def test_the_figures_stored_at_a_games_end_are_those_its_replay_gives(study_database, tmp_path, monkeypatch):
    replays_dir = tmp_path / "recordings"
    replays_dir.mkdir()
    study = record_study(study_database, replays_dir, monkeypatch)
    stored = read_tables(study_database, study.id)["games"]
    assert len(stored) == 12 and all(g["steps"] in (2, 3) for g in stored)
    for g in stored:
        assert {k: g[k] for k in FIGURES} == game_figures(load(replays_dir / f"{g['replay_id']}.replay.json"))
    accuracy = [g["belief_accuracy"] for g in stored]
    assert any(a is None for a in accuracy) and any(a is not None for a in accuracy)  # copy keeps no belief
    trials = tables(study, study_database, replays_dir)["trials"]
    clear_figures(study_database, study)  # the export computes them from the replays, as before
    pd.testing.assert_frame_equal(tables(study, study_database, replays_dir)["trials"], trials)
    summary = open_service(study, study_database).summary(0)
    figures = [arm["trials"] for arm in summary["arms"]]
    assert sum(f["games"] for f in figures) == 9 and all(f.get("team_score") is None for f in figures)


def downgrade_to_version_1(path: Path) -> None:
    """The file as colorgrid wrote it before the figures: no figure columns, schema 1."""
    with sqlite3.connect(path) as db:
        for name in (*SCORES, *FIGURES):
            db.execute(f"ALTER TABLE games DROP COLUMN {name}")
        db.execute("UPDATE meta SET value = '1' WHERE key = 'schema'")


def test_a_version_1_sqlite_file_is_exported_as_before_and_brought_to_version_2(tmp_path, monkeypatch):
    replays_dir, path = tmp_path / "recordings", tmp_path / "study.sqlite"
    replays_dir.mkdir()
    study = record_study(path, replays_dir, monkeypatch)
    current = tables(study, path, replays_dir)
    downgrade_to_version_1(path)
    old = tables(study, path, replays_dir)  # read as it is: the figures from the replays
    for name, frame in current.items():
        pd.testing.assert_frame_equal(old[name], frame, obj=name)
    store = StudyStore(path, study.id, study_hash(study))  # a study opening it brings it to version 2
    store.close()
    with sqlite3.connect(path) as db:
        assert db.execute("SELECT value FROM meta WHERE key = 'schema'").fetchone() == (str(SCHEMA_VERSION),)
        rows = db.execute("SELECT team_score, steps FROM games").fetchall()
    assert all(team is not None and steps is None for team, steps in rows)  # scores from their JSON
    pd.testing.assert_frame_equal(tables(study, path, replays_dir)["trials"], current["trials"])


def test_the_tables_are_read_as_of_one_moment_while_participants_go_on(study_database, monkeypatch):
    study = example_study(None)
    service = open_service(study, study_database)
    service.join({"PROLIFIC_PID": "p1"}, None, "browser")
    game = SimpleNamespace(game_id="g1", study={"participant": "p1", "step": 0, "attempt": 0, "kind": "trial",
                                                "trial_index": 0, "condition_index": 0, "condition": {}})
    read = store_module.rows_of

    def meanwhile(result):  # a game starts between the read of the participants and that of the games
        rows = read(result)
        if rows and "arm" in rows[0] and service.store.last_game("p1", 0) is None:
            service.game_started(game)
        return rows

    monkeypatch.setattr(store_module, "rows_of", meanwhile)
    assert read_tables(study_database, study.id)["games"] == []
    assert len(read_tables(study_database, study.id)["games"]) == 1
