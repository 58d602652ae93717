"""``colorgrid study export``: a study's database and replays as analysis-ready tables.

Nine tables, each written as Parquet and CSV, of the columns and types declared in
``server.study.schema`` (listed in docs/STUDIES.md, "Data dictionary"):
``participants``, ``trials`` (one row per game played, practice included), ``steps`` (one row
per game step), ``keys`` (the key log with reaction times), ``answers``, ``focus`` (the page's
focus and visibility changes during games), for games in the follower seat ``probes`` (each
probe's answer) and ``statements`` (each stated belief; ``server.study.stated_export``), and
``exclusions`` (each rule of the study's ``[exclusions]`` a trial or a participant breaks, with its
evidence: ``server.study.exclusions``). The database is read through ``server.study.store``
(SQLite or PostgreSQL alike). A game's figures in ``trials`` are those stored when it ended
(``server.study.figures``); games recorded before have them computed from their replays, the same
way. The per-step tables read the replay files back and re-simulate them, so positions come from
the rules, not from what the page showed. Every table carries the participant's arm and the
condition of the row's game or trial, so a ``groupby`` needs no join.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import pandas as pd

from colorgrid.config import AGENTS, FOLLOWER
from colorgrid.replay import load
from colorgrid.replay.simulate import replay_states
from colorgrid.replay.timeline import reaction_times
from server.study.assign import arm_labels, arms
from server.study.config import GameSettings, Study
from server.study.figures import FIGURES, SCORES, game_figures, score_figures
from server.study.columns import SCHEMA_FILE, conform
from server.study.exclusions import attention_figures, exclusion_rows
from server.study.schema import export_schema, questions_metadata, sidecar, write_parquet
from server.study.stated_export import probe_rows, stated_by_step, stated_figures, statement_rows
from server.study.store import read_tables

TABLES = ("participants", "trials", "steps", "keys", "answers", "focus", "probes", "statements", "exclusions")


def _time(seconds) -> pd.Timestamp | None:
    return pd.Timestamp(seconds, unit="s", tz="UTC") if seconds is not None else None


def _condition(study: Study, index: int | None, settings: dict | None = None) -> dict:
    """The ``condition*`` columns: a condition by index, or a game's own settings (practice: no index); a setting
    the game did not have is empty (``GameSettings.as_played``: no AI follower in the follower seat, no clock
    turn-based)."""
    if settings is None:
        settings = study.conditions[index].played() if index is not None else {}
    elif settings:  # a game recorded before a setting existed played its default (the seat: a leader's)
        settings = GameSettings.as_played({**dataclasses.asdict(GameSettings()), **settings})
    return {"condition_index": index, "condition": f"C{index + 1}" if index is not None else None,
            **{f"condition_{k}": v for k, v in settings.items()}}


def numbered_on(seqs: list[int | None]) -> list[int | None]:
    """A game's key numbers (its key log's ``seq``, in arrival order) numbered on across reloads: the server tells a
    page that joins or rejoins a game where its numbers go on (``welcome.next_seq``) and refuses a number already
    used, so these come back unchanged. A game recorded before that has its page's numbers start again at 0 after a
    reload; its later keys are numbered on from the highest before (one page's numbers only grow, so a number that
    does not is a new page's), which makes ``(game_id, seq)`` name one key in every game."""
    out, shift, last = [], 0, None
    for seq in seqs:
        if seq is not None:
            if last is not None and seq + shift <= last:
                shift = last + 1 - seq
            last = seq + shift
        out.append(last if seq is not None else None)
    return out


def tables(study: Study, database: str | Path, replays_dir: Path) -> dict[str, pd.DataFrame]:
    """The nine tables as pandas DataFrames, each of the columns and types ``export_schema`` declares.
    ``database``: the study's SQLite file or its URL (``server.study.store.database_url``)."""
    data = read_tables(database, study.id)
    labels, arm_list = arm_labels(study), arms(study)
    between = study.design.assignment == "between"
    people = {p["pid"]: p for p in data["participants"]}

    def who(pid: str) -> dict:
        arm = people[pid]["arm"] if pid in people else None
        return {"participant": pid, "arm": arm, "arm_label": labels[arm] if arm is not None and 0 <= arm < len(labels)
                else None}

    def own_condition(pid: str) -> int | None:
        """The participant's one condition (between subjects), else None."""
        arm = people[pid]["arm"] if pid in people else None
        return arm_list[arm][0] if between and arm is not None and 0 <= arm < len(arm_list) else None

    participants = [{
        **who(p["pid"]), **_condition(study, own_condition(p["pid"])),
        "conditions": json.dumps(json.loads(p["conditions"])), "status": p["status"], "step": p["step"],
        **{f"url_{k}": v for k, v in json.loads(p["url_params"]).items()},
        "user_agent": p["user_agent"], "started": _time(p["started"]), "completed": _time(p["completed"]),
        "minutes": (p["completed"] - p["started"]) / 60 if p["completed"] else None,
    } for p in data["participants"]]
    trials, steps, keys, focus, probes, statements = [], [], [], [], [], []
    for g in data["games"]:
        base = {**who(g["pid"]), "kind": g["kind"], "trial_index": g["trial_index"],
                **_condition(study, g["condition"], json.loads(g["settings"])), "attempt": g["attempt"]}
        row = {**base, "page_step": g["step"], "game_id": g["game_id"], "replay_id": g["replay_id"],
               "ended": g["ended"], "started": _time(g["started"]), "finished": _time(g["finished"])}
        stored = g.get("steps") is not None  # the figures written at the game's end (schema version 2)
        path = replays_dir / f"{g['replay_id']}.replay.json" if g["replay_id"] else None
        replay = load(path) if path is not None and path.is_file() else None
        if stored:
            figures = {name: g.get(name) for name in (*SCORES, *FIGURES)}
            if g.get("away_s") is None and replay is not None:  # stored before the attention figures (schema 2)
                figures.update(attention_figures(replay))
        else:  # a game recorded before: its figures from the replay, as it was exported then
            scores = score_figures(json.loads(g["scores"]) if g["scores"] else None)
            figures = {**scores, **(game_figures(replay) if replay is not None else {})}
        trials.append({**row, **figures, **stated_figures(replay), "replay_found": replay is not None})
        if replay is None:
            continue
        follower = AGENTS[FOLLOWER]
        beliefs = replay.goal_probs.get(follower) or []
        states = replay_states(replay, path)
        stated = stated_by_step(replay)  # the follower seat's stated color at each step
        for t in range(replay.num_steps):
            pos = states[t].agent_pos[0]
            step = {**base, "t": t, "goal": replay.goal[t], "goal_switched": bool(replay.goal_switched[t]),
                    "team_reward": replay.team_reward[t]}
            for i, name in enumerate(AGENTS):
                step[f"{name}_row"], step[f"{name}_col"] = int(pos[i][0]), int(pos[i][1])
                step[f"{name}_action"] = replay.actions[t][i]
                step[f"{name}_reward"] = replay.block_reward[t][i]
                step[f"{name}_picked"] = replay.picked_color[t][i]
            for c, p in enumerate(beliefs[t] if t < len(beliefs) else []):
                step[f"belief_{c}"] = p
            step["stated_belief"] = stated[t]
            steps.append(step)
        logged = reaction_times(replay.key_events or [], replay.meta.get("state_sent_ms"))
        for k, seq in zip(logged, numbered_on([k.get("seq") for k in logged])):
            keys.append({**base, "game_id": g["game_id"], "seq": seq, "key": k.get("key"), "action": k.get("action"),
                         "color": k.get("color"),
                         "status": k.get("status"), "applied_step": k.get("applied_step"),
                         "t_client_ms": k.get("t_client"), "t_server_ms": k.get("t_server"),
                         "shown_step": k.get("shown_step"), "reaction_ms": k.get("reaction_ms")})
        for e in replay.meta.get("page_events", []):
            focus.append({**base, "event": e["event"], "visible": e.get("visible"), "step": e.get("step"),
                          "t_client_ms": e.get("t_client"), "t_server_ms": e.get("t_server")})
        probes += probe_rows(replay, base, g["game_id"])
        statements += statement_rows(replay, base, g["game_id"])
    questions = {(page, q["id"]): q for page, qs in questions_metadata(study).items() for q in qs}
    answers, checks = [], []
    for a in data["answers"]:
        q = questions.get((a["page"], a["question"]), {})
        value = json.loads(a["value"]) if a["value"] is not None else None
        kind = q.get("kind")
        if a["trial_index"] is not None and a["pid"] in people:
            condition = json.loads(people[a["pid"]]["conditions"])[a["trial_index"]]
        else:
            condition = own_condition(a["pid"])
        answers.append({**who(a["pid"]), "page": a["page"], "trial_index": a["trial_index"],
                        **_condition(study, condition), "question": a["question"], "question_kind": kind,
                        "correct": value == q["answer"] if kind == "check" else None,
                        "likert": value if kind == "likert" else None,
                        "scale": q["scale"] if kind == "likert" else None,
                        "choice": value if kind in ("choice", "check") else None,
                        "text": value if kind == "text" else None, "answered": _time(a["answered"])})
        if kind == "check":
            checks.append({"participant": a["pid"], "page": a["page"], "question": a["question"], "answer": value})
    exclusions = [{**who(row["participant"]), **row,
                   "condition": f"C{row['condition_index'] + 1}" if row["condition_index"] is not None else None}
                  for row in exclusion_rows(study, trials, checks)]
    schema = export_schema(study)
    rows = {"participants": participants, "trials": trials, "steps": steps, "keys": keys, "answers": answers,
            "focus": focus, "probes": probes, "statements": statements, "exclusions": exclusions}
    return {name: conform(rows[name], schema[name]) for name in TABLES}


def write_tables(study: Study, database: str | Path, replays_dir: Path, out: Path) -> dict[str, int]:
    """Write every table as ``out/NAME.parquet`` (its types in its schema) and ``out/NAME.csv`` (its types in
    ``out/schema.json``, read back by ``server.study.schema.read_csv``); returns the row counts. ``database``:
    the study's SQLite file or its URL."""
    frames = tables(study, database, replays_dir)
    out.mkdir(parents=True, exist_ok=True)
    schema = export_schema(study)
    counts = {}
    for name, frame in frames.items():
        write_parquet(frame, study, schema[name], out / f"{name}.parquet")
        frame.to_csv(out / f"{name}.csv", index=False)
        counts[name] = len(frame)
    (out / SCHEMA_FILE).write_text(json.dumps(sidecar(study), indent=1, ensure_ascii=False) + "\n", encoding="utf-8")
    return counts
