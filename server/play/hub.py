"""The game hub: one facade over the play engine's parts (``server.play``), with the methods the connections, the
routes and the tests call."""

from __future__ import annotations

import asyncio
import logging
import time
from pathlib import Path

from colorgrid.config import FOLLOWER, EnvConfig
from colorgrid.enums import Ending, SeatFit
from server.followers import PolicyPool
from server.game import Game, Seat
from server.play.clock import Clock
from server.play.ending import Finisher
from server.play.live import Client, Live, ServerFull
from server.play.lobby import Lobby
from server.play.offer import Offer, make_config
from server.play.pools import Pools
from server.play.sessions import Sessions
from server.play.source import FreePlay, GameSource
from server.protocol import GameRequest, Mode, RoomClosedReason, Team
from server.rooms import Room
from server.settings import ServerSettings

__all__ = ["Client", "GameHub", "ServerFull"]
log = logging.getLogger("colorgrid.server")
SWEEP_EVERY_S = 0.5


class GameHub:
    """Owns all games and waiting rooms. Real-time games advance together on one clock (``tick_hz``), with one
    batched call per policy pool per tick; turn-based games advance once every person has moved.

    An application plugs in through ``source`` (who chooses a new game: the player, or a study) and ``listeners``
    (told of each game's start and end)."""

    def __init__(self, settings: ServerSettings):
        self.settings = settings
        self.live = Live(settings)
        self.offer = Offer(settings)
        self.pools = Pools(settings, self.offer, self.live.stats)
        self.finisher = Finisher(self.live)
        self.clock = Clock(self.live, self.pools, self.finisher)
        self.sessions = Sessions(self.live, self.pools, self.clock, self.finisher)
        self.lobby = Lobby(self.live, self.offer, self.sessions)
        self.source: GameSource = FreePlay()
        self._tasks: list[asyncio.Task] = []  # the sweeper and the warm-up

    # ------------------------------------------------------------ what routes and tests read
    games = property(lambda self: self.live.games, doc="Game id -> each game in play.")
    rooms = property(lambda self: self.live.rooms, doc="Code -> each room waiting for its people.")
    stats = property(lambda self: self.live.stats, doc="Ticks, lateness, deadline misses, games saved (health).")
    stopped = property(lambda self: self.live.stopped, doc="Whether ``stop`` ran: no game starts any more.")
    lateness_ms = property(lambda self: self.clock.lateness_ms, doc="The last ticks' lateness.")
    inference = property(lambda self: self.pools.inference, doc="The process every pool's policy runs in.")
    executor = property(lambda self: self.pools.executor, doc="The thread that waits on the inference process.")
    ready = property(lambda self: self.pools.ready, doc="Whether the offered followers are warmed up.")
    listeners = property(lambda self: self.finisher.listeners, doc="Told of each game's start and end.")

    # ------------------------------------------------------------ lifecycle
    def start(self) -> None:
        """Start the sweeper, the followers' warm-up and the server's clock (in the event loop)."""
        Path(self.settings.replays_dir).mkdir(parents=True, exist_ok=True)
        self._tasks = [asyncio.create_task(self._sweep_loop()), asyncio.create_task(self.pools.warm_up())]
        self.clock.run(self.settings.tick_hz)

    async def stop(self) -> list[Client]:
        """Save every live game and tell its people (``game_over``, reason ``server_shutdown``); close every
        waiting room (``room_closed``).

        Returns the connections that were told, so the caller can close them once the message is
        out. Each game is saved on its own: one that fails is logged and the rest are still saved.
        Calling it again does nothing.
        """
        live = self.live
        if live.stopped:
            return []
        live.stopped = True
        for task in self._tasks:
            task.cancel()
        self.clock.stop()
        self.finisher.cancel_waits()
        told = [s.client for g in [*live.games.values(), *live.finishing.values()] for s in g.people
                if s.client is not None]
        told += [m.client for room in live.rooms.values() for m in room.members if m is not None]
        for room in list(live.rooms.values()):
            await self.lobby.close_room(room, RoomClosedReason.SERVER_SHUTDOWN,
                                        "the server is shutting down; try again in a minute")
        await self.finisher.finish_complete()  # complete already: saved as such, without waiting for late keys
        for game in list(live.games.values()):
            try:
                await self.finish(game, Ending.SERVER_SHUTDOWN)
            except Exception:
                log.exception("could not finish game %s at shutdown", game.game_id)
        await self.pools.close()
        self.finisher.close()
        return told

    async def _sweep_loop(self) -> None:
        while True:
            await asyncio.sleep(SWEEP_EVERY_S)
            try:
                await self.sweep()
            except Exception:  # the sweeper must outlive any bug: later games still need saving
                log.exception("sweep failed")

    async def sweep(self) -> None:
        """People gone past the rejoin grace or idle too long leave their games (the last one's leaving ends
        it); rooms waiting too long close; policy pools nobody uses are freed."""
        now = time.monotonic()
        await self.sessions.sweep(now)
        await self.lobby.expire(now)
        self.pools.free_idle()

    # ------------------------------------------------------------ what a player may choose
    make_config = staticmethod(make_config)

    def team_followers(self, team: Team = Team.TWO_FOLLOWERS) -> list[str]:
        """The offered followers that play in ``team`` (``Offer.team_followers``)."""
        return self.offer.team_followers(team)

    def team_leaders(self, team: Team) -> dict[str, SeatFit]:
        """The offered AI leaders beside a person in ``team``, each with how it leads (``Offer.team_leaders``)."""
        return self.offer.team_leaders(team)

    def seat_leaders(self, team: Team) -> list[str]:
        """The offered AI leaders beside a person in ``team``'s follower seat (``Offer.seat_leaders``)."""
        return self.offer.seat_leaders(team)

    async def pool_for(self, follower: str, config: EnvConfig, agent_index: int = FOLLOWER) -> PolicyPool:
        """The pool for this follower, config and agent index (``Pools.pool_for``)."""
        return await self.pools.pool_for(follower, config, agent_index)

    def live_games(self) -> int:
        """Games in play or past their last step but not yet saved (each holds its followers' slots)."""
        return self.live.live_games()

    # ------------------------------------------------------------ games and their people
    async def new_game(self, request: GameRequest, client: Client, client_info: dict | None = None,
                       tick_hz: float | None = None, study: dict | None = None) -> Game:
        """Start the game ``request`` asks for, for ``client``, the team's one person; in a team of several leaders,
        its ``leader`` (an offered AI leader, ``team_leaders``) plays every other leader seat. In the follower
        ``seat`` (``server.seats``), its ``leader`` plays every leader seat, ``goal`` says whether the person sees the
        goal and ``probes`` when the game asks what they believe. ``tick_hz`` (default: the server's) sets a
        real-time game's clock; ``study`` is what a study's game records about itself (``meta.study``)."""
        choice = self.offer.seat_choice(request)
        chosen, preset, config = self.offer.choose(request)
        return await self.sessions.open_game(config, request.mode, chosen, preset, request.show_belief,
                                             [(client, client_info or {})], tick_hz=tick_hz, study=study,
                                             leaders=choice.leaders, seat=request.seat, goal_view=choice.goal_view,
                                             probes=choice.probes)

    async def rejoin(self, game_id: str, token: str, client: Client) -> Game:
        """Give the seat whose token it is to ``client`` (``Sessions.rejoin``)."""
        return await self.sessions.rejoin(game_id, token, client)

    def controls(self, game: Game, client: Client) -> bool:
        """Whether ``client`` plays ``game`` now (it is live and was not taken over, and the person is in it)."""
        return game.game_id in self.live.games and game.seat_of(client) is not None

    def seat_of(self, game: Game | None, client: Client) -> Seat | None:
        """The seat ``client`` plays in ``game`` while the game takes its keys (live, or taking its late keys)."""
        return game.seat_of(client) if self.live.takes_keys(game) else None

    def disconnect(self, game: Game, client: Client) -> None:
        """``client`` closed: its seat waits for a rejoin (``Sessions.disconnect``)."""
        self.sessions.disconnect(game, client)

    async def key(self, game: Game, key: str, seq: int, t_client: float, seat: Seat | None = None) -> str | None:
        """A key of the person in ``seat`` (the first by default); a turn-based game steps once everyone moved."""
        return await self.sessions.key(game, key, seq, t_client, seat)

    async def answer_probe(self, game: Game, probe: int, color: int, confidence: float, t_client: float) -> None:
        """The answer to ``game``'s open probe (``Sessions.answer_probe``)."""
        await self.sessions.answer_probe(game, probe, color, confidence, t_client)

    async def quit(self, game: Game, client: Client) -> None:
        """The person on ``client`` ends the game; in a game other people still play, only leaves it."""
        seat = game.seat_of(client)
        if seat is not None:
            await self.sessions.leave(game, seat, Ending.QUIT)

    async def step_games(self, games: list[Game]) -> None:
        """Advance ``games`` one step (``Clock.step_games``)."""
        await self.clock.step_games(games)

    def round_trip(self, game: Game, ms: float) -> None:
        """A page measured a round trip over its socket during ``game`` (``ping.round_trip_ms``): the listeners that
        take it (``round_trip(game, ms)``) are told."""
        for listener in self.listeners:
            told = getattr(listener, "round_trip", None)
            if told is not None:
                told(game, ms)

    async def finish(self, game: Game, reason: Ending) -> None:
        """Save ``game`` and tell its people and listeners; idempotent, never raises (``Finisher.finish``)."""
        await self.finisher.finish(game, reason)

    # ------------------------------------------------------------ rooms
    async def create_room(self, team: Team, follower: str | None, preset: str | None, mode: Mode,
                          horizon: int | None, show_belief: bool, client: Client,
                          client_info: dict | None = None) -> Room:
        """Open a room for ``team`` with ``client`` in its first seat (``Lobby.create_room``)."""
        return await self.lobby.create_room(team, follower, preset, mode, horizon, show_belief, client, client_info)

    async def join_room(self, code: str, client: Client, client_info: dict | None = None) -> Room:
        """Seat ``client`` in the room with ``code`` (``Lobby.join_room``)."""
        return await self.lobby.join_room(code, client, client_info)

    def room_of(self, client: Client, room: Room | None) -> Room | None:
        """``room`` if it still waits and ``client`` sits in it, else None."""
        return self.lobby.room_of(client, room)

    async def set_ready(self, room: Room, client: Client, ready: bool = True) -> None:
        """Mark ``client``'s seat ready or not (``Lobby.set_ready``)."""
        await self.lobby.set_ready(room, client, ready)

    async def leave_room(self, room: Room, client: Client) -> None:
        """``client`` leaves a waiting room (``Lobby.leave_room``)."""
        await self.lobby.leave_room(room, client)
