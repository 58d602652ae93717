"""People in games: a game opened for them, a seat given back on rejoin (its token), keys and probe answers, a
person leaving (the last one's leaving ends the game; otherwise a stand-in plays on in their seat)."""

from __future__ import annotations

import asyncio
import hmac
import logging
import time

from colorgrid.config import EnvConfig
from colorgrid.enums import Ending, Role
from server.followers import follower_label
from server.game import Game
from server.messages import Replaced
from server.play.clock import Clock
from server.play.ending import Finisher, game_over_message
from server.play.live import Client, Live, ServerFull, send_to
from server.play.pools import Pools
from server.protocol import GoalView, Mode
from server.seats import STAND_IN, Seat, lineup
from server.stated import ProbePlan

log = logging.getLogger("colorgrid.server")


def secrets_equal(a: str, b: str) -> bool:
    """Compare two secrets in constant time."""
    return hmac.compare_digest(a.encode(), b.encode())


class Sessions:
    """Opens games for people and keeps each person's seat: their keys, their rejoin, their leaving."""

    def __init__(self, live: Live, pools: Pools, clock: Clock, finisher: Finisher):
        self.live, self.pools, self.clock, self.finisher = live, pools, clock, finisher
        first = live.settings.first_seed or int(time.time())
        self._seed_counter = first - 1  # the seed of the last game opened
        self._notices: set[asyncio.Task] = set()  # seat changes being told to the other people of a game

    async def open_game(self, config: EnvConfig, mode: Mode, followers: tuple[str, ...], preset: str,
                        show_belief: bool, people: list[tuple[Client, dict]], tick_hz: float | None = None,
                        study: dict | None = None, room: str | None = None, leaders: tuple[str, ...] = (),
                        seat: Role = Role.LEADER, goal_view: GoalView = GoalView.SHOWN,
                        probes: ProbePlan | None = None) -> Game:
        """Make a game for ``people`` (connection and page info, one per person's seat, in agent order), with a
        slot in each AI follower's pool (``followers``: one kind per AI follower, in agent order) and each AI
        leader's (``leaders``: one kind per leader seat after the people's, or every one beside a person in the
        follower ``seat``); send each person their ``welcome`` and the first ``state``."""
        live, settings = self.live, self.live.settings
        # The session is counted before the first await, so concurrent requests never overshoot the limit.
        live.check_capacity()
        live.reserved += 1
        try:
            _, ai_leaders, ai_followers = lineup(config, seat, len(leaders))
            ai = [*zip(followers, ai_followers), *zip(leaders, ai_leaders)]
            pools = [(agent, *await self.pools.seat_pool(kind, config, agent)) for kind, agent in ai]
            if live.stopped:
                raise ServerFull("the server is shutting down; try again in a minute")
            self._seed_counter += 1
            game = Game(config=config, mode=mode, follower=follower_label(followers), follower_kinds=tuple(followers),
                        leader_kinds=tuple(leaders), preset=preset, seed=self._seed_counter,
                        show_belief=show_belief and settings.show_belief, max_key_log=settings.max_key_log,
                        tick_hz=tick_hz or settings.tick_hz, study=study, room=room, seat=seat,
                        goal_view=goal_view, probes=probes or ProbePlan())
            for person, (client, client_info) in zip(game.seats, people):
                person.client, person.client_info = client, client_info
            for agent, pool, view in pools:
                game.attach(agent, pool, pool.acquire(), view)
            try:
                await self.finisher.started(game)  # recorded before the player sees the game
            except BaseException:
                game.release_slots()
                raise
            live.games[game.game_id] = game  # counted here before the reservation ends: no gap
        finally:
            live.reserved -= 1
        if game.mode == Mode.REALTIME:
            self.clock.run(game.tick_hz)
        for person in game.seats:
            await send_to(person.client, game.welcome(person))
        await live.send(game, game.state_message())
        return game

    async def rejoin(self, game_id: str, token: str, client: Client) -> Game:
        """Give a seat of the game to ``client`` (the seat whose token it is); a connection that still had it
        is told ``replaced`` and loses it."""
        game = self.live.games.get(game_id)
        seat = next((s for s in game.people if secrets_equal(s.token, token)), None) if game is not None else None
        if seat is None:
            raise ValueError("no game with that id and token is waiting (it may have ended or the grace period passed)")
        previous = seat.client
        if previous is not None and previous is not client:
            previous.detach()
            await send_to(previous, Replaced(type="replaced", game_id=game_id,
                                             message="this game was taken over by another connection"))
        was_away = previous is None
        seat.client, seat.disconnected_at, seat.last_key_at = client, None, time.monotonic()
        await client.send(game.welcome(seat).wire())
        await client.send(game.state_message().wire())
        if was_away and not game.solo:
            await self.live.send_seats(game)
        if game.mode == Mode.TURN:  # the others may all have moved while this person was away
            await self.clock.step_games([game])
        return game

    def disconnect(self, game: Game, client: Client) -> None:
        """``client`` closed: its seat waits for a rejoin (a connection that was replaced changes nothing)."""
        seat = game.seat_of(client) if game.game_id in self.live.games else None
        if seat is not None:
            seat.client, seat.disconnected_at = None, time.monotonic()
            if not game.solo:  # the others see the seat reconnecting
                notice = asyncio.get_running_loop().create_task(self.live.send_seats(game))
                self._notices.add(notice)
                notice.add_done_callback(self._notices.discard)

    async def key(self, game: Game, key: str, seq: int, t_client: float, seat: Seat | None = None) -> str | None:
        """A key of the person in ``seat`` (the first by default); a turn-based game steps once everyone moved."""
        problem = game.press(key, seq, t_client, seat)
        if problem is None and game.mode == Mode.TURN:
            await self.clock.step_games([game])
        return problem

    async def answer_probe(self, game: Game, probe: int, color: int, confidence: float, t_client: float) -> None:
        """The answer to ``game``'s open probe; a turn-based game waited for it, and steps now if a move is
        pending."""
        game.answer_probe(probe, color, confidence, t_client)
        if game.mode == Mode.TURN:
            await self.clock.step_games([game])

    async def sweep(self, now: float) -> None:
        """People gone past the rejoin grace (``disconnected``) or idle too long (``idle``) leave their games."""
        settings = self.live.settings
        for game in list(self.live.games.values()):
            for seat in game.people:
                if seat.disconnected_at is not None and now - seat.disconnected_at > settings.rejoin_grace_s:
                    await self.leave(game, seat, Ending.DISCONNECTED)
                elif now - seat.last_key_at > settings.idle_timeout_s:
                    await self.leave(game, seat, Ending.IDLE)

    async def leave(self, game: Game, seat: Seat, reason: Ending) -> None:
        """The person in ``seat`` is gone (``quit``, ``disconnected``, ``idle``). The last person's leaving ends
        the game; otherwise the scripted leader (``STAND_IN``) plays on in the seat, and the person is told
        ``game_over`` with reason ``left``."""
        if game.game_id not in self.live.games or seat.left is not None:
            return
        if len(game.people) == 1:
            await self.finisher.finish(game, reason)
            return
        client = seat.client
        game.leave(seat, reason)
        if client is not None:
            client.detach()
            await send_to(client, game_over_message(game, Ending.LEFT, None))
        await self.live.send_seats(game)
        try:
            pool = await self.pools.pool_for(STAND_IN, game.config, seat.agent)
        except Exception:  # without a stand-in the seat could never move again: end the game, saved
            log.exception("could not load the stand-in leader for game %s", game.game_id)
            await self.finisher.finish(game, Ending.STAND_IN_FAILED)
            return
        if game.game_id not in self.live.games:  # ended while the stand-in loaded
            return
        game.attach(seat.agent, pool, pool.acquire())
        if game.mode == Mode.TURN:  # the others' keys may all be waiting
            await self.clock.step_games([game])
