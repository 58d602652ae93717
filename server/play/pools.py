"""Policy pools (AI followers, AI leaders, stand-ins): built on the inference thread, warmed and timed at start-up,
freed when no game uses them.

One pool serves one policy at one agent index of one config, for every live game that plays it, in one batched call
(``server.followers.PolicyPool``); every pool's policy runs in the inference process (``server.inference``).
"""

from __future__ import annotations

import asyncio
import dataclasses
import gc
import logging
from concurrent.futures import ThreadPoolExecutor
from enum import StrEnum
from functools import partial

from colorgrid.config import FOLLOWER, LEADER, EnvConfig
from colorgrid.enums import Role, SeatFit
from server.followers import PolicyPool, is_scripted
from server.inference import InferenceLost, InferenceWorker
from server.play.offer import Offer, make_config
from server.protocol import GameRequest, Mode, Team
from server.seats import leader_seats
from server.settings import ServerSettings

log = logging.getLogger("colorgrid.server")
POOL_IDLE_S = 120.0  # a policy pool with no game for this long is freed (the default follower's stay)


class Warmed(StrEnum):
    """The seats a pool is warmed for at start-up (``Pools.warm_seats``)."""

    FOLLOWER = "follower"  # every AI follower of a team
    LEADER = "leader"  # the AI leaders beside a person in a team of several leaders
    LEADER_OF_A_PERSON = "lead a person"  # every leader, beside a person in the follower seat


class Pools:
    """This process's policy pools (``by_key``), the thread that waits on them and the inference process that runs
    them.

    Pools of ``kept_kinds`` are never freed: the default follower's, and the trained followers' and AI leaders'
    (building one again would stall the inference thread)."""

    def __init__(self, settings: ServerSettings, offer: Offer, stats: dict):
        self.settings, self.offer, self.stats = settings, offer, stats
        self.by_key: dict[tuple, PolicyPool] = {}  # (kind, config, agent index) -> its pool
        self._loading: dict[tuple, asyncio.Future] = {}
        self.ready = False  # the default follower and the compiled env step are loaded
        self.executor = ThreadPoolExecutor(max_workers=1, thread_name_prefix="follower")  # waits on the worker
        self.inference = InferenceWorker()  # every pool's policy runs in this process, away from the GIL here
        self.warmed_followers = {settings.follower, *(f for f in settings.follower_choices if not is_scripted(f))}
        self.kept_kinds = {*self.warmed_followers, *(kind for kind in settings.leaders if not is_scripted(kind))}

    async def pool_for(self, follower: str, config: EnvConfig, agent_index: int = FOLLOWER) -> PolicyPool:
        """The pool for this follower, config and agent index, built on the inference thread (loading never
        blocks the loop)."""
        key = (follower, config, agent_index)
        if key in self.by_key:
            return self.by_key[key]
        loading = self._loading.get(key)
        if loading is None:  # the first game to ask builds it; games arriving meanwhile wait for the same one
            loading = asyncio.get_running_loop().run_in_executor(
                self.executor, partial(PolicyPool, follower, config, self.settings.max_sessions,
                                       agent_index=agent_index, worker=self.inference))
            self._loading[key] = loading
        try:
            pool = await asyncio.shield(loading)
        finally:
            if loading.done():
                self._loading.pop(key, None)
        self.by_key.setdefault(key, pool)
        return self.by_key[key]

    async def seat_pool(self, kind: str, config: EnvConfig, agent: int) -> tuple[PolicyPool, tuple[int, int] | None]:
        """The pool that plays ``kind`` at agent ``agent`` of ``config``, and the agents it sees when it sees the game
        as a 1:1 game (``SeatFit.PAIR_VIEW``: a network trained in 1:1 in a leader seat of a larger team; its pool is
        built for the 1:1 team's leader), else None."""
        fit = self.offer.leader_fit(kind, Team(config.team)) if config.roles[agent] == Role.LEADER else None
        if fit == SeatFit.PAIR_VIEW:
            pair = dataclasses.replace(config, num_leaders=1, num_followers=1)
            return await self.pool_for(kind, pair, LEADER), (agent, *config.followers)
        return await self.pool_for(kind, config, agent), None

    # ------------------------------------------------------------ warmed at start-up
    async def warm_up(self) -> None:
        """Load the default follower, and every offered trained follower and AI leader, for both modes before the
        first player waits on it: a trained network's first call pays for loading torch and the weights, and a
        pool is built on the inference thread, where games must not wait for it. Each trained one's call is then
        timed (``time_calls``)."""
        loop = asyncio.get_running_loop()
        timed = set()
        for kind, team, role in self.warm_seats():
            for mode in Mode:
                config = make_config(GameRequest(mode=mode, team=team), self.settings.preset)
                agents = (config.followers if role == Warmed.FOLLOWER else config.leaders
                          if role == Warmed.LEADER_OF_A_PERSON else leader_seats(config, config.num_leaders - 1)[1])
                try:
                    for agent in agents:
                        pool, _ = await self.seat_pool(kind, config, agent)
                        await loop.run_in_executor(self.executor, pool.warm_up)
                    if kind not in timed and not is_scripted(kind):
                        timed.add(kind)
                        await loop.run_in_executor(self.executor, self.time_calls, pool)
                except Exception as err:
                    if role != Warmed.FOLLOWER and not isinstance(err, InferenceLost):  # one that cannot lead is not offered
                        log.error("AI leader %s is not offered in team %s: %s", kind, team.value, err)
                        self.offer.withdraw_leader(kind, team)
                        break
                    log.exception("could not warm up %s %s", role, kind)  # a game asking for it is told why
        gc.freeze()  # what start-up loaded (torch, the networks) is left out of later collections
        self.ready = True

    def warm_seats(self) -> list[tuple[str, Team, Warmed]]:
        """``(kind, team, role)`` of the pools made at start-up: the default follower first (in 1:1 when it is
        scripted), each trained follower in each team it plays, each trained AI leader in each team it leads."""
        seats = []
        for follower in sorted(self.warmed_followers, key=lambda f: f != self.settings.follower):
            teams = ([Team.ONE_TO_ONE] if is_scripted(follower)
                     else [t for t in Team if follower in self.offer.team_followers(t)])
            seats += [(follower, team, Warmed.FOLLOWER) for team in teams]
        for leader in self.kept_kinds - self.warmed_followers:
            seats += [(leader, team, Warmed.LEADER) for team in Team if leader in self.offer.team_leaders(team)]
            seats += [(leader, team, Warmed.LEADER_OF_A_PERSON) for team in Team
                      if leader in self.offer.seat_leaders(team)]
        return seats

    def time_calls(self, pool: PolicyPool) -> None:
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

    # ------------------------------------------------------------ freed
    def free_idle(self) -> None:
        """Free the pools no game has used for ``POOL_IDLE_S`` (but never those of ``kept_kinds``)."""
        for key, pool in list(self.by_key.items()):
            if key[0] not in self.kept_kinds and pool.idle_for() > POOL_IDLE_S:
                del self.by_key[key]
                self.executor.submit(pool.close)  # queued behind inference; the sweep does not wait for it

    async def close(self) -> None:
        """Stop the inference thread (dropping what waits on it) and the inference process."""
        self.executor.shutdown(wait=False, cancel_futures=True)
        await asyncio.get_running_loop().run_in_executor(None, self.inference.stop)
