"""The end of a game: saved as a replay (atomically, off the event loop), its listeners told, its people sent
``game_over``; a real-time game first takes the keys still on their way (``LATE_KEYS_S``)."""

from __future__ import annotations

import asyncio
import logging
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Protocol

from colorgrid.enums import Ending
from colorgrid.replay import Replay, save
from colorgrid.replay.human_follower import person_measures, scored_probes
from colorgrid.roles import scores
from server.game import Game
from server.messages import GameOver
from server.play.live import Live

log = logging.getLogger("colorgrid.server")
LATE_KEYS_S = 0.3
"""After a real-time game's last step, how long its keys still on their way are taken (logged ``unapplied``) before it
is saved and its people told ``game_over``: a held key repeats every ~33 ms, and a page learns of the end a network
trip late. (A turn-based game ends on a key of its own: it is saved at once.)"""


class GameListener(Protocol):
    """Told of each game's start and end (a study records its participants' games); both run on the saver thread."""

    def game_started(self, game: Game) -> None:
        """``game`` is about to be shown to its people; raising refuses it (its people are told why)."""

    def game_over(self, game: Game, reason: Ending, scores: dict) -> None:
        """``game`` ended for ``reason`` with ``scores`` (``colorgrid.roles.scores``), after it was saved."""


def game_over_message(game: Game, reason: Ending, replay_id: str | None) -> GameOver:
    """The ``game_over`` that tells a person the game ended (for them, with reason ``left``); in the follower seat,
    once saved, with what the person said beside the goal's history (``stated``)."""
    s = game.env.state
    stated = {} if game.stated_record is None else {"stated": game.stated_record}
    return GameOver(type="game_over", reason=reason, replay_id=replay_id, steps=int(s.t[0]),
                    scores=scores(s, game.env.config), **stated)


def stated_record(replay: Replay, agent: str) -> dict:
    """The ``game_over``'s ``stated`` of the person in ``agent``'s follower seat: the goal and the stated color at each
    step, the scored probes, and the person's measures (``person_measures``: the same as rescore's)."""
    m = person_measures(replay, agent)
    return {"goal": list(replay.goal), "stated": list(replay.stated_beliefs[agent]),
            "probes": scored_probes(replay, agent),
            **{name: m[name] for name in ("steps", "stated_steps", "accuracy", "probes_asked", "probes_answered",
                                          "probe_accuracy")}}


class Finisher:
    """Ends games: each is saved, its listeners told, its people sent ``game_over``."""

    def __init__(self, live: Live):
        self.live = live
        self.saver = ThreadPoolExecutor(max_workers=1, thread_name_prefix="replay-saver")
        self.listeners: list[GameListener] = []
        self._late_keys: set[asyncio.Task] = set()  # games waiting out LATE_KEYS_S before they are saved

    async def started(self, game: Game) -> None:
        """Tell the listeners ``game`` starts (before its people see it); one that raises refuses it."""
        for listener in self.listeners:
            await asyncio.get_running_loop().run_in_executor(self.saver, listener.game_started, game)

    def after_late_keys(self, game: Game) -> None:
        """Real-time ``game`` made its last step: keys still on their way are logged ``unapplied`` for ``LATE_KEYS_S``,
        then it is saved and its people told ``game_over`` (off the tick: no other game waits for it)."""
        self.live.games.pop(game.game_id, None)
        self.live.finishing[game.game_id] = game

        async def end() -> None:
            await asyncio.sleep(LATE_KEYS_S)
            await self.finish(game, Ending.COMPLETE)  # never raises: one game's failure is its own

        task = asyncio.get_running_loop().create_task(end())
        self._late_keys.add(task)
        task.add_done_callback(self._late_keys.discard)

    async def finish(self, game: Game, reason: Ending) -> None:
        """Save the game's replay (atomically) and tell its people; idempotent, and never raises:
        a game that cannot be saved is logged and counted, and its people still get ``game_over``."""
        live = self.live
        if live.games.pop(game.game_id, None) is None and live.finishing.pop(game.game_id, None) is None:
            return
        game.finished = True
        descriptions = None
        if game.actions:
            try:  # before the slots are given back (on the saver thread: it may ask the inference process)
                descriptions = await asyncio.get_running_loop().run_in_executor(self.saver, game.describe_ai)
            except Exception:
                live.stats["save_failures"] += 1
                log.exception("could not describe the AI players of game %s (%s)", game.game_id, reason)
        game.release_slots()
        if descriptions is not None:
            try:
                await self._save(game, reason, descriptions)
            except Exception:
                live.stats["save_failures"] += 1
                log.exception("could not save game %s (%s)", game.game_id, reason)
        for listener in self.listeners:
            try:
                await asyncio.get_running_loop().run_in_executor(self.saver, listener.game_over, game, reason,
                                                                 scores(game.env.state, game.env.config))
            except Exception:
                log.exception("a listener failed on the end of game %s", game.game_id)
        await live.send(game, game_over_message(game, reason, game.replay_id))

    async def _save(self, game: Game, reason: Ending, descriptions: dict[int, dict]) -> None:
        stamp = time.strftime("%Y%m%dT%H%M%S", time.gmtime(game.created))
        replay_id = f"play-{stamp}-{game.game_id}"
        replay = game.to_replay(reason, descriptions)
        # Written (atomically, fsynced) on a worker thread so saving never stalls the tick.
        path = Path(self.live.settings.replays_dir) / f"{replay_id}.replay.json"
        await asyncio.get_running_loop().run_in_executor(self.saver, save, replay, path)
        game.replay_id = replay_id
        if game.stated is not None:
            game.stated_record = stated_record(replay, game.stated.agent)
        self.live.stats["games_saved"] += 1

    def cancel_waits(self) -> None:
        """At shutdown: stop waiting for late keys (``finish_complete`` then saves those games at once)."""
        for task in self._late_keys:
            task.cancel()

    async def finish_complete(self) -> None:
        """Save the games past their last step as complete, without waiting for their late keys."""
        for game in list(self.live.finishing.values()):
            await self.finish(game, Ending.COMPLETE)

    def close(self) -> None:
        """Wait for the replays being written."""
        self.saver.shutdown(wait=True)
