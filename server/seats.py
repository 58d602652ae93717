"""The seat a person asks for in a new game, checked: a leader's, or the follower's beside AI leaders.

A team of one leader (``Team.seats``) offers its first follower seat to a person: every leader seat is then played by
an AI leader (one of the server's ``--leaders`` that plays a leader seat of that team: ``follower_seat_leaders``), the
goal is hidden from the person unless the game shows it (``GoalView``), and probes may ask what they believe
(``server.stated.ProbePlan``). Every refusal is a ``ValueError`` whose words the page shows (``rejected``).
"""

from __future__ import annotations

from dataclasses import dataclass

from server.followers import leads
from server.protocol import GoalView, SeatKind, Team
from server.stated import ProbePlan


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
    if SeatKind.FOLLOWER not in team.seats:
        return []
    return [kind for kind in leaders if leads(kind, team) == "direct"]


def follower_seat(team: Team, leader: str | None, goal: GoalView | None, probes: str | None,
                  offered: list[str], known: tuple[str, ...]) -> SeatChoice:
    """The follower seat of ``team`` with AI leader ``leader`` (default: the first ``offered``), the goal ``goal``
    (default hidden) and ``probes`` (default none); ``known``: every leader the server has (for the messages)."""
    if SeatKind.FOLLOWER not in team.seats:
        raise ValueError(f"team {team.value} has no follower seat for a person: its {team.num_leaders} leaders are "
                         f"people's and its follower is the AI's; take the follower seat in team "
                         f"{' or '.join(t.value for t in Team if SeatKind.FOLLOWER in t.seats)}")
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
