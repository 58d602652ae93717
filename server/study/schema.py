"""The exported tables' columns, declared once: name, type, unit and meaning of every column.

``export_schema(study)`` lists each table's columns for a study (a few depend on it: the
condition factors' levels, the URL parameters kept, the questions, the number of colors).
``server.study.export`` writes every table through ``conform`` (the declared columns, in order,
each cast to its type; a value outside its type or its categories is an error, never a silent
NaN), with the types in the Parquet schema and in ``schema.json`` beside the CSV files;
``read_csv`` and ``read_parquet`` read a table back with them (a table without rows too), and
``check_frame`` / ``check_arrow`` check a table read back against the declaration. docs/STUDIES.md's data dictionary is ``data_dictionary``'s text.

Types (``Column.type``), as pandas dtypes and Arrow types:

| type | pandas | Arrow | missing values |
|---|---|---|---|
| ``int64`` | ``int64`` | ``int64`` | none |
| ``Int64`` | ``Int64`` (nullable) | ``int64`` | ``<NA>`` |
| ``float64`` | ``float64`` | ``double`` | ``NaN`` |
| ``bool`` | ``bool`` | ``bool`` | none |
| ``boolean`` | ``boolean`` (nullable) | ``bool`` | ``<NA>`` |
| ``string`` | ``string`` | ``string`` | ``<NA>`` |
| ``category`` | ``category`` (the declared categories) | ``dictionary<int32, string>`` | ``NaN`` |
| ``timestamp`` | ``datetime64[us, UTC]`` | ``timestamp[us, tz=UTC]`` | ``NaT`` |
"""

from __future__ import annotations

import dataclasses
import json
import typing
from dataclasses import dataclass
from pathlib import Path

import pandas as pd
import pyarrow as pa

from colorgrid.config import AGENTS
from colorgrid.presets import PRESETS, env_config
from server.protocol import GoalView, PageEvent, SeatKind
from server.stated import ProbeKind, ProbeStatus, Via
from server.study.assign import arm_labels
from server.study.config import QUESTION_KINDS, GameSettings, Study

SCHEMA_FILE = "schema.json"
"""The CSV files' types, written beside them."""
FORMAT_VERSION = 4
"""Bumped whenever a column is added, removed or changes type (3: ``keys.game_id``, and each table's ``unique``; 4: the
follower seat: ``condition_seat``, ``_leader``, ``_goal``, ``_probes``, the stated beliefs' columns, ``probes`` and
``statements``)."""


@dataclass(frozen=True)
class Kind:
    pandas: str
    arrow: pa.DataType
    nullable: bool


TYPES: dict[str, Kind] = {
    "int64": Kind("int64", pa.int64(), False),
    "Int64": Kind("Int64", pa.int64(), True),
    "float64": Kind("float64", pa.float64(), True),
    "bool": Kind("bool", pa.bool_(), False),
    "boolean": Kind("boolean", pa.bool_(), True),
    "string": Kind("string", pa.string(), True),
    "category": Kind("category", pa.dictionary(pa.int32(), pa.string()), True),
    "timestamp": Kind("datetime64[us, UTC]", pa.timestamp("us", tz="UTC"), True),
}

GAME_KINDS = ("practice", "trial")
STATUSES = ("active", "completed")
ENDINGS = ("complete", "idle", "quit", "left", "disconnected", "server_shutdown", "stand_in_failed", "server_lost")
"""Why a game ended (``game_over.reason``, or ``server_lost``: its process stopped without saving it); a lost game
(disconnected, server_shutdown, server_lost) is played again."""
KEY_STATUSES = ("applied", "superseded", "ignored", "unapplied", "stated")
PAGE_EVENTS = typing.get_args(PageEvent.model_fields["event"].annotation)


@dataclass(frozen=True)
class Column:
    """One column of an exported table."""

    name: str
    type: str
    """A key of ``TYPES``."""
    unit: str
    """The unit of a number, or what a text holds (empty where none applies)."""
    description: str
    categories: tuple = ()
    """``category``: every value it may take, in order (none for a study that has none: a study without questions
    has no question ids, and its column stays empty)."""

    def __post_init__(self):
        if self.type not in TYPES:
            raise ValueError(f"column {self.name}: type {self.type!r} is not one of {list(TYPES)}")
        if self.categories and self.type != "category":
            raise ValueError(f"column {self.name}: categories are for type 'category' only")

    @property
    def nullable(self) -> bool:
        return TYPES[self.type].nullable

    def pandas_dtype(self):
        if self.type == "category":
            return pd.CategoricalDtype([str(c) for c in self.categories])
        return pd.api.types.pandas_dtype(TYPES[self.type].pandas)

    def arrow_field(self) -> pa.Field:
        meta = {"type": self.type, "unit": self.unit, "description": self.description}
        if self.type == "category":
            meta["categories"] = json.dumps([str(c) for c in self.categories])
        return pa.field(self.name, TYPES[self.type].arrow, nullable=self.nullable, metadata=meta)

    def as_dict(self) -> dict:
        out = {"name": self.name, "type": self.type, "pandas_dtype": TYPES[self.type].pandas,
               "arrow_type": str(TYPES[self.type].arrow), "nullable": self.nullable, "unit": self.unit,
               "description": self.description}
        if self.type == "category":
            out["categories"] = [str(c) for c in self.categories]
        return out


@dataclass(frozen=True)
class Table:
    """An exported table: what a row is, its columns in order, and the columns that name one row."""

    name: str
    row: str
    columns: tuple[Column, ...]
    unique: tuple[str, ...] = ()
    """Columns whose values no two rows share (a table's key); ``conform`` refuses a table that breaks it."""

    @property
    def names(self) -> list[str]:
        return [c.name for c in self.columns]

    def arrow_schema(self, metadata: dict | None = None) -> pa.Schema:
        return pa.schema([c.arrow_field() for c in self.columns], metadata=metadata)


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
        "follower": Column("condition_follower", "category", "name", "the AI follower (the study's followers)",
                           tuple(followers)),
        "show_belief": Column("condition_show_belief", "boolean", "", "whether the follower's belief was shown"),
        "mode": Column("condition_mode", "category", "name", "`realtime` or `turn`", ("realtime", "turn")),
        "preset": Column("condition_preset", "category", "name", "the environment preset", tuple(PRESETS)),
        "horizon": Column("condition_horizon", "Int64", "steps", "steps in the game"),
        "tick_hz": Column("condition_tick_hz", "float64", "steps/s", "steps a second in real time"),
        "seat": Column("condition_seat", "category", "name", "the participant's seat: `leader` (they know the goal) or "
                                                             "`follower` (they assist an AI leader)",
                       tuple(s.value for s in SeatKind)),
        "leader": Column("condition_leader", "category", "name", "the AI leader of the follower seat (the study's "
                                                                 "leaders; a leader's game names the default)",
                         tuple(sorted({g.leader for g in games}))),
        "goal": Column("condition_goal", "category", "name", "the follower seat: whether the goal was `hidden` from "
                                                             "the participant or `shown`",
                       tuple(g.value for g in GoalView)),
        "probes": Column("condition_probes", "category", "plan", "the follower seat: when the game asked what they "
                                                                 "believed (`none`, `steps:10,40`, `random:0.05`)",
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
        Column("kind", "category", "name", "`practice` or `trial`", GAME_KINDS),
        Column("trial_index", "Int64", "index", "the trial (0-based, in play order); empty for practice"),
        *_condition(study, "the game (practice: empty; the `condition_*` columns hold its own settings)"),
        Column("attempt", "int64", "count", "0, then 1, 2... when a game was lost and played again"),
    ]


def stated_figures() -> list[Column]:
    """The trials' columns of a game in the follower seat (``colorgrid_apps.human_follower``'s measures; empty in a
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
                   ", ".join(f"`{e}`" for e in ENDINGS), ENDINGS),
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
            Column("user_agent", "string", "text", "the browser's user agent in this game"))),
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
                   KEY_STATUSES),
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
            Column("question_kind", "category", "name", "`likert`, `choice` or `text`", QUESTION_KINDS),
            Column("likert", "Int64", "point", "a Likert answer: 1 (the lowest point) .. `scale`"),
            Column("scale", "Int64", "points", "a Likert question's number of points"),
            Column("choice", "string", "text", "a choice answer: the option, as shown"),
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
    ]
    return {t.name: t for t in tables}


def questions_metadata(study: Study) -> dict:
    """Every question by page (``after_trial`` for the trials page's): kind, prompt, scale and labels, options."""
    return {("after_trial" if p.kind == "trials" else p.name): [dataclasses.asdict(q) for q in (*p.questions,
                                                                                                  *p.after_each)]
            for p in study.pages if p.questions or p.after_each}


# ---------------------------------------------------------------- writing and checking
def conform(rows: list[dict], table: Table) -> pd.DataFrame:
    """``rows`` as a DataFrame of exactly the declared columns, in order, each of its declared type. A column
    the rows have and the table does not, a missing value in a column that allows none, or a value outside its
    categories raises ``ValueError`` naming the table, the column and the value."""
    extra = sorted({k for r in rows for k in r} - set(table.names))
    if extra:
        raise ValueError(f"{table.name}: columns {extra} are not declared in server/study/schema.py")
    frame = pd.DataFrame(rows, columns=table.names)
    if table.unique:
        repeated = frame[frame.duplicated(list(table.unique), keep=False)]
        if len(repeated):
            first = ", ".join(f"{c}={repeated.iloc[0][c]}" for c in table.unique)
            raise ValueError(f"{table.name}: {len(repeated)} rows share their ({', '.join(table.unique)}), which names "
                             f"one row; the first: {first}")
    out = {}
    for column in table.columns:
        values = frame[column.name]
        if not column.nullable and values.isna().any():
            raise ValueError(f"{table.name}.{column.name}: a missing value in a column of type {column.type}")
        if column.type == "category":
            values = values.map(lambda v: v if v is None or v != v else str(v))
            unknown = sorted(set(values.dropna()) - {str(c) for c in column.categories})
            if unknown:
                raise ValueError(f"{table.name}.{column.name}: {unknown} not among its categories "
                                 f"{list(column.categories)}")
        elif column.type in ("Int64", "int64", "boolean", "bool"):
            values = values.astype(object).where(values.notna(), None)
        out[column.name] = values.astype(column.pandas_dtype())
    return pd.DataFrame(out, columns=table.names)


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


def read_csv(folder: str | Path, name: str) -> pd.DataFrame:
    """A table's CSV file read back with its declared types (from ``schema.json`` beside it)."""
    folder = Path(folder)
    columns = json.loads((folder / SCHEMA_FILE).read_text())["tables"][name]["columns"]
    times = [c["name"] for c in columns if c["type"] == "timestamp"]
    dtypes = {c["name"]: pd.CategoricalDtype(c["categories"]) if c["type"] == "category" else c["pandas_dtype"]
              for c in columns if c["type"] != "timestamp"}
    # only an empty field is missing: a text answer "NA" or "null" stays text
    frame = pd.read_csv(folder / f"{name}.csv", dtype=dtypes, keep_default_na=False, na_values=[""])
    for n in times:
        frame[n] = pd.to_datetime(frame[n], utc=True, format="ISO8601").astype("datetime64[us, UTC]")
    return frame


def read_parquet(folder: str | Path, name: str) -> pd.DataFrame:
    """A table's Parquet file read back with its declared types, as ``read_csv`` reads its CSV file.

    ``pd.read_parquet`` gives them too, but for the categories of a table without rows: Parquet keeps a column's
    dictionary with its values, so a file of no rows holds none. Each category column's field in the file names its
    categories (its ``categories`` metadata), and they are given back here."""
    import pyarrow.parquet as pq

    path = Path(folder) / f"{name}.parquet"
    frame = pd.read_parquet(path)
    for field in pq.read_schema(path):
        named = (field.metadata or {}).get(b"categories")
        if named is not None:
            frame[field.name] = frame[field.name].astype(pd.CategoricalDtype(json.loads(named)))
    return frame


def check_frame(frame: pd.DataFrame, table: Table) -> list[str]:
    """How a DataFrame read back differs from the declaration (empty: it matches)."""
    if list(frame.columns) != table.names:
        return [f"{table.name}: columns {list(frame.columns)} != declared {table.names}"]
    return [f"{table.name}.{c.name}: {frame[c.name].dtype} != declared {c.pandas_dtype()}"
            for c in table.columns if frame[c.name].dtype != c.pandas_dtype()]


def check_arrow(schema: pa.Schema, table: Table) -> list[str]:
    """How an Arrow schema (a Parquet file's) differs from the declaration (empty: it matches)."""
    if schema.names != table.names:
        return [f"{table.name}: columns {schema.names} != declared {table.names}"]
    return [f"{table.name}.{c.name}: {schema.field(c.name).type} != declared {TYPES[c.type].arrow}"
            for c in table.columns if schema.field(c.name).type != TYPES[c.type].arrow]


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
