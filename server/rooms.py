"""Rooms: where the people of one team meet before their game: a short code to share, a seat each, ready.

A room holds the settings of the game it will start (chosen by the person who opened it) and one seat
per person (the team's leaders, in agent order). The game starts once every seat is taken and ready;
the room is then gone and the game carries its code (``Game.room``). See docs/SERVER_PROTOCOL.md.
"""

from __future__ import annotations

import secrets
import time
from dataclasses import dataclass, field

from colorgrid.config import EnvConfig
from server.followers import follower_label
from server.messages import RoomClosed, RoomMessage, RoomSeat
from server.protocol import (ROOM_CODE_ALPHABET, ROOM_CODE_LENGTH, Mode, RoomClosedReason, RoomErrorCode,
                             RoomSeatStatus, Team, normalise_room_code)


class RoomError(ValueError):
    """A room request that cannot be met; ``code`` is the ``error`` message's code."""

    def __init__(self, code: RoomErrorCode, message: str):
        super().__init__(message)
        self.code = code


@dataclass(eq=False)
class Member:
    """A person in a room's seat."""

    client: object  # their connection
    client_info: dict  # the page's user agent and viewport
    ready: bool = False


@dataclass(eq=False)
class Room:
    """A waiting room and the game it will start."""

    code: str
    team: Team
    config: EnvConfig  # the game's config (its team, preset, mode and horizon applied)
    followers: tuple[str, ...]  # one kind per AI follower, in agent order
    preset: str
    mode: Mode
    show_belief: bool
    tick_hz: float
    created: float = field(default_factory=time.monotonic)

    def __post_init__(self) -> None:
        self.members: list[Member | None] = [None] * self.team.people  # one per seat (leader), in agent order
        self.starting_in_s: float | None = None  # every seat ready: the game starts after this countdown
        self.start_task = None  # the task that starts the game after the countdown
        self.opening = False  # its game is being made (the room is no longer waiting)
        self.dropped: list = []  # connections that closed while the game was being made

    @property
    def full(self) -> bool:
        return all(m is not None for m in self.members)

    @property
    def empty(self) -> bool:
        return all(m is None for m in self.members)

    @property
    def all_ready(self) -> bool:
        return self.full and all(m.ready for m in self.members)

    def seat_of(self, client) -> int | None:
        return next((i for i, m in enumerate(self.members) if m is not None and m.client is client), None)

    def join(self, client, client_info: dict) -> int:
        """Seat ``client`` in the first free seat; a full room raises ``RoomError`` (``room_full``)."""
        free = next((i for i, m in enumerate(self.members) if m is None), None)
        if free is None:
            raise RoomError(RoomErrorCode.ROOM_FULL,
                            f"room {self.code} is full: all {len(self.members)} seats are taken")
        self.members[free] = Member(client, client_info)
        return free

    def leave(self, client) -> None:
        seat = self.seat_of(client)
        if seat is not None:
            self.members[seat] = None

    def members_view(self) -> list[RoomSeat]:
        """Each seat for the pages: ``{agent, symbol, status}`` (``RoomSeatStatus``)."""
        names, symbols = self.config.agent_names, self.config.symbols
        return [RoomSeat(agent=names[i], symbol=symbols[i],
                         status=RoomSeatStatus.OPEN if m is None else RoomSeatStatus.READY if m.ready
                         else RoomSeatStatus.JOINED)
                for i, m in enumerate(self.members)]

    def message(self, seat: int) -> RoomMessage:
        """The ``room`` message for the person in ``seat``."""
        return RoomMessage(type="room", code=self.code, link=f"/?room={self.code}", team=self.team.value,
                           mode=self.mode, preset=self.preset, follower=follower_label(self.followers),
                           horizon=self.config.horizon, seats=self.members_view(), you=self.config.agent_names[seat],
                           starting_in_s=self.starting_in_s)

    def closed_message(self, reason: RoomClosedReason, message: str) -> RoomClosed:
        """The ``room_closed`` message: why the room closed without its game."""
        return RoomClosed(type="room_closed", code=self.code, reason=reason, message=message)


def new_code(taken) -> str:
    """A fresh room code, not one of ``taken``."""
    while True:
        code = "".join(secrets.choice(ROOM_CODE_ALPHABET) for _ in range(ROOM_CODE_LENGTH))
        if code not in taken:
            return code


def parse_code(text: str) -> str:
    """A room code as typed or pasted, or ``RoomError`` (``bad_room_code``) saying what a code looks like."""
    code = normalise_room_code(text)
    if code is None:
        raise RoomError(RoomErrorCode.BAD_ROOM_CODE, f"{text[:32]!r} is not a room code: a code has {ROOM_CODE_LENGTH} "
                                         f"letters and digits from {ROOM_CODE_ALPHABET}")
    return code
