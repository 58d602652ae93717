"""What a player may choose for a new game or room: the team, its followers and AI leaders, the preset, the seat.

Which offered follower plays in which team, and how each offered AI leader leads, is read once (a checkpoint file
says the team it was trained in); every refusal is a ``ValueError`` whose words the page shows.
"""

from __future__ import annotations

from colorgrid.config import EnvConfig
from colorgrid.enums import Role, SeatFit
from colorgrid.policies import policy_teams
from colorgrid.presets import env_config
from server.followers import leads, plays
from server.protocol import GameRequest, GoalView, Mode, Team
from server.seats import SeatChoice, follower_seat, follower_seat_leaders, leader_seat
from server.settings import ServerSettings, yardstick_reason
from server.stated import ProbePlan


def make_config(request: GameRequest, default_preset: str) -> EnvConfig:
    """The env config of the game ``request`` asks for: its team in its mode (real time lets a leader stay), from its
    preset (or ``default_preset``), with its horizon (or the preset's)."""
    changes = {}
    team = request.team
    if team != Team.ONE_TO_ONE:
        changes.update(num_leaders=team.num_leaders, num_followers=team.num_followers)
    if request.mode == Mode.REALTIME:
        changes["allow_stay"] = True  # the leader stays when no key is pending
    if request.horizon is not None:
        changes["horizon"] = request.horizon
    return env_config(request.preset or default_preset, **changes)


class Offer:
    """The followers, AI leaders and seats this server offers (``ServerSettings``), by team."""

    def __init__(self, settings: ServerSettings):
        self.settings = settings
        self._followers: dict[Team, list[str]] | None = None  # team_followers, by team
        self._leaders: dict[Team, dict[str, SeatFit]] | None = None  # team_leaders: how each offered leader leads
        self._seat_leaders: dict[Team, list[str]] | None = None  # seat_leaders: beside a person in the follower seat

    def team_followers(self, team: Team = Team.TWO_FOLLOWERS) -> list[str]:
        """The offered followers that play in ``team`` (a trained network only in the team it was trained in),
        the default first if it does."""
        if self._followers is None:  # once: a checkpoint file is read to know its team
            self._followers = {t: [f for f in self.settings.follower_choices if plays(f, t)] for t in Team}
        return self._followers[team]

    def team_leaders(self, team: Team) -> dict[str, SeatFit]:
        """The offered AI leaders (``ServerSettings.leaders``) that play a leader seat beside a person in ``team``,
        each with how it plays it (``followers.leads``); none in a team of one leader."""
        if self._leaders is None:  # once: a checkpoint file is read to know its team
            self._leaders = {t: {kind: fit for kind in self.settings.leaders if (fit := leads(kind, t))}
                             if t.num_leaders > 1 else {} for t in Team}
        return self._leaders[team]

    def seat_leaders(self, team: Team) -> list[str]:
        """The offered AI leaders (``ServerSettings.leaders``) that lead beside a person in ``team``'s follower seat
        (``server.seats.follower_seat_leaders``); none in a team without one."""
        if self._seat_leaders is None:  # once: a checkpoint file is read to know its team
            self._seat_leaders = {t: follower_seat_leaders(self.settings.leaders, t) for t in Team}
        return self._seat_leaders[team]

    def withdraw_leader(self, kind: str, team: Team) -> None:
        """AI leader ``kind`` could not be loaded to lead in ``team``: it is no longer offered there."""
        self.team_leaders(team).pop(kind, None)
        if kind in self.seat_leaders(team):
            self.seat_leaders(team).remove(kind)

    def leader_fit(self, kind: str, team: Team) -> SeatFit | None:
        """How AI leader ``kind`` plays a leader seat of ``team`` (``followers.leads``; an offered one's is read
        once), or None."""
        return self.team_leaders(team).get(kind) if kind in self.settings.leaders else leads(kind, team)

    def choose(self, request: GameRequest) -> tuple[tuple[str, ...], str, EnvConfig]:
        """The followers (one per AI seat, in agent order), preset and config of the game or room ``request`` asks
        for: every seat its ``follower``, or each its own of its ``followers``; what is not offered raises
        ``ValueError``. A person in the follower ``seat`` takes the first follower's (the AI followers are the
        others)."""
        team, follower, followers, seat = request.team, request.follower, request.followers, request.seat
        if followers is not None and follower is not None:
            raise ValueError("give either follower (every AI seat) or followers (one per AI seat), not both")
        ai_seats = team.num_followers - (Role(seat) == Role.FOLLOWER)
        if followers is not None and len(followers) != ai_seats:
            beside = " beside a person in its follower seat" if ai_seats < team.num_followers else ""
            raise ValueError(f"followers: team {team.value} has {ai_seats} AI follower(s){beside}; give one name "
                             f"each, got {len(followers)}")
        offered = self.team_followers(team)
        default = self.settings.follower if self.settings.follower in offered else next(iter(offered), None)
        chosen = tuple(followers) if followers is not None else (follower or default,) * ai_seats
        for name in chosen:
            if name not in self.settings.follower_choices:
                reason = yardstick_reason(name)  # a yardstick is never offered: say why
                what = f"follower {name!r} is not offered ({reason})" if reason else f"unknown follower {name!r}"
                raise ValueError(f"{what}; choose one of {list(self.settings.follower_choices)}")
            if name not in offered:
                raise ValueError(f"follower {name!r} does not play in team {team.value} (a trained network plays the "
                                 f"team it was trained in: {'/'.join(policy_teams(name) or ())}); for team "
                                 f"{team.value} choose one of {offered}")
        return chosen, request.preset or self.settings.preset, make_config(request, self.settings.preset)

    def seat_choice(self, request: GameRequest) -> SeatChoice:
        """The seat of the game of one person ``request`` asks for: in the follower ``seat``, its ``leader`` in every
        leader seat, the goal shown or not, the probes; in a leader's seat, its ``leader`` in every other leader seat
        (a team of several leaders needs one, or a room)."""
        team, seat, leader, goal, probes = request.team, request.seat, request.leader, request.goal, request.probes
        if seat == Role.FOLLOWER:
            return follower_seat(team, leader, goal, probes, self.seat_leaders(team), self.settings.leaders)
        leader_seat(goal, probes)
        choice = SeatChoice(self.choose_leaders(team, leader), GoalView.SHOWN, ProbePlan())
        if team.room and not choice.leaders:
            raise ValueError(f"team {team.value} has {team.people} leaders: people meet in a room (create_room, "
                             f"then share its code), or one person plays beside an AI leader (leader: one of "
                             f"{list(self.team_leaders(team))})")
        return choice

    def choose_leaders(self, team: Team, leader: str | None) -> tuple[str, ...]:
        """The AI leaders of a game of one person in ``team``: ``leader`` in every leader seat but the person's;
        none without one. One not offered for the team raises ``ValueError``."""
        if leader is None:
            return ()
        offered = list(self.team_leaders(team))
        if team.num_leaders == 1:
            raise ValueError(f"team {team.value} has one leader, you: an AI leader plays beside a person in a team of "
                             f"several leaders (team 2:1)")
        if leader not in offered:
            why = f"does not play a leader seat of team {team.value}" if leader in self.settings.leaders else \
                "is not offered"
            raise ValueError(f"AI leader {leader!r} {why}; choose one of {offered}")
        return (leader,) * (team.num_leaders - 1)
