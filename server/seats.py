"""Who plays each agent of a game, and the seat a person asks for in a new game, checked.

A leader played by a person is a ``Seat``; an agent played by a policy (an AI follower, an AI leader, or the stand-in
that plays on in the seat of a person who left: ``STAND_IN``) is an ``AIPlayer``; ``lineup`` says which agent is
which. A team of one leader (``Team.seats``) offers its first follower seat to a person: every leader seat is then
played by an AI leader (one of the server's ``--leaders`` that plays a leader seat of that team:
``follower_seat_leaders``), the goal is hidden from the person unless the game shows it (``GoalView``), and probes may
ask what they believe (``server.stated.ProbePlan``). Every refusal is a ``ValueError`` whose words the page shows
(``rejected``).
"""

from __future__ import annotations

import dataclasses
import secrets
import time
from dataclasses import dataclass, field

from colorgrid.config import EnvConfig
from colorgrid.enums import Ending, Role, SeatFit
from colorgrid.env import ACTION_NAMES
from colorgrid.policies.base import AgentInput
from server.followers import leads
from server.protocol import GoalView, SeatStatus, Team
from server.stated import ProbePlan

STAY = ACTION_NAMES.index("stay")
STAND_IN = "astar"
"""The scripted leader that plays on in the seat of a person who left a game other people still play."""


@dataclass(eq=False)
class Seat:
    """A leader played by a person: their connection, their latest key, and whether they are still there."""

    agent: int  # the leader's agent index
    name: str  # the agent's name (``config.agent_names``)
    client: object | None = None  # the connection playing this seat; None while waiting for a rejoin
    client_info: dict = field(default_factory=dict)  # the page's user agent and viewport
    token: str = field(default_factory=lambda: secrets.token_urlsafe(18))
    pending: dict | None = None  # the latest key not yet applied (its key-log entry)
    disconnected_at: float | None = None  # monotonic time the connection closed; None while connected
    last_key_at: float = field(default_factory=time.monotonic)
    left: Ending | None = None  # why the person left (an ``Ending``: quit, disconnected, idle); None while they play
    left_at_step: int | None = None
    last_applied_seq: int | None = None  # the highest ``seq`` of this person's keys applied so far
    last_seq: int | None = None  # the highest ``seq`` of this person's keys received (each is logged, or counted)

    @property
    def next_seq(self) -> int:
        """The ``seq`` this person's next key takes (the ``welcome`` says it, so a reloaded page numbers on)."""
        return 0 if self.last_seq is None else self.last_seq + 1

    def action(self) -> int:
        """The pending key's move, or stay (real time with no key pending)."""
        return STAY if self.pending is None else self.pending["action"]

    def status(self) -> SeatStatus:
        """How the other people see this seat."""
        return SeatStatus.LEFT if self.left else SeatStatus.RECONNECTING if self.client is None else SeatStatus.PLAYING


@dataclass(eq=False)
class AIPlayer:
    """An agent played by a policy: its slot in the pool built for its agent index."""

    agent: int
    pool: object = field(repr=False)  # the PolicyPool serving this agent index
    slot: int
    beliefs: list = field(default_factory=list)  # [t][C] the policy's belief when acting, when it gives one
    fresh: bool = True  # no step acted yet: its first input starts an episode (clears the slot's memory)
    view: tuple[int, int] | None = None  # a network trained in 1:1 leading here: the agents it sees (``pair_view``)


def leader_seats(config: EnvConfig, ai_leaders: int) -> tuple[range, range]:
    """The agent indices of the leader seats that people play and of those that AI leaders play (the last
    ``ai_leaders``)."""
    people = config.num_leaders - ai_leaders
    return config.leaders[:people], config.leaders[people:]


def lineup(config: EnvConfig, seat: Role, ai_leaders: int) -> tuple[tuple[int, ...], ...]:
    """Who plays each agent: the agent indices of the people, of the AI leaders and of the AI followers. A person in
    the follower seat plays the first follower, beside an AI leader in every leader seat; people in leader seats play
    the first leaders, ``ai_leaders`` AI leaders the last ones (``leader_seats``), AI followers every follower."""
    if Role(seat) == Role.FOLLOWER:
        return (config.followers[0],), tuple(config.leaders), tuple(config.followers[1:])
    people, ai = leader_seats(config, ai_leaders)
    return tuple(people), tuple(ai), tuple(config.followers)


def pair_view(inp: AgentInput, config: EnvConfig, agents: tuple[int, int]) -> AgentInput:
    """``inp`` (an agent's input in ``config``'s team) as the input of a 1:1 game of ``agents`` (a leader, then
    the follower): the color planes and those two agents' planes, and their last actions and pickups. Every other
    agent is left out: a network trained in the 1:1 team reads the board it knows, and another leader is, to it,
    an obstacle it cannot see (``SeatFit.PAIR_VIEW``)."""
    C, agents = config.num_colors, list(agents)
    return dataclasses.replace(inp, observation=inp.observation[:, [*range(C), *(C + a for a in agents)]],
                               prev_picked_color=inp.prev_picked_color[:, agents],
                               prev_actions=inp.prev_actions[:, agents])


@dataclass(frozen=True)
class SeatChoice:
    """What a person in the follower seat plays with."""

    leaders: tuple[str, ...]
    """The AI leader's kind in each leader seat, in agent order."""
    goal_view: GoalView
    probes: ProbePlan


def follower_seat_leaders(leaders: tuple[str, ...], team: Team) -> list[str]:
    """The AI leaders among ``leaders`` (the server's ``--leaders``) that lead beside a person in ``team``'s follower
    seat: a scripted leader or population in any team of one leader, a trained network in the team it was trained in
    (``followers.leads``; a network trained in 1:1 does not lead two followers)."""
    if Role.FOLLOWER not in team.seats:
        return []
    return [kind for kind in leaders if leads(kind, team) == SeatFit.DIRECT]


def follower_seat(team: Team, leader: str | None, goal: GoalView | None, probes: str | None,
                  offered: list[str], known: tuple[str, ...]) -> SeatChoice:
    """The follower seat of ``team`` with AI leader ``leader`` (default: the first ``offered``), the goal ``goal``
    (default hidden) and ``probes`` (default none); ``known``: every leader the server has (for the messages)."""
    if Role.FOLLOWER not in team.seats:
        raise ValueError(f"team {team.value} has no follower seat for a person: its {team.num_leaders} leaders are "
                         f"people's and its follower is the AI's; take the follower seat in team "
                         f"{' or '.join(t.value for t in Team if Role.FOLLOWER in t.seats)}")
    if not offered:
        raise ValueError(f"no AI leader of this server ({list(known)}) leads beside a person in the follower seat of "
                         f"team {team.value}")
    leader = offered[0] if leader is None else leader
    if leader not in offered:
        why = (f"cannot lead team {team.value} (a network leads only the team it was trained in)" if leader in known
               else "is not offered")
        raise ValueError(f"AI leader {leader!r} {why}; for the follower seat of team {team.value} choose one of "
                         f"{offered}")
    return SeatChoice(leaders=(leader,) * team.num_leaders, goal_view=GoalView(goal or GoalView.HIDDEN),
                      probes=ProbePlan.parse(probes))


def leader_seat(goal: GoalView | None, probes: str | None) -> None:
    """A leader's seat takes neither ``goal`` nor ``probes``: a leader sees the goal and is never asked it."""
    if goal is not None or probes is not None:
        raise ValueError("goal and probes are for the follower seat (seat: \"follower\"): a leader sees the goal")
