"""The game hub in-process (real games, pools, files): one game's failure is its own, the sweeper
outlives bugs, unused follower pools are freed, the key log is capped."""

import asyncio
import time

import pytest

from colorgrid.replay import load, verify
from server.play import pools as hub_module
from server.play.hub import GameHub
from server.protocol import GameRequest
from server.settings import ServerSettings
from tests.helpers import Inbox, until


def make_hub(tmp_path, **changes) -> GameHub:
    return GameHub(ServerSettings(replays_dir=tmp_path, follower="copy", **changes))


async def start(hub, follower=None, horizon=20):
    client = Inbox()
    game = await hub.new_game(GameRequest(follower=follower, mode="turn", horizon=horizon), client)
    return game, client


def test_a_game_that_cannot_be_saved_costs_no_other_game(tmp_path, caplog):
    async def scenario():
        hub = make_hub(tmp_path)
        (broken, broken_client), (good, good_client) = await start(hub), await start(hub)
        for game in (broken, good):
            await hub.key(game, "ArrowUp", 0, 0.0)

        def fail(*args, **kwargs):
            raise RuntimeError("a bug while building the replay")

        broken.to_replay = fail
        await hub.stop()
        return hub, broken_client, good_client

    hub, broken_client, good_client = asyncio.run(scenario())
    assert hub.stats["save_failures"] == 1 and hub.stats["games_saved"] == 1
    assert "could not save game" in caplog.text
    assert broken_client.last("game_over")["replay_id"] is None  # told, even though it was not saved
    over = good_client.last("game_over")
    assert over["reason"] == "server_shutdown"
    assert verify(load(tmp_path / f"{over['replay_id']}.replay.json")).ok


def test_the_sweeper_outlives_an_exception_and_still_saves_abandoned_games(tmp_path, monkeypatch):
    async def scenario():
        hub = make_hub(tmp_path, rejoin_grace_s=0.1)
        game, client = await start(hub)
        await hub.key(game, "ArrowUp", 0, 0.0)
        hub.disconnect(game, client)
        real, calls = hub.sweep, []

        async def flaky():
            calls.append(1)
            if len(calls) == 1:
                raise RuntimeError("a bug in one sweep")
            await real()

        hub.sweep = flaky
        hub._tasks = [asyncio.create_task(hub._sweep_loop())]
        await until(lambda: hub.stats["games_saved"] == 1)  # the sweeper runs every second
        await hub.stop()
        return hub, calls

    hub, calls = asyncio.run(scenario())
    assert len(calls) >= 2 and not hub.games
    saved = list(tmp_path.glob("*.replay.json"))
    assert len(saved) == 1 and load(saved[0]).ended == "disconnected"


def test_follower_pools_nobody_uses_are_freed_but_the_default_stays(tmp_path):
    async def scenario():
        hub = make_hub(tmp_path)
        for follower in ("copy", "bayes"):
            game, _ = await start(hub, follower)
            await hub.finish(game, "quit")
        assert len(hub.pools.by_key) == 2
        await hub.sweep()
        assert len(hub.pools.by_key) == 2  # just used: kept
        for pool in hub.pools.by_key.values():
            pool.last_release -= hub_module.POOL_IDLE_S + 1
        busy, _ = await start(hub, "oracle")
        list(hub.pools.by_key.values())[-1].last_release -= hub_module.POOL_IDLE_S + 1  # idle long, but a game runs
        await hub.sweep()
        kept = sorted(key[0] for key in hub.pools.by_key)
        await hub.stop()
        return kept

    assert asyncio.run(scenario()) == ["copy", "oracle"]


def test_the_key_log_is_capped_and_the_dropped_keys_are_counted(tmp_path):
    async def scenario():
        hub = make_hub(tmp_path, max_key_log=3)
        game, client = await start(hub, horizon=5)
        for seq in range(5):
            await hub.key(game, ["ArrowUp", "ArrowLeft"][seq % 2], seq, 0.0)
        return client

    client = asyncio.run(scenario())
    over = client.last("game_over")
    replay = load(tmp_path / f"{over['replay_id']}.replay.json")
    assert verify(replay).ok and replay.num_steps == 5  # every key still moved the leader
    assert [e["seq"] for e in replay.key_events] == [0, 1, 2]
    assert replay.meta["key_events_dropped"] == 2


@pytest.mark.parametrize("changes, words", [
    ({"max_connections": 0}, "max_connections must be a positive integer"),
    ({"connection_idle_s": float("nan")}, "connection_idle_s must be a finite number > 0"),
    ({"allowed_origins": ("",)}, "allowed_origins must be a tuple of non-empty strings"),
    ({"idle_timeout_s": float("inf")}, "idle_timeout_s must be a finite number > 0"),
    ({"first_seed": -1}, r"first_seed must be an integer in \[0, 2147483647\] \(0: from the clock\)"),
])
def test_settings_refuse_what_would_break_the_server(changes, words):
    with pytest.raises(ValueError, match=words):
        ServerSettings(**changes)


def test_inference_runs_in_its_own_process_and_a_killed_one_costs_one_step_not_the_game(tmp_path):
    """The follower's policy lives in the inference process (not this one); kill -9 it mid-game: that step takes
    the documented fallback move (a recorded deadline miss), the next starts a new process with the follower
    built afresh, and the game plays to the end and verifies."""
    import os
    import signal

    async def scenario():
        hub = make_hub(tmp_path, inference_deadline_ms=30_000)  # only the dead process may cost a move, not load
        game, client = await start(hub, "bayes", horizon=12)
        first = hub.inference.pid
        assert first is not None and first != os.getpid()
        for t in range(4):
            await hub.key(game, "ArrowRight", t, 0.0)
        os.kill(first, signal.SIGKILL)
        await until(lambda: not hub.inference._process.is_alive())  # gone for its parent too
        await hub.key(game, "ArrowLeft", 4, 0.0)  # finds it dead: the fallback move, and a new process starts
        assert hub.inference.generation == 2 and hub.inference._process.is_alive()  # started by that call
        # time passes while it loads (steps meanwhile would take the fallback move too): wait until it answers
        await asyncio.get_running_loop().run_in_executor(hub.executor, hub.inference.call, "ping")
        for t in range(5, 12):
            await hub.key(game, "ArrowLeft" if t % 2 else "ArrowDown", t, 0.0)
        second = hub.inference.pid
        await hub.stop()
        return hub, game, client, first, second

    hub, game, client, first, second = asyncio.run(scenario())
    over = client.last("game_over")
    assert over["reason"] == "complete" and over["steps"] == 12
    assert second != first and hub.inference.generation == 2
    assert game.deadline_misses == [4] and hub.stats["deadline_misses"] == 1
    replay = load(tmp_path / f"{over['replay_id']}.replay.json")
    assert verify(replay).ok and replay.agents["follower"]["policy"] == "bayes"
    assert replay.meta["deadline_misses"] == [4]


def test_a_follower_that_misses_its_first_step_starts_its_belief_uniform_and_keeps_a_row_a_step(tmp_path):
    """Kill the inference process before the first step: that step's move is the fallback and the follower has no
    belief yet, so its belief is the uniform one it starts from; the replay keeps a belief for every step (a
    loaded machine that misses the first deadline lost the whole belief track before)."""
    import os
    import signal

    async def scenario():
        hub = make_hub(tmp_path, inference_deadline_ms=30_000)  # only the dead process may cost a move, not load
        game, client = await start(hub, "bayes", horizon=6)
        os.kill(hub.inference.pid, signal.SIGKILL)
        await until(lambda: not hub.inference._process.is_alive())
        await hub.key(game, "ArrowRight", 0, 0.0)  # the fallback move, with no belief of its own
        first_state = client.last("state")
        await asyncio.get_running_loop().run_in_executor(hub.executor, hub.inference.call, "ping")
        for t in range(1, 6):
            await hub.key(game, "ArrowLeft" if t % 2 else "ArrowDown", t, 0.0)
        await hub.stop()
        return game, client, first_state

    game, client, first_state = asyncio.run(scenario())
    over = client.last("game_over")
    assert over["reason"] == "complete" and game.deadline_misses == [0]
    third = pytest.approx([1 / 3] * 3, abs=1e-5)  # beliefs are kept to 5 decimals
    assert first_state["belief"] == third  # the page shows it from the first step
    replay = load(tmp_path / f"{over['replay_id']}.replay.json")
    beliefs = replay.goal_probs["follower"]
    assert len(beliefs) == 6 and beliefs[0] == third
    assert all(sum(b) == pytest.approx(1.0, abs=1e-4) for b in beliefs)


def test_a_follower_without_a_belief_gets_none_for_a_missed_step(tmp_path):
    """The copy follower holds no belief: a missed step gives it none (not a made-up uniform one)."""
    import os
    import signal

    async def scenario():
        hub = make_hub(tmp_path, inference_deadline_ms=30_000)
        game, client = await start(hub, "copy", horizon=2)
        if hub.inference.pid is not None:
            os.kill(hub.inference.pid, signal.SIGKILL)
            await until(lambda: not hub.inference._process.is_alive())
        for t in range(2):
            await hub.key(game, "ArrowRight", t, 0.0)
        await hub.stop()
        return client

    client = asyncio.run(scenario())
    over = client.last("game_over")
    assert client.last("state")["belief"] is None
    assert "follower" not in load(tmp_path / f"{over['replay_id']}.replay.json").goal_probs


def test_an_inference_process_that_cannot_start_is_tried_again_after_a_growing_wait():
    """Not spawned again on every call (each spawn costs a second of CPU): calls fail at once while it waits."""
    from server.inference import InferenceLost, InferenceWorker
    from tests.helpers import dies_at_start

    patient = InferenceWorker(target=dies_at_start, backoff=60.0)
    with pytest.raises(InferenceLost, match="ended during 'ping'"):
        patient.call("ping")
    for _ in range(5):
        with pytest.raises(InferenceLost, match=r"failed to start 1 time\(s\) in a row; next try in"):
            patient.call("ping")
    assert patient.generation == 1 and patient.pid is None  # one process, and none since
    patient.stop()

    now = [0.0]
    eager = InferenceWorker(target=dies_at_start, backoff=0.05, clock=lambda: now[0])
    for tries in (1, 2):
        with pytest.raises(InferenceLost, match="ended during 'ping'"):
            eager.call("ping")
        assert eager.generation == tries and eager.failed_starts == tries
        with pytest.raises(InferenceLost, match=r"next try in 0\.[01] s"):  # its wait (0.05 s, then 0.1 s) not over
            eager.call("ping")
        now[0] += 0.11  # its clock past that wait
    eager.stop()

    capped = InferenceWorker(target=dies_at_start, backoff=0.5)
    capped.failed_starts = 5000  # hours of failed starts: the wait stays at its cap, and the doubling never overflows
    with pytest.raises(InferenceLost, match="ended during 'ping'"):
        capped.call("ping")
    with pytest.raises(InferenceLost, match=r"5001 time\(s\) in a row; next try in (59|60)\.\d s"):
        capped.call("ping")
    capped.stop()

    healthy = InferenceWorker(backoff=60.0)  # the real process answers: nothing to wait for
    assert healthy.call("ping") is None and healthy.failed_starts == 0
    healthy.stop()


def test_a_follower_that_cannot_be_built_is_refused_with_its_reason_and_the_process_serves_on(tmp_path):
    async def scenario():
        hub = make_hub(tmp_path)
        with pytest.raises(ValueError, match="unknown policy 'nosuch'"):
            await hub.pool_for("nosuch", hub.make_config(GameRequest(mode="turn", horizon=10), "default"))
        game, client = await start(hub, "copy", horizon=3)
        for t in range(3):
            await hub.key(game, "ArrowUp", t, 0.0)
        await hub.stop()
        return hub, client

    hub, client = asyncio.run(scenario())
    assert client.last("game_over")["reason"] == "complete" and hub.inference.generation == 1


def test_a_first_seed_fixes_the_games_boards_and_each_later_game_gets_the_next(tmp_path):
    async def scenario(first_seed):
        hub = make_hub(tmp_path / str(first_seed), first_seed=first_seed)
        games = [(await start(hub))[0] for _ in range(2)]
        boards = [game.env.state.block_cell.copy() for game in games]
        await hub.stop()
        return [game.seed for game in games], boards

    seeds, boards = asyncio.run(scenario(2026))
    again, same_boards = asyncio.run(scenario(2026))
    assert seeds == again == [2026, 2027]
    assert all((a == b).all() for a, b in zip(boards, same_boards)) and not (boards[0] == boards[1]).all()
    clock_seeds, _ = asyncio.run(scenario(0))
    assert abs(clock_seeds[0] - time.time()) < 600 and clock_seeds[1] == clock_seeds[0] + 1
