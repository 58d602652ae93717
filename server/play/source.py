"""Where a new game comes from: the player's own choice (``FreePlay``), or an application that chooses people's games
for them and plugs into the hub as its ``GameSource`` (a study plays what its study file assigns each participant)."""

from __future__ import annotations

from collections.abc import Awaitable, Callable
from typing import Protocol

from server.game import Game
from server.play.live import Client
from server.protocol import NewGame

OpenGame = Callable[..., Awaitable[Game]]
"""``GameHub.new_game``: opens the game a ``GameRequest`` asks for, for one person."""


class GameSource(Protocol):
    """Opens the game a ``new_game`` asks for; an application's source may refuse rooms and quitting, and it knows
    which person's game runs here (``game_of``: a cluster's backends ask each other)."""

    room_refusal: str | None
    """Why people may not meet in rooms on this server (a sentence for the page), or None when they may."""

    quit_refusal: str | None
    """Why a person may not end their game early (a sentence for the page), or None when they may."""

    elsewhere: Callable[[str], dict | None]
    """Where another process of the deployment runs the game of the person a key names, or None (a cluster sets it)."""

    async def new_game(self, open_game: OpenGame, request: NewGame, client: Client, client_info: dict) -> Game:
        """Open (``open_game``) the game ``request`` asks for, for ``client``; a refusal is a ``ValueError`` with a
        sentence for the page."""

    def game_of(self, key: str) -> Game | None:
        """The live game this process runs for the person ``key`` names (a participant id), or None."""


class FreePlay:
    """A player chooses their own game (``new_game``'s fields); people may meet in rooms and quit."""

    room_refusal = None
    quit_refusal = None

    def __init__(self) -> None:
        self.elsewhere: Callable[[str], dict | None] = lambda key: None

    async def new_game(self, open_game: OpenGame, request: NewGame, client: Client, client_info: dict) -> Game:
        """The game ``request`` chooses; a study's ticket (``new_game.study``) is refused."""
        if request.study is not None:
            raise ValueError("this server runs no study")
        return await open_game(request, client, client_info)

    def game_of(self, key: str) -> Game | None:
        """Free play keeps no game by person."""
        return None
