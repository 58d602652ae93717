"""The game hub: every live game, the real-time tick, batched follower inference, saving."""

from __future__ import annotations

import asyncio
import gc
import logging
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Protocol

import numpy as np

from colorgrid.policies import SCRIPTED
from colorgrid.presets import env_config
from colorgrid.config import EnvConfig
from colorgrid.replay import save
from colorgrid.replay.format import describe_agent
from colorgrid.roles import scores
from server.followers import FollowerPool, build_pool
from server.game import Game
from server.protocol import Mode
from server.settings import ServerSettings

log = logging.getLogger("colorgrid.server")
POOL_IDLE_S = 120.0  # a follower pool with no game for this long is freed (the default follower's stay)


class Client(Protocol):
    """What the hub needs of a player's connection."""

    async def send(self, message: dict) -> None: ...

    def detach(self) -> None:
        """The connection no longer controls its game (another connection took it over)."""


class ServerFull(Exception):
    pass


class GameHub:
    """Owns all games. Real-time games advance together on one clock (``tick_hz``), with one
    batched follower call per follower pool per tick; turn-based games advance on a key."""

    def __init__(self, settings: ServerSettings):
        self.settings = settings
        self.games: dict[str, Game] = {}
        self.clients: dict[str, Client | None] = {}  # game id -> the connection playing it (None: waiting)
        self.reserved = 0  # new games past the session check, still loading their follower
        self.pools: dict[tuple, FollowerPool] = {}
        self._loading: dict[tuple, asyncio.Future] = {}
        self.ready = False  # the default follower and the compiled env step are loaded
        self.executor = ThreadPoolExecutor(max_workers=1, thread_name_prefix="follower")
        self.saver = ThreadPoolExecutor(max_workers=1, thread_name_prefix="replay-saver")
        self.lock = asyncio.Lock()  # one step at a time: ticks and turn-based keys never interleave
        self.stats = {"ticks": 0, "late_ticks": 0, "max_lateness_ms": 0.0, "deadline_misses": 0, "games_saved": 0,
                      "save_failures": 0}
        self.lateness_ms: list[float] = []
        self._tasks: list[asyncio.Task] = []
        self._clocks: dict[float, asyncio.Task] = {}
        self.listeners: list = []  # told game_started(game) and game_over(game, reason, scores): a study's records
        self._seed_counter = int(time.time())
        self.stopped = False
        # pools never freed: the default's, and the trained followers' (building one would stall the inference thread)
        self.keep_warm = {settings.follower, *(f for f in settings.follower_choices
                                               if f.partition(":")[0] not in SCRIPTED)}

    # ------------------------------------------------------------ lifecycle
    def start(self) -> None:
        Path(self.settings.replays_dir).mkdir(parents=True, exist_ok=True)
        self._tasks = [asyncio.create_task(self._sweep_loop()), asyncio.create_task(self._warm_up())]
        self.clock(self.settings.tick_hz)

    async def _warm_up(self) -> None:
        """Load the default follower, and every offered trained one, for both modes before the first player
        waits on it: a trained network's first call pays for loading torch and the weights, and a pool is
        built on the inference thread, where games must not wait for it."""
        for follower in sorted(self.keep_warm, key=lambda f: f != self.settings.follower):  # the default first
            for mode in Mode:
                try:
                    pool = await self.pool_for(follower, self.make_config(self.settings.preset, mode, None))
                    await asyncio.get_running_loop().run_in_executor(self.executor, pool.warm_up)
                except Exception:  # a bad follower is reported when a game asks for it
                    log.exception("could not warm up follower %s", follower)
        gc.freeze()  # what start-up loaded (torch, the networks) is left out of later collections
        self.ready = True

    async def stop(self) -> list[Client]:
        """Save every live game and tell its player (``game_over``, reason ``server_shutdown``).

        Returns the connections that were told, so the caller can close them once the message is
        out. Each game is saved on its own: one that fails is logged and the rest are still saved.
        Calling it again does nothing.
        """
        if self.stopped:
            return []
        self.stopped = True
        for task in self._tasks:
            task.cancel()
        told = [c for c in self.clients.values() if c is not None]
        for game in list(self.games.values()):
            try:
                await self.finish(game, "server_shutdown")
            except Exception:
                log.exception("could not finish game %s at shutdown", game.game_id)
        self.executor.shutdown(wait=False, cancel_futures=True)
        self.saver.shutdown(wait=True)
        return told

    # ------------------------------------------------------------ sessions
    def make_config(self, preset: str, mode: Mode, horizon: int | None) -> EnvConfig:
        changes = {}
        if mode == Mode.REALTIME:
            changes["allow_stay"] = True  # the leader stays when no key is pending
        if horizon is not None:
            changes["horizon"] = horizon
        return env_config(preset, **changes)

    async def pool_for(self, follower: str, config: EnvConfig) -> FollowerPool:
        """The pool for this follower and config, built on the inference thread (loading never blocks the loop)."""
        key = (follower, config)
        if key in self.pools:
            return self.pools[key]
        loading = self._loading.get(key)
        if loading is None:  # the first game to ask builds it; games arriving meanwhile wait for the same one
            loading = asyncio.get_running_loop().run_in_executor(
                self.executor, build_pool, follower, config, self.settings.max_sessions)
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

    async def new_game(self, follower: str | None, preset: str | None, mode: Mode, horizon: int | None,
                       show_belief: bool, client: Client, tick_hz: float | None = None, study: dict | None = None,
                       client_info: dict | None = None) -> Game:
        """Start a game for ``client``. ``tick_hz`` (default: the server's) sets a real-time game's clock;
        ``study`` is what a study's game records about itself (its replay's ``meta.study``)."""
        follower = follower or self.settings.follower
        if follower not in self.settings.follower_choices:
            raise ValueError(f"unknown follower {follower!r}; choose one of {list(self.settings.follower_choices)}")
        preset = preset or self.settings.preset
        config = self.make_config(preset, mode, horizon)
        # The session is counted before the first await, so concurrent requests never overshoot the limit.
        running = len(self.games) + self.reserved
        if self.stopped or running >= self.settings.max_sessions:
            raise ServerFull(f"server full: {running} games are running (limit {self.settings.max_sessions});"
                             " try again in a minute")
        self.reserved += 1
        try:
            pool = await self.pool_for(follower, config)
            if self.stopped:
                raise ServerFull("the server is shutting down; try again in a minute")
            self._seed_counter += 1
            game = Game(config=config, mode=mode, follower=follower, preset=preset, seed=self._seed_counter,
                        show_belief=show_belief and self.settings.show_belief, slot=pool.acquire(), pool=pool,
                        max_key_log=self.settings.max_key_log, tick_hz=tick_hz or self.settings.tick_hz,
                        study=study, client=client_info or {})
            try:
                for listener in self.listeners:  # recorded before the player sees the game
                    await asyncio.get_running_loop().run_in_executor(self.saver, listener.game_started, game)
            except BaseException:
                pool.release(game.slot)
                raise
            self.games[game.game_id] = game  # counted here before the reservation ends: no gap
        finally:
            self.reserved -= 1
        if game.mode == Mode.REALTIME:
            self.clock(game.tick_hz)
        self.clients[game.game_id] = client
        await client.send(game.welcome())
        await client.send(game.state_message())
        return game

    async def rejoin(self, game_id: str, token: str, client: Client) -> Game:
        """Give the game to ``client``; a connection that still had it is told ``replaced`` and loses it."""
        game = self.games.get(game_id)
        if game is None or not secrets_equal(game.token, token):
            raise ValueError("no game with that id and token is waiting (it may have ended or the grace period passed)")
        previous = self.clients.get(game_id)
        if previous is not None and previous is not client:
            previous.detach()
            await self._send_to(previous, {"type": "replaced", "game_id": game_id,
                                           "message": "this game was taken over by another connection"})
        game.disconnected_at = None
        game.last_key_at = time.monotonic()
        self.clients[game_id] = client
        await client.send(game.welcome())
        await client.send(game.state_message())
        return game

    def controls(self, game: Game, client: Client) -> bool:
        """Whether ``client`` plays ``game`` now (it is live and was not taken over)."""
        return game.game_id in self.games and self.clients.get(game.game_id) is client

    def disconnect(self, game: Game, client: Client) -> None:
        """``client`` closed: its game waits for a rejoin (a connection that was replaced changes nothing)."""
        if self.controls(game, client):
            self.clients[game.game_id] = None
            game.disconnected_at = time.monotonic()

    async def key(self, game: Game, key: str, seq: int, t_client: float) -> str | None:
        problem = game.press(key, seq, t_client)
        if problem is None and game.mode == Mode.TURN:
            await self.step_games([game])
        return problem

    # ------------------------------------------------------------ stepping
    async def step_games(self, games: list[Game]) -> None:
        """Advance ``games`` one step: one batched follower call per pool, then the env steps."""
        async with self.lock:
            games = [g for g in games if g.ready() and g.game_id in self.games]
            by_pool: dict[int, list[Game]] = {}
            for g in games:
                by_pool.setdefault(id(g.pool), []).append(g)
            for group in by_pool.values():
                pool = group[0].pool
                inputs = [g.follower_input() for g in group]
                slots = [g.slot for g in group]
                actions, beliefs, missed = await self._infer(pool, inputs, slots)
                for i, g in enumerate(group):
                    belief = beliefs[i] if beliefs is not None else (np.array(g.beliefs[-1]) if g.beliefs else None)
                    g.apply(int(actions[i]), belief, missed)
            for g in games:
                await self._send(g, g.state_message())
                if g.finished:
                    await self.finish(g, "complete")  # never raises: one game's failure is its own

    async def _infer(self, pool: FollowerPool, inputs, slots):
        """Run the pool within the deadline; on a miss, fall back to idle moves and say so."""
        deadline = self.settings.inference_deadline_ms / 1000.0
        if not pool.busy:
            loop = asyncio.get_running_loop()
            future = loop.run_in_executor(self.executor, pool.act, inputs, slots)
            try:
                actions, beliefs = await asyncio.wait_for(asyncio.shield(future), deadline)
                return actions, beliefs, False
            except asyncio.TimeoutError:
                pass
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
                    if g.mode == Mode.REALTIME and g.tick_hz == tick_hz and g.disconnected_at is None]
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
        """End games abandoned past the rejoin grace or idle too long, and free follower pools nobody uses."""
        now = time.monotonic()
        for game in list(self.games.values()):
            if game.disconnected_at is not None and now - game.disconnected_at > self.settings.rejoin_grace_s:
                await self.finish(game, "disconnected")
            elif now - game.last_key_at > self.settings.idle_timeout_s:
                await self.finish(game, "idle")
        for key, pool in list(self.pools.items()):
            if key[0] not in self.keep_warm and pool.idle_for() > POOL_IDLE_S:
                del self.pools[key]

    # ------------------------------------------------------------ ending
    async def finish(self, game: Game, reason: str) -> None:
        """Save the game's replay (atomically) and tell the player; idempotent, and never raises:
        a game that cannot be saved is logged and counted, and its player still gets ``game_over``."""
        if self.games.pop(game.game_id, None) is None:
            return
        game.finished = True
        game.pool.release(game.slot)
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
        client = self.clients.pop(game.game_id, None)
        if client is not None:
            s = game.env.state
            await self._send_to(client, {
                "type": "game_over", "reason": reason, "replay_id": game.replay_id, "steps": int(s.t[0]),
                "scores": scores(s, game.env.config),
            })

    async def _save(self, game: Game, reason: str) -> None:
        stamp = time.strftime("%Y%m%dT%H%M%S", time.gmtime(game.created))
        replay_id = f"play-{stamp}-{game.game_id}"
        replay = game.to_replay("complete" if reason == "complete" else reason,
                                describe_agent(game.pool.policy.describe(),
                                               game.follower if game.follower.endswith(".pt") else None))
        # Written (atomically, fsynced) on a worker thread so saving never stalls the tick.
        path = Path(self.settings.replays_dir) / f"{replay_id}.replay.json"
        await asyncio.get_running_loop().run_in_executor(self.saver, save, replay, path)
        game.replay_id = replay_id
        self.stats["games_saved"] += 1

    async def _send(self, game: Game, message: dict) -> None:
        client = self.clients.get(game.game_id)
        if client is not None:
            await self._send_to(client, message)

    @staticmethod
    async def _send_to(client: Client, message: dict) -> None:
        try:
            await client.send(message)
        except Exception:  # a closed socket: the disconnect handler takes care of the game
            pass


def secrets_equal(a: str, b: str) -> bool:
    import hmac

    return hmac.compare_digest(a.encode(), b.encode())
