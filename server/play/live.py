"""What the play engine's parts share: this process's live games and waiting rooms, the session count, and
sending to the people of a game."""

from __future__ import annotations

import asyncio
from typing import Protocol

from server.game import Game
from server.messages import Seats, ServerModel
from server.rooms import Room
from server.settings import ServerSettings


class Client(Protocol):
    """What the hub needs of a player's connection."""

    async def send(self, message: dict) -> None:
        """Send ``message`` as it goes on the wire (``ServerModel.wire``)."""

    def detach(self) -> None:
        """The connection no longer plays its game or sits in its room (another connection took the game
        over, the person left it, or the room closed)."""

    def attach(self, game: Game) -> None:
        """The connection now plays ``game``: its room's game started (another person's ``ready``)."""


class ServerFull(Exception):
    """A new game or room refused: the server runs ``max_sessions`` sessions already, or it is stopping."""


class Live:
    """The games and rooms of this process, and the counters every part of the hub reads and writes."""

    def __init__(self, settings: ServerSettings):
        self.settings = settings
        self.games: dict[str, Game] = {}  # game id -> a game in play
        self.finishing: dict[str, Game] = {}  # games past their last step, taking late keys (``ending.LATE_KEYS_S``)
        self.rooms: dict[str, Room] = {}  # code -> a room waiting for its people (each counts as a session)
        self.reserved = 0  # new games past the session check, still loading their followers
        self.stopped = False
        self.lock = asyncio.Lock()  # one step at a time: ticks and turn-based keys never interleave
        self.stats = {"ticks": 0, "late_ticks": 0, "max_lateness_ms": 0.0, "deadline_misses": 0, "games_saved": 0,
                      "save_failures": 0, "policy_call_ms": {}}  # policy_call_ms: each trained one's, at warm-up

    def live_games(self) -> int:
        """Games in play or past their last step but not yet saved (each holds its followers' slots)."""
        return len(self.games) + len(self.finishing)

    def check_capacity(self) -> None:
        """Refuse a new game or room past ``max_sessions`` (games, games being made and waiting rooms)."""
        running = self.live_games() + self.reserved + len(self.rooms)
        if self.stopped or running >= self.settings.max_sessions:
            raise ServerFull(f"server full: {running} games are running (limit {self.settings.max_sessions});"
                             " try again in a minute")

    def takes_keys(self, game: Game | None) -> bool:
        """Whether ``game`` takes its people's keys: it is live, or it has made its last step and takes the keys
        still on their way."""
        return game is not None and (game.game_id in self.games or game.game_id in self.finishing)

    async def send(self, game: Game, message: ServerModel) -> None:
        """To every person still in ``game``."""
        for seat in game.people:
            if seat.client is not None:
                await send_to(seat.client, message)

    async def send_seats(self, game: Game) -> None:
        """Tell the people of a team game how each seat stands (``seats``)."""
        await self.send(game, Seats(type="seats", seats=game.seats_view()))


async def send_to(client: Client, message: ServerModel) -> None:
    """Send ``message`` to ``client``; a closed socket is left to its disconnect handler, which takes care of the
    game."""
    try:
        await client.send(message.wire())
    except Exception:
        pass
