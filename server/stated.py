"""What a person in the follower seat says they believe the goal is: statements, probes, and their record.

**Statements.** At any moment the person may say which color they believe is the goal: a number key (``1`` is the
first color) or a click on a color's swatch. The latest one is their *stated belief*; the replay records, for every
step, the stated belief when the step's moves were made (``steps.stated_belief``), and every statement in the order
made (``belief_events``).

**Probes.** At steps set in advance or drawn at random (``ProbePlan``) the game asks "which color is the goal now, and
how sure are you?". A probe opens with the state of its step; in turn-based play the world waits for the answer, in
real time the clock goes on. The answer (a color and a confidence: the probability the person gives that color, from
chance to 1) is also a statement. A probe still open when the next one opens is ``missed``; one open when the game
ends is ``unanswered``. Each probe is recorded with its answer, its confidence and its response time (``probes``).

See docs/SERVER_PROTOCOL.md ("The follower seat") and docs/REPLAY_FORMAT.md.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field
from enum import StrEnum

import numpy as np

from colorgrid.config import EnvConfig
from server.protocol import MAX_HORIZON


class ProbeKind(StrEnum):
    """When a game asks its probes."""

    NONE = "none"
    STEPS = "steps"
    RANDOM = "random"

    @property
    def label(self) -> str:
        """How a page names the kind."""
        return {ProbeKind.NONE: "no questions", ProbeKind.STEPS: "at set steps",
                ProbeKind.RANDOM: "at random steps"}[self]


class ProbeStatus(StrEnum):
    """How a probe ended."""

    OPEN = "open"
    ANSWERED = "answered"
    MISSED = "missed"  # the next probe opened first (real time)
    UNANSWERED = "unanswered"  # the game ended first


class Via(StrEnum):
    """How a statement was made."""

    KEY = "key"
    CLICK = "click"
    PROBE = "probe"


PROBE_FORMS = "'none', 'steps:T1,T2,...' (steps 1..1000) or 'random:P' (each step with probability P in (0, 1])"
"""The written forms of a ``ProbePlan``, for error messages."""
PROBE_STREAM = 0x9E0B
"""Mixed into a game's seed for its random probe steps (so a replay's probe steps follow from its seed)."""


@dataclass(frozen=True)
class ProbePlan:
    """When a game asks its probes: never, at the given steps, or at each step with probability ``rate``. Written as
    text everywhere it is chosen (a ``new_game``, a study file): ``none``, ``steps:10,40,70``, ``random:0.05``."""

    kind: ProbeKind = ProbeKind.NONE
    steps: tuple[int, ...] = ()
    """``steps``: the steps whose state asks (1..``MAX_HORIZON``; a step past a game's last is never reached)."""
    rate: float = 0.0
    """``random``: each step from 1 on asks with this probability."""

    @classmethod
    def parse(cls, text: str | None) -> ProbePlan:
        """A plan from its text (None: none); ``ValueError`` naming the text and the forms allowed."""
        if text is None or text.strip() == ProbeKind.NONE.value:
            return cls()
        head, _, rest = text.strip().partition(":")
        try:
            if head == ProbeKind.STEPS.value:
                steps = tuple(sorted({int(part) for part in rest.split(",")}))
                if steps and all(1 <= s <= MAX_HORIZON for s in steps):
                    return cls(ProbeKind.STEPS, steps=steps)
            elif head == ProbeKind.RANDOM.value:
                rate = float(rest)
                if 0 < rate <= 1:
                    return cls(ProbeKind.RANDOM, rate=rate)
        except ValueError:
            pass
        raise ValueError(f"probes {text!r} is not a probe plan: {PROBE_FORMS}")

    @property
    def text(self) -> str:
        """The plan as written (``parse`` reads it back)."""
        if self.kind == ProbeKind.STEPS:
            return f"steps:{','.join(map(str, self.steps))}"
        return f"random:{self.rate:g}" if self.kind == ProbeKind.RANDOM else ProbeKind.NONE.value

    def schedule(self, horizon: int, seed: int) -> tuple[int, ...]:
        """The steps (1..horizon-1: a state the person acts on) whose state opens a probe, in a game of ``horizon``
        steps seeded ``seed``."""
        if self.kind == ProbeKind.STEPS:
            return tuple(s for s in self.steps if s < horizon)
        if self.kind == ProbeKind.RANDOM:
            draws = np.random.default_rng([seed, PROBE_STREAM]).random(horizon)
            return tuple(int(t) for t in np.flatnonzero(draws < self.rate) if t >= 1)
        return ()


class StatementError(ValueError):
    """A statement or probe answer that cannot be taken; ``code`` is the protocol's error code. Nothing is recorded
    and the game goes on (an open probe stays open)."""

    def __init__(self, code: str, message: str):
        super().__init__(message)
        self.code = code


def confidence_floor(num_colors: int) -> float:
    """The lowest confidence an answer may give: chance, 1 / colors (the stated color is the person's best guess)."""
    return 1.0 / num_colors


@dataclass
class Probe:
    """One probe: when it was asked and how it was answered (the replay's ``probes`` entry)."""

    id: int
    step: int  # the state that asked it
    trigger: str  # ProbeKind: "steps" or "random"
    asked_ms: float  # server time the question went out (ms since the epoch)
    status: str = ProbeStatus.OPEN.value
    color: int | None = None
    confidence: float | None = None
    answered_step: int | None = None  # the state on screen when the answer arrived (real time: the clock went on)
    t_client: float | None = None
    answered_ms: float | None = None
    response_ms: float | None = None  # answered_ms - asked_ms: network both ways included
    refused: int = 0  # answers refused (out of range) before this one


@dataclass
class StatedBeliefs:
    """The statements and probes of the person in a game's follower seat ``agent`` (its name)."""

    config: EnvConfig
    agent: str
    plan: ProbePlan
    seed: int
    tagged: bool = False  # entries name their agent (a team other than 1:1)
    current: int | None = None  # the latest stated color
    per_step: list = field(default_factory=list)  # [t] the stated color when step t's moves were made, or None
    events: list = field(default_factory=list)  # every statement, in order
    probes: list = field(default_factory=list)  # every Probe, in order

    def __post_init__(self) -> None:
        self.schedule = frozenset(self.plan.schedule(self.config.horizon, self.seed))

    # ------------------------------------------------------------ what the person says
    def _color(self, color: int, code: str) -> None:
        C, names = self.config.num_colors, self.config.color_names
        if not 0 <= color < C:
            allowed = ", ".join(f"{k} {names[k]}" for k in range(C))
            raise StatementError(code, f"color {color} is out of range: a color of this game is 0..{C - 1} "
                                       f"({allowed})")

    def state(self, color: int, via: Via, t_client: float, step: int) -> None:
        """The person says the goal is ``color`` (``StatementError`` with ``bad_belief`` for one out of range)."""
        self._color(color, "bad_belief")
        self.current = int(color)
        entry = {"color": int(color), "via": Via(via).value, "step": step, "t_client": t_client,
                 "t_server": time.time() * 1000.0}
        self.events.append({"agent": self.agent, **entry} if self.tagged else entry)

    def answer(self, probe_id: int, color: int, confidence: float, t_client: float, step: int) -> Probe:
        """The answer to the open probe ``probe_id``; ``StatementError`` (``bad_probe``) for no such open probe, a
        color out of range or a confidence outside chance..1. The probe stays open after a refused answer."""
        probe = self.open_probe
        if probe is None or probe.id != probe_id:
            now = f"the open probe is {probe.id}" if probe is not None else "no probe is open"
            raise StatementError("bad_probe", f"probe {probe_id} is not open ({now}): answer the open probe only")
        floor = confidence_floor(self.config.num_colors)
        try:
            self._color(color, "bad_probe")
            if not floor - 1e-9 <= confidence <= 1:
                raise StatementError("bad_probe", f"confidence {confidence:g} is out of range: a probability from "
                                                  f"{floor:.2f} (a guess among {self.config.num_colors} colors) to 1 "
                                                  "(certain)")
        except StatementError:
            probe.refused += 1
            raise
        now = time.time() * 1000.0
        probe.status, probe.color, probe.confidence = ProbeStatus.ANSWERED.value, int(color), float(confidence)
        probe.answered_step, probe.t_client, probe.answered_ms = step, t_client, now
        probe.response_ms = round(now - probe.asked_ms, 3)
        self.state(color, Via.PROBE, t_client, step)
        return probe

    # ------------------------------------------------------------ the game's steps
    @property
    def open_probe(self) -> Probe | None:
        last = self.probes[-1] if self.probes else None
        return last if last is not None and last.status == ProbeStatus.OPEN.value else None

    def before_step(self) -> None:
        """The world is about to step: record the stated belief its moves were made with."""
        self.per_step.append(self.current)

    def after_step(self, step: int, finished: bool) -> None:
        """State ``step`` is made: it asks its probe, if its step is in the schedule (a probe still open is
        ``missed``)."""
        if finished or step not in self.schedule:
            return
        if self.open_probe is not None:
            self.open_probe.status = ProbeStatus.MISSED.value
        self.probes.append(Probe(id=len(self.probes), step=step, trigger=self.plan.kind.value,
                                 asked_ms=time.time() * 1000.0))

    def close(self) -> None:
        """The game ended: a probe still open is ``unanswered``."""
        if self.open_probe is not None:
            self.open_probe.status = ProbeStatus.UNANSWERED.value

    # ------------------------------------------------------------ views
    def view(self) -> dict:
        """What a ``state`` tells the person: their stated color and the open probe (``{id, step}``), or None."""
        probe = self.open_probe
        return {"stated": self.current, "probe": None if probe is None else {"id": probe.id, "step": probe.step}}

    def record(self) -> tuple[list, list, list]:
        """The replay's ``steps.stated_belief`` list for this agent, its ``belief_events`` and its ``probes``."""
        probes = [asdict(p) for p in self.probes]
        if self.tagged:
            probes = [{"agent": self.agent, **p} for p in probes]
        return list(self.per_step), list(self.events), probes
