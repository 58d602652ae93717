"""The game hub: every live game and waiting room, the real-time tick, batched follower inference, saving."""

from __future__ import annotations

import asyncio
import dataclasses
import gc
import logging
import time
from concurrent.futures import ThreadPoolExecutor
from functools import partial
from pathlib import Path
from typing import Protocol

from colorgrid.config import FOLLOWER, LEADER, EnvConfig
from colorgrid.policies import policy_teams
from colorgrid.presets import env_config
from colorgrid.replay import save
from colorgrid.roles import scores
from server.followers import FollowerPool, follower_label, is_scripted, leads, plays
from server.game import PAIR_VIEW, STAND_IN, Game, Seat, leader_seats, lineup
from server.inference import InferenceLost, InferenceWorker
from server.protocol import ROOM_COUNTDOWN_S, GoalView, Mode, SeatKind, Team
from server.rooms import Room, RoomError, new_code, parse_code
from server.seats import SeatChoice, follower_seat, follower_seat_leaders, leader_seat
from server.settings import ServerSettings
from server.stated import ProbePlan

log = logging.getLogger("colorgrid.server")
POOL_IDLE_S = 120.0  # a follower pool with no game for this long is freed (the default follower's stay)
LATE_KEYS_S = 0.3
"""After a real-time game's last step, how long its keys still on their way are taken (logged ``unapplied``) before it
is saved and its people told ``game_over``: a held key repeats every ~33 ms, and a page learns of the end a network
trip late. (A turn-based game ends on a key of its own: it is saved at once.)"""


class Client(Protocol):
    """What the hub needs of a player's connection."""

    async def send(self, message: dict) -> None: ...

    def detach(self) -> None:
        """The connection no longer plays its game or sits in its room (another connection took the game
        over, the person left it, or the room closed)."""

    def attach(self, game: Game) -> None:
        """The connection now plays ``game``: its room's game started (another person's ``ready``)."""


class ServerFull(Exception):
    pass


class GameHub:
    """Owns all games and waiting rooms. Real-time games advance together on one clock (``tick_hz``), with one
    batched call per follower pool per tick; turn-based games advance once every person has moved."""

    def __init__(self, settings: ServerSettings):
        self.settings = settings
        self.games: dict[str, Game] = {}
        self.ending: dict[str, Game] = {}  # games past their last step, taking late keys for LATE_KEYS_S
        self.rooms: dict[str, Room] = {}  # code -> a room waiting for its people (each counts as a session)
        self.reserved = 0  # new games past the session check, still loading their followers
        self.pools: dict[tuple, FollowerPool] = {}
        self._loading: dict[tuple, asyncio.Future] = {}
        self.ready = False  # the default follower and the compiled env step are loaded
        self.executor = ThreadPoolExecutor(max_workers=1, thread_name_prefix="follower")  # waits on the worker
        self.inference = InferenceWorker()  # every pool's policy runs in this process, away from the GIL here
        self.saver = ThreadPoolExecutor(max_workers=1, thread_name_prefix="replay-saver")
        self.lock = asyncio.Lock()  # one step at a time: ticks and turn-based keys never interleave
        self.stats = {"ticks": 0, "late_ticks": 0, "max_lateness_ms": 0.0, "deadline_misses": 0, "games_saved": 0,
                      "save_failures": 0, "policy_call_ms": {}}  # policy_call_ms: each trained one's, at warm-up
        self.lateness_ms: list[float] = []
        self._tasks: list[asyncio.Task] = []
        self._notices: set[asyncio.Task] = set()  # seat changes being told to the other people of a game
        self._endings: set[asyncio.Task] = set()  # games waiting out LATE_KEYS_S before they are saved
        self._clocks: dict[float, asyncio.Task] = {}
        self.listeners: list = []  # told game_started(game) and game_over(game, reason, scores): a study's records
        self._seed_counter = int(time.time())
        self.stopped = False
        # pools never freed: the default's, and the trained followers' and leaders' (building one would stall the
        # inference thread)
        self._offered: dict[Team, list[str]] | None = None  # team_followers, by team
        self._leading: dict[Team, dict[str, str]] | None = None  # team_leaders: how each offered leader leads
        self._seat_leading: dict[Team, list[str]] | None = None  # seat_leaders: beside a person in the follower seat
        self.warm_followers = {settings.follower, *(f for f in settings.follower_choices if not is_scripted(f))}
        self.keep_warm = {*self.warm_followers, *(kind for kind in settings.leaders if not is_scripted(kind))}

    # ------------------------------------------------------------ lifecycle
    def start(self) -> None:
        Path(self.settings.replays_dir).mkdir(parents=True, exist_ok=True)
        self._tasks = [asyncio.create_task(self._sweep_loop()), asyncio.create_task(self._warm_up())]
        self.clock(self.settings.tick_hz)

    async def _warm_up(self) -> None:
        """Load the default follower, and every offered trained follower and AI leader, for both modes before the
        first player waits on it: a trained network's first call pays for loading torch and the weights, and a
        pool is built on the inference thread, where games must not wait for it. Each trained one's call is then
        timed (``_time_calls``)."""
        loop = asyncio.get_running_loop()
        timed = set()
        for kind, team, role in self._warm_seats():
            for mode in Mode:
                config = self.make_config(self.settings.preset, mode, None, team)
                agents = (config.followers if role == "follower" else config.leaders if role == "lead a person"
                          else leader_seats(config, config.num_leaders - 1)[1])
                try:
                    for agent in agents:
                        pool, _ = await self.seat_pool(kind, config, agent)
                        await loop.run_in_executor(self.executor, pool.warm_up)
                    if kind not in timed and not is_scripted(kind):
                        timed.add(kind)
                        await loop.run_in_executor(self.executor, self._time_calls, pool)
                except Exception as err:
                    if role != "follower" and not isinstance(err, InferenceLost):  # one that cannot lead is not offered
                        log.error("AI leader %s is not offered in team %s: %s", kind, team.value, err)
                        self.team_leaders(team).pop(kind, None)
                        if kind in self.seat_leaders(team):
                            self.seat_leaders(team).remove(kind)
                        break
                    log.exception("could not warm up %s %s", role, kind)  # a game asking for it is told why
        gc.freeze()  # what start-up loaded (torch, the networks) is left out of later collections
        self.ready = True

    def _warm_seats(self) -> list[tuple[str, Team, str]]:
        """``(kind, team, role)`` of the pools made at start-up: the default follower first (in 1:1 when it is
        scripted), each trained follower in each team it plays, each trained AI leader in each team it leads."""
        seats = []
        for follower in sorted(self.warm_followers, key=lambda f: f != self.settings.follower):
            teams = ([Team.ONE_TO_ONE] if is_scripted(follower)
                     else [t for t in Team if follower in self.team_followers(t)])
            seats += [(follower, team, "follower") for team in teams]
        for leader in self.keep_warm - self.warm_followers:
            seats += [(leader, team, "leader") for team in Team if leader in self.team_leaders(team)]
            seats += [(leader, team, "lead a person") for team in Team if leader in self.seat_leaders(team)]
        return seats

    def _time_calls(self, pool: FollowerPool) -> None:
        """Time one call of ``pool``'s policy for one game and for ``max_sessions`` games on this machine, record
        it (``stats["policy_call_ms"]``, in ``/api/health``) and warn when a full server's call would miss the
        inference deadline: past about ``within_deadline`` games at once, every step of every game it plays takes
        the fallback move (a large network on a small CPU: the paper's, docs/PAPER_CODE.md)."""
        games, deadline = self.settings.max_sessions, self.settings.inference_deadline_ms
        one = pool.call_ms(1)
        full = pool.call_ms(games) if games > 1 else one
        per_game = (full - one) / max(1, games - 1)
        within = 0 if one > deadline else games if full <= deadline else 1 + int((deadline - one) / per_game)
        self.stats["policy_call_ms"][pool.name] = {"one_game": round(one, 1), "games": games,
                                                   "all_games": round(full, 1), "within_deadline": within}
        if within < games:
            log.warning("%s: one call takes %.0f ms for one game and %.0f ms for %d (max_sessions) on this machine; "
                        "past about %d games at once it misses the %.0f ms inference deadline and its games take the "
                        "fallback move", pool.name, one, full, games, within, deadline)

    async def stop(self) -> list[Client]:
        """Save every live game and tell its people (``game_over``, reason ``server_shutdown``); close every
        waiting room (``room_closed``).

        Returns the connections that were told, so the caller can close them once the message is
        out. Each game is saved on its own: one that fails is logged and the rest are still saved.
        Calling it again does nothing.
        """
        if self.stopped:
            return []
        self.stopped = True
        for task in [*self._tasks, *self._endings]:
            task.cancel()
        told = [s.client for g in [*self.games.values(), *self.ending.values()] for s in g.people
                if s.client is not None]
        told += [m.client for room in self.rooms.values() for m in room.members if m is not None]
        for room in list(self.rooms.values()):
            await self._close_room(room, "server_shutdown", "the server is shutting down; try again in a minute")
        for game in list(self.ending.values()):  # complete already: saved as such, without waiting for late keys
            await self.finish(game, "complete")
        for game in list(self.games.values()):
            try:
                await self.finish(game, "server_shutdown")
            except Exception:
                log.exception("could not finish game %s at shutdown", game.game_id)
        self.executor.shutdown(wait=False, cancel_futures=True)
        await asyncio.get_running_loop().run_in_executor(None, self.inference.stop)
        self.saver.shutdown(wait=True)
        return told

    # ------------------------------------------------------------ sessions
    def make_config(self, preset: str, mode: Mode, horizon: int | None, team: Team = Team.ONE_TO_ONE) -> EnvConfig:
        changes = {}
        if team != Team.ONE_TO_ONE:
            changes.update(num_leaders=team.num_leaders, num_followers=team.num_followers)
        if mode == Mode.REALTIME:
            changes["allow_stay"] = True  # the leader stays when no key is pending
        if horizon is not None:
            changes["horizon"] = horizon
        return env_config(preset, **changes)

    async def pool_for(self, follower: str, config: EnvConfig, agent_index: int = FOLLOWER) -> FollowerPool:
        """The pool for this follower, config and agent index, built on the inference thread (loading never
        blocks the loop)."""
        key = (follower, config, agent_index)
        if key in self.pools:
            return self.pools[key]
        loading = self._loading.get(key)
        if loading is None:  # the first game to ask builds it; games arriving meanwhile wait for the same one
            loading = asyncio.get_running_loop().run_in_executor(
                self.executor, partial(FollowerPool, follower, config, self.settings.max_sessions,
                                       agent_index=agent_index, worker=self.inference))
            self._loading[key] = loading
        try:
            pool = await asyncio.shield(loading)
        finally:
            if loading.done():
                self._loading.pop(key, None)
        self.pools.setdefault(key, pool)
        return self.pools[key]

    def clock(self, tick_hz: float) -> None:
        """Make sure real-time games at ``tick_hz`` have a clock (one per rate in use; studies may vary it)."""
        if tick_hz not in self._clocks:
            self._clocks[tick_hz] = asyncio.create_task(self._tick_loop(tick_hz))
            self._tasks.append(self._clocks[tick_hz])

    async def seat_pool(self, kind: str, config: EnvConfig, agent: int) -> tuple[FollowerPool, tuple[int, int] | None]:
        """The pool that plays ``kind`` at agent ``agent`` of ``config``, and the agents it sees when it sees the game
        as a 1:1 game (``PAIR_VIEW``: a network trained in 1:1 in a leader seat of a larger team; its pool is
        built for the 1:1 team's leader), else None."""
        fit = self.leader_fit(kind, Team(config.team)) if config.roles[agent] == "leader" else None
        if fit == PAIR_VIEW:
            pair = dataclasses.replace(config, num_leaders=1, num_followers=1)
            return await self.pool_for(kind, pair, LEADER), (agent, *config.followers)
        return await self.pool_for(kind, config, agent), None

    def leader_fit(self, kind: str, team: Team) -> str | None:
        """How AI leader ``kind`` plays a leader seat of ``team`` (``followers.leads``; an offered one's is read
        once), or None."""
        return self.team_leaders(team).get(kind) if kind in self.settings.leaders else leads(kind, team)

    def team_leaders(self, team: Team) -> dict[str, str]:
        """The offered AI leaders (``ServerSettings.leaders``) that play a leader seat beside a person in ``team``,
        each with how it plays it (``followers.leads``); none in a team of one leader."""
        if self._leading is None:  # once: a checkpoint file is read to know its team
            self._leading = {t: {kind: fit for kind in self.settings.leaders if (fit := leads(kind, t))}
                             if t.num_leaders > 1 else {} for t in Team}
        return self._leading[team]

    def seat_leaders(self, team: Team) -> list[str]:
        """The offered AI leaders (``ServerSettings.leaders``) that lead beside a person in ``team``'s follower seat
        (``server.seats.follower_seat_leaders``); none in a team without one."""
        if self._seat_leading is None:  # once: a checkpoint file is read to know its team
            self._seat_leading = {t: follower_seat_leaders(self.settings.leaders, t) for t in Team}
        return self._seat_leading[team]

    def team_followers(self, team: Team = Team.TWO_FOLLOWERS) -> list[str]:
        """The offered followers that play in ``team`` (a trained network only in the team it was trained in),
        the default first if it does."""
        if self._offered is None:  # once: a checkpoint file is read to know its team
            self._offered = {t: [f for f in self.settings.follower_choices if plays(f, t)] for t in Team}
        return self._offered[team]

    def choose(self, team: Team, follower: str | None, preset: str | None, mode: Mode, horizon: int | None,
               followers: list[str] | None = None,
               seat: SeatKind = SeatKind.LEADER) -> tuple[tuple[str, ...], str, EnvConfig]:
        """The followers (one per AI seat, in agent order), preset and config of a new game or room: every seat
        ``follower``, or each its own of ``followers``; what is not offered raises ``ValueError``. A person in the
        follower ``seat`` takes the first follower's (the AI followers are the others)."""
        if followers is not None and follower is not None:
            raise ValueError("give either follower (every AI seat) or followers (one per AI seat), not both")
        ai_seats = team.num_followers - (SeatKind(seat) == SeatKind.FOLLOWER)
        if followers is not None and len(followers) != ai_seats:
            beside = " beside a person in its follower seat" if ai_seats < team.num_followers else ""
            raise ValueError(f"followers: team {team.value} has {ai_seats} AI follower(s){beside}; give one name "
                             f"each, got {len(followers)}")
        offered = self.team_followers(team)
        default = self.settings.follower if self.settings.follower in offered else next(iter(offered), None)
        chosen = tuple(followers) if followers is not None else (follower or default,) * ai_seats
        for name in chosen:
            if name not in self.settings.follower_choices:
                raise ValueError(f"unknown follower {name!r}; choose one of {list(self.settings.follower_choices)}")
            if name not in offered:
                raise ValueError(f"follower {name!r} does not play in team {team.value} (a trained network plays the "
                                 f"team it was trained in: {'/'.join(policy_teams(name) or ())}); for team "
                                 f"{team.value} choose one of {offered}")
        preset = preset or self.settings.preset
        return chosen, preset, self.make_config(preset, mode, horizon, team)

    def check_capacity(self) -> None:
        """Refuse a new game or room past ``max_sessions`` (games, games being made and waiting rooms)."""
        running = self.live_games() + self.reserved + len(self.rooms)
        if self.stopped or running >= self.settings.max_sessions:
            raise ServerFull(f"server full: {running} games are running (limit {self.settings.max_sessions});"
                             " try again in a minute")

    def live_games(self) -> int:
        """Games in play or past their last step but not yet saved (each holds its followers' slots)."""
        return len(self.games) + len(self.ending)

    async def new_game(self, follower: str | None, preset: str | None, mode: Mode, horizon: int | None,
                       show_belief: bool, client: Client, tick_hz: float | None = None, study: dict | None = None,
                       client_info: dict | None = None, team: Team = Team.ONE_TO_ONE,
                       followers: list[str] | None = None, leader: str | None = None,
                       seat: SeatKind = SeatKind.LEADER, goal: GoalView | None = None,
                       probes: str | None = None) -> Game:
        """Start a game for ``client``, the team's one person; in a team of several leaders, ``leader`` (an offered
        AI leader, ``team_leaders``) plays every other leader seat. In the follower ``seat`` (``server.seats``),
        ``leader`` plays every leader seat, ``goal`` says whether the person sees the goal and ``probes`` when the
        game asks what they believe. ``tick_hz`` (default: the server's) sets a real-time game's clock; ``study`` is
        what a study's game records about itself (``meta.study``)."""
        team, seat = Team(team), SeatKind(seat)
        if seat == SeatKind.FOLLOWER:
            choice = follower_seat(team, leader, goal, probes, self.seat_leaders(team), self.settings.leaders)
        else:
            leader_seat(goal, probes)
            choice = SeatChoice(self.choose_leaders(team, leader), GoalView.SHOWN, ProbePlan())
            if team.room and not choice.leaders:
                raise ValueError(f"team {team.value} has {team.people} leaders: people meet in a room (create_room, "
                                 f"then share its code), or one person plays beside an AI leader (leader: one of "
                                 f"{list(self.team_leaders(team))})")
        chosen, preset, config = self.choose(team, follower, preset, Mode(mode), horizon, followers, seat)
        return await self._open_game(config, Mode(mode), chosen, preset, show_belief, [(client, client_info or {})],
                                     tick_hz=tick_hz, study=study, leaders=choice.leaders, seat=seat,
                                     goal_view=choice.goal_view, probes=choice.probes)

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

    async def _open_game(self, config: EnvConfig, mode: Mode, followers: tuple[str, ...], preset: str,
                         show_belief: bool, people: list[tuple[Client, dict]], tick_hz: float | None = None,
                         study: dict | None = None, room: str | None = None, leaders: tuple[str, ...] = (),
                         seat: SeatKind = SeatKind.LEADER, goal_view: GoalView = GoalView.SHOWN,
                         probes: ProbePlan | None = None) -> Game:
        """Make a game for ``people`` (connection and page info, one per person's seat, in agent order), with a
        slot in each AI follower's pool (``followers``: one kind per AI follower, in agent order) and each AI
        leader's (``leaders``: one kind per leader seat after the people's, or every one beside a person in the
        follower ``seat``); send each person their ``welcome`` and the first ``state``."""
        # The session is counted before the first await, so concurrent requests never overshoot the limit.
        self.check_capacity()
        self.reserved += 1
        try:
            _, ai_leaders, ai_followers = lineup(config, seat, len(leaders))
            ai = [*zip(followers, ai_followers), *zip(leaders, ai_leaders)]
            pools = [(agent, *await self.seat_pool(kind, config, agent)) for kind, agent in ai]
            if self.stopped:
                raise ServerFull("the server is shutting down; try again in a minute")
            self._seed_counter += 1
            game = Game(config=config, mode=mode, follower=follower_label(followers), follower_kinds=tuple(followers),
                        leader_kinds=tuple(leaders), preset=preset, seed=self._seed_counter,
                        show_belief=show_belief and self.settings.show_belief, max_key_log=self.settings.max_key_log,
                        tick_hz=tick_hz or self.settings.tick_hz, study=study, room=room, seat=seat,
                        goal_view=goal_view, probes=probes or ProbePlan())
            for seat, (client, client_info) in zip(game.seats, people):
                seat.client, seat.client_info = client, client_info
            for agent, pool, view in pools:
                game.attach(agent, pool, pool.acquire(), view)
            try:
                for listener in self.listeners:  # recorded before the player sees the game
                    await asyncio.get_running_loop().run_in_executor(self.saver, listener.game_started, game)
            except BaseException:
                self._release(game)
                raise
            self.games[game.game_id] = game  # counted here before the reservation ends: no gap
        finally:
            self.reserved -= 1
        if game.mode == Mode.REALTIME:
            self.clock(game.tick_hz)
        for seat in game.seats:
            await self._send_to(seat.client, game.welcome(seat))
        await self._send(game, game.state_message())
        return game

    async def rejoin(self, game_id: str, token: str, client: Client) -> Game:
        """Give a seat of the game to ``client`` (the seat whose token it is); a connection that still had it
        is told ``replaced`` and loses it."""
        game = self.games.get(game_id)
        seat = next((s for s in game.people if secrets_equal(s.token, token)), None) if game is not None else None
        if seat is None:
            raise ValueError("no game with that id and token is waiting (it may have ended or the grace period passed)")
        previous = seat.client
        if previous is not None and previous is not client:
            previous.detach()
            await self._send_to(previous, {"type": "replaced", "game_id": game_id,
                                           "message": "this game was taken over by another connection"})
        was_away = previous is None
        seat.client, seat.disconnected_at, seat.last_key_at = client, None, time.monotonic()
        await client.send(game.welcome(seat))
        await client.send(game.state_message())
        if was_away and not game.solo:
            await self._send_seats(game)
        if game.mode == Mode.TURN:  # the others may all have moved while this person was away
            await self.step_games([game])
        return game

    def controls(self, game: Game, client: Client) -> bool:
        """Whether ``client`` plays ``game`` now (it is live and was not taken over, and the person is in it)."""
        return game.game_id in self.games and game.seat_of(client) is not None

    def seat_of(self, game: Game | None, client: Client) -> Seat | None:
        """The seat ``client`` plays in ``game`` while the game takes its keys: it is live, or it has made its last
        step and takes the keys still on their way (``LATE_KEYS_S``); else None."""
        if game is None or (game.game_id not in self.games and game.game_id not in self.ending):
            return None
        return game.seat_of(client)

    def disconnect(self, game: Game, client: Client) -> None:
        """``client`` closed: its seat waits for a rejoin (a connection that was replaced changes nothing)."""
        seat = game.seat_of(client) if game.game_id in self.games else None
        if seat is not None:
            seat.client, seat.disconnected_at = None, time.monotonic()
            if not game.solo:  # the others see the seat reconnecting
                notice = asyncio.get_running_loop().create_task(self._send_seats(game))
                self._notices.add(notice)
                notice.add_done_callback(self._notices.discard)

    async def key(self, game: Game, key: str, seq: int, t_client: float, seat: Seat | None = None) -> str | None:
        """A key of the person in ``seat`` (the first by default); a turn-based game steps once everyone moved."""
        problem = game.press(key, seq, t_client, seat)
        if problem is None and game.mode == Mode.TURN:
            await self.step_games([game])
        return problem

    async def answer_probe(self, game: Game, probe: int, color: int, confidence: float, t_client: float) -> None:
        """The answer to ``game``'s open probe; a turn-based game waited for it, and steps now if a move is
        pending."""
        game.answer_probe(probe, color, confidence, t_client)
        if game.mode == Mode.TURN:
            await self.step_games([game])

    async def quit(self, game: Game, client: Client) -> None:
        """The person on ``client`` ends the game; in a game other people still play, only leaves it."""
        seat = game.seat_of(client)
        if seat is not None:
            await self._leave(game, seat, "quit")

    async def _leave(self, game: Game, seat: Seat, reason: str) -> None:
        """The person in ``seat`` is gone (``quit``, ``disconnected``, ``idle``). The last person's leaving ends
        the game; otherwise the scripted leader (``STAND_IN``) plays on in the seat, and the person is told
        ``game_over`` with reason ``left``."""
        if game.game_id not in self.games or seat.left is not None:
            return
        if len(game.people) == 1:
            await self.finish(game, reason)
            return
        client = seat.client
        game.leave(seat, reason)
        if client is not None:
            client.detach()
            await self._send_to(client, self._game_over(game, "left", None))
        await self._send_seats(game)
        try:
            pool = await self.pool_for(STAND_IN, game.config, seat.agent)
        except Exception:  # without a stand-in the seat could never move again: end the game, saved
            log.exception("could not load the stand-in leader for game %s", game.game_id)
            await self.finish(game, "stand_in_failed")
            return
        if game.game_id not in self.games:  # ended while the stand-in loaded
            return
        game.attach(seat.agent, pool, pool.acquire())
        if game.mode == Mode.TURN:  # the others' keys may all be waiting
            await self.step_games([game])

    # ------------------------------------------------------------ rooms
    async def create_room(self, team: Team, follower: str | None, preset: str | None, mode: Mode,
                          horizon: int | None, show_belief: bool, client: Client,
                          client_info: dict | None = None) -> Room:
        """Open a room for ``team`` with ``client`` in its first seat; it counts as a session until its game
        starts or it closes."""
        team, mode = Team(team), Mode(mode)
        if not team.room:
            raise ValueError(f"team {team.value} has one person: start it with new_game (rooms are for teams of "
                             "several people)")
        chosen, preset, config = self.choose(team, follower, preset, mode, horizon)
        self.check_capacity()
        room = Room(code=new_code(self.rooms), team=team, config=config, followers=chosen, preset=preset, mode=mode,
                    show_belief=show_belief, tick_hz=self.settings.tick_hz)
        room.join(client, client_info or {})
        self.rooms[room.code] = room
        await self._send_room(room)
        return room

    async def join_room(self, code: str, client: Client, client_info: dict | None = None) -> Room:
        """Seat ``client`` in the room with ``code``; unknown, started and full rooms raise ``RoomError``."""
        code = parse_code(code)
        room = self.rooms.get(code)
        if room is None:
            if any(g.room == code for g in self.games.values()):
                raise RoomError("room_started", f"the game of room {code} has already started")
            raise RoomError("room_not_found", f"no room {code} is waiting (it may have expired or closed)")
        room.join(client, client_info or {})
        await self._send_room(room)
        return room

    def room_of(self, client: Client, room: Room | None) -> Room | None:
        """``room`` if it still waits and ``client`` sits in it, else None."""
        live = room is not None and self.rooms.get(room.code) is room and room.seat_of(client) is not None
        return room if live else None

    async def set_ready(self, room: Room, client: Client, ready: bool = True) -> None:
        """Mark ``client``'s seat ready (or not); once every seat is taken and ready the game starts, after a
        countdown in real time (``ROOM_COUNTDOWN_S``) that every page shows."""
        seat = room.seat_of(client)
        if room.starting_in_s is not None:
            if not ready:
                raise ValueError("the game is starting: it can no longer be delayed")
            return
        room.members[seat].ready = ready
        if room.all_ready:
            room.starting_in_s = ROOM_COUNTDOWN_S if room.mode == Mode.REALTIME else 0
            room.start_task = asyncio.create_task(self._start_room(room))
        await self._send_room(room)

    async def leave_room(self, room: Room, client: Client) -> None:
        """``client`` leaves a waiting room (quit, or its socket closed); an empty room closes. A countdown
        under way stops (everyone's ``ready`` is cleared)."""
        if self.rooms.get(room.code) is not room:
            if room.opening:  # closed while the game was being made: its seat waits for a rejoin
                room.dropped.append(client)
            return
        room.leave(client)
        if room.start_task is not None:
            room.start_task.cancel()
            room.start_task, room.starting_in_s = None, None
            for member in room.members:
                if member is not None:
                    member.ready = False
        if room.empty:
            del self.rooms[room.code]
        else:
            await self._send_room(room)

    async def _start_room(self, room: Room) -> None:
        await asyncio.sleep(room.starting_in_s)
        if self.rooms.get(room.code) is not room or not room.all_ready:
            return
        del self.rooms[room.code]  # its session passes to the game (no await between: nothing overtakes it)
        room.opening = True
        people = [(m.client, m.client_info) for m in room.members]
        try:
            game = await self._open_game(room.config, room.mode, room.followers, room.preset, room.show_belief,
                                         people, tick_hz=room.tick_hz, room=room.code)
        except Exception as err:  # ServerFull while stopping, a follower that does not load
            log.exception("could not start the game of room %s", room.code)
            for client, _ in people:
                client.detach()
                await self._send_to(client, room.closed_message("failed", f"the game could not start: {err}"))
            return
        finally:
            room.opening = False
        for client, _ in people:
            if client not in room.dropped:
                client.attach(game)
        for client, _ in people:  # its welcome (and rejoin token) went to a closed socket: it can never come back
            seat = game.seat_of(client) if client in room.dropped else None
            if seat is not None:
                await self._leave(game, seat, "disconnected")

    async def _close_room(self, room: Room, reason: str, message: str) -> None:
        if self.rooms.pop(room.code, None) is None:
            return
        if room.start_task is not None:
            room.start_task.cancel()
        for member in room.members:
            if member is not None:
                member.client.detach()
                await self._send_to(member.client, room.closed_message(reason, message))

    async def _send_room(self, room: Room) -> None:
        for seat, member in enumerate(room.members):
            if member is not None:
                await self._send_to(member.client, room.message(seat))

    async def _send_seats(self, game: Game) -> None:
        """Tell the people of a team game how each seat stands (``seats``)."""
        await self._send(game, {"type": "seats", "seats": game.seats_view()})

    # ------------------------------------------------------------ stepping
    async def step_games(self, games: list[Game]) -> None:
        """Advance ``games`` one step: one batched call per pool (every AI player of these games that the pool
        plays), then each game's env steps."""
        async with self.lock:
            games = [g for g in games if g.ready() and g.game_id in self.games]
            by_pool: dict[int, list] = {}  # every AI player of these games, by the pool that plays it
            for g in games:
                for player in g.ai.values():
                    by_pool.setdefault(id(player.pool), []).append((g, player))
            moves: dict[str, dict] = {g.game_id: {} for g in games}
            for group in by_pool.values():
                pool = group[0][1].pool
                inputs = [g.ai_input(player) for g, player in group]
                slots = [player.slot for _, player in group]
                actions, beliefs, missed = await self._infer(pool, inputs, slots)
                for i, (g, player) in enumerate(group):
                    belief = beliefs[i] if beliefs is not None else None
                    moves[g.game_id][player.agent] = (int(actions[i]), belief, missed)
            for g in games:
                g.apply(moves[g.game_id])
            for g in games:
                await self._send(g, g.state_message())
                if g.finished and g.mode == Mode.REALTIME:
                    self._end_after_late_keys(g)
                elif g.finished:
                    await self.finish(g, "complete")  # never raises: one game's failure is its own

    def _end_after_late_keys(self, game: Game) -> None:
        """Real-time ``game`` made its last step: keys still on their way are logged ``unapplied`` for ``LATE_KEYS_S``,
        then it is saved and its people told ``game_over`` (off the tick: no other game waits for it)."""
        self.games.pop(game.game_id, None)
        self.ending[game.game_id] = game

        async def end() -> None:
            await asyncio.sleep(LATE_KEYS_S)
            await self.finish(game, "complete")  # never raises: one game's failure is its own

        task = asyncio.get_running_loop().create_task(end())
        self._endings.add(task)
        task.add_done_callback(self._endings.discard)

    async def _infer(self, pool: FollowerPool, inputs, slots):
        """Run the pool within the deadline; on a miss, fall back to idle moves and say so."""
        deadline = self.settings.inference_deadline_ms / 1000.0
        if pool.pending is None or pool.pending.done():
            loop = asyncio.get_running_loop()
            future = pool.pending = loop.run_in_executor(self.executor, pool.act, inputs, slots)
            try:
                actions, beliefs = await asyncio.wait_for(asyncio.shield(future), deadline)
                return actions, beliefs, False
            except TimeoutError:  # the call goes on; its late failure, if any, is logged
                future.add_done_callback(lambda f: f.cancelled() or f.exception() is None or log.error(
                    "follower %s failed after its deadline: %s", pool.name, f.exception()))
            except InferenceLost as err:  # a new process serves the next call; this step takes the fallback
                log.error("follower %s: %s", pool.name, err)
            except Exception:  # a policy's own failure costs its games this step's move, not the tick
                log.exception("follower %s failed", pool.name)
        self.stats["deadline_misses"] += len(slots)
        log.warning("follower %s missed its %.0f ms deadline for %d game(s)", pool.name, deadline * 1000, len(slots))
        return pool.fallback(inputs, slots), None, True

    async def _tick_loop(self, tick_hz: float) -> None:
        period = 1.0 / tick_hz
        next_tick = time.perf_counter() + period
        while True:
            await asyncio.sleep(max(0.0, next_tick - time.perf_counter()))
            lateness = (time.perf_counter() - next_tick) * 1000.0
            live = [g for g in self.games.values()
                    if g.mode == Mode.REALTIME and g.tick_hz == tick_hz and not g.paused]
            if live:  # lateness matters to games: ticks with none to step are not counted
                self._record_lateness(lateness)
            if live and lateness > 50:
                log.warning("tick %.0f ms late (%d real-time games, %d games in all)", lateness, len(live),
                            len(self.games))
            if live:
                try:
                    await self.step_games(live)
                except Exception:  # a bug in one tick must not stop every game
                    log.exception("tick failed")
            next_tick += period
            if time.perf_counter() > next_tick + period:  # fell far behind: skip, do not burst
                next_tick = time.perf_counter() + period

    def _record_lateness(self, ms: float) -> None:
        self.stats["ticks"] += 1
        self.stats["late_ticks"] += ms > 20
        self.stats["max_lateness_ms"] = max(self.stats["max_lateness_ms"], ms)
        self.lateness_ms.append(ms)
        del self.lateness_ms[:-5000]

    async def _sweep_loop(self) -> None:
        while True:
            await asyncio.sleep(0.5)
            try:
                await self.sweep()
            except Exception:  # the sweeper must outlive any bug: later games still need saving
                log.exception("sweep failed")

    async def sweep(self) -> None:
        """People gone past the rejoin grace or idle too long leave their games (the last one's leaving ends
        it); rooms waiting too long close; follower pools nobody uses are freed."""
        now = time.monotonic()
        for game in list(self.games.values()):
            for seat in game.people:
                if seat.disconnected_at is not None and now - seat.disconnected_at > self.settings.rejoin_grace_s:
                    await self._leave(game, seat, "disconnected")
                elif now - seat.last_key_at > self.settings.idle_timeout_s:
                    await self._leave(game, seat, "idle")
        for room in list(self.rooms.values()):
            if room.starting_in_s is None and now - room.created > self.settings.room_wait_s:
                await self._close_room(room, "expired", f"nobody started the game within "
                                                        f"{self.settings.room_wait_s:g} s")
        for key, pool in list(self.pools.items()):
            if key[0] not in self.keep_warm and pool.idle_for() > POOL_IDLE_S:
                del self.pools[key]
                self.executor.submit(pool.close)  # queued behind inference; the sweep does not wait for it

    # ------------------------------------------------------------ ending
    async def finish(self, game: Game, reason: str) -> None:
        """Save the game's replay (atomically) and tell its people; idempotent, and never raises:
        a game that cannot be saved is logged and counted, and its people still get ``game_over``."""
        if self.games.pop(game.game_id, None) is None and self.ending.pop(game.game_id, None) is None:
            return
        game.finished = True
        self._release(game)
        if game.actions:
            try:
                await self._save(game, reason)
            except Exception:
                self.stats["save_failures"] += 1
                log.exception("could not save game %s (%s)", game.game_id, reason)
        for listener in self.listeners:
            try:
                await asyncio.get_running_loop().run_in_executor(self.saver, listener.game_over, game, reason,
                                                                 scores(game.env.state, game.env.config))
            except Exception:
                log.exception("a listener failed on the end of game %s", game.game_id)
        over = self._game_over(game, reason, game.replay_id)
        for seat in game.people:
            if seat.client is not None:
                await self._send_to(seat.client, over)

    @staticmethod
    def _game_over(game: Game, reason: str, replay_id: str | None) -> dict:
        s = game.env.state
        return {"type": "game_over", "reason": reason, "replay_id": replay_id, "steps": int(s.t[0]),
                "scores": scores(s, game.env.config)}

    @staticmethod
    def _release(game: Game) -> None:
        for player in game.ai.values():
            player.pool.release(player.slot)

    async def _save(self, game: Game, reason: str) -> None:
        stamp = time.strftime("%Y%m%dT%H%M%S", time.gmtime(game.created))
        replay_id = f"play-{stamp}-{game.game_id}"
        replay = game.to_replay(reason, {agent: player.pool.describe() for agent, player in game.ai.items()})
        # Written (atomically, fsynced) on a worker thread so saving never stalls the tick.
        path = Path(self.settings.replays_dir) / f"{replay_id}.replay.json"
        await asyncio.get_running_loop().run_in_executor(self.saver, save, replay, path)
        game.replay_id = replay_id
        self.stats["games_saved"] += 1

    async def _send(self, game: Game, message: dict) -> None:
        """To every person still in ``game``."""
        for seat in game.people:
            if seat.client is not None:
                await self._send_to(seat.client, message)

    @staticmethod
    async def _send_to(client: Client, message: dict) -> None:
        try:
            await client.send(message)
        except Exception:  # a closed socket: the disconnect handler takes care of the game
            pass


def secrets_equal(a: str, b: str) -> bool:
    import hmac

    return hmac.compare_digest(a.encode(), b.encode())
