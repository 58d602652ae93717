"""Leaders that stand in for people: the A* leader with the ways people depart from it.

A person who knows the goal does not walk like A*: they slip, notice a goal switch late,
move less than optimally, set off after a wrong block now and then, hesitate and take
detours. ``PersonLeader`` has one parameter for each (``PersonStyle``; all off, it is the
A* leader), so that populations of such leaders can be written as named specs
(``person:slip=0.1,notice_delay=3``) and split into training and held-out parts
(``colorgrid.policies.population``).

The departures are written once (``PersonDepartures``): what a person pursues before the intended move is chosen,
and what becomes of that move after. ``PersonLeader`` chooses it by A*; ``colorgrid.policies.styled`` lets any
leader policy choose it (``person:base=ippo-leader,slip=0.1``).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import ClassVar

import numpy as np

from colorgrid.config import EnvConfig
from colorgrid.configkit import ConfigBase, check_int, check_number, fail
from colorgrid.policies.base import AgentInput, Policy, PolicyOutput
from colorgrid.policies.card import Part, PolicyCard
from colorgrid.policies.grid import INF, decode
from colorgrid.policies.registry import scripted
from colorgrid.policies.scripted import AStarLeader, Seeker

PERSON = "person"
"""The person leaders' policy name (``person:slip=0.1``)."""
BASES = "astar, a leader policy's name (ippo-leader, ippo-leader-0.8M, random) or a checkpoint path ending in .pt"
"""What ``PersonStyle.base`` may be, in the words of its errors."""


@dataclass(frozen=True)
class PersonStyle(ConfigBase):
    """How a person-like leader departs from its base leader, A* unless told (every default: not at all)."""

    ERROR_STYLE: ClassVar[str] = "PersonStyle.{name} must be {allowed}, got {value!r}"

    base: str = AStarLeader.name
    """The leader whose moves the person departs from: ``astar`` (``PersonLeader``), or any leader policy by name
    or checkpoint path (``ippo-leader``, ``runs/x/leader_200k.pt``; ``StyledLeader``), shown the goal the person
    pursues. Not a person leader itself, nor a population."""
    slip: float = 0.0
    """Probability, each step, of a uniformly random move instead of the intended one."""
    notice_delay: int = 0
    """Steps the leader keeps pursuing the old goal after a switch (exactly this many)."""
    notice_delay_max: int | None = None
    """With a value, each switch's delay is drawn anew, uniformly from ``notice_delay`` to this (a person
    notices some switches sooner than others). None: always ``notice_delay``."""
    rationality: float | None = None
    """Boltzmann rationality beta: moves are drawn with probability proportional to
    exp(-beta * distance to the target after the move). None: always a shortest step."""
    wrong_pickup: float = 0.0
    """Probability, each step, of setting off after the nearest block of a wrong color (until it collects a block)."""
    hesitate: float = 0.0
    """Probability, each step, of repeating the last move instead of choosing afresh."""
    detour: float = 0.0
    """Probability, each step, of starting a detour: ``detour_len`` steps in one random direction."""
    detour_len: int = 4
    """Steps of a detour."""

    def __post_init__(self) -> None:
        for name in ("slip", "wrong_pickup", "hesitate", "detour"):
            check_number(self, name, "a probability in [0, 1]", lambda v: 0.0 <= v <= 1.0)
        check_int(self, "notice_delay", 0, 10_000)
        if self.notice_delay_max is not None:
            check_int(self, "notice_delay_max", self.notice_delay, 10_000)
        check_int(self, "detour_len", 1, 1000)
        if self.rationality is not None:
            check_number(self, "rationality", "a number > 0, or null for shortest steps", lambda v: v > 0)
        if self.slip + self.hesitate > 1.0:
            fail(self, "hesitate", f"at most 1 - slip = {1 - self.slip:g} (they share a step's chance)")
        if not isinstance(self.base, str) or not self.base:
            fail(self, "base", BASES)
        if self.base.partition(":")[0] == PERSON:
            fail(self, "base", f"{BASES}, not a person leader itself")
        if self.rationality is not None and not self.around_astar:
            fail(self, "rationality", f"unset with base {self.base!r} (a Boltzmann choice over A* distances: base "
                 f"{AStarLeader.name} only)")

    def inner(self) -> dict[str, str]:
        """The policy it is built around, when not A* (``colorgrid.policies.inner_policies``)."""
        return {} if self.around_astar else {"base": self.base}

    @property
    def around_astar(self) -> bool:
        """Whether the base is the A* leader (``PersonLeader``), not another leader policy (``StyledLeader``)."""
        return self.base == AStarLeader.name

    def described(self) -> dict:
        """The style as replays and reports name it: every field, less those at a default that came after the
        first replays (``notice_delay_max`` unset, ``base`` astar), so those replays still match."""
        params = asdict(self)
        if params["notice_delay_max"] is None:
            del params["notice_delay_max"]
        if self.around_astar:
            del params["base"]
        return params


class PersonDepartures(Policy):
    """The departures of a ``PersonStyle`` around whatever chooses the intended move, each drawn per env and step
    from the policy's ``rng``: ``pursue`` says which color the person goes for (the goal noticed late, or a wrong
    color now and then), and ``depart`` turns the intended move into the one made (a detour, a repeated move or a
    slip). Between them the subclass chooses the intended move toward the pursued color."""

    style: PersonStyle
    rng: np.random.Generator
    state_fields = ("target", "pending", "delay", "distracted", "last_action", "detour_left", "detour_dir")

    def reset_departures(self, num_envs: int) -> None:
        """Clear the departures' state for a batch of ``num_envs`` (called by the subclass's ``reset``)."""
        self.target = np.full(num_envs, -1, dtype=np.int64)  # the goal it pursues (lags the true one when late)
        self.pending = np.zeros(num_envs, dtype=np.int64)  # steps since it could have seen a new goal
        self.delay = np.full(num_envs, self.style.notice_delay, dtype=np.int64)  # the pending switch's delay
        self.distracted = np.full(num_envs, -1, dtype=np.int64)  # a wrong color it is after, -1 if none
        self.last_action = np.full(num_envs, -1, dtype=np.int64)
        self.detour_left = np.zeros(num_envs, dtype=np.int64)
        self.detour_dir = np.zeros(num_envs, dtype=np.int64)

    def load_state_dict(self, state: dict) -> None:
        if "delay" not in state:  # saved before delays could vary: every switch's delay was notice_delay
            state = {**state, "delay": np.full(self.num_envs, self.style.notice_delay, dtype=np.int64)}
        super().load_state_dict(state)

    def pursue(self, inp: AgentInput, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Begin the step of envs ``rows``: ``(goal [n], pursued [n], draws [n, 6])``, the true goal, the color the
        person goes for, and the step's uniform draws (one per departure, for ``depart``)."""
        style, C = self.style, self.config.num_colors
        n = len(rows)
        goal = inp.goal_info.argmax(axis=1)
        if not (inp.goal_info > 0.5).any(axis=1).all():
            raise ValueError("the person leader needs the goal: use it as the leader or with asymmetric=False")
        target, pending, distracted = self.target[rows], self.pending[rows], self.distracted[rows]
        start = inp.episode_start | (target < 0)
        target[start], pending[start], distracted[start] = goal[start], 0, -1
        self.last_action[rows[start]], self.detour_left[rows[start]] = -1, 0
        u = self.rng.random((n, 6))  # one draw per departure, per env and step

        # late noticing: a new goal is pursued only after notice_delay steps (or a delay drawn for this switch)
        differs = goal != target
        delay = self.delay[rows]
        if style.notice_delay_max is not None:
            fresh = differs & (pending == 0)
            delay[fresh] = self.rng.integers(style.notice_delay, style.notice_delay_max + 1, int(fresh.sum()))
        pending = np.where(differs, pending + 1, 0)
        noticed = differs & (pending > delay)
        target[noticed], pending[noticed] = goal[noticed], 0

        # wrong pickups: now and then it sets off after a wrong color, until it collects a block
        distracted[inp.prev_picked_color[:, self.agent_index] >= 0] = -1
        tempted = (distracted < 0) & (u[:, 0] < style.wrong_pickup)
        if tempted.any():
            offset = 1 + (u[tempted, 1] * (C - 1)).astype(np.int64)
            distracted[tempted] = (target[tempted] + offset) % C
        self.target[rows], self.pending[rows], self.delay[rows] = target, pending, delay
        self.distracted[rows] = distracted
        return goal, np.where(distracted >= 0, distracted, target), u

    def depart(self, actions: np.ndarray, u: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """``[n]``: the moves made in envs ``rows`` instead of the intended ``actions`` (changed in place), with the
        step's draws ``u`` from ``pursue``: a detour's step, the last move repeated, or a slip's random move."""
        style = self.style
        last, detour_left, detour_dir = self.last_action[rows], self.detour_left[rows], self.detour_dir[rows]

        # detours: a few steps in one random direction
        begin = (detour_left == 0) & (u[:, 2] < style.detour)
        detour_left[begin] = style.detour_len
        detour_dir[begin] = self.rng.integers(0, 4, int(begin.sum()))
        on_detour = detour_left > 0
        actions[on_detour] = detour_dir[on_detour]
        detour_left[on_detour] -= 1

        # hesitation repeats the last move; a slip is any move
        hesitates = (u[:, 3] < style.hesitate) & (last >= 0)
        actions[hesitates] = last[hesitates]
        slips = (u[:, 3] >= 1.0 - style.slip)
        actions[slips] = (u[slips, 4] * 4).astype(np.int64)

        self.last_action[rows], self.detour_left[rows], self.detour_dir[rows] = actions, detour_left, detour_dir
        return actions


@scripted(PolicyCard(lead=Part("Person-like scripted leader",
                                "the A* leader with the slips, late turns and mistakes of people")))
class PersonLeader(PersonDepartures, Seeker):
    """The A* leader with a ``PersonStyle``: each departure is drawn per env and step from its own RNG.

    In a team it walks around every other agent, and while it pursues the goal it leaves the blocks that
    lower-index leaders go for as the A* leaders do (``Seeker.claims``), so that with every departure off
    it is the A* leader in any team.
    """

    name = PERSON
    Params = PersonStyle

    @staticmethod
    def card_around(style: PersonStyle, cards: dict) -> PolicyCard:
        """What a person around another leader (``StyledLeader``) says of itself: named by that leader's card."""
        return styled_card(style.base, cards["base"])

    def __init__(self, style: PersonStyle | None = None):
        self.style = style or PersonStyle()
        if not self.style.around_astar:
            raise ValueError(f"PersonLeader departs from A*, not {self.style.base!r}: make_policy builds "
                             "person:base=... as a StyledLeader")

    def describe(self) -> dict:
        return {"policy": self.name, "params": self.style.described()}

    def reset(self, config: EnvConfig, num_envs: int, agent_index: int, seed: int = 0) -> None:
        super().reset(config, num_envs, agent_index, seed)
        self.reset_departures(num_envs)

    def act(self, inp: AgentInput, rows=None) -> PolicyOutput:
        C = self.config.num_colors
        rows = self._rows(rows)
        goal, pursued, u = self.pursue(inp, rows)
        block_color, agent_cell = decode(inp.observation, self.config)
        me, other = agent_cell[:, self.agent_index], agent_cell[:, self.other_indices]
        wanted = np.eye(C, dtype=bool)[pursued]
        claimed = self.claims(np.eye(C, dtype=bool)[goal], block_color, agent_cell)  # None for the first leader
        if claimed is not None:  # the lower-index leaders' goal blocks matter only while it pursues the goal
            claimed &= (pursued == goal)[:, None, None]
        if self.style.rationality is None:
            actions, _ = self.seek(wanted, block_color, me, other, claimed=claimed)
        else:
            actions = self.boltzmann(wanted, block_color, me, other, self.style.rationality, claimed)
        return PolicyOutput(self.depart(actions, u, rows))

    def boltzmann(self, wanted, block_color, me, other, beta: float, claimed=None) -> np.ndarray:
        """Moves drawn with probability proportional to exp(-beta * distance to a wanted block after the move)
        (``boltzmann_probs``)."""
        p = self.boltzmann_probs(wanted, block_color, me, other, beta, claimed)
        u = self.rng.random((p.shape[0], 1))
        return np.minimum((p.cumsum(axis=1) <= u).sum(axis=1), 3)

    def boltzmann_probs(self, wanted, block_color, me, other, beta: float, claimed=None) -> np.ndarray:
        """``[B, 4]``: the probability of each move, proportional to exp(-beta * distance to a wanted block after it).

        other: [B, K] the other agents' cells; claimed: [B, H, W] blocks lower-index leaders go for (left alone
        where an unclaimed wanted block is within reach), or None.
        """
        B = block_color.shape[0]
        is_wanted, _, passable = self.cells(wanted, block_color, other)
        dist = self.field(is_wanted, passable, passable, me, avoid_unwanted=False, claimed=claimed).reshape(B, -1)
        nxt, moves = self.mover.neighbours(me, other)
        values = dist[np.arange(B)[:, None], nxt]
        stuck = values >= INF
        values = np.where(stuck, values.min(axis=1, keepdims=True, where=~stuck, initial=INF) + 2, values)
        logits = np.where(moves, -beta * values, -math.inf)
        logits = np.where(moves.any(axis=1, keepdims=True), logits, 0.0)  # boxed in: any move
        logits -= logits.max(axis=1, keepdims=True)
        p = np.exp(logits)
        return p / p.sum(axis=1, keepdims=True)


def styled_card(base: str, base_card: PolicyCard | None) -> PolicyCard:
    """What ``person:base=BASE,...`` says of itself: a person-like leader around its base, named by the base's own
    leader label (its policy name when it has none), not the A* person's words."""
    shown = base_card.lead.label if base_card is not None and base_card.lead is not None else base
    return PolicyCard(lead=Part("Person-like leader", f"{shown}, with the slips, late turns and mistakes of people"),
                      summary=f"{base} with a person's departures (colorgrid/policies/styled.py)")
