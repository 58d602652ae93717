"""The study file: what a researcher writes to run a human study (TOML, checked on load).

A study is a list of pages shown in order (consent, instructions, a practice game, the trials,
questionnaires, a debrief), a set of conditions (the product of its factors' levels over the
trial defaults) and an assignment of conditions to participants. ``load_study`` reads a file and
raises ``StudyError`` with the field's place in the file and what is allowed
(``pages[3].questions[0].scale=1 is invalid: a whole number in 2..11``). See docs/STUDIES.md.

The file's questions and checks are declared in ``server.study.questions``, its ``[screening]`` in
``server.study.screening``; this module declares the rest and the study as a whole.
"""

from __future__ import annotations

import dataclasses
import itertools
import re
from dataclasses import dataclass, field
from pathlib import Path

from colorgrid import configkit
from colorgrid.configkit import (ConfigError, check_bool, check_choice, check_int, check_member, check_number,
                                 check_strings, fail)
from colorgrid.enums import Role, SeatFit
from colorgrid.presets import PRESETS
from server.protocol import MAX_HORIZON, GameRequest, GoalView, Mode, Team
from server.stated import PROBE_FORMS, ProbePlan
from server.study.questions import ID_ALLOWED, ID_PATTERN, Question
from server.study.screening import Screening

PAGE_KINDS = ("consent", "instructions", "practice", "trials", "questionnaire", "debrief")
STUDY_MODES = tuple(sorted(Mode))
"""The game modes in the order a study file's messages and its export list them (``realtime``, ``turn``)."""


class StudyError(ConfigError):
    """The study file is wrong; the message names the place in the file and what is allowed."""


@dataclass(frozen=True)
class GameSettings:
    """One game of the study: a trial's condition, or the practice game."""

    follower: str = "bayes-people"
    """The AI follower: any name ``colorgrid play --follower`` takes (``ippo-people``, ``copy``, a ``.pt``)."""
    show_belief: bool = True
    """Whether the participant sees what the follower believes the goal is."""
    mode: Mode = Mode.REALTIME
    """``realtime`` (the world moves ``tick_hz`` steps a second; a 3-2-1 countdown first) or ``turn``."""
    preset: str = "default"
    """The environment preset (``colorgrid presets``)."""
    horizon: int = 100
    """Steps in the game."""
    tick_hz: float = 5.0
    """Steps a second in real time."""
    seat: Role = Role.LEADER
    """The participant's seat: ``leader`` (they know the goal; the AI ``follower`` assists them) or ``follower`` (they
    assist the AI ``leader`` and work out the goal; no AI follower plays)."""
    leader: str = "astar"
    """The follower seat: the AI leader (any name ``colorgrid play --leaders`` takes: ``astar``, ``person:slip=0.1``,
    ``population:people#held_out``, ``ippo-leader``, a ``.pt``)."""
    goal: GoalView = GoalView.HIDDEN
    """The follower seat: whether the goal is ``hidden`` from the participant (their task) or ``shown`` (a control)."""
    probes: str = "none"
    """The follower seat: when the game asks which color is the goal and how sure they are: ``none``,
    ``steps:10,40,70`` or ``random:0.05``."""

    def __post_init__(self):
        if not isinstance(self.follower, str) or not self.follower:
            fail(self, "follower", "a follower name (e.g. 'bayes-people', 'ippo-people', 'copy')")
        from server.settings import yardstick_reason

        if (reason := yardstick_reason(self.follower)) is not None:
            fail(self, "follower", f"a follower a person may play beside ({reason})")
        check_bool(self, "show_belief")
        check_member(self, "mode", STUDY_MODES)
        check_choice(self, "preset", PRESETS, f"one of {sorted(PRESETS)}")
        check_int(self, "horizon", 1, MAX_HORIZON, allowed=f"a whole number in 1..{MAX_HORIZON}")
        check_number(self, "tick_hz", "a number in [0.5, 60]", lambda v: 0.5 <= v <= 60)
        check_member(self, "seat", Role)
        from server.followers import is_leader_kind, leader_kinds_allowed

        if not isinstance(self.leader, str) or not is_leader_kind(self.leader):
            fail(self, "leader", leader_kinds_allowed())
        check_member(self, "goal", GoalView)
        try:
            ProbePlan.parse(self.probes if isinstance(self.probes, str) else None)
        except ValueError:
            fail(self, "probes", PROBE_FORMS)
        if not isinstance(self.probes, str):
            fail(self, "probes", PROBE_FORMS)

    def label(self) -> str:
        return ", ".join(f"{k}={v}" for k, v in dataclasses.asdict(self).items())

    def played(self) -> dict:
        """This game's settings by field, None for those it did not have (``as_played``)."""
        return self.as_played(dataclasses.asdict(self))

    @staticmethod
    def as_played(settings: dict) -> dict:
        """A game's settings (every field, as ``dataclasses.asdict`` gives them: a game's record) with those it did
        not have set to None, so that no default passes for a condition: in the follower seat the AI follower and
        whether its belief was shown (no AI follower plays beside the participant); in a leader's seat the AI leader,
        the goal's visibility and the probes (the follower seat's); turn-based, the clock's ``tick_hz``."""
        out = dict(settings)
        if out["seat"] == Role.FOLLOWER:
            out.update(follower=None, show_belief=None)
        else:
            out.update(leader=None, goal=None, probes=None)
        if out["mode"] != Mode.REALTIME:
            out["tick_hz"] = None
        return out

    def request(self) -> GameRequest:
        """This game as the hub takes it (``GameHub.new_game``), every choice stated by the study file: for the
        follower seat also its AI leader, the goal's visibility and the probes (a leader's seat leaves them unset)."""
        seat = {} if self.seat == Role.LEADER else {"seat": self.seat, "leader": self.leader, "goal": self.goal,
                                                    "probes": self.probes}
        return GameRequest(follower=self.follower, preset=self.preset, mode=self.mode, horizon=self.horizon,
                           show_belief=self.show_belief, **seat)


FACTORS = tuple(f.name for f in dataclasses.fields(GameSettings))
"""What a condition may vary: every field of ``GameSettings`` (a new field is a new factor)."""


@dataclass(frozen=True)
class Page:
    """One page of the study, shown in order."""

    kind: str
    """``consent`` (text and an agree button), ``instructions``, ``practice`` (one game), ``trials`` (every trial
    of the participant's assignment, in its order), ``questionnaire`` or ``debrief`` (the completion code)."""
    id: str = ""
    """A name for the page (questionnaires: the name its answers carry in the export; default: its kind)."""
    title: str = ""
    """The heading shown."""
    text: str = ""
    """Markdown shown on the page (consent, instructions, debrief, or above a questionnaire)."""
    questions: tuple[Question, ...] = ()
    """``questionnaire``: its questions; ``instructions``: its comprehension checks (kind ``check``), asked below
    the instructions, which are shown again after a wrong answer."""
    after_each: tuple[Question, ...] = ()
    """``trials``: questions asked after every trial (answers carry the trial's index)."""
    game: GameSettings | None = None
    """``practice``: its game (default: the trial defaults, belief shown)."""

    def __post_init__(self):
        check_choice(self, "kind", PAGE_KINDS, f"one of {list(PAGE_KINDS)}")
        if not isinstance(self.id, str) or (self.id and not ID_PATTERN.match(self.id)):
            fail(self, "id", ID_ALLOWED)
        for name in ("title", "text"):
            if not isinstance(getattr(self, name), str):
                fail(self, name, "a string")
        if self.kind == "consent" and not self.text.strip():
            fail(self, "text", "the consent text (Markdown), which the participant agrees to")
        if self.kind == "questionnaire" and not self.questions:
            fail(self, "questions", "at least one question for a questionnaire page")
        if self.kind not in ("questionnaire", "instructions") and self.questions:
            fail(self, "questions", "only on a questionnaire or an instructions page (a trials page asks "
                                    "'after_each')")
        if self.kind == "instructions" and any(q.kind != "check" for q in self.questions):
            fail(self, "questions", "only questions of kind 'check' on an instructions page (its comprehension "
                                    "checks)", value=[q.kind for q in self.questions])
        if self.kind != "trials" and self.after_each:
            fail(self, "after_each", "only on the trials page")
        if self.game is not None and self.kind != "practice":
            fail(self, "game", "only on the practice page (trials take their settings from the conditions)")
        for name in ("questions", "after_each"):
            ids = [q.id for q in getattr(self, name)]
            if len(set(ids)) != len(ids):
                fail(self, name, f"questions with distinct ids (got {ids})", value="...")

    @property
    def name(self) -> str:
        return self.id or self.kind


@dataclass(frozen=True)
class Design:
    """How conditions reach participants."""

    assignment: str = "within"
    """``within`` (every participant plays every condition, in a counterbalanced order) or ``between`` (one
    condition per participant)."""
    order: str = "latin_square"
    """``within``: ``latin_square`` (balanced for first-order carry-over: Williams' design), ``random`` (a fresh
    random order each) or ``fixed`` (the conditions' order)."""
    balance: str = "balanced"
    """How an arm (a condition, or an order within subjects) is picked: ``balanced`` (the arm with the fewest
    participants so far, ties at random) or ``random``."""
    trials_per_condition: int = 1
    """Trials of each condition (within: the order is repeated; between: that many trials)."""
    quota: int | None = None
    """At most this many participants per arm (None: no quota)."""
    seed: int = 0
    """Seed of the random choices (ties, random orders)."""

    def __post_init__(self):
        check_choice(self, "assignment", ("within", "between"), "'within' or 'between'")
        check_choice(self, "order", ("latin_square", "random", "fixed"), "'latin_square', 'random' or 'fixed'")
        check_choice(self, "balance", ("balanced", "random"), "'balanced' or 'random'")
        check_int(self, "trials_per_condition", 1, 100, allowed="a whole number in 1..100")
        check_int(self, "quota", 1, optional=True, allowed="a positive whole number, or leave it out")
        check_int(self, "seed", 0, 2**63 - 1, allowed="a whole number >= 0")


@dataclass(frozen=True)
class Exclusions:
    """The rules by which a trial or a participant is excluded from the analysis (``[exclusions]``): applied at
    export into the ``exclusions`` table (a row per rule a trial or a participant breaks, with its evidence), and
    counted per arm on the admin page. Each rule is off when left out; practice games are never excluded."""

    away_s: float | None = None
    """A trial in which the page was hidden or out of focus for more than this many seconds in all."""
    idle_s: float | None = None
    """A trial with a stretch of more than this many seconds without a key (moves, beliefs and probe answers)."""
    round_trip_ms: float | None = None
    """A trial whose median round trip over the play socket, measured during play, was above this many ms."""
    failed_checks: int | None = None
    """A participant who failed at least this many comprehension or attention checks (every try wrong)."""

    def __post_init__(self):
        for name in ("away_s", "idle_s", "round_trip_ms"):
            check_number(self, name, "a number >= 0, or leave it out", lambda v: v >= 0, optional=True)
        check_int(self, "failed_checks", 1, 100, optional=True, allowed="a whole number in 1..100, or leave it out")


@dataclass(frozen=True)
class Study:
    """A whole study file."""

    id: str
    """The study's name: its database and recordings are kept under it."""
    title: str
    """Shown at the top of every page."""
    pages: tuple[Page, ...]
    """The pages, in order; exactly one ``trials`` page."""
    factors: dict = field(default_factory=dict)
    """Condition factors: a field of ``GameSettings`` -> its levels (``follower = ["bayes-people", "ippo-people"]``).
    The conditions are every combination, in the order written."""
    defaults: GameSettings = field(default_factory=GameSettings)
    """Game settings of every trial, where no factor sets them."""
    design: Design = field(default_factory=Design)
    """How conditions are assigned."""
    max_participants: int = 100
    """Participants who may start; the next one is told the study is full."""
    returning: str = "refuse"
    """A participant id that has started, arriving from a browser without its session: ``refuse`` (it cannot
    start over or continue elsewhere) or ``resume`` (it continues where it was). The same browser always
    resumes."""
    id_params: tuple[str, ...] = ("PROLIFIC_PID", "pid")
    """URL parameters holding the participant id, the first present wins (Prolific: ``PROLIFIC_PID``)."""
    keep_params: tuple[str, ...] = ("STUDY_ID", "SESSION_ID")
    """Further URL parameters recorded with the participant (Prolific's study and session ids)."""
    anonymous: bool = False
    """Let a participant without an id in the URL take part (a random id is made)."""
    completion_code: str = ""
    """Shown on the debrief page (and put into ``redirect_url`` as ``{code}``)."""
    redirect_url: str = ""
    """Where the debrief page sends the participant (``https://app.prolific.com/submissions/complete?cc={code}``)."""
    screening: Screening | None = None
    """Who may take part, checked before consent (None: anyone)."""
    exclusions: Exclusions = field(default_factory=Exclusions)
    """The rules by which trials and participants are excluded at export (none by default)."""

    ERROR_STYLE = "{name}={value!r} is invalid: {allowed}"

    def __post_init__(self):
        if not isinstance(self.id, str) or not ID_PATTERN.match(self.id):
            fail(self, "id", ID_ALLOWED)
        if not isinstance(self.title, str) or not self.title.strip():
            fail(self, "title", "a non-empty string")
        if not self.pages:
            fail(self, "pages", "at least one [[pages]] entry", value=[])
        kinds = [p.kind for p in self.pages]
        if kinds.count("trials") != 1:
            fail(self, "pages", f"exactly one page of kind 'trials' (got {kinds.count('trials')})", value=kinds)
        if kinds.count("debrief") > 1 or ("debrief" in kinds and kinds[-1] != "debrief"):
            fail(self, "pages", "at most one 'debrief' page, and it comes last", value=kinds)
        names = [p.name for p in self.pages]
        if len(set(names)) != len(names):
            fail(self, "pages", f"pages with distinct ids (two pages of one kind need an id each: {names})",
                 value=kinds)
        if not isinstance(self.factors, dict):
            fail(self, "factors", "a table: factor = [levels]")
        for name, levels in self.factors.items():
            if name not in FACTORS:
                raise StudyError(f"factors.{name} is not a factor: choose from {list(FACTORS)}", f"factors.{name}")
            if not isinstance(levels, (list, tuple)) or not levels or len(set(map(repr, levels))) != len(levels):
                raise StudyError(f"factors.{name}={levels!r} is invalid: a list of distinct levels",
                                 f"factors.{name}")
            for level in levels:
                try:
                    dataclasses.replace(self.defaults, **{name: level})
                except ConfigError as err:
                    raise StudyError(f"factors.{name}: level {level!r} is invalid: "
                                     f"{str(err).split(': ', 1)[-1]}", f"factors.{name}") from None
        check_int(self, "max_participants", 1, allowed="a positive whole number")
        check_choice(self, "returning", ("refuse", "resume"), "'refuse' or 'resume'")
        check_strings(self, "id_params", distinct=True)
        check_strings(self, "keep_params", distinct=True)
        check_bool(self, "anonymous")
        for name in ("completion_code", "redirect_url"):
            if not isinstance(getattr(self, name), str):
                fail(self, name, "a string")
        if self.redirect_url and not re.match(r"^https?://", self.redirect_url):
            fail(self, "redirect_url", "an http:// or https:// address (with {code} where the code goes)")

    # ---------------------------------------------------------------- derived
    @property
    def conditions(self) -> list[GameSettings]:
        """Every combination of the factors' levels, the first factor varying slowest."""
        names = list(self.factors)
        return [dataclasses.replace(self.defaults, **dict(zip(names, combo)))
                for combo in itertools.product(*(self.factors[n] for n in names))]

    @property
    def trials_page(self) -> Page:
        return next(p for p in self.pages if p.kind == "trials")

    @property
    def leaders(self) -> set[str]:
        """Every AI leader a game of this study uses (the follower seat's)."""
        return set(self.leader_places())

    def leader_places(self) -> dict[str, str]:
        """Every AI leader of a game in the follower seat, with the field of the study file that names it first."""
        places = {}
        for condition in self.conditions:
            if condition.seat == Role.FOLLOWER:
                places.setdefault(condition.leader, "factors.leader" if "leader" in self.factors else "defaults.leader")
        for i, page in enumerate(self.pages):
            game = self.practice_game(page) if page.kind == "practice" else None
            if game is not None and game.seat == Role.FOLLOWER:
                places.setdefault(game.leader, f"pages[{i}].game.leader" if page.game is not None
                                  else "defaults.leader")
        return places

    @property
    def followers(self) -> set[str]:
        """Every follower a game of this study uses."""
        return set(self.follower_places())

    def follower_places(self) -> dict[str, str]:
        """Every follower a game of this study uses, with the field of the study file that names it first:
        ``{"bayes-people": "factors.follower", "copy": "pages[2].game.follower"}``."""
        places = {}
        for condition in self.conditions:
            places.setdefault(condition.follower, "factors.follower" if "follower" in self.factors
                              else "defaults.follower")
        for i, page in enumerate(self.pages):
            if page.kind == "practice":
                places.setdefault(self.practice_game(page).follower,
                                  f"pages[{i}].game.follower" if page.game is not None else "defaults.follower")
        return places

    def practice_game(self, page: Page) -> GameSettings:
        return page.game or dataclasses.replace(self.defaults, show_belief=True)


def check_followers(study: Study, path: str | Path) -> None:
    """Refuse a study whose games name a follower or an AI leader that cannot be loaded (or a leader that cannot lead
    a study's game: a follower's name, a network trained in another team), in one line naming the study file's field
    and what is allowed: ``study.toml: factors.follower: level 'bayes-peple' is invalid: unknown policy
    'bayes-peple'; choose one of [...]``. It builds each one (a network's weights are read): ``study run`` calls it
    before it serves, not ``load_study``."""
    from colorgrid.policies import make_policy
    from server.followers import is_leader_kind, leader_kinds_allowed, leads

    def blame(place: str, name: str, problem: str) -> StudyError:
        what = f"{place}: level {name!r}" if place.startswith("factors.") else f"{place}={name!r}"
        return StudyError(f"{path}: {what} is invalid: {problem}", place)

    for name, place in study.follower_places().items():
        try:
            make_policy(name, role="follower")
        except (ValueError, FileNotFoundError, OSError) as err:
            raise blame(place, name, str(err)) from None
    for name, place in study.leader_places().items():  # a study's games are 1:1
        if not is_leader_kind(name):
            raise blame(place, name, leader_kinds_allowed())
        try:
            make_policy(name, role="leader")
            fit = leads(name, Team.ONE_TO_ONE)
        except (ValueError, FileNotFoundError, OSError) as err:
            raise blame(place, name, str(err)) from None
        if fit != SeatFit.DIRECT:
            raise blame(place, name, "a leader of another team: a study's games are one leader and one follower")


def parse_study(data: dict) -> Study:
    """A ``Study`` from the parsed file (its tables resolved as every config is: ``configkit.resolve``)."""
    try:
        return configkit.resolve(Study, data)
    except ConfigError as err:  # every mistake in the file is a StudyError
        raise StudyError(str(err), err.field) from None


def load_study(path: str | Path) -> Study:
    """Read and check a study file; ``StudyError`` (one line, naming the file) when it is wrong."""
    try:
        return parse_study(configkit.read_toml(path, "study file"))
    except ConfigError as err:
        raise StudyError(f"{path}: {err}") from None
