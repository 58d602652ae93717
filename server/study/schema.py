"""The exported tables' columns, declared once: name, type, unit and meaning of every column.

``export_schema(study)`` lists each table's columns for a study (a few depend on it: the
condition factors' levels, the URL parameters kept, the questions, the number of colors).
``server.study.export`` writes every table through ``server.study.columns.conform``, with the types in the Parquet
schema and in ``schema.json`` (``sidecar``) beside the CSV files; ``server.study.columns`` reads them back and checks
them. The categories of endings, key statuses and game kinds are ``colorgrid.enums``'s, in its order.
docs/STUDIES.md's data dictionary is ``data_dictionary``'s text.
"""

from __future__ import annotations

import dataclasses
import json
import typing
from pathlib import Path

import pandas as pd
import pyarrow as pa

from colorgrid.config import AGENTS
from colorgrid.enums import Ending, GameKind, KeyStatus, Role
from colorgrid.presets import PRESETS, env_config
from server.protocol import GoalView, PageEvent
from server.stated import ProbeKind, ProbeStatus, Via
from server.study.assign import arm_labels
from server.study.columns import Column, Table
from server.study.config import STUDY_MODES, GameSettings, Study
from server.study.exclusions import RULES
from server.study.questions import QUESTION_KINDS

FORMAT_VERSION = 5
"""Bumped whenever a column is added, removed or changes type (3: ``keys.game_id``, and each table's ``unique``; 4: the
follower seat: ``condition_seat``, ``_leader``, ``_goal``, ``_probes``, the stated beliefs' columns, ``probes`` and
``statements``; 5: screening and exclusions: ``trials.away_s``, ``idle_s``, ``round_trip_ms``, ``answers.correct``
and the ``exclusions`` table)."""
STATUSES = ("active", "completed")
"""A participant's status."""
PAGE_EVENTS = typing.get_args(PageEvent.model_fields["event"].annotation)


# ---------------------------------------------------------------- the declaration
def _who(study: Study) -> list[Column]:
    """The participant and their assignment: in every table, so that a ``groupby`` needs no join."""
    return [
        Column("participant", "string", "id", "the participant id from the study link"),
        Column("arm", "int64", "index", "the participant's arm (0-based): a condition (between subjects) or an "
                                        "order of conditions (within subjects)"),
        Column("arm_label", "category", "label", "the arm as conditions: `C2`, or `C1 → C2 → C4 → C3`",
               tuple(arm_labels(study))),
    ]


def _condition(study: Study, whose: str) -> list[Column]:
    """The condition and its settings; ``whose`` says which row's condition it is."""
    followers = sorted(study.followers)
    labels = tuple(f"C{i + 1}" for i in range(len(study.conditions)))
    games = study.conditions + [study.practice_game(p) for p in study.pages if p.kind == "practice"]
    settings = {
        "follower": Column("condition_follower", "category", "name",
                           "the AI follower (the study's followers); empty in the follower seat, where none plays",
                           tuple(followers)),
        "show_belief": Column("condition_show_belief", "boolean", "",
                              "whether the follower's belief was shown; empty in the follower seat"),
        "mode": Column("condition_mode", "category", "name", " or ".join(f"`{m}`" for m in STUDY_MODES),
                       tuple(m.value for m in STUDY_MODES)),
        "preset": Column("condition_preset", "category", "name", "the environment preset", tuple(PRESETS)),
        "horizon": Column("condition_horizon", "Int64", "steps", "steps in the game"),
        "tick_hz": Column("condition_tick_hz", "float64", "steps/s", "steps a second in real time; empty turn-based"),
        "seat": Column("condition_seat", "category", "name", "the participant's seat: `leader` (they know the goal) or "
                                                             "`follower` (they assist an AI leader)",
                       tuple(s.value for s in Role)),
        "leader": Column("condition_leader", "category", "name", "the AI leader of the follower seat (the study's "
                                                                 "leaders); empty in a leader's seat",
                         tuple(sorted({g.leader for g in games}))),
        "goal": Column("condition_goal", "category", "name", "the follower seat: whether the goal was `hidden` from "
                                                             "the participant or `shown`; empty in a leader's seat",
                       tuple(g.value for g in GoalView)),
        "probes": Column("condition_probes", "category", "plan", "the follower seat: when the game asked what they "
                                                                 "believed (`none`, `steps:10,40`, `random:0.05`); "
                                                                 "empty in a leader's seat",
                         tuple(sorted({g.probes for g in games}))),
    }
    missing = {f.name for f in dataclasses.fields(GameSettings)} ^ set(settings)
    assert not missing, f"declare the exported column of GameSettings field(s) {sorted(missing)}"
    return [Column("condition_index", "Int64", "index", f"the condition (0-based) of {whose}"),
            Column("condition", "category", "label", "the same condition as `C1`, `C2`, ... (the admin page's names)",
                   labels),
            *settings.values()]


def _game(study: Study) -> list[Column]:
    """Which game of the participant a row belongs to."""
    return [
        Column("kind", "category", "name", " or ".join(f"`{k}`" for k in GameKind), tuple(GameKind)),
        Column("trial_index", "Int64", "index", "the trial (0-based, in play order); empty for practice"),
        *_condition(study, "the game (practice: empty; the `condition_*` columns hold its own settings)"),
        Column("attempt", "int64", "count", "0, then 1, 2... when a game was lost and played again"),
    ]


def stated_figures() -> list[Column]:
    """The trials' columns of a game in the follower seat (``colorgrid.replay.human_follower``'s measures; empty in a
    leader's game)."""
    return [
        Column("stated_steps", "Int64", "steps", "the follower seat: steps at which the participant had said which "
                                                 "color they believe is the goal"),
        Column("stated_accuracy", "float64", "fraction", "the follower seat: the share of those steps whose stated "
                                                         "color was the goal"),
        Column("switches", "Int64", "count", "the follower seat: goal switches in the game"),
        Column("switch_lag_median", "float64", "steps", "the follower seat: the median steps from a goal switch until "
                                                        "the stated color was the new goal (switches caught)"),
        Column("probes_asked", "Int64", "count", "the follower seat: probes asked"),
        Column("probes_answered", "Int64", "count", "the follower seat: probes answered (and scored)"),
        Column("probe_log_loss", "float64", "nats", "the follower seat: the answers' mean log-loss"),
        Column("probe_brier", "float64", "score", "the follower seat: the answers' mean Brier score"),
    ]


def num_colors(study: Study) -> int:
    """The most block colors of any game of the study (the ``belief_K`` columns)."""
    games = study.conditions + [study.practice_game(p) for p in study.pages if p.kind == "practice"]
    return max(env_config(g.preset).num_colors for g in games)


def question_ids(study: Study) -> tuple[str, ...]:
    return tuple(dict.fromkeys(q.id for p in study.pages for q in (*p.questions, *p.after_each)))


def answer_pages(study: Study) -> tuple[str, ...]:
    return tuple(dict.fromkeys("after_trial" if p.kind == "trials" else p.name for p in study.pages
                               if p.questions or p.after_each))


def export_schema(study: Study) -> dict[str, Table]:
    """Every exported table of ``study``, in the order written."""
    who, game = _who(study), _game(study)
    url = [Column(f"url_{name}", "string", "text", f"the link's `{name}` parameter")
           for name in dict.fromkeys((*study.id_params, *study.keep_params))]
    ms = "ms since the epoch"
    per_agent = [column for name in AGENTS for column in (
        Column(f"{name}_row", "int64", "cell", f"the {name}'s row before the step (0 = top)"),
        Column(f"{name}_col", "int64", "cell", f"the {name}'s column before the step (0 = left)"),
        Column(f"{name}_action", "int64", "action", f"the {name}'s action: 0 up, 1 down, 2 left, 3 right, 4 stay"),
        Column(f"{name}_reward", "float64", "points", f"the {name}'s reward this step"),
        Column(f"{name}_picked", "int64", "color", f"the color the {name} collected (-1: none)"))]
    beliefs = [Column(f"belief_{k}", "float64", "probability", f"the follower's probability of color {k} when it "
                                                               "acted (empty: the follower has no belief)")
               for k in range(num_colors(study))]
    tables = [
        Table("participants", "one row per participant", unique=("participant",), columns=(
            *who,
            *_condition(study, "the participant between subjects (within subjects: empty, each trial has its "
                               "own)"),
            Column("conditions", "string", "JSON", "the condition index of each trial, in play order (a JSON list)"),
            Column("status", "category", "name", "`active` or `completed`", STATUSES),
            Column("step", "int64", "index", "the page they are on (0-based, over their expanded pages)"),
            *url,
            Column("user_agent", "string", "text", "the browser's user agent when they joined"),
            Column("started", "timestamp", "UTC", "when they joined"),
            Column("completed", "timestamp", "UTC", "when they finished (empty while active)"),
            Column("minutes", "float64", "minutes", "from start to completion"))),
        Table("trials", "one row per game played, practice included", unique=("game_id",), columns=(
            *who, *game,
            Column("page_step", "int64", "index", "the page the game was played on"),
            Column("game_id", "string", "id", "the server's game id"),
            Column("replay_id", "string", "id", "the game's replay (`recordings/STUDY_ID/REPLAY_ID.replay.json`)"),
            Column("ended", "category", "name", "why the game ended (empty while it runs): " +
                   ", ".join(f"`{e}`" for e in Ending), tuple(Ending)),
            Column("started", "timestamp", "UTC", "when the game started"),
            Column("finished", "timestamp", "UTC", "when it ended"),
            Column("team_score", "float64", "points", "the team's score at the end"),
            Column("leader_score", "float64", "points", "the participant's (the leader's) score"),
            Column("follower_score", "float64", "points", "the AI follower's score"),
            Column("replay_found", "bool", "", "whether the replay file was found (the steps, keys and focus tables "
                                              "need it; the columns below are stored when the game ends, and read "
                                              "from the replay for games recorded before)"),
            Column("steps", "Int64", "steps", "steps played"),
            Column("follower_goal_pickups", "Int64", "blocks", "goal-colored blocks the follower collected"),
            Column("follower_wrong_pickups", "Int64", "blocks", "blocks of another color the follower collected"),
            Column("follower_net_pickups", "Int64", "blocks", "goal pickups minus wrong pickups, the follower's"),
            Column("leader_goal_pickups", "Int64", "blocks", "goal-colored blocks the participant collected"),
            Column("leader_wrong_pickups", "Int64", "blocks", "blocks of another color the participant collected"),
            Column("belief_accuracy", "float64", "fraction", "the share of steps where the follower's most probable "
                                                              "color was the goal (empty: no belief)"),
            Column("deadline_misses", "Int64", "steps", "steps where the follower missed the server's inference "
                                                         "deadline and stayed"),
            *stated_figures(),
            Column("viewport", "string", "JSON", "the page's `[width, height]` in CSS pixels"),
            Column("user_agent", "string", "text", "the browser's user agent in this game"),
            Column("away_s", "float64", "s", "seconds the page was hidden or out of focus during the game, in all "
                                             "(the `focus` table's changes, by the server's clock)"),
            Column("idle_s", "float64", "s", "the longest stretch of the game without a key, a stated belief or a "
                                             "probe's answer, by the server's clock"),
            Column("round_trip_ms", "float64", "ms", "the median round trip the page measured over its socket during "
                                                     "the game (empty: none measured)"))),
        Table("steps", "one row per step of every game, re-simulated from its replay", (
            *who, *game,
            Column("t", "int64", "step", "the step (0-based)"),
            Column("goal", "int64", "color", "the goal color during the step"),
            Column("goal_switched", "bool", "", "whether the goal switched at the end of this step"),
            Column("team_reward", "float64", "points", "the team's reward this step"),
            *per_agent, *beliefs,
            Column("stated_belief", "Int64", "color", "the follower seat: the color the participant had said they "
                                                      "believe is the goal when they moved (empty: none said yet, or "
                                                      "a leader's game)"))),
        Table("keys", "one row per key the participant pressed during a game", unique=("game_id", "seq"), columns=(
            *who, *game,
            Column("game_id", "string", "id", "the server's game id (as in `trials`)"),
            Column("seq", "Int64", "count", "the key's number in its game: 0, 1, 2... in the order pressed, across "
                                            "reloads and reconnects (the server tells the page where to go on)"),
            Column("key", "string", "key", "the key (`ArrowUp`, `w`, ...)"),
            Column("action", "Int64", "action", "its action: 0 up, 1 down, 2 left, 3 right"),
            Column("color", "Int64", "color", "the follower seat: the color a number key said is the goal"),
            Column("status", "category", "name", "`applied`; `superseded` (another key came before the step); "
                                                 "`ignored`; `unapplied` (pressed after the game's last step); "
                                                 "`stated` (a number key: a belief, not a move)",
                   tuple(KeyStatus)),
            Column("applied_step", "Int64", "step", "the step it moved the participant in"),
            Column("t_client_ms", "float64", ms, "when it was pressed, by the participant's clock"),
            Column("t_server_ms", "float64", ms, "when it reached the server, by the server's clock"),
            Column("shown_step", "Int64", "step", "the state on screen when it arrived"),
            Column("reaction_ms", "float64", "ms", "from that state being sent to the key arriving, network "
                                                   "included"))),
        Table("answers", "one row per question answered or skipped", (
            *who,
            Column("page", "category", "name", "the questionnaire's id, or `after_trial`", answer_pages(study)),
            Column("trial_index", "Int64", "index", "for `after_trial`: the trial the answer is about"),
            *_condition(study, "the trial the answer is about (other pages: the participant's between subjects, "
                               "else empty)"),
            Column("question", "category", "id", "the question's id in the study file", question_ids(study)),
            Column("question_kind", "category", "name", "`likert`, `choice`, `text` or `check` (a comprehension "
                                                        "or attention check)", QUESTION_KINDS),
            Column("correct", "boolean", "", "a check: whether the answer kept was the right one (wrong: every try "
                                             "was wrong)"),
            Column("likert", "Int64", "point", "a Likert answer: 1 (the lowest point) .. `scale`"),
            Column("scale", "Int64", "points", "a Likert question's number of points"),
            Column("choice", "string", "text", "a choice or check answer: the option, as shown (a check's: the "
                                               "last one tried)"),
            Column("text", "string", "text", "a free-text answer"),
            Column("answered", "timestamp", "UTC", "when the page was sent"))),
        Table("focus", "one row per focus or visibility change of the page during a game", (
            *who, *game,
            Column("event", "category", "name", "`blur`, `focus` or `visibilitychange`", PAGE_EVENTS),
            Column("visible", "boolean", "", "whether the page was visible"),
            Column("step", "Int64", "step", "the game's step at that moment"),
            Column("t_client_ms", "float64", ms, "by the participant's clock"),
            Column("t_server_ms", "float64", ms, "by the server's clock"))),
        Table("probes", "one row per probe asked in the follower seat (\"which color is the goal now, and how sure "
                        "are you?\")", unique=("game_id", "probe"), columns=(
            *who, *game,
            Column("game_id", "string", "id", "the server's game id (as in `trials`)"),
            Column("probe", "int64", "index", "the probe's number in its game (0, 1, 2...)"),
            Column("step", "int64", "step", "the state that asked it"),
            Column("trigger", "category", "name", "`steps` (a step set in advance) or `random`",
                   tuple(k.value for k in ProbeKind if k != ProbeKind.NONE)),
            Column("status", "category", "name", "`answered`; `missed` (real time: the next probe came first); "
                                                 "`unanswered` (the game ended first)",
                   tuple(s.value for s in ProbeStatus if s != ProbeStatus.OPEN)),
            Column("color", "Int64", "color", "the color answered"),
            Column("confidence", "float64", "probability", "how sure: the probability given to that color, from "
                                                           "1 / colors (a guess) to 1 (certain)"),
            Column("answered_step", "Int64", "step", "the state on screen when the answer arrived (real time goes on)"),
            Column("goal", "Int64", "color", "the goal at that step (empty: answered after the last step)"),
            Column("correct", "boolean", "", "whether the color answered was that goal"),
            Column("log_loss", "float64", "nats", "-log of the probability the answer gave the goal (its confidence on "
                                                  "the color, the rest shared by the others; clipped at 1e-6)"),
            Column("brier", "float64", "score", "the answer's squared distance to the one-hot goal, summed over "
                                                "colors"),
            Column("response_ms", "float64", "ms", "from the question going out to the answer arriving, network "
                                                   "included"),
            Column("refused", "int64", "count", "answers refused (out of range) before this one"),
            Column("asked_ms", "float64", ms, "when it was asked, by the server's clock"),
            Column("answered_ms", "float64", ms, "when the answer arrived, by the server's clock"),
            Column("t_client_ms", "float64", ms, "when it was answered, by the participant's clock"))),
        Table("statements", "one row per belief the participant stated in the follower seat (a number key, a click "
                            "on a color, a probe's answer)", columns=(
            *who, *game,
            Column("game_id", "string", "id", "the server's game id (as in `trials`)"),
            Column("color", "int64", "color", "the color they said is the goal"),
            Column("via", "category", "name", "`key`, `click` or `probe`", tuple(v.value for v in Via)),
            Column("step", "int64", "step", "the state on screen"),
            Column("goal", "Int64", "color", "the goal at that step (empty: after the last step)"),
            Column("t_client_ms", "float64", ms, "by the participant's clock"),
            Column("t_server_ms", "float64", ms, "by the server's clock"))),
        Table("exclusions", "one row per exclusion rule (`[exclusions]` in the study file) a trial or a participant "
                            "breaks: a trial's rules name its game, a participant's (failed checks) none",
              unique=("participant", "game_id", "rule"), columns=(
            *who,
            Column("game_id", "string", "id", "the trial's game (as in `trials`); empty: the participant is excluded"),
            Column("trial_index", "Int64", "index", "the trial (0-based, in play order); empty for a participant"),
            Column("condition_index", "Int64", "index", "the trial's condition (0-based); empty for a participant"),
            Column("condition", "category", "label", "the same condition as `C1`, `C2`, ...",
                   tuple(f"C{i + 1}" for i in range(len(study.conditions)))),
            Column("rule", "category", "name", "`away` (`away_s`), `idle` (`idle_s`), `round_trip` (`round_trip_ms`) "
                                               "or `failed_checks`", RULES),
            Column("value", "float64", "s, ms or checks", "the evidence: the trial's `away_s`, `idle_s` or "
                                                          "`round_trip_ms`, or the checks failed"),
            Column("threshold", "float64", "s, ms or checks", "the rule's setting: excluded above it (checks: at it "
                                                              "or above)"),
            Column("evidence", "string", "text", "the same in words (a failed check: its page, question, the answer "
                                                 "kept and the right one)"))),
    ]
    return {t.name: t for t in tables}


def questions_metadata(study: Study) -> dict:
    """Every question by page (``after_trial`` for the trials page's): kind, prompt, scale and labels, options."""
    return {("after_trial" if p.kind == "trials" else p.name): [dataclasses.asdict(q) for q in (*p.questions,
                                                                                                  *p.after_each)]
            for p in study.pages if p.questions or p.after_each}


# ---------------------------------------------------------------- writing
def metadata(study: Study, table: Table) -> dict:
    """What ``schema.json`` (and each Parquet file's ``colorgrid`` metadata) holds for ``table``."""
    out = {"row": table.row, "unique": list(table.unique), "columns": [c.as_dict() for c in table.columns]}
    if table.name == "answers":
        out["questions"] = questions_metadata(study)
    return out


def sidecar(study: Study) -> dict:
    """``schema.json``: every table's columns and types, for reading the CSV files back."""
    return {"format": "colorgrid-study-export", "version": FORMAT_VERSION, "study": study.id,
            "tables": {name: metadata(study, table) for name, table in export_schema(study).items()}}


def write_parquet(frame: pd.DataFrame, study: Study, table: Table, path: Path) -> None:
    import pyarrow.parquet as pq

    arrow = pa.Table.from_pandas(frame, schema=table.arrow_schema(), preserve_index=False)
    extra = {b"colorgrid": json.dumps({"study": study.id, "version": FORMAT_VERSION, "table": table.name,
                                       **metadata(study, table)}).encode()}
    pq.write_table(arrow.replace_schema_metadata({**arrow.schema.metadata, **extra}), path)


# ---------------------------------------------------------------- the data dictionary
def data_dictionary(study: Study) -> str:
    """The tables' columns as Markdown (docs/STUDIES.md, for the example study)."""
    parts = []
    for table in export_schema(study).values():
        key = f" No two rows share {' and '.join(f'`{c}`' for c in table.unique)}." if table.unique else ""
        parts.append(f"**{table.name}**: {table.row}.{key}\n\n| column | type | unit | meaning |\n|---|---|---|---|")
        for c in table.columns:
            parts[-1] += f"\n| `{c.name}` | {c.type} | {c.unit} | {c.description} |"
    return "\n\n".join(parts) + "\n"
