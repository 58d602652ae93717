"""The clock: real-time games step together on one tick per rate, each step one batched call per policy pool
within the inference deadline (a miss takes the fallback move and is recorded); the tick's lateness is measured."""

from __future__ import annotations

import asyncio
import logging
import time

from colorgrid.enums import Ending
from server.followers import PolicyPool
from server.game import Game
from server.inference import InferenceLost
from server.play.ending import Finisher
from server.play.live import Live
from server.play.pools import Pools
from server.protocol import Mode

log = logging.getLogger("colorgrid.server")
LATE_TICK_MS = 20  # a tick this late counts in ``late_ticks``
WARN_LATE_TICK_MS = 50  # a tick this late is logged
LATENESS_KEPT = 5000  # the last ticks whose lateness ``/api/health`` reports percentiles of


class Clock:
    """Steps games: on a tick per rate in use (real time), or when a turn-based game's people have all moved."""

    def __init__(self, live: Live, pools: Pools, finisher: Finisher):
        self.live, self.pools, self.finisher = live, pools, finisher
        self.lateness_ms: list[float] = []  # the last ``LATENESS_KEPT`` ticks' lateness
        self._ticks: dict[float, asyncio.Task] = {}  # tick_hz -> its tick loop

    def run(self, tick_hz: float) -> None:
        """Make sure real-time games at ``tick_hz`` have a clock (one per rate in use; studies may vary it)."""
        if tick_hz not in self._ticks:
            self._ticks[tick_hz] = asyncio.create_task(self._tick_loop(tick_hz))

    def stop(self) -> None:
        """Stop every tick loop."""
        for task in self._ticks.values():
            task.cancel()

    async def step_games(self, games: list[Game]) -> None:
        """Advance ``games`` one step: one batched call per pool (every AI player of these games that the pool
        plays), then each game's env steps."""
        async with self.live.lock:
            games = [g for g in games if g.ready() and g.game_id in self.live.games]
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
                await self.live.send(g, g.state_message())
                if g.finished and g.mode == Mode.REALTIME:
                    self.finisher.after_late_keys(g)
                elif g.finished:
                    await self.finisher.finish(g, Ending.COMPLETE)  # never raises: one game's failure is its own

    async def _infer(self, pool: PolicyPool, inputs, slots):
        """Run the pool within the deadline; on a miss, fall back to idle moves and say so."""
        deadline = self.live.settings.inference_deadline_ms / 1000.0
        if pool.pending is None or pool.pending.done():
            loop = asyncio.get_running_loop()
            future = pool.pending = loop.run_in_executor(self.pools.executor, pool.act, inputs, slots)
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
        self.live.stats["deadline_misses"] += len(slots)
        log.warning("follower %s missed its %.0f ms deadline for %d game(s)", pool.name, deadline * 1000, len(slots))
        return pool.fallback(inputs, slots), None, True

    async def _tick_loop(self, tick_hz: float) -> None:
        period = 1.0 / tick_hz
        next_tick = time.perf_counter() + period
        while True:
            await asyncio.sleep(max(0.0, next_tick - time.perf_counter()))
            lateness = (time.perf_counter() - next_tick) * 1000.0
            games = self.live.games
            live = [g for g in games.values() if g.mode == Mode.REALTIME and g.tick_hz == tick_hz and not g.paused]
            if live:  # lateness matters to games: ticks with none to step are not counted
                self._record_lateness(lateness)
            if live and lateness > WARN_LATE_TICK_MS:
                log.warning("tick %.0f ms late (%d real-time games, %d games in all)", lateness, len(live), len(games))
            if live:
                try:
                    await self.step_games(live)
                except Exception:  # a bug in one tick must not stop every game
                    log.exception("tick failed")
            next_tick += period
            if time.perf_counter() > next_tick + period:  # fell far behind: skip, do not burst
                next_tick = time.perf_counter() + period

    def _record_lateness(self, ms: float) -> None:
        stats = self.live.stats
        stats["ticks"] += 1
        stats["late_ticks"] += ms > LATE_TICK_MS
        stats["max_lateness_ms"] = max(stats["max_lateness_ms"], ms)
        self.lateness_ms.append(ms)
        del self.lateness_ms[:-LATENESS_KEPT]
